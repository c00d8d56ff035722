"""The dynamic model an optimal-control problem is written on: named states, controls and parameters."""

from __future__ import annotations

import functools
from dataclasses import dataclass

import casadi as ca

from rollbot_oc.model.dynamics import NU, NW, NZ, REDUCED, REDUCED_NAMES, StateSlices, reduced_model, rk4
from rollbot_oc.model.params import NP, PARAM_VECTOR_FIELDS

__all__ = ["OCPModel", "rollbot_model"]


@dataclass(frozen=True, eq=False)  # hashed by identity (cached integrators)
class OCPModel:
    """A controlled ODE ``x' = f(x, u, p)`` with names, for optimal control.

    Attributes
    ----------
    name : str
    f : casadi.Function (x, u, p) -> xdot
        The right-hand side (SX).
    state_names, control_names, parameter_names : tuple of str
    slices : StateSlices
        Named parts of the state (``position``, ``quaternion``, ...).
    """

    name: str
    f: ca.Function
    state_names: tuple
    control_names: tuple
    parameter_names: tuple
    slices: StateSlices

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

    @functools.lru_cache(maxsize=None)
    def interval(self, substeps: int) -> ca.Function:
        """``(x, u, h, p) -> x(h)``: ``substeps`` RK4 steps over an interval of length ``h`` (s), ``u`` held."""
        x, u = ca.SX.sym("x", self.nx), ca.SX.sym("u", self.nu)
        h, p = ca.SX.sym("h"), ca.SX.sym("p", self.np)
        return ca.Function(f"{self.name}_interval", [x, u, h, p], [rk4(self.f, x, h, substeps, u, p)],
                           ["x", "u", "h", "p"], ["x_next"])


@functools.lru_cache(maxsize=None)
def rollbot_model() -> OCPModel:
    """Rollbot in the pendulum frame (``dynamics.reduced_model``, 10 states), no external wrench.

    States ``(x, y, pw, px, py, pz, wx, wy, wz, theta_dot)`` (m, unit quaternion of
    the pendulum frame, rad/s, rad/s); control the motor acceleration (rad/s^2);
    parameters ``RollbotParams.vector()`` (the floor's tilt included).
    """
    red = reduced_model()
    z, u, p = ca.SX.sym("z", NZ), ca.SX.sym("u", NU), ca.SX.sym("p", NP)
    f = ca.Function("rollbot", [z, u, p], [red.f(z, u, p, ca.DM.zeros(NW))], ["x", "u", "p"], ["xdot"])
    return OCPModel("rollbot", f, REDUCED_NAMES, ("theta_ddot",), PARAM_VECTOR_FIELDS, REDUCED)
