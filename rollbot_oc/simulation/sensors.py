"""Onboard sensors of Rollbot: a body-fixed IMU, the motor encoder and (optionally) motion capture.

What each sensor measures, in the plant's terms (SI units, radians):

* **Gyroscope** (body-fixed, on the shell): the shell's angular velocity in
  the body frame, ``T^T omega``, plus a bias and white noise.  The bias starts
  at a value drawn uniformly from ``[-gyro_bias, gyro_bias]`` on each axis and
  then walks (``gyro_bias_walk``, a rate random walk).  The white noise of one
  sample is ``gyro_noise_density * sqrt(rate)`` (a density sampled at
  ``rate``).
* **Accelerometer** (body-fixed, at the shell centre): the specific force
  ``T^T (a_c - g)``, with ``a_c = omega_dot x (R z)`` the centre's
  acceleration in rolling without slip and ``g`` the gravity vector of the
  (possibly tilted) floor; plus a bias (uniform initial value, random walk)
  and white noise, likewise.
* **Motor encoder**: the motor angle ``theta`` in whole counts,
  ``2 pi / counts`` rad each (rounded to the nearest count: the quantisation
  error is uniform, of variance ``(2 pi / counts)^2 / 12``); an incremental
  count, so it does not wrap.  ``counts = None`` is an ideal encoder.
* **Motion capture** (optional): the shell-centre position and the
  orientation, with Gaussian noise (a small random rotation for the
  orientation), captured at ``rate`` and delivered ``latency`` later; captures
  that fall in an outage (``outage_length`` s starting at each of
  ``outage_times`` and, if ``outage_every > 0``, at every multiple of
  ``outage_every``) are lost.

The IMU is sampled ``samples_per_period`` times per control period, at the
end of each equal part of it, with the motor command of that period held
(``body_signals`` gives the noise-free signals; the plant evaluates them
inside its step, ``simulation.plant.plant_step(..., samples=m)``).  Motion capture
samples the state at control instants.  Every random number comes from one
``numpy.random.default_rng(seed)`` in a fixed order: the same seed gives the
same readings.

The defaults are a consumer MEMS IMU (gyroscope noise density 0.005 deg/s/sqrt(Hz),
initial bias up to 0.5 deg/s, accelerometer noise 150 ug/sqrt(Hz)), a 4096-count
encoder and a motion-capture system like the paper's OptiTrack (100 Hz, 1 mm).

Scenario files set them in the ``[sensor]`` table (``mode``,
``encoder_counts``) and its ``[sensor.imu]`` and ``[sensor.mocap]`` tables,
with the keys of ``ImuModel.FILE_KEYS``, ``MocapModel.FILE_KEYS`` (file units:
``*_deg`` keys in degrees; see ``rollbot_oc.scenarios.problem``).
"""

from __future__ import annotations

import functools
import math
from collections import deque
from dataclasses import dataclass, field
from typing import ClassVar

import casadi as ca
import numpy as np

from rollbot_oc.model.dynamics import NU, NW, NX, OMEGA, POS, QUAT, THETA, gravity_vector, symbolic_model
from rollbot_oc.core.errors import ConfigError
from rollbot_oc.model.params import NP, ParamView
from rollbot_oc.core.reproducible import norm
from rollbot_oc.model.rotations import quat_multiply_np, quat_to_matrix

__all__ = ["ImuModel", "EncoderModel", "MocapModel", "SensingConfig", "MODES", "NSIG", "body_signals",
           "ImuReading", "Capture", "OnboardSensors", "G0", "rotate_randomly"]

MODES = ("mocap", "imu", "imu+mocap")
G0 = 9.80665  # m/s^2 per g (accelerometer datasheets give densities in ug/sqrt(Hz))
NSIG = 7  # body_signals rows: body angular velocity (3), specific force (3), motor angle
_DEG = math.pi / 180.0


def _check_fields(obj, where: str) -> None:
    """Range checks of a sensor model's fields from its ``FILE_KEYS`` (SI values against SI ranges)."""
    for key, (attr, scale, low, high, unit) in obj.FILE_KEYS.items():
        value = getattr(obj, attr)
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise ConfigError(f"{where}: {attr} = {value!r} must be a finite number ({unit})")
        if not low * scale <= value <= high * scale:
            raise ConfigError(f"{where}: {attr} = {value!r} is out of range: valid is [{low * scale:g}, "
                              f"{high * scale:g}] (file key {key}: [{low:g}, {high:g}] {unit})")


@dataclass(frozen=True)
class ImuModel:
    """A body-fixed MEMS IMU at the shell centre: gyroscope and accelerometer (SI units).

    Attributes
    ----------
    rate : float
        Sampling rate, Hz; a whole multiple of the control rate.
    gyro_noise_density : float
        Gyroscope white noise, rad/s/sqrt(Hz) (0.005 deg/s/sqrt(Hz)).
    gyro_bias : float
        Bound of the initial gyroscope bias on each axis, rad/s (drawn
        uniformly in ``[-gyro_bias, gyro_bias]``; 0.5 deg/s).
    gyro_bias_walk : float
        Rate random walk of the gyroscope bias, rad/s/sqrt(s) (0.001 deg/s/sqrt(s)).
    accel_noise_density : float
        Accelerometer white noise, m/s^2/sqrt(Hz) (150 ug/sqrt(Hz)).
    accel_bias : float
        Bound of the initial accelerometer bias on each axis, m/s^2 (10 mg,
        a calibrated consumer part).
    accel_bias_walk : float
        Random walk of the accelerometer bias, m/s^2/sqrt(s).
    """

    rate: float = 100.0
    gyro_noise_density: float = 0.005 * _DEG
    gyro_bias: float = 0.5 * _DEG
    gyro_bias_walk: float = 0.001 * _DEG
    accel_noise_density: float = 150e-6 * G0
    accel_bias: float = 0.010 * G0
    accel_bias_walk: float = 1e-4

    # file key -> (attribute, scale from file units to SI, low, high (file units), unit)
    FILE_KEYS: ClassVar[dict] = {
        "rate": ("rate", 1.0, 1.0, 10000.0, "Hz"),
        "gyro_noise_density_deg": ("gyro_noise_density", _DEG, 0.0, 10.0, "deg/s/sqrt(Hz)"),
        "gyro_bias_deg": ("gyro_bias", _DEG, 0.0, 100.0, "deg/s"),
        "gyro_bias_walk_deg": ("gyro_bias_walk", _DEG, 0.0, 10.0, "deg/s/sqrt(s)"),
        "accel_noise_density": ("accel_noise_density", 1.0, 0.0, 10.0, "m/s^2/sqrt(Hz)"),
        "accel_bias": ("accel_bias", 1.0, 0.0, 10.0, "m/s^2"),
        "accel_bias_walk": ("accel_bias_walk", 1.0, 0.0, 10.0, "m/s^2/sqrt(s)"),
    }

    def __post_init__(self):
        _check_fields(self, "ImuModel")

    @classmethod
    def perfect(cls, rate: float = 100.0) -> "ImuModel":
        """An IMU without noise or bias (for checks)."""
        return cls(rate, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)

    def samples_per_period(self, dt: float) -> int:
        """IMU samples per control period ``dt`` (s); raises ``ConfigError`` unless ``rate * dt`` is whole."""
        m = self.rate * dt
        if abs(m - round(m)) > 1e-6 * max(1.0, m) or round(m) < 1:
            raise ConfigError(f"IMU rate = {self.rate:g} Hz must be a whole multiple of the control rate "
                              f"{1 / dt:g} Hz (valid: {1 / dt:g}, {2 / dt:g}, {3 / dt:g}, ... Hz)")
        return int(round(m))

    def sample_noise(self, dt: float) -> np.ndarray:
        """Standard deviations of one sample's white noise: gyroscope (rad/s) and accelerometer (m/s^2)."""
        root = math.sqrt(self.rate)
        return np.array([self.gyro_noise_density * root, self.accel_noise_density * root])


@dataclass(frozen=True)
class EncoderModel:
    """The motor encoder.

    Attributes
    ----------
    counts : int or None
        Counts per revolution (4096); ``None`` is an ideal encoder.
    """

    counts: int | None = 4096

    def __post_init__(self):
        if self.counts is not None and (isinstance(self.counts, bool) or int(self.counts) != self.counts
                                        or not 16 <= self.counts <= 1 << 30):
            raise ConfigError(f"EncoderModel: counts = {self.counts!r} must be a whole number in [16, 2^30]")

    @property
    def resolution(self) -> float:
        """Angle of one count, rad (0 for an ideal encoder)."""
        return 0.0 if self.counts is None else 2 * math.pi / self.counts

    @property
    def sigma(self) -> float:
        """Standard deviation of the quantisation error, rad (uniform over one count)."""
        return self.resolution / math.sqrt(12.0)

    def read(self, theta: float) -> float:
        """The angle the encoder reports for a motor angle ``theta`` (rad): the nearest whole count."""
        q = self.resolution
        return float(theta) if q == 0.0 else q * round(float(theta) / q)


@dataclass(frozen=True)
class MocapModel:
    """Motion capture: position and orientation at a rate, with latency, noise and outages.

    Attributes
    ----------
    rate : float
        Capture rate, Hz; its period must be a whole number of control periods.
    latency : float
        Time from capture to delivery, s; a capture is used at the first
        control instant at or after it arrives.
    position_noise : float
        Standard deviation of the position noise, m.
    angle_noise : float
        Standard deviation of the orientation noise (a small random rotation), rad.
    outage_length : float
        Length of each outage, s.
    outage_every : float
        Period of repeated outages, s (0: none); outages start at
        ``outage_every``, ``2 outage_every``, ...
    outage_times : tuple of float
        Further outage starts, s.
    """

    rate: float = 100.0
    latency: float = 0.01
    position_noise: float = 0.001
    angle_noise: float = 0.003
    outage_length: float = 0.0
    outage_every: float = 0.0
    outage_times: tuple = ()

    FILE_KEYS: ClassVar[dict] = {
        "rate": ("rate", 1.0, 0.1, 10000.0, "Hz"),
        "latency": ("latency", 1.0, 0.0, 1.0, "s"),
        "position_noise": ("position_noise", 1.0, 0.0, 1.0, "m"),
        "angle_noise": ("angle_noise", 1.0, 0.0, 1.0, "rad"),
        "outage_length": ("outage_length", 1.0, 0.0, 3600.0, "s"),
        "outage_every": ("outage_every", 1.0, 0.0, 3600.0, "s"),
    }

    def __post_init__(self):
        _check_fields(self, "MocapModel")
        times = tuple(float(t) for t in self.outage_times)
        if not all(math.isfinite(t) and 0.0 <= t <= 3600.0 for t in times):
            raise ConfigError(f"MocapModel: outage_times = {self.outage_times!r} must be times in [0, 3600] s")
        object.__setattr__(self, "outage_times", times)
        if 0 < self.outage_every <= self.outage_length:
            raise ConfigError(f"MocapModel: outage_every = {self.outage_every!r} s must be longer than "
                              f"outage_length = {self.outage_length!r} s (or 0 for no repeated outages)")

    def period_steps(self, dt: float) -> int:
        """Control periods between captures; raises ``ConfigError`` unless ``1 / (rate dt)`` is whole."""
        n = 1.0 / (self.rate * dt)
        if abs(n - round(n)) > 1e-6 * max(1.0, n) or round(n) < 1:
            raise ConfigError(f"motion-capture rate = {self.rate:g} Hz: its period must be a whole number of "
                              f"control periods of {dt:g} s (valid: {1 / dt:g}, {1 / (2 * dt):g}, "
                              f"{1 / (3 * dt):g}, ... Hz)")
        return int(round(n))

    def in_outage(self, t: float) -> bool:
        """True if a capture at time ``t`` (s) is lost to an outage."""
        if self.outage_length <= 0:
            return False
        eps = 1e-9
        if any(start - eps <= t < start + self.outage_length - eps for start in self.outage_times):
            return True
        if self.outage_every > 0 and t >= self.outage_every - eps:
            phase = (t + eps) % self.outage_every
            return phase < self.outage_length
        return False


@dataclass(frozen=True)
class SensingConfig:
    """How the controller learns the state: the sensing mode and its sensors.

    Attributes
    ----------
    mode : {"mocap", "imu", "imu+mocap"}
        ``"mocap"``: the controller sees motion capture and a gyroscope
        directly (``simulation.plant.Sensor``); ``"imu"``: it sees
        the estimate from the IMU and the encoder (dead reckoning);
        ``"imu+mocap"``: the estimate fusing motion capture too.
    imu : ImuModel
    encoder : EncoderModel
    mocap : MocapModel
        Used in ``"imu+mocap"``.
    """

    mode: str = "mocap"
    imu: ImuModel = field(default_factory=ImuModel)
    encoder: EncoderModel = field(default_factory=EncoderModel)
    mocap: MocapModel = field(default_factory=MocapModel)

    def __post_init__(self):
        if self.mode not in MODES:
            raise ConfigError(f"sensing mode = {self.mode!r}; valid are {', '.join(MODES)}")

    @property
    def onboard(self) -> bool:
        """True if the controller sees an estimate from onboard sensors (modes ``imu`` and ``imu+mocap``)."""
        return self.mode != "mocap"

    @property
    def uses_mocap(self) -> bool:
        """True if the estimator fuses motion capture."""
        return self.mode == "imu+mocap"

    def check_period(self, dt: float) -> None:
        """Check the rates against the control period ``dt`` (s); raises ``ConfigError``."""
        if self.onboard:
            self.imu.samples_per_period(dt)
        if self.uses_mocap:
            self.mocap.period_steps(dt)


_EZ = ca.DM([0.0, 0.0, 1.0])


def rotate_randomly(q, sigma: float, rng: np.random.Generator) -> np.ndarray:
    """The orientation ``q`` (4,) turned by a small random rotation of about ``sigma`` rad per axis (a copy).

    The rotation is the unit quaternion along ``(1, n / 2)`` with ``n ~ N(0, sigma^2 I3)``, applied in the
    floor frame; ``sigma = 0`` draws nothing.
    """
    q = np.array(q, float)
    if sigma > 0:
        q = quat_multiply_np(np.concatenate([[1.0], 0.5 * rng.normal(0.0, sigma, 3)]), q)
        q /= norm(q)
    return q


@functools.lru_cache(maxsize=None)
def body_signals() -> ca.Function:
    """What the onboard sensors feel, noise-free, as a cached CasADi Function.

    Returns
    -------
    casadi.Function
        ``(x, a, p, w) -> s (7,)``: the shell's angular velocity in the body
        frame (rad/s), the specific force at the shell centre in the body frame
        (m/s^2; ``T^T (omega_dot x R z - g)``, the motor acceleration ``a``
        (rad/s^2) held and saturated as in the plant) and the motor angle (rad).
    """
    sym = symbolic_model()
    x, a, p, w = ca.SX.sym("x", NX), ca.SX.sym("a", NU), ca.SX.sym("p", NP), ca.SX.sym("w", NW)
    P = ParamView(p)
    T = quat_to_matrix(x[QUAT])
    omega_dot = sym.plant_rhs(x, a, p, w)[OMEGA]
    gravity = gravity_vector(P.g, P.tilt_x, P.tilt_y)
    specific_force = ca.cross(omega_dot, P.R * _EZ) - gravity
    out = ca.vertcat(ca.mtimes(T.T, x[OMEGA]), ca.mtimes(T.T, specific_force), x[THETA])
    return ca.Function("body_signals", [x, a, p, w], [out], ["x", "a", "p", "w"], ["s"])


@dataclass(frozen=True)
class ImuReading:
    """One IMU sample and the encoder read with it.

    Attributes
    ----------
    gyro : numpy.ndarray (3,)
        Angular velocity, body frame, rad/s.
    accel : numpy.ndarray (3,)
        Specific force, body frame, m/s^2.
    theta : float
        Encoder angle, rad.
    """

    gyro: np.ndarray
    accel: np.ndarray
    theta: float


@dataclass(frozen=True)
class Capture:
    """A motion-capture sample.

    Attributes
    ----------
    step : int
        Control step at which it was captured (its time is ``step * dt``).
    position : numpy.ndarray (2,)
        Shell-centre position, m.
    quaternion : numpy.ndarray (4,)
        Orientation body -> floor, scalar first.
    """

    step: int
    position: np.ndarray
    quaternion: np.ndarray


class OnboardSensors:
    """The sensors of one run: their true biases, noise, sampling and the motion-capture queue.

    Parameters
    ----------
    config : SensingConfig
    dt : float
        Control period, s.
    seed : int
        Seed of every random number (initial biases, noise, bias walks).
    """

    def __init__(self, config: SensingConfig, dt: float, seed: int = 0):
        config.check_period(dt)
        self.config, self.dt, self.seed = config, dt, seed
        self.samples = config.imu.samples_per_period(dt)
        self.h = dt / self.samples
        self.reset()

    def reset(self) -> None:
        """Draw the initial biases again from the seed and empty the motion-capture queue."""
        imu = self.config.imu
        self.rng = np.random.default_rng(self.seed)
        self.gyro_bias = self.rng.uniform(-imu.gyro_bias, imu.gyro_bias, 3)
        self.accel_bias = self.rng.uniform(-imu.accel_bias, imu.accel_bias, 3)
        self._queue: deque[tuple[int, Capture]] = deque()

    @property
    def bias(self) -> np.ndarray:
        """The true biases now: gyroscope (3, rad/s) then accelerometer (3, m/s^2)."""
        return np.concatenate([self.gyro_bias, self.accel_bias])

    def read_imu(self, signals) -> list[ImuReading]:
        """Readings of one control period from the noise-free ``signals`` (7, samples) of ``body_signals``.

        Each sample first walks the biases, then adds them and the white noise (one draw of 12 normal
        numbers per sample: bias walks, gyroscope noise, accelerometer noise).
        """
        imu, h = self.config.imu, self.h
        sigma_g, sigma_a = imu.sample_noise(self.dt)
        scale = np.repeat([imu.gyro_bias_walk * math.sqrt(h), imu.accel_bias_walk * math.sqrt(h), sigma_g, sigma_a], 3)
        signals = np.asarray(signals, float).reshape(NSIG, -1, order="F")
        draws = self.rng.normal(size=(signals.shape[1], 12)) * scale
        out = []
        for i, d in enumerate(draws):
            self.gyro_bias = self.gyro_bias + d[0:3]
            self.accel_bias = self.accel_bias + d[3:6]
            gyro = signals[0:3, i] + self.gyro_bias + d[6:9]
            accel = signals[3:6, i] + self.accel_bias + d[9:12]
            out.append(ImuReading(gyro, accel, self.config.encoder.read(signals[6, i])))
        return out

    def capture(self, step: int, x) -> None:
        """Let motion capture see the state ``x`` (11,) at control ``step`` (queued until it arrives)."""
        mocap = self.config.mocap
        if not self.config.uses_mocap or step % mocap.period_steps(self.dt) or mocap.in_outage(step * self.dt):
            return
        rng = self.rng
        q = rotate_randomly(x[QUAT], mocap.angle_noise, rng)
        position = np.asarray(x[POS], float) + (rng.normal(0.0, mocap.position_noise, 2)
                                               if mocap.position_noise else 0.0)
        arrival = math.ceil((step * self.dt + mocap.latency) / self.dt - 1e-9)
        self._queue.append((arrival, Capture(step, position, q)))

    def arrived(self, step: int) -> list[Capture]:
        """The captures delivered by control ``step``, oldest first."""
        out = []
        while self._queue and self._queue[0][0] <= step:
            out.append(self._queue.popleft()[1])
        return out
