"""Linearised stability of quasi-stable states (paper eqns "perturb" and "ode"), by AD.

Coordinates.  A quasi-stable state is a relative equilibrium: constant in a
frame turning at ``Omega`` about the vertical.  Because the shell is
spherically symmetric, the dynamics depend on the shell orientation ``T`` and
the motor angle ``theta`` only through the pendulum frame ``P = T Rz(theta)``,
which at a quasi-stable state is constant in the turning frame.  We perturb

* the pendulum frame by a small rotation ``alpha`` (3, rad, turning-frame
  axes): ``P = cay(alpha) P*`` with the Cayley map (smooth, equal to the
  rotation exponential to first order), the same perturbation as the paper's
  ``T^p = (1 + [T_r alpha]) T``;
* the shell angular velocity by ``d_omega`` (3, rad/s, turning-frame axes);
* the driving speed by ``d_theta_dot`` (rad/s), driven by the input
  ``theta_ddot`` (rad/s^2).

In the turning frame the perturbation obeys ``alpha' = omega + theta_dot z' -
Omega z`` and ``d_omega' = omega_dot(x) - Omega z x omega`` with ``omega_dot``
the full equations of motion of ``dynamics``; CasADi's ``jacobian`` of these
at the quasi-stable state gives the constant-coefficient linear system (no
finite differences, no hand-typed matrices).  With the driving speed held
(``d_theta_dot = 0``) this is the paper's six-dimensional system (its
``(alpha, alpha')`` are a linear change of our ``(alpha, d_omega)``).

The symmetry mode.  Turning the whole robot about the vertical through its
centre gives another quasi-stable state, so ``v0 = (z, z x omega*)`` is an
exact null vector of the 6x6 matrix (eigenvalue 0, the paper's "mode of
revolution about l").  We remove it by passing to the quotient: the five
coordinates ``(alpha_x, alpha_y, d_omega - alpha_z z x omega*)`` do not change
along ``v0``, and the induced map ``Q A Q+`` on them has exactly the other
five eigenvalues.  ``lambda_2`` is the one of those with the largest real part
(the slowest mode), and the recovery time is ``tau = -1 / Re(lambda_2)``.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field

import casadi as ca
import numpy as np

from rollbot_oc.model.dynamics import FULL, NW, symbolic_model
from rollbot_oc.core.errors import NumericalFailure
from rollbot_oc.model.params import PARAM_VECTOR_FIELDS, RollbotParams
from rollbot_oc.core.fastcall import fast_map
from rollbot_oc.analysis.quasi_stable import QuasiStableState, _curve, _states, level, quasi_symbolic
from rollbot_oc.core.reproducible import norm
from rollbot_oc.model.rotations import quat_multiply, quat_to_matrix

__all__ = [
    "Stability", "linearise", "stability", "stability_curve", "stability_of_states", "stability_record", "state_space",
    "perturbed_state", "STATE_LABELS",
]

STATE_LABELS = ("alpha_x", "alpha_y", "d_omega_x", "d_omega_y", "d_omega_z", "d_theta_dot")
STATE_UNITS = ("rad", "rad", "rad/s", "rad/s", "rad/s", "rad/s")
_EZ = ca.DM([0.0, 0.0, 1.0])


@functools.lru_cache(maxsize=None)
def _linear_functions() -> tuple[ca.Function, ca.Function]:
    """The linearisation ``(z, omega0, p) -> (A7, B7, Aq, Bq, v0)`` at the quasi-stable state with unknowns
    ``z``, and the map ``(z, omega0, p, yq) -> x`` from quotient coordinates to a full state."""
    sym, q = symbolic_model(), quasi_symbolic()
    z, omega0 = ca.SX.sym("z", 3), ca.SX.sym("omega0")
    p = ca.SX.sym("p", len(PARAM_VECTOR_FIELDS))
    alpha, d_omega, d_speed, accel = ca.SX.sym("alpha", 3), ca.SX.sym("d_omega", 3), ca.SX.sym("dv"), ca.SX.sym("a")
    x_star = q.state(z, omega0, p)
    Omega = z[0] * omega0
    omega_star = x_star[FULL.omega]
    # Cayley map as a unit quaternion: (1, alpha/2) normalised.
    q_alpha = ca.vertcat(1, alpha / 2) / ca.sqrt(1 + ca.sumsqr(alpha) / 4)
    quat = quat_multiply(q_alpha, x_star[FULL.quaternion])
    omega = omega_star + d_omega
    speed = omega0 + d_speed
    x = ca.vertcat(x_star[FULL.position], quat, omega, x_star[FULL.theta], speed)
    xdot = sym.f(x, accel, p, ca.DM.zeros(NW))
    motor_axis = ca.mtimes(quat_to_matrix(quat), _EZ)
    y = ca.vertcat(alpha, d_omega, d_speed)
    ydot = ca.vertcat(omega + speed * motor_axis - Omega * _EZ, xdot[FULL.omega] - ca.cross(Omega * _EZ, omega), accel)
    perturbation = ca.vertcat(y, accel)
    A7 = ca.substitute(ca.jacobian(ydot, y), perturbation, ca.DM.zeros(8))
    B7 = ca.substitute(ca.jacobian(ydot, accel), perturbation, ca.DM.zeros(8))
    # Quotient by the symmetry mode v0 = (z, z x omega*, 0).
    zxw = ca.cross(_EZ, omega_star)
    v0 = ca.vertcat(_EZ, zxw, 0)
    Q = ca.SX.zeros(6, 7)
    Q[0, 0], Q[1, 1], Q[5, 6] = 1, 1, 1
    Q[2:5, 3:6] = ca.SX.eye(3)
    Q[2:5, 2] = -zxw
    Q_plus = ca.SX.zeros(7, 6)
    Q_plus[0, 0], Q_plus[1, 1], Q_plus[6, 5] = 1, 1, 1
    Q_plus[3:6, 2:5] = ca.SX.eye(3)
    Aq = ca.mtimes([Q, A7, Q_plus])
    Bq = ca.mtimes(Q, B7)
    linear = ca.Function("quasi_linearisation", [z, omega0, p], [A7, B7, Aq, Bq, v0],
                         ["z", "omega0", "p"], ["A7", "B7", "Aq", "Bq", "v0"], {"cse": True})
    yq = ca.SX.sym("yq", 6)
    lift = ca.Function("quasi_perturbed_state", [z, omega0, p, yq],
                       [ca.substitute(x, y, ca.mtimes(Q_plus, yq))], ["z", "omega0", "p", "yq"], ["x"])
    return linear, lift


@dataclass(frozen=True)
class Stability:
    """Linearised stability of one quasi-stable state (SI units).

    Attributes
    ----------
    state : QuasiStableState
        The quasi-stable state.
    eigenvalues : numpy.ndarray (5,) complex
        Eigenvalues with the driving speed held, the symmetry mode removed,
        sorted by decreasing real part, 1/s.
    lambda2 : complex
        The slowest remaining mode (largest real part), 1/s.
    tau : float
        Recovery time ``-1 / Re(lambda2)``, s (``inf`` if not decaying).
    stable : bool
        All five eigenvalues have negative real part.
    symmetry_eigenvalue : float
        The eigenvalue of the removed mode ``v0`` (an exact eigenvector of the
        6x6 system), its Rayleigh quotient ``v0.A v0 / v0.v0``: zero up to round-off, 1/s.
    A : numpy.ndarray (6, 6)
        Quotient system matrix, states ``STATE_LABELS`` (driving speed included).
    B : numpy.ndarray (6, 1)
        Input matrix for the motor acceleration ``theta_ddot``.
    A_full : numpy.ndarray (7, 7)
        The linearisation before the quotient, states (alpha, d_omega, d_theta_dot).
    """

    state: QuasiStableState
    eigenvalues: np.ndarray
    lambda2: complex
    tau: float
    stable: bool
    symmetry_eigenvalue: float
    A: np.ndarray = field(repr=False)
    B: np.ndarray = field(repr=False)
    A_full: np.ndarray = field(repr=False)

    def to_dict(self) -> dict:
        """JSON-ready record (the CLI's ``stability --json`` objects)."""
        return {
            "omega0": self.state.omega0,
            "branch": self.state.branch,
            "converged": True,
            "eigenvalues": [[float(e.real), float(e.imag)] for e in self.eigenvalues],
            "lambda2": [float(self.lambda2.real), float(self.lambda2.imag)],
            "tau": self.tau if math.isfinite(self.tau) else None,
            "stable": self.stable,
            "symmetry_eigenvalue": self.symmetry_eigenvalue,
        }


def linearise(state: QuasiStableState):
    """The linearisation at a quasi-stable state: ``(A7, B7, Aq, Bq, v0)`` as numpy arrays (see module doc)."""
    _require_converged(state)
    out = _linear_functions()[0](state.unknowns, state.omega0, level(state.params).vector())
    return tuple(np.array(v) for v in out)


def _require_converged(state: QuasiStableState):
    if not state.converged:
        raise NumericalFailure(f"linearise: the quasi-stable state at omega0 = {state.omega0} rad/s did not "
                               f"converge (residual {state.full_residual:.3g}); there is nothing to linearise about",
                               "not converged")


def _analyse(states: list[QuasiStableState], Z: np.ndarray, params: RollbotParams) -> list[Stability]:
    """``Stability`` of ``states`` (unknowns ``Z``, (n, 3)): one mapped linearisation, stacked eigenvalues."""
    n = len(states)
    W = np.array([s.omega0 for s in states])
    # mapped outputs come back flat, block after block, each block column-major
    A7, B7, Aq, Bq, v0 = (np.array(v).reshape(n, -1, rows).transpose(0, 2, 1) for v, rows in
                          zip(fast_map(_linear_functions()[0], n, shared=(2,))(Z.ravel(), W, level(params).vector()),
                              (7, 7, 6, 6, 7)))
    eig = np.linalg.eigvals(Aq[:, :5, :5]).astype(complex)
    eig = np.take_along_axis(eig, np.argsort(-eig.real, axis=1, kind="stable"), axis=1)
    v0 = v0[:, :, 0]
    symmetry = np.einsum("ni,nij,nj->n", v0, A7, v0) / np.einsum("ni,ni->n", v0, v0)  # A7 v0 = lambda v0
    lam2 = eig[:, 0]
    tau = np.full(n, math.inf)
    tau[lam2.real < 0] = -1.0 / lam2.real[lam2.real < 0]
    stable = np.all(eig.real < 0, axis=1)
    return [Stability(*args) for args in zip(states, eig, lam2.tolist(), tau.tolist(), stable.tolist(),
                                             symmetry.tolist(), Aq, Bq, A7)]


def stability(state: QuasiStableState) -> Stability:
    """Eigenvalues, ``lambda_2`` and recovery time of a quasi-stable state."""
    _require_converged(state)
    return _analyse([state], state.unknowns[None, :], state.params)[0]


def stability_curve(omegas, params: RollbotParams | None = None, branch: str = "slow") -> list[Stability]:
    """``stability`` along a branch at driving speeds ``omegas`` (rad/s).

    The quasi-stable states come from one batched solve (``quasi_stable_curve``),
    the linearisations from one mapped CasADi call over all of them and the
    eigenvalues from one stacked ``numpy.linalg.eigvals``.

    Raises
    ------
    ConfigError
        If a speed is out of range, the branch is unknown or ``k0`` is 0.
    NumericalFailure
        If a quasi-stable state on the way does not converge (its speed is named).
    """
    params = params or RollbotParams()
    omegas, Z, rows, ok = _curve(omegas, params, branch)
    if not ok.all():
        raise NumericalFailure(f"stability: no quasi-stable state on the {branch} branch at omega0 = "
                               f"{omegas[np.argmin(ok)]:.4g} rad/s", "not converged")
    if not omegas.size:
        return []
    return _analyse(_states(omegas, Z, rows, ok, params, branch), Z, params)


def stability_of_states(states: list[QuasiStableState]) -> list[Stability | None]:
    """``stability`` of each state (one mapped CasADi call); None for a state that did not converge."""
    good = [s for s in states if s.converged]
    if not good:
        return [None] * len(states)
    found = iter(_analyse(good, np.array([s.unknowns for s in good]), good[0].params))
    return [next(found) if s.converged else None for s in states]


def stability_record(state: QuasiStableState, result: Stability | None) -> dict:
    """The JSON object of ``stability --json`` for a state: ``result.to_dict()``, or nulls if it did not converge."""
    if result is not None:
        return result.to_dict()
    return {"omega0": state.omega0, "branch": state.branch, "converged": False, "eigenvalues": None, "lambda2": None,
            "tau": None, "stable": None, "symmetry_eigenvalue": None}


def perturbed_state(state: QuasiStableState, y) -> np.ndarray:
    """A full state (11,) near a quasi-stable state, from quotient coordinates ``y``.

    Parameters
    ----------
    state : QuasiStableState
        The quasi-stable state (revolving about the origin, robot on +x).
    y : array_like (6,)
        Perturbation in ``STATE_LABELS`` coordinates: pendulum-frame tilt
        ``alpha_x, alpha_y`` (rad), angular-velocity perturbation (rad/s) and
        driving-speed perturbation (rad/s).  To first order the tilt of the
        motor axis changes by ``alpha_y``.
    """
    y = np.asarray(y, float).ravel()
    if y.shape != (6,):
        raise ValueError(f"perturbed_state: y has {y.size} entries, expected 6 ({', '.join(STATE_LABELS)})")
    x = np.array(_linear_functions()[1](state.unknowns, state.omega0, level(state.params).vector(), y)).ravel()
    x[FULL.quaternion] /= norm(x[FULL.quaternion])
    return x


def state_space(result: Stability):
    """The linearisation as a python-control ``StateSpace`` (continuous time).

    States ``STATE_LABELS`` (the quotient coordinates plus the driving-speed
    perturbation), input ``theta_ddot`` (rad/s^2), outputs equal to the
    states.  Its poles are the five eigenvalues of ``result`` and a zero from
    the motor (acceleration integrates to driving speed).
    """
    import control  # start-up: python-control is slow to import and only this function uses it

    return control.ss(result.A, result.B, np.eye(6), np.zeros((6, 1)), states=list(STATE_LABELS),
                      inputs=["theta_ddot"], outputs=list(STATE_LABELS),
                      name=f"rollbot_{result.state.branch}_omega0_{result.state.omega0:.3f}".replace(".", "p"))
