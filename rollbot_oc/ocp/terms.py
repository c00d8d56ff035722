"""The terms an ``OCP`` is written in: a free phase duration (``FreeTime``) and a named, possibly soft,
constraint (``Constraint``, ``bounded``, and one made from a CasADi relation).

Both the problem (``ocp.problem``) and its transcription (``ocp.transcription``) read them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import casadi as ca
import numpy as np

from rollbot_oc.core.errors import ConfigError

__all__ = ["FreeTime", "Constraint", "bounded"]


@dataclass(frozen=True)
class FreeTime:
    """A free phase duration: a decision variable with bounds and an initial guess (s)."""

    guess: float = 5.0
    lower: float = 0.1
    upper: float = 60.0

    def __post_init__(self):
        if not (0 <= self.lower <= self.guess <= self.upper and math.isfinite(self.upper)):
            raise ConfigError(f"FreeTime: need 0 <= lower <= guess <= upper < inf s, got lower = {self.lower}, "
                              f"guess = {self.guess}, upper = {self.upper}")


@dataclass(frozen=True)
class Constraint:
    """``lower <= expr <= upper`` elementwise, with a name; ``soft`` (a penalty weight) makes it soft.

    A soft constraint may be violated by slacks ``s >= 0`` at the price
    ``soft * sum(s) + 0.5 * soft_quadratic * sum(s^2)`` in the cost (an exact
    penalty: for a weight above the constraint's multiplier the solution is
    the hard one whenever that exists, and a nearby one when it does not).
    """

    expr: object
    lower: np.ndarray
    upper: np.ndarray
    name: str = "constraint"
    soft: float | None = None
    soft_quadratic: float = 0.0

    def __post_init__(self):
        n = self.expr.numel()
        lower = np.broadcast_to(np.asarray(self.lower, float), (n,)).copy()
        upper = np.broadcast_to(np.asarray(self.upper, float), (n,)).copy()
        if np.any(lower > upper):
            raise ConfigError(f"constraint {self.name}: lower bound above upper bound")
        object.__setattr__(self, "lower", lower)
        object.__setattr__(self, "upper", upper)
        if self.soft is not None and not self.soft > 0:
            raise ConfigError(f"constraint {self.name}: soft = {self.soft!r} must be a weight > 0")

    def softened(self, weight: float, quadratic: float = 0.0) -> "Constraint":
        """The same constraint as a soft one with L1 weight ``weight`` and L2 weight ``quadratic``."""
        return Constraint(self.expr, self.lower, self.upper, self.name, weight, quadratic)


def bounded(lower, expr, upper, name: str = "bounded") -> Constraint:
    """``lower <= expr <= upper`` (CasADi cannot chain comparisons)."""
    return Constraint(ca.SX(expr) if not isinstance(expr, (ca.SX, ca.MX)) else expr, lower, upper, name)


def _from_relation(relation, name: str) -> Constraint:
    """A ``Constraint`` from an SX relation ``a <= b``, ``a >= b`` or ``a == b`` (elementwise)."""
    exprs, lower, upper = [], [], []
    for i in range(relation.numel()):
        e = relation[i]
        if e.is_op(ca.OP_EQ):
            kind = "eq"
        elif e.is_op(ca.OP_LE) or e.is_op(ca.OP_LT):
            kind = "le"
        else:
            raise ConfigError(f"{name}: expected a relation (<=, >=, ==) or a Constraint, got {e}")
        a, b = e.dep(0), e.dep(1)
        if b.is_constant():
            expr, bound, constant_right = a, float(b), True
        elif a.is_constant():
            expr, bound, constant_right = b, float(a), False
        else:
            expr, bound, constant_right = a - b, 0.0, True
        exprs.append(expr)
        if kind == "eq":
            lower.append(bound)
            upper.append(bound)
        elif constant_right:  # expr <= bound
            lower.append(-np.inf)
            upper.append(bound)
        else:  # bound <= expr
            lower.append(bound)
            upper.append(np.inf)
    return Constraint(ca.vertcat(*exprs), np.array(lower), np.array(upper), name)
