"""The dynamic model an optimal-control problem is written on: named states, controls and parameters.

The optimal-control layer knows a system only through its ``OCPModel``: the right-hand side ``x' = f(x, u, p)``
and the names of its states, controls and parameters (and, optionally, named groups of them).  A double
integrator in a few lines::

    s, v, a = ca.SX.sym("s"), ca.SX.sym("v"), ca.SX.sym("a")
    model = OCPModel.ode("double_integrator", ca.vertcat(s, v), a, ca.vertcat(v, a))
    ocp = OCP(model, N=20, T=1.0)      # ocp.state.s, ocp.state.v, ocp.control.a

Rollbot's model and its named limits live above this layer (``rollbot_oc.planning.rollbot``).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field
from types import SimpleNamespace
from typing import Callable

import casadi as ca

import rollbot_oc
from rollbot_oc.core.errors import ConfigError
from rollbot_oc.core.integration import rk4

__all__ = ["OCPModel"]


@dataclass(frozen=True, eq=False)  # hashed by identity (cached integrators)
class OCPModel:
    """A controlled ODE ``x' = f(x, u, p)`` with names, for optimal control.

    Attributes
    ----------
    name : str
    f : casadi.Function (x, u, p) -> xdot
        The right-hand side (SX), of sizes ``nx``, ``nu``, ``np`` -> ``nx``.
    state_names, control_names, parameter_names : tuple of str
        One name per entry, unique within each tuple.
    state_parts, control_parts : dict
        Named groups of entries, name -> index or slice (Rollbot's ``"position": slice(0, 2)``); a group named
        like an entry must be that entry.
    parameter_view : callable, optional
        ``p -> object`` giving named (and derived) access to the parameter vector, what ``OCP.params`` is;
        by default a namespace of the entries by their names.
    """

    name: str
    f: ca.Function
    state_names: tuple
    control_names: tuple
    parameter_names: tuple
    state_parts: dict = field(default_factory=dict)
    control_parts: dict = field(default_factory=dict)
    parameter_view: Callable | None = None

    def __post_init__(self):
        for what in ("state_names", "control_names", "parameter_names"):
            object.__setattr__(self, what, tuple(getattr(self, what)))
        sizes = (self.nx, self.nu, self.np)
        f = self.f
        if not isinstance(f, ca.Function) or f.n_in() != 3 or f.n_out() != 1:
            raise ConfigError(f"OCPModel {self.name}: f must be a casadi.Function (x, u, p) -> xdot")
        got = tuple(f.numel_in(i) for i in range(3))
        if got != sizes or f.numel_out(0) != self.nx:
            raise ConfigError(f"OCPModel {self.name}: f takes sizes {got} -> {f.numel_out(0)}, but the names give "
                              f"{sizes} -> {self.nx} (states, controls, parameters)")
        for what, names in (("state", self.state_names), ("control", self.control_names),
                            ("parameter", self.parameter_names)):
            if len(set(names)) != len(names):
                raise ConfigError(f"OCPModel {self.name}: the {what} names repeat ({', '.join(names)})")
        for what, parts, names in (("state", self.state_parts, self.state_names),
                                   ("control", self.control_parts, self.control_names)):
            object.__setattr__(self, f"{what}_parts", dict(parts))
            for part, where in parts.items():
                picked = list(range(len(names)))[where] if isinstance(where, slice) else None
                if picked is None and not (isinstance(where, int) and 0 <= where < len(names)):
                    raise ConfigError(f"OCPModel {self.name}: {what} part {part!r} = {where!r} must be an index "
                                      f"in 0..{len(names) - 1} or a slice")
                if picked == []:
                    raise ConfigError(f"OCPModel {self.name}: {what} part {part!r} = {where!r} is empty")
                if part in names and (picked or [where]) != [names.index(part)]:
                    raise ConfigError(f"OCPModel {self.name}: {what} part {part!r} is not the {what} of that name")

    @classmethod
    def ode(cls, name: str, x, u, xdot, p=None, state_names=None, control_names=None, parameter_names=None,
            **parts) -> "OCPModel":
        """The model of ``x' = xdot(x, u, p)`` from CasADi SX symbols ``x``, ``u``, ``p`` (optional) and the
        expression ``xdot``; names default to those of the symbols' entries.  ``parts``: ``state_parts``,
        ``control_parts``, ``parameter_view`` as in the class."""
        x, u = ca.vertcat(x), ca.vertcat(u)
        p = ca.vertcat(p) if p is not None else ca.SX(0, 1)
        f = ca.Function(name, [x, u, p], [xdot], ["x", "u", "p"], ["xdot"])

        def names(sym, given):
            return tuple(given) if given is not None else tuple(str(sym[i]) for i in range(sym.numel()))

        return cls(name, f, names(x, state_names), names(u, control_names), names(p, parameter_names), **parts)

    @property
    def nx(self) -> int:
        """Number of states."""
        return len(self.state_names)

    @property
    def nu(self) -> int:
        """Number of controls."""
        return len(self.control_names)

    @property
    def np(self) -> int:
        """Length of the model parameter vector."""
        return len(self.parameter_names)

    @property
    def slices(self) -> SimpleNamespace:
        """Where each named state and state part sits in the state vector (index or slice), by name."""
        return SimpleNamespace(**{**{name: i for i, name in enumerate(self.state_names)}, **self.state_parts})

    def named_states(self, x) -> SimpleNamespace:
        """The entries and parts of a state vector ``x`` by name (``OCP.state``)."""
        return SimpleNamespace(**{name: x[where] for name, where in vars(self.slices).items()})

    def named_controls(self, u) -> SimpleNamespace:
        """The entries and parts of a control vector ``u`` by name (``OCP.control``)."""
        where = {**{name: i for i, name in enumerate(self.control_names)}, **self.control_parts}
        return SimpleNamespace(**{name: u[index] for name, index in where.items()})

    def named_parameters(self, p):
        """Named access to a parameter vector ``p`` (``OCP.params``): ``parameter_view(p)``, or the entries by
        their names and the whole vector as ``vector``."""
        if self.parameter_view is not None:
            return self.parameter_view(p)
        return SimpleNamespace(**{"vector": p, **{name: p[i] for i, name in enumerate(self.parameter_names)}})

    @functools.lru_cache(maxsize=None)
    def interval(self, substeps: int) -> ca.Function:
        """``(x, u, h, p) -> x(h)``: ``substeps`` RK4 steps over an interval of length ``h`` (s), ``u`` held."""
        x, u = ca.SX.sym("x", self.nx), ca.SX.sym("u", self.nu)
        h, p = ca.SX.sym("h"), ca.SX.sym("p", self.np)
        return ca.Function(f"{self.name}_interval", [x, u, h, p], [rk4(self.f, x, h, substeps, u, p)],
                           ["x", "u", "h", "p"], ["x_next"])


def __getattr__(name: str):
    return rollbot_oc.moved_name(__name__, name)
