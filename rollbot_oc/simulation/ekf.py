"""State estimation from onboard sensors: an error-state EKF on Rollbot's full CasADi model.

Why an error-state extended Kalman filter.  The measurements come at 100 Hz
or faster and the estimate must be ready within the same control period, so
the estimator has to be recursive and cheap: an EKF costs one prediction and
one update per IMU sample, where moving-horizon estimation would solve a
nonlinear program over a window every sample.  MHE's strengths (constraints,
strongly nonlinear measurements, outliers) are not needed here: every
measurement is smooth and close to linear in the state over one sample, and
the errors stay small.  The orientation is a unit quaternion, which has 3
degrees of freedom in 4 numbers; an EKF on the quaternion itself would carry
a singular 4x4 block and break the unit norm with every update.  The
error-state form keeps the quaternion in the nominal state and estimates a
3-vector rotation error instead (a minimal, unconstrained parametrisation;
Sola, "Quaternion kinematics for the error-state Kalman filter", 2017).

The filter runs on the full model (``dynamics.symbolic_model``: no-slip
rolling, the pendulum, damping, the motor's limits), so that:

* the shell-centre position follows from the angular velocity through the
  no-slip kinematics ``s' = (omega x R z)_xy``: the filter dead-reckons;
* the accelerometer's prediction includes the centre's acceleration
  ``omega_dot x R z`` from the dynamics, not only gravity;
* the floor tilt (in-plane gravity per g, ``RollbotParams.tilt_x``,
  ``tilt_y``) is a state: it enters the dynamics and the accelerometer;
* the gyroscope's bias is observable from the mismatch between the measured
  rate and the rate the model predicts, and from the accelerometer's view of
  gravity as the shell turns.

Nominal state ``xa`` (19, ``AUG``): the model state (11) of ``dynamics``, the
gyroscope bias (3, rad/s, body frame), the accelerometer bias (3, m/s^2,
body frame) and the tilt (2).  Error state ``dx`` (18, ``ERR``): the same
with the quaternion replaced by a rotation error ``dphi`` in the floor frame,
``q = q(dphi) * q_nominal`` (``boxplus``; ``q(dphi)`` is the unit quaternion
along ``(1, dphi / 2)``).  The covariance ``P`` is that of ``dx``.

Prediction over one IMU sample interval: RK4 of the model with the motor
command held (``ESTIMATOR_STEP`` per step, the plant's own step), biases and
tilt constant; the error transition ``Phi = d(F(xa [+] dx) [-] F(xa))/d dx``
at ``dx = 0`` by CasADi's automatic differentiation, ``P <- Phi P Phi^T + Q``
with ``Q = (Phi Qc Phi^T + Qc) h / 2`` from the noise densities ``Qc`` of
``EstimatorSettings``.  Updates: the IMU sample and the encoder (7 values,
their Jacobian by AD, Joseph form), and motion capture when it arrives
(position and the rotation between the measured and the estimated
orientation, 5 values).  A motion-capture sample that is ``L`` periods old is
compared with the estimate of its capture time (a short buffer of past
estimates) and corrects the current state, which is exact to first order
while the error changes little over ``L``.  Each update is one CasADi
Function, built once per process (``functools.lru_cache``) and called through
``fastcall.FastFunction``.
"""

from __future__ import annotations

import functools
import math
from collections import deque
from dataclasses import dataclass

import casadi as ca
import numpy as np

from rollbot_oc.model.codegen import compiled
from rollbot_oc.model.dynamics import NX, POS, QUAT, THETA_DOT, motor_speed_clip, rk4, symbolic_model
from rollbot_oc.core.fastcall import FastFunction
from rollbot_oc.model.params import NP, TILT, ParamView, RollbotParams
from rollbot_oc.model.rotations import quat_multiply
from rollbot_oc.simulation.sensors import NSIG, Capture, ImuReading, SensingConfig, body_signals

__all__ = ["NA", "NE", "AUG", "ERR", "ERROR_NAMES", "ERROR_UNITS", "ESTIMATOR_STEP", "EstimatorSettings",
           "Estimate", "ErrorStateEKF", "boxplus", "boxminus", "imu_model", "imu_update", "mocap_update",
           "error_between"]

NA, NE = NX + 8, NX + 7
ESTIMATOR_STEP = 0.005  # s: the RK4 step of the prediction (the plant's own: 2 steps per 10 ms period)


class AUG:
    """Parts of the nominal state ``xa`` (19): ``xa[AUG.tilt]``."""

    state = slice(0, NX)
    gyro_bias = slice(NX, NX + 3)  # rad/s, body frame
    accel_bias = slice(NX + 3, NX + 6)  # m/s^2, body frame
    tilt = slice(NX + 6, NX + 8)  # in-plane gravity per g


class ERR:
    """Parts of the error state ``dx`` (18): ``dx[ERR.attitude]``."""

    position = slice(0, 2)  # m
    attitude = slice(2, 5)  # rad, floor frame
    omega = slice(5, 8)  # rad/s, floor frame
    theta = 8  # rad
    theta_dot = 9  # rad/s
    gyro_bias = slice(10, 13)  # rad/s
    accel_bias = slice(13, 16)  # m/s^2
    tilt = slice(16, 18)
ERROR_NAMES = ("x", "y", "phi_x", "phi_y", "phi_z", "wx", "wy", "wz", "theta", "theta_dot",
               "bg_x", "bg_y", "bg_z", "ba_x", "ba_y", "ba_z", "tilt_x", "tilt_y")
ERROR_UNITS = ("m", "m", "rad", "rad", "rad", "rad/s", "rad/s", "rad/s", "rad", "rad/s",
               "rad/s", "rad/s", "rad/s", "m/s^2", "m/s^2", "m/s^2", "1", "1")


def _small_rotation(phi):
    """Unit quaternion along ``(1, phi / 2)`` (CasADi): the rotation ``phi`` (rad) to first order."""
    dq = ca.vertcat(1.0, phi / 2)
    return dq / ca.norm_2(dq)


def _rotation_between(q1, q0):
    """The rotation error ``phi`` (3, rad) with ``q1 = q(phi) * q0`` (CasADi; the inverse of ``_small_rotation``)."""
    r = quat_multiply(q1, ca.vertcat(q0[0], -q0[1], -q0[2], -q0[3]))
    return 2 * r[1:4] / r[0]


def boxplus(xa, dx):
    """The nominal state ``xa`` (19) moved by an error ``dx`` (18) (CasADi)."""
    q = quat_multiply(_small_rotation(dx[ERR.attitude]), xa[QUAT])
    return ca.vertcat(xa[POS] + dx[ERR.position], q, xa[6:NA] + dx[ERR.omega.start:NE])


def boxminus(xa1, xa0):
    """The error ``dx`` (18) from ``xa0`` to ``xa1`` (19), ``xa1 = xa0 [+] dx`` (CasADi)."""
    return ca.vertcat(xa1[POS] - xa0[POS], _rotation_between(xa1[QUAT], xa0[QUAT]), xa1[6:NA] - xa0[6:NA])


@functools.lru_cache(maxsize=None)
def _boxminus_function() -> ca.Function:
    a, b = ca.SX.sym("a", NA), ca.SX.sym("b", NA)
    return ca.Function("boxminus", [a, b], [boxminus(a, b)])


def error_between(xa_true, xa_estimate) -> np.ndarray:
    """The estimation error ``xa_true [-] xa_estimate`` (18,), numpy (for checks and NEES)."""
    return np.array(_boxminus_function()(np.asarray(xa_true, float), np.asarray(xa_estimate, float))).ravel()


def _model_params(p, tilt):
    """The parameter vector ``p`` with its tilt replaced by the estimated one (CasADi)."""
    return ca.vertcat(p[:TILT.start], tilt, p[TILT.stop:])


def _kalman_update(xa, P, residual, H, R):
    """Joseph-form update of ``(xa, P)`` with a residual, its Jacobian ``H`` in ``dx`` and noise ``R``.

    MX expressions: the dense 18x18 products and the solve are single operations here (an SX
    expansion of them costs ten times as much to evaluate).
    """
    S = ca.mtimes([H, P, H.T]) + R
    K = ca.solve(S, ca.mtimes(H, P), "ldl").T  # P H^T S^-1 (S and P symmetric)
    A = ca.MX.eye(NE) - ca.mtimes(K, H)
    P_new = ca.mtimes([A, P, A.T]) + ca.mtimes([K, R, K.T])
    return _boxplus_function()(xa, ca.mtimes(K, residual)), 0.5 * (P_new + P_new.T), S


@functools.lru_cache(maxsize=None)
def _boxplus_function() -> ca.Function:
    xa, dx = ca.SX.sym("xa", NA), ca.SX.sym("dx", NE)
    return ca.Function("boxplus", [xa, dx], [boxplus(xa, dx)])


@functools.lru_cache(maxsize=None)
def imu_model(h: float, substeps: int) -> ca.Function:
    """The model part of ``imu_update`` (SX): prediction, error transition rate and measurement Jacobian.

    Returns
    -------
    casadi.Function
        ``(xa, a, p, z) -> (predicted (19), Ah (18, 18), H (7, 18), residual (7))`` with
        ``Phi = I + Ah + Ah^2 / 2`` the error transition over ``h`` (s).
    """
    sym, signals = symbolic_model(), body_signals()
    xa, a, p = ca.SX.sym("xa", NA), ca.SX.sym("a"), ca.SX.sym("p", NP)
    z, dx = ca.SX.sym("z", NSIG), ca.SX.sym("dx", NE)

    def advance(y):
        x = rk4(sym.plant_rhs, y[:NX], h, substeps, a, _model_params(p, y[AUG.tilt]), ca.DM.zeros(6))
        return ca.vertcat(x[POS], x[QUAT] / ca.norm_2(x[QUAT]), x[6:NX], y[NX:])

    def euler(y):  # one Euler step of the same model: its Jacobian gives the error transition's rate
        x = y[:NX] + h * sym.plant_rhs(y[:NX], a, _model_params(p, y[AUG.tilt]), ca.DM.zeros(6))
        return ca.vertcat(x, y[NX:])

    def measure(y):
        bias = ca.vertcat(y[AUG.gyro_bias], y[AUG.accel_bias], 0.0)
        return signals(y[:NX], a, _model_params(p, y[AUG.tilt]), ca.DM.zeros(6)) + bias

    zero = ca.DM.zeros(NE)
    predicted = advance(xa)
    # Error transition over h to second order, Phi = I + A h + (A h)^2 / 2, with A h the Jacobian (AD) of
    # one Euler step of the error at the midpoint of the interval (RK4's own Jacobian costs 8x as much).
    middle = boxplus(xa, 0.5 * boxminus(predicted, xa))
    Ah = ca.substitute(ca.jacobian(boxminus(euler(boxplus(middle, dx)), euler(middle)), dx), dx, zero) - ca.DM.eye(NE)
    H = ca.substitute(ca.jacobian(measure(boxplus(predicted, dx)), dx), dx, zero)
    return ca.Function("ekf_imu_model", [xa, a, p, z], [predicted, Ah, H, z - measure(predicted)],
                       ["xa", "a", "p", "z"], ["predicted", "Ah", "H", "residual"])


@functools.lru_cache(maxsize=None)
def imu_update(h: float, substeps: int, compile_model: bool = False) -> ca.Function:
    """One IMU sample interval of the filter: prediction and update with the IMU and encoder readings.

    Parameters
    ----------
    h : float
        Sample interval, s.
    substeps : int
        RK4 steps of the prediction.
    compile_model : bool
        Evaluate the model part (``imu_model``) as compiled C (``codegen.compiled``,
        cached on disk; CasADi's virtual machine, with a warning, where that fails).

    Returns
    -------
    casadi.Function
        ``(xa, P, a, p, z, r, qc) -> (xa_next, P_next, residual, S)``: nominal
        state (19) and covariance (18, 18) before; motor acceleration held
        over the interval (rad/s^2, after the speed limit); the robot's
        parameter vector (its tilt is ignored: the state's is used); the
        reading ``z`` (7: gyroscope rad/s, accelerometer m/s^2, encoder rad);
        the variances ``r`` (7) of its noise; the noise densities ``qc`` (18)
        of the error state's random walks (per second).  ``residual`` (7) and
        ``S`` (7, 7) are the innovation and its covariance.
    """
    model = compiled(imu_model(h, substeps)) if compile_model else imu_model(h, substeps)
    xm, Pm, am, pm = ca.MX.sym("xa", NA), ca.MX.sym("P", NE, NE), ca.MX.sym("a"), ca.MX.sym("p", NP)
    zm, rm, qm = ca.MX.sym("z", NSIG), ca.MX.sym("r", NSIG), ca.MX.sym("qc", NE)
    predicted, Ah, H, residual = model(xm, am, pm, zm)
    Phi = ca.MX.eye(NE) + Ah + 0.5 * ca.mtimes(Ah, Ah)
    Qc = ca.diag(qm)
    P_pred = ca.mtimes([Phi, Pm, Phi.T]) + 0.5 * h * (ca.mtimes([Phi, Qc, Phi.T]) + Qc)
    xa_new, P_new, S = _kalman_update(predicted, P_pred, residual, H, ca.diag(rm))
    return ca.Function("ekf_imu_update", [xm, Pm, am, pm, zm, rm, qm], [xa_new, P_new, residual, S],
                       ["xa", "P", "a", "p", "z", "r", "qc"], ["xa_next", "P_next", "residual", "S"])


@functools.lru_cache(maxsize=None)
def mocap_update() -> ca.Function:
    """The filter's update with a motion-capture sample.

    Returns
    -------
    casadi.Function
        ``(xa, P, xa_capture, z, r) -> (xa_next, P_next, residual, S)``: the
        estimate now, the estimate at the capture time, the measurement ``z``
        (6: position (2, m) and quaternion (4)) and the variances ``r`` (5:
        position m^2, rotation rad^2).  The residual (5) is
        the measured position minus the estimated one at capture and the
        rotation from the estimated to the measured orientation there.
    """
    xa, dx = ca.SX.sym("xa", NA), ca.SX.sym("dx", NE)
    xc, z = ca.SX.sym("xa_capture", NA), ca.SX.sym("z", 6)
    moved = boxplus(xa, dx)
    pose_error = ca.vertcat(moved[POS] - xa[POS], _rotation_between(moved[QUAT], xa[QUAT]))
    H = ca.substitute(ca.jacobian(pose_error, dx), dx, ca.DM.zeros(NE))
    residual = ca.vertcat(z[0:2] - xc[POS], _rotation_between(z[2:6], xc[QUAT]))
    model = ca.Function("ekf_mocap_model", [xa, xc, z], [H, residual])
    xm, Pm, xcm = ca.MX.sym("xa", NA), ca.MX.sym("P", NE, NE), ca.MX.sym("xa_capture", NA)
    zm, rm = ca.MX.sym("z", 6), ca.MX.sym("r", 5)
    H, residual = model(xm, xcm, zm)
    xa_new, P_new, S = _kalman_update(xm, Pm, residual, H, ca.diag(rm))
    return ca.Function("ekf_mocap_update", [xm, Pm, xcm, zm, rm], [xa_new, P_new, residual, S],
                       ["xa", "P", "xa_capture", "z", "r"], ["xa_next", "P_next", "residual", "S"])


@dataclass(frozen=True)
class EstimatorSettings:
    """Process noise and prior of the filter (SI units).

    The measurement noise comes from the sensor models (``SensingConfig``):
    one sample's gyroscope and accelerometer noise, the encoder's
    quantisation, the motion capture's noise.  The bias random walks are the
    IMU's own.

    Attributes
    ----------
    omega_noise : float
        Density of the model error in the shell's angular acceleration,
        rad/s^2/sqrt(Hz): how much the filter trusts the dynamics over the
        gyroscope.
    motor_noise : float
        Density of the error in the driving speed's rate, rad/s^2/sqrt(Hz)
        (the motor not following the command exactly).
    slip_noise : float
        Density of the position's random walk, m/sqrt(s) (slip).
    tilt_walk : float
        Density of the tilt's random walk, 1/sqrt(s) (a floor that is not flat).
    position_std, attitude_std : float
        Prior standard deviations of the start pose, m and rad (the start is known).
    omega_std, theta_std, theta_dot_std : float
        Prior standard deviations of the shell's angular velocity (rad/s), the
        motor angle (rad) and the driving speed (rad/s).
    tilt_std : float
        Prior standard deviation of the tilt, per component (2 deg).
    gyro_bias_std, accel_bias_std : float or None
        Prior standard deviations of the biases, rad/s and m/s^2; ``None``:
        the IMU's bound over sqrt(3) (its uniform distribution's).
    compiled : bool
        Evaluate the model part of the IMU update as compiled C (built once
        and cached, see ``codegen``); False: CasADi's virtual machine.
    """

    omega_noise: float = 0.05
    motor_noise: float = 0.05
    slip_noise: float = 1e-4
    tilt_walk: float = 1e-5
    position_std: float = 1e-3
    attitude_std: float = math.radians(0.1)
    omega_std: float = 1e-3
    theta_std: float = 1e-3
    theta_dot_std: float = 1e-3
    tilt_std: float = math.sin(math.radians(2.0))
    gyro_bias_std: float | None = None
    accel_bias_std: float | None = None
    compiled: bool = True

    @classmethod
    def exact_model(cls) -> "EstimatorSettings":
        """Process noise for a plant that is the filter's own model (simulation checks, NEES).

        The default leaves room for model error (masses, damping, slip), which
        makes the filter conservative where the plant is the model; here the
        model-error densities are almost zero, as they are in such a simulation.
        """
        return cls(omega_noise=1e-5, motor_noise=1e-5, slip_noise=1e-7, tilt_walk=0.0)

    def __post_init__(self):
        for name, value in vars(self).items():
            if name == "compiled":
                continue
            if value is not None and not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0):
                raise ValueError(f"EstimatorSettings: {name} = {value!r} must be a finite number >= 0")


@dataclass(frozen=True)
class Estimate:
    """The filter's estimate at one time (SI units, floor frame).

    Attributes
    ----------
    t : float
        Time, s.
    state : numpy.ndarray (11,)
        Estimated model state (``dynamics``): position, quaternion, angular
        velocity, motor angle and driving speed.
    gyro_bias : numpy.ndarray (3,)
        Gyroscope bias, body frame, rad/s.
    accel_bias : numpy.ndarray (3,)
        Accelerometer bias, body frame, m/s^2.
    tilt : numpy.ndarray (2,)
        Floor tilt, in-plane gravity per g (``RollbotParams.tilt_x``, ``tilt_y``).
    covariance : numpy.ndarray (18, 18)
        Covariance of the error state (``ERROR_NAMES``, ``ERROR_UNITS``).
    """

    t: float
    state: np.ndarray
    gyro_bias: np.ndarray
    accel_bias: np.ndarray
    tilt: np.ndarray
    covariance: np.ndarray

    @property
    def augmented(self) -> np.ndarray:
        """The nominal state (19,): state, gyroscope bias, accelerometer bias, tilt."""
        return np.concatenate([self.state, self.gyro_bias, self.accel_bias, self.tilt])

    @property
    def std(self) -> np.ndarray:
        """Standard deviations of the error state (18,), units as ``ERROR_UNITS``."""
        return np.sqrt(np.maximum(np.diag(self.covariance), 0.0))

    @property
    def position_covariance(self) -> np.ndarray:
        """Covariance of the shell-centre position (2, 2), m^2."""
        return self.covariance[ERR.position, ERR.position]


class ErrorStateEKF:
    """The error-state EKF (module doc) for one robot and one set of sensors.

    Parameters
    ----------
    params : RollbotParams
        The robot the filter believes in; its tilt is the prior mean of the tilt state.
    sensing : SensingConfig
        The sensors (their noise sets the measurement noise).
    dt : float
        Control period, s (the IMU samples ``sensing.imu.rate * dt`` times per period).
    settings : EstimatorSettings, optional
    """

    def __init__(self, params: RollbotParams, sensing: SensingConfig, dt: float,
                 settings: EstimatorSettings | None = None):
        self.params, self.sensing, self.dt = params, sensing, dt
        self.settings = s = settings or EstimatorSettings()
        imu = sensing.imu
        self.samples = imu.samples_per_period(dt)
        self.h = dt / self.samples
        self._imu = FastFunction(imu_update(self.h, max(1, round(self.h / ESTIMATOR_STEP)), s.compiled))
        self._mocap = FastFunction(mocap_update())
        self.p = params.vector()
        self.max_speed = float(ParamView(self.p).max_speed)
        sigma_g, sigma_a = imu.sample_noise(dt)
        floor = 1e-14  # a perfect sensor still gets a tiny variance, so S stays invertible
        self.r_imu = np.maximum(np.array([sigma_g**2] * 3 + [sigma_a**2] * 3 + [sensing.encoder.sigma**2]), floor)
        mocap = sensing.mocap
        self.r_mocap = np.maximum(np.array([mocap.position_noise**2] * 2 + [mocap.angle_noise**2] * 3), floor)
        qc = np.zeros(NE)
        qc[ERR.position] = s.slip_noise**2
        qc[ERR.omega] = s.omega_noise**2
        qc[ERR.theta_dot] = s.motor_noise**2
        qc[ERR.gyro_bias] = imu.gyro_bias_walk**2
        qc[ERR.accel_bias] = imu.accel_bias_walk**2
        qc[ERR.tilt] = s.tilt_walk**2
        self.qc = qc
        bias_g = s.gyro_bias_std if s.gyro_bias_std is not None else imu.gyro_bias / math.sqrt(3)
        bias_a = s.accel_bias_std if s.accel_bias_std is not None else imu.accel_bias / math.sqrt(3)
        self.prior_std = np.array([s.position_std] * 2 + [s.attitude_std] * 3 + [s.omega_std] * 3
                                  + [s.theta_std, s.theta_dot_std] + [bias_g] * 3 + [bias_a] * 3
                                  + [s.tilt_std] * 2)
        self.prior_std = np.maximum(self.prior_std, 1e-7)
        history = math.ceil(mocap.latency / dt) + 2 if sensing.uses_mocap else 1
        self._history: deque[tuple[int, np.ndarray]] = deque(maxlen=history)
        self.xa = np.zeros(NA)
        self.P = np.eye(NE)
        self.step = 0

    def reset(self, x0, step: int = 0, rng: np.random.Generator | None = None) -> None:
        """Start from the known state ``x0`` (11,) at control ``step``: biases zero, tilt from ``params``.

        With ``rng`` the start is not known but drawn: the state's and the
        tilt's initial errors are drawn from the prior (the biases' errors
        are the sensors' own draws), as a Monte Carlo consistency check needs.
        """
        self.xa = np.concatenate([np.asarray(x0, float), np.zeros(6), self.p[TILT]])
        self.P = np.diag(self.prior_std**2)
        if rng is not None:
            error = rng.normal(0.0, self.prior_std)
            error[ERR.gyro_bias] = error[ERR.accel_bias] = 0.0
            self.xa = np.array(_boxplus_function()(self.xa, error)).ravel()
        self.step = step
        self._history.clear()
        self._history.append((step, self.xa.copy()))
        self.last_residual = np.zeros(NSIG)

    def propagate(self, a_cmd: float, readings: list[ImuReading]) -> None:
        """Advance one control period under the motor command ``a_cmd`` (rad/s^2) with its IMU readings.

        The command is limited as the motor's driver limits it
        (``dynamics.motor_speed_clip``, from the estimated driving speed).
        """
        if len(readings) != self.samples:
            raise ValueError(f"ErrorStateEKF: {len(readings)} IMU readings for a period, expected {self.samples}")
        a = motor_speed_clip(float(a_cmd), self.xa[THETA_DOT], self.max_speed, self.dt)
        for reading in readings:
            z = np.concatenate([reading.gyro, reading.accel, [reading.theta]])
            xa, P, residual, _ = self._imu(self.xa, self.P, a, self.p, z, self.r_imu, self.qc)
            self.xa, self.P, self.last_residual = xa.copy(), P.reshape(NE, NE).copy(), residual.copy()
        self.step += 1
        self._history.append((self.step, self.xa.copy()))

    def fuse(self, capture: Capture) -> bool:
        """Fold in a motion-capture sample; False if it is older than the buffer of past estimates."""
        past = next((xa for step, xa in self._history if step == capture.step), None)
        if past is None:
            return False
        z = np.concatenate([capture.position, capture.quaternion])
        xa, P, _, _ = self._mocap(self.xa, self.P, past, z, self.r_mocap)
        self.xa, self.P = xa.copy(), P.reshape(NE, NE).copy()
        self._history[-1] = (self.step, self.xa.copy())
        return True

    def estimate(self) -> Estimate:
        """The current estimate and its covariance."""
        xa = self.xa
        return Estimate(self.step * self.dt, xa[:NX].copy(), xa[AUG.gyro_bias].copy(), xa[AUG.accel_bias].copy(),
                        xa[AUG.tilt].copy(), self.P.copy())
