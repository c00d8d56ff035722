"""Offset-free NMPC: a Kalman filter on the floor's tilt from the shell's measured angular velocity."""

from __future__ import annotations

import functools
import math

import casadi as ca
import numpy as np

from rollbot_oc.ocp import rollbot_model
from rollbot_oc.dynamics import NZ, REDUCED
from rollbot_oc.fastcall import FastFunction
from rollbot_oc.params import NP, TILT, RollbotParams

__all__ = ["TiltEstimator"]


@functools.lru_cache(maxsize=None)
def _one_step(substeps: int, dt: float) -> ca.Function:
    """``(z, u, p) -> (z_next, d omega_next / d tilt)`` over one control period, for the estimator."""
    F = rollbot_model().interval(substeps)  # the model every OCP of the toolkit predicts with
    z, u, p = ca.SX.sym("z", NZ), ca.SX.sym("u"), ca.SX.sym("p", NP)
    zn = F(z, u, dt, p)
    return ca.Function("one_step", [z, u, p], [zn, ca.jacobian(zn[REDUCED.omega], p)[:, TILT]])


class TiltEstimator:
    """Kalman filter on the floor's tilt vector (in-plane gravity per g) from the shell's angular velocity.

    Parameters
    ----------
    params : RollbotParams
        Nominal model (its tilt is the prior).
    dt : float
        Control period, s.
    process_noise : float
        Random-walk rate of the tilt, 1/sqrt(s).
    gyro_sigma : float
        One-step prediction error of the angular velocity, rad/s.
    model_error : float
        Relative error of the model's predicted change of the angular velocity
        (masses, damping): in motion the prediction error grows with the change,
        so the filter learns the floor at rest and near it, not the model's
        errors in hard manoeuvres.
    """

    def __init__(self, params: RollbotParams, dt: float, process_noise: float = 0.01, gyro_sigma: float = 2e-3,
                 model_error: float = 0.1):
        self.p = params.vector()
        self.dt = dt
        self.q = process_noise**2 * dt
        self.r = gyro_sigma**2
        self.model_error = model_error
        self.step = FastFunction(_one_step(1, dt))
        self.reset()

    def reset(self):
        """Back to the prior (the nominal tilt, a 2 deg standard deviation)."""
        self.tilt = self.p[TILT].copy()
        self.P = np.eye(2) * math.radians(2.0) ** 2

    def update(self, z_prev, u_prev: float, z_now) -> np.ndarray:
        """Fold in one period: state ``z_prev``, command ``u_prev`` (rad/s^2), then state ``z_now``."""
        p = self.p.copy()
        p[TILT] = self.tilt
        zn, H = self.step(z_prev, u_prev, p)
        H = H.reshape(2, 3).T  # the buffer is column-major
        residual = np.asarray(z_now)[REDUCED.omega] - zn[REDUCED.omega]
        if not (np.all(np.isfinite(residual)) and np.all(np.isfinite(H))):
            return self.tilt  # nothing to learn from a broken prediction
        self.P = self.P + np.eye(2) * self.q
        change = float(np.linalg.norm(zn[REDUCED.omega] - np.asarray(z_prev)[REDUCED.omega]))
        S = H @ self.P @ H.T + np.eye(3) * (self.r + (self.model_error * change) ** 2)
        K = np.linalg.solve(S, H @ self.P).T  # S is symmetric positive definite (r > 0)
        self.tilt = np.clip(self.tilt + K @ residual, -0.5, 0.5)
        self.P = (np.eye(2) - K @ H) @ self.P
        return self.tilt

    def params(self) -> np.ndarray:
        """The model parameter vector with the estimated tilt."""
        p = self.p.copy()
        p[TILT] = self.tilt
        return p
