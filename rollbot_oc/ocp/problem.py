"""An optimal-control problem written like the math: states, controls, costs, constraints, free or fixed time.

::

    ocp = OCP(model, N=40, T=FreeTime(guess=4.0))   # model: an OCPModel (the dynamics and their names)
    x, u, P = ocp.state, ocp.control, ocp.params    # named parts, by the model's names
    goal = ocp.parameter("goal", 2)
    ocp.initial_state()                             # x(0) = parameter "x0"
    ocp.minimize_time()
    ocp.add_cost(1e-3 * u.a**2)                     # integral over the horizon
    ocp.subject_to(bounded(-1, u.a, 1))             # a path constraint
    ocp.subject_to(x.s == goal, at="end")
    solution = ocp.solver("ipopt").solve(x0=z0, goal=1.0, p=model_parameters)

Expressions are CasADi SX in the symbols of one stage: ``ocp.x`` (states),
``ocp.u`` (controls), ``ocp.p`` (model parameters), the problem's own
parameters (``ocp.parameter``), stage parameters, which take a value at
every node (``ocp.stage_parameter``: a reference to track, time-varying
weights), and global decision variables (``ocp.variable``).  Where a term applies is ``at``: ``"path"`` (every
interval, and for terms without controls also the last node), ``"start"``,
``"end"``, ``("end", phase)`` (the last node of a phase) or a node index.

Phases.  ``N`` and ``T`` may be sequences: the horizon is a chain of phases,
each with its own number of intervals and its own (fixed or free) duration,
joined by continuity of the state; a multi-stop motion plans every leg with
one problem.

Every route (``ocp.solver(name)``) solves this one description; see
``rollbot_oc.ocp.routes``.  The layer knows a system only through the model it is given; Rollbot's model,
its named limits and ``rollbot_ocp`` (an ``OCP`` of Rollbot) are in ``rollbot_oc.planning.rollbot``.
"""

from __future__ import annotations

import math

import casadi as ca
import numpy as np

from rollbot_oc.core.errors import ConfigError
from rollbot_oc.ocp.model import OCPModel
from rollbot_oc.ocp.routes import make_route
from rollbot_oc.ocp.terms import Constraint, FreeTime, _from_relation, bounded
from rollbot_oc.ocp.transcription import Transcription

__all__ = ["OCP", "FreeTime", "Constraint", "bounded"]


_PLACES = ("path", "start", "end")


def _check_place(at, n_phases: int):
    if at in _PLACES:
        return at
    if isinstance(at, tuple) and len(at) == 2 and at[0] == "end" and isinstance(at[1], int) \
            and 0 <= at[1] < n_phases:
        return at
    if isinstance(at, int) and not isinstance(at, bool):
        return at
    raise ConfigError(f"at = {at!r}; valid are 'path', 'start', 'end', ('end', phase in 0..{n_phases - 1}) "
                      "or a node index")


class OCP:
    """An optimal-control problem over a chain of phases (see module doc).

    Parameters
    ----------
    model : OCPModel
        The dynamics, with the names of the states, controls and parameters.
    N : int or sequence of int
        Shooting intervals of each phase.
    T : float, FreeTime, or a sequence of them
        Duration of each phase, s: fixed (a number) or free (``FreeTime``).
    substeps : int
        RK4 steps per shooting interval.
    """

    def __init__(self, model: OCPModel, N=40, T=None, substeps: int = 2):
        if not isinstance(model, OCPModel):
            raise ConfigError(f"OCP: model = {model!r} must be an OCPModel (the dynamics and the names of its "
                              "states, controls and parameters)")
        self.model = model
        Ns = tuple(N) if isinstance(N, (list, tuple)) else (N,)
        Ts = tuple(T) if isinstance(T, (list, tuple)) else (T if T is not None else FreeTime(),) * len(Ns)
        if len(Ts) != len(Ns):
            raise ConfigError(f"OCP: {len(Ns)} phases in N but {len(Ts)} durations in T")
        for n in Ns:
            if not (isinstance(n, int) and n >= 1):
                raise ConfigError(f"OCP: N = {n!r} must be a whole number of intervals >= 1")
        for t in Ts:
            if not isinstance(t, FreeTime) and not (isinstance(t, (int, float)) and 0 < t < math.inf):
                raise ConfigError(f"OCP: T = {t!r} must be a duration > 0 s or FreeTime(...)")
        if not (isinstance(substeps, int) and substeps >= 1):
            raise ConfigError(f"OCP: substeps = {substeps!r} must be a whole number >= 1")
        self.N, self.durations, self.substeps = Ns, Ts, substeps
        m = self.model
        self.x = ca.SX.sym("x", m.nx)
        self.u = ca.SX.sym("u", m.nu)
        self.p = ca.SX.sym("p", m.np)
        self.state = m.named_states(self.x)
        self.control = m.named_controls(self.u)
        self.params = m.named_parameters(self.p)
        self.parameters: dict[str, ca.SX] = {}
        self.stage_parameters: dict[str, ca.SX] = {}
        self.fixed_start = False  # x(0) given (``initial_state``)
        self.variables: dict[str, tuple] = {}  # name -> (symbol, lower, upper, guess)
        self.costs: list[tuple] = []           # (kind, expression, at)
        self.constraints: list[tuple] = []     # (Constraint, at)
        self.time_weight = 0.0

    # -- declarations ---------------------------------------------------------------------------
    @property
    def phases(self) -> int:
        """Number of phases."""
        return len(self.N)

    def parameter(self, name: str, n: int = 1) -> ca.SX:
        """A named problem parameter of ``n`` entries, given at solve time (``solve(name=value)``)."""
        self._check_new_parameter(name)
        self.parameters[name] = ca.SX.sym(name, n)
        return self.parameters[name]

    def stage_parameter(self, name: str, n: int = 1) -> ca.SX:
        """A named parameter of ``n`` entries with a value at every node, given at solve time.

        In a stage's expressions it stands for its value at that stage's node
        (on the path: at the interval's first node).  ``solve(name=values)``
        takes an array ``(n, N+1)`` (one column per node) or ``(n,)`` (the
        same at every node).  What an NMPC tracks is a stage parameter: the
        reference and the weights of each node of the horizon.
        """
        self._check_new_parameter(name)
        self.stage_parameters[name] = ca.SX.sym(name, n)
        return self.stage_parameters[name]

    def _check_new_parameter(self, name: str):
        if name in self.parameters or name in self.stage_parameters or name == "p":
            raise ConfigError(f"OCP: parameter {name!r} is already declared (or reserved)")

    def variable(self, name: str, n: int = 1, lower=-np.inf, upper=np.inf, guess=0.0) -> ca.SX:
        """A named global decision variable of ``n`` entries (not tied to a stage), with bounds and a guess."""
        if name in self.variables:
            raise ConfigError(f"OCP: variable {name!r} is already declared")
        sym = ca.SX.sym(name, n)
        self.variables[name] = (sym, np.broadcast_to(np.asarray(lower, float), (n,)).copy(),
                                np.broadcast_to(np.asarray(upper, float), (n,)).copy(),
                                np.broadcast_to(np.asarray(guess, float), (n,)).copy())
        return sym

    def initial_state(self, name: str = "x0") -> ca.SX:
        """Declare the parameter ``name`` and the constraint ``x(0) = name``; returns the parameter."""
        x0 = self.parameter(name, self.model.nx)
        self.subject_to(self.x == x0, at="start", name="initial state")
        self.fixed_start = True
        return x0

    # -- costs ----------------------------------------------------------------------------------
    def minimize_time(self, weight: float = 1.0):
        """Add ``weight`` times the total duration (sum of the phase durations), s."""
        self.time_weight += float(weight)

    def add_cost(self, expr, at="path"):
        """Add a general cost term: on the path its integral over time (``sum h_k expr_k``), else its value."""
        self.costs.append(("general", ca.SX(expr), _check_place(at, self.phases)))

    def add_least_squares(self, residual, weight=1.0, at="path"):
        """Add ``0.5 * sum(weight * residual^2)``: integrated over time on the path, else at the node.

        Least-squares terms are what the Gauss-Newton routes (SQP, RTI) build
        their Hessian from (``J^T W J`` by AD).
        """
        residual = ca.SX(residual)
        w = np.broadcast_to(np.asarray(weight, float), (residual.numel(),))
        if np.any(w < 0):
            raise ConfigError("add_least_squares: weights must be >= 0")
        self.costs.append(("lsq", residual * ca.DM(np.sqrt(w)), _check_place(at, self.phases)))

    # -- constraints ----------------------------------------------------------------------------
    def subject_to(self, *constraints, at="path", name: str | None = None, soft: float | None = None):
        """Add constraints: ``Constraint`` objects (e.g. Rollbot's limits, ``rollbot_oc.planning.rollbot``) or
        SX relations (``expr <= c``, ``expr == goal``), applied ``at`` a place (see module doc).

        ``soft`` makes them soft with that L1 penalty weight (see ``Constraint``).
        """
        place = _check_place(at, self.phases)
        for c in constraints:
            if not isinstance(c, Constraint):
                c = _from_relation(ca.SX(c), name or "constraint")
            elif name:
                c = Constraint(c.expr, c.lower, c.upper, name, c.soft, c.soft_quadratic)
            if soft is not None:
                c = c.softened(soft)
            if place != "path" and ca.depends_on(c.expr, self.u) and place != "start":
                raise ConfigError(f"constraint {c.name}: a condition on the controls cannot apply at {place!r} "
                                  "(the last node has no control)")
            self.constraints.append((c, place))

    # -- solving --------------------------------------------------------------------------------
    def solver(self, route: str = "ipopt", **options):
        """Build (once) a solver of this problem by the named route (``rollbot_oc.ocp.routes.ROUTES``)."""
        return make_route(route, Transcription(self), **options)
