"""The NMPC's tracking problem, written once on the optimal-control layer, and its two solvers.

The problem (``tracking_problem``), over a horizon of ``N`` intervals of
``h`` seconds from the measured state ``x0``::

    min  sum_k h |W_k (x_k - x_ref,k)|^2 + h |w_u,k (u_k - u_ref,k)|^2 + h |w_m,k r_m(x_k)|^2
         + terminal terms at k = N
    s.t. x_0 = x0, continuity, motor torque, no jump, no slide, driving speed, motor acceleration

with the reference and the weights of every node as parameters of each solve
(stage parameters: the holds at a stop, the brake and the orbit change them,
not the problem) and ``r_m`` the mission's own residuals
(``Mission.tracking_terms``: a circle's is the distance from it).  Every term is a least-squares
residual, so the real-time iteration's Gauss-Newton Hessian ``J^T J`` and its
gradients come from CasADi's AD of the same description that IPOPT solves.

``RTISolver`` takes one real-time iteration per call (route ``"rti"``, QPs by
qrqp; the control step evaluates its ``to_function`` form, ``control.nmpc.period``);
``TrackingSolver`` solves to convergence (route ``"ipopt"``, exact Hessian).
Both return ``(x, multipliers, status, success, seconds)`` to the loop.
"""

from __future__ import annotations

import functools

import casadi as ca
import numpy as np

from rollbot_oc.model.codegen import compiler
from rollbot_oc.control.nmpc.settings import NMPCSettings, TrackingWeights
from rollbot_oc.model.dynamics import NZ
from rollbot_oc.missions.base import Mission
from rollbot_oc.ocp import OCP
from rollbot_oc.planning.rollbot import robot_limits, rollbot_ocp
from rollbot_oc.model.params import RollbotParams

__all__ = ["tracking_problem", "TrackingSolver", "RTISolver", "RELAXABLE"]

RELAXABLE = ("motor torque", "no jump", "no slide")  # dropped from a QP no command can satisfy


def tracking_problem(N: int, h: float, substeps: int = 2, torque_margin: float = 0.95, normal_margin: float = 0.1,
                     friction_margin: float = 0.95, speed_margin: float = 0.98, constraints=(),
                     mission: type[Mission] | Mission | None = None) -> OCP:
    """The NMPC's tracking problem (module doc) on ``N`` intervals of ``h`` s.

    Stage parameters: ``reference`` (10) and ``accel_reference`` (1), the
    square roots of the weights ``state_weight`` (10), ``accel_weight`` and
    ``mission_weight`` (one per residual of the mission's ``tracking_terms``);
    parameter ``x0`` (10) and those the mission declares.  The margins are
    the fractions of the limits it may use; ``constraints``: more path
    constraints, functions of the ``OCP`` giving a ``Constraint``
    (``NMPCSettings.constraints``).
    """
    ocp = rollbot_ocp(N=N, T=N * h, substeps=substeps)
    x, u = ocp.x, ocp.u
    ocp.initial_state()
    reference, accel_reference = ocp.stage_parameter("reference", NZ), ocp.stage_parameter("accel_reference")
    state_weight, accel_weight = ocp.stage_parameter("state_weight", NZ), ocp.stage_parameter("accel_weight")
    terms = mission.tracking_terms(ocp) if mission is not None else []
    mission_weight = ocp.stage_parameter("mission_weight", len(terms))
    tracking = ca.vertcat(state_weight * (x - reference), mission_weight * ca.vertcat(*terms)) if terms \
        else state_weight * (x - reference)
    ocp.add_least_squares(ca.vertcat(tracking, accel_weight * (u - accel_reference)))
    ocp.add_least_squares(tracking, at="end")
    ocp.subject_to(*robot_limits(ocp, torque_margin, normal_margin, friction_margin, speed_margin, 1.0, constraints))
    return ocp


@functools.lru_cache(maxsize=8)
def _route(route: str, N: int, h: float, substeps: int, margins: tuple, constraints: tuple, kind: type,
           compiled: bool, qp_max_iter: int = 1000):
    """The tracking problem's solver by ``route``, built once per horizon, margins, extra constraints and
    mission kind (``kind``, a ``Mission`` class: its terms are written once per kind)."""
    ocp = tracking_problem(N, h, substeps, *margins, constraints=constraints, mission=kind)
    if route == "rti":
        # qrqp: the QP solver CasADi generates as C with the step (``control.nmpc.period``)
        return ocp.solver("rti", qp_solver="qrqp", compiled=compiled, qp_options={"max_iter": qp_max_iter})
    return ocp.solver("ipopt", hessian="exact", max_iter=50, tol=1e-6,
                      options={"warm_start_init_point": "yes", "warm_start_bound_push": 1e-6,
                               "warm_start_mult_bound_push": 1e-6, "mu_init": 1e-4})


class _Tracking:
    """What both solvers share: the route, the parameters of a solve, and the decision vector's parts."""

    route_name = ""

    def __init__(self, params: RollbotParams, settings: NMPCSettings, weights: TrackingWeights,
                 mission: Mission | None = None):
        s = self.settings = settings
        self.params = params
        self.mission = mission if mission is not None else Mission()
        self._mission_values = self.mission.tracking_values()
        use_c = s.horizon.compiled if s.horizon.compiled is not None else compiler() is not None
        self.compiled = use_c and self.route_name == "rti"
        margins = (s.limits.torque_margin, s.limits.normal_margin, s.limits.friction_margin, s.limits.speed_margin)
        self.route = _route(self.route_name, s.horizon.N, s.horizon.h, s.horizon.substeps, margins,
                            tuple(s.limits.constraints),
                            type(self.mission), self.compiled, s.horizon.qp_max_iter)
        ocp = self.route.transcription.ocp
        self.relax = RELAXABLE + tuple(c.name for c, at in ocp.constraints[-len(s.limits.constraints):]) \
            if s.limits.constraints else RELAXABLE
        self.layout = self.route.transcription.layout
        self.diag = weights.diagonal(s.horizon.N)
        self.n_x = self.layout.size
        self._last = None

    def _parameters(self, z0, Zr, Ur, p, mission_weights, diag) -> dict:
        """The solve's parameters: node weights ``diag`` (``TrackingWeights.diagonal``) and ``mission_weights``
        as the square roots the problem takes; the last node's by ``h`` (the path terms are integrals, the
        terminal one is not)."""
        N, h = self.settings.horizon.N, self.settings.horizon.h
        diag = self.diag if diag is None else diag
        node = np.ones(N + 1)
        node[-1] = h
        state_weight = np.sqrt(diag[:NZ * (N + 1)].reshape(N + 1, NZ).T * node)
        n_terms = self.layout.stage_parameters["mission_weight"]
        n_terms = n_terms.stop - n_terms.start
        weights = np.zeros((n_terms, N + 1)) if mission_weights is None else \
            np.broadcast_to(np.asarray(mission_weights, float), (n_terms, N + 1))
        return dict(x0=np.asarray(z0, float), p=p, reference=np.asarray(Zr, float),
                    accel_reference=np.append(np.ravel(Ur), 0.0)[None, :],
                    state_weight=state_weight, accel_weight=np.append(np.sqrt(diag[NZ * (N + 1):]), 0.0)[None, :],
                    mission_weight=np.sqrt(weights * node), **self._mission_values)

    def _guess(self, z0, Zr, Ur):
        Z = np.array(Zr, float)
        Z[:, 0] = z0  # the horizon starts at the measured state
        return self.layout.pack(Z, np.ravel(Ur)[None, :])

    def solve(self, z0, Zr, Ur, p, warm=None, mission_weights=None, diag=None):
        """Solve from ``warm`` (``(x, lam_w, lam_g)``; else from the reference); returns
        ``(x, (lam_w, lam_g), status, success, seconds)``.

        Parameters
        ----------
        z0 : array_like (10,)
            The (delay-compensated) measured reduced state.
        Zr : array_like (10, N+1)
            Reference states at the nodes.
        Ur : array_like (N,)
            Reference motor accelerations, rad/s^2.
        p : array_like
            The model parameter vector (the estimated tilt in it).
        mission_weights : array_like (N+1,) or (terms, N+1), optional
            Weights of the mission's residuals at each node (for a circle, of
            the distance from it, 1/m^2); none by default.
        diag : array_like, optional
            Tracking weights of every decision variable (``TrackingWeights.diagonal``).
        """
        values = self._parameters(z0, Zr, Ur, p, mission_weights, diag)
        x, lam_w, lam_g = warm if warm is not None else (None, None, None)
        guess = self._guess(z0, Zr, Ur) if x is None else x
        try:
            sol = self._attempt(guess, (lam_w, lam_g) if lam_w is not None else None, values)
        except RuntimeError as exc:  # a solver's own error is a failed solve, never a crash of the loop
            return guess, (lam_w, lam_g), f"error: {str(exc).splitlines()[-1][:60]}", False, 0.0
        self._last = sol
        ok = sol.success and bool(np.all(np.isfinite(sol.w)))
        return sol.w, (sol.lam_w, sol.lam_g), sol.status, ok, sol.solve_time

    def split(self, x):
        """``(Z (10, N+1), U (N,))`` of a decision vector."""
        return self.layout.states(x), self.layout.controls(x)[0]

    def shift(self, x):
        """The decision vector moved on by one interval (the last node and control repeated), for a warm start."""
        Z, U = self.split(x)
        return self.layout.pack(np.hstack([Z[:, 1:], Z[:, -1:]]), np.concatenate([U[1:], U[-1:]])[None, :])


class RTISolver(_Tracking):
    """The tracking problem by real-time iterations: one Gauss-Newton SQP step per call (route ``"rti"``).

    Parameters
    ----------
    params : RollbotParams
        The robot the controller believes in.
    settings : NMPCSettings
    weights : TrackingWeights
        The default node weights (a solve may give others).
    iterations : int
        SQP steps per call.
    """

    route_name = "rti"

    def __init__(self, params: RollbotParams, settings: NMPCSettings, weights: TrackingWeights, iterations: int = 1,
                 mission: Mission | None = None):
        super().__init__(params, settings, weights, mission)
        self.iterations = iterations

    def _attempt(self, guess, multipliers, values):
        return self.route.attempt(guess, max_iter=self.iterations, multipliers=multipliers, relax=self.relax,
                                  **values)

    def modelled_time(self) -> float:
        """Modelled compute time of a solve: ``iterations`` RTI steps of ``timing.rti_step``, s."""
        return self.iterations * self.settings.timing.rti_step


class TrackingSolver(_Tracking):
    """The tracking problem solved to convergence by IPOPT (exact Hessian, warm-started; route ``"ipopt"``)."""

    route_name = "ipopt"

    def _attempt(self, guess, multipliers, values):
        return self.route.attempt(guess, multipliers=multipliers, **values)

    def modelled_time(self) -> float:
        """Modelled compute time of the last solve: its IPOPT iterations times ``ipopt_iteration_time``, s."""
        return (self._last.iterations if self._last is not None else 0) * self.settings.timing.ipopt_iteration
