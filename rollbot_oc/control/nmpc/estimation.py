"""Offset-free, model-learning NMPC: a Kalman filter on the floor's tilt, and on scale factors of the model's
masses and damping, from the shell's measured angular velocity."""

from __future__ import annotations

import functools
import math

import casadi as ca
import numpy as np

from rollbot_oc.planning.rollbot import rollbot_model
from rollbot_oc.model.dynamics import NZ, REDUCED
from rollbot_oc.core.fastcall import FastFunction
from rollbot_oc.model.params import NP, PARAM_INDEX, TILT, RollbotParams
from rollbot_oc.core.reproducible import dot, matmul, norm, solve

__all__ = ["TiltEstimator", "LEARNABLE", "check_filter"]

# parameters whose scale factors the filter may learn: the shell's mass, the pendulum's mass, the rolling damping
# and the shell's inertia (those a robot is weighed and measured with least exactly; its geometry and motor limits
# are known)
LEARNABLE = ("M", "m", "k0", "I")
SCALE_RANGE = (0.7, 1.3)  # a learned scale factor stays within 30 % of the nominal model


def check_filter(learn, learn_sigma: float, attitude_gain: float, what: str = "") -> None:
    """Raise ``ValueError`` (one line, prefixed by ``what``) unless ``learn`` names only ``LEARNABLE`` parameters,
    ``learn_sigma`` is in (0, 0.3] and ``attitude_gain`` in (0, 1]."""
    unknown = [name for name in learn if name not in LEARNABLE]
    if unknown:
        raise ValueError(f"{what}cannot learn {', '.join(map(repr, unknown))}: valid are {', '.join(LEARNABLE)}")
    if not (math.isfinite(learn_sigma) and 0 < learn_sigma <= 0.3):
        raise ValueError(f"{what}learn_sigma = {learn_sigma!r} is out of range: valid is (0, 0.3]")
    if not (math.isfinite(attitude_gain) and 0 < attitude_gain <= 1):
        raise ValueError(f"{what}attitude_gain = {attitude_gain!r} is out of range: valid is (0, 1]")


@functools.lru_cache(maxsize=None)
def _one_step(substeps: int, dt: float, names: tuple = ()) -> ca.Function:
    """``(z, u, p) -> (z_next, d omega_next / d (tilt, p[names]))`` over one control period, for the estimator."""
    F = rollbot_model().interval(substeps)  # the model every OCP of the toolkit predicts with
    z, u, p = ca.SX.sym("z", NZ), ca.SX.sym("u"), ca.SX.sym("p", NP)
    zn = F(z, u, dt, p)
    columns = list(range(TILT.start, TILT.stop)) + [PARAM_INDEX[name] for name in names]
    return ca.Function("one_step", [z, u, p], [zn, ca.jacobian(zn[REDUCED.omega], p)[:, columns]])


class TiltEstimator:
    """Kalman filter on the floor's tilt vector (in-plane gravity per g) from the shell's angular velocity, and
    optionally on scale factors of model parameters (``learn``).

    The state is the tilt (2) and one factor per learned parameter (the model's value is its nominal times the
    factor); the measurement is the shell's angular velocity one period after the last, against the model's
    prediction from the state before and the command; the Jacobian of that prediction comes from AD.

    Parameters
    ----------
    params : RollbotParams
        Nominal model (its tilt is the prior; its masses and damping the learned factors' 1).
    dt : float
        Control period, s.
    process_noise : float
        Random-walk rate of the tilt, 1/sqrt(s) (the factors are constants: no random walk).
    gyro_sigma : float
        One-step prediction error of the angular velocity, rad/s.
    model_error : float
        Relative error of the model's predicted change of the angular velocity
        (what the filter does not learn): in motion the prediction error grows with the change,
        so the filter learns the floor at rest and near it, not the model's
        errors in hard manoeuvres.
    learn : sequence of str
        Parameters of ``LEARNABLE`` whose scale factors are learned (none by default: the tilt alone).
    learn_sigma : float
        Prior standard deviation of each factor (relative error of the nominal value).
    attitude_gain : float
        Gain, in (0, 1] per control period, of the attitude the predictions start from: each period the model's
        predicted attitude (carried from the measured angular velocity) moves this fraction of the way to the
        measured one, a time constant of about ``dt / attitude_gain``; 1 uses the measurement alone, whose noise
        then enters the prediction, its Jacobian and, in closed loop, the commands, and biases the learned factors.
    """

    def __init__(self, params: RollbotParams, dt: float, process_noise: float = 0.01, gyro_sigma: float = 2e-3,
                 model_error: float = 0.1, learn=(), learn_sigma: float = 0.1,
                 attitude_gain: float = 0.05):
        check_filter(learn, learn_sigma, attitude_gain)
        self.attitude_gain = attitude_gain
        self.p = params.vector()
        self.dt = dt
        self.q = process_noise**2 * dt
        self.r = gyro_sigma**2
        self.model_error = model_error
        self.learn = tuple(learn)
        self.learn_sigma = learn_sigma
        self._columns = [PARAM_INDEX[name] for name in self.learn]
        self.step = FastFunction(_one_step(1, dt, self.learn))
        self.reset()

    def reset(self):
        """Back to the prior (the nominal tilt, a 2 deg standard deviation; the nominal model)."""
        self.tilt = self.p[TILT].copy()
        self.scales = np.ones(len(self.learn))
        self._P = np.diag([math.radians(2.0) ** 2] * 2 + [self.learn_sigma**2] * len(self.learn))
        self.attitude = None  # the filtered attitude the next prediction starts from (None: the measured one)

    @property
    def P(self) -> np.ndarray:
        """Covariance of the tilt estimate (2, 2)."""
        return self._P[:2, :2]

    def update(self, z_prev, u_prev: float, z_now) -> np.ndarray:
        """Fold in one period: measured state ``z_prev``, command ``u_prev`` (rad/s^2), then measured state
        ``z_now``. With ``attitude_gain`` below 1 the filtered attitude carries over to the next call, whose
        ``z_prev`` is this ``z_now`` (else call ``lose_track`` first)."""
        n = 2 + len(self.learn)
        start = np.array(z_prev, dtype=float)
        if self.attitude is not None:
            start[REDUCED.quaternion] = self.attitude
        zn, J = self.step(start, u_prev, self.params())
        if self.attitude_gain < 1.0:
            self.attitude = _blend(zn[REDUCED.quaternion], np.asarray(z_now)[REDUCED.quaternion], self.attitude_gain)
        J = J.reshape(n, 3).T  # the buffer is column-major
        H = np.column_stack([J[:, :2], J[:, 2:] * self.p[self._columns]])  # per unit of each factor
        residual = np.asarray(z_now)[REDUCED.omega] - zn[REDUCED.omega]
        if not (np.all(np.isfinite(residual)) and np.all(np.isfinite(H))):
            return self.tilt  # nothing to learn from a broken prediction
        P = self._P + np.diag([self.q] * 2 + [0.0] * len(self.learn))
        change = float(norm(zn[REDUCED.omega] - np.asarray(z_prev)[REDUCED.omega]))
        HP = matmul(H, P)
        S = matmul(HP, H.T) + np.eye(3) * (self.r + (self.model_error * change) ** 2)
        K = solve(S, HP).T  # S is symmetric positive definite (r > 0)
        P = matmul(np.eye(n) - matmul(K, H), P)
        x = np.concatenate([self.tilt, self.scales]) + matmul(K, residual)
        self.tilt = np.clip(x[:2], -0.5, 0.5)
        self.scales = np.clip(x[2:], *SCALE_RANGE)
        self._P = 0.5 * (P + P.T)  # (rounding would make the covariance lose its symmetry)
        return self.tilt

    def lose_track(self):
        """The next ``update`` starts from its measured attitude (a measurement missed or repeated, the first)."""
        self.attitude = None

    def params(self) -> np.ndarray:
        """The model parameter vector with the estimated tilt and the learned factors."""
        p = self.p.copy()
        p[TILT] = self.tilt
        p[self._columns] *= self.scales
        return p

    def learned(self) -> dict:
        """The learned scale factors by parameter name."""
        return {name: float(scale) for name, scale in zip(self.learn, self.scales)}


def _blend(predicted, measured, gain: float):
    """The unit quaternion ``gain`` of the way from ``predicted`` to ``measured`` (either sign of either; the
    measured one if the prediction is broken, the predicted one if the measurement is)."""
    measured = np.array(measured, dtype=float)
    predicted = np.array(predicted, dtype=float)
    if not np.all(np.isfinite(predicted)):
        return measured
    if not np.all(np.isfinite(measured)):
        return predicted
    if dot(predicted, measured) < 0:
        measured = -measured
    q = (1.0 - gain) * predicted + gain * measured  # a chord between the two (degrees apart): back onto the sphere
    return q / norm(q)
