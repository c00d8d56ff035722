"""Onboard sensing in the closed loop: the sensors read the plant, the filter turns readings into the estimate.

``OnboardSensing`` is what ``simulation.plant.simulate`` takes as its ``sensor`` in
the modes ``"imu"`` and ``"imu+mocap"`` (``sensors.SensingConfig``).  At
each control step ``k`` (time ``k dt``) it

1. reads the IMU samples and the encoder of the period that just ended
   (the plant's noise-free signals, ``simulation.plant.plant_step(..., samples=m)``,
   with the sensors' noise and biases) and advances the filter through them
   under the motor command of that period;
2. lets motion capture see the true state (mode ``"imu+mocap"``; queued
   until its latency has passed, lost in an outage) and fuses the captures
   that have arrived;
3. returns the estimate, which the loop hands to the controller as its
   ``Observation``, and records it with its covariance
   (``EstimationRecord``) beside the true biases, for metrics and checks.

The start pose is known: the filter starts from the true initial state
(``ErrorStateEKF.reset``) with the prior of ``EstimatorSettings``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import stats

from rollbot_oc.model.dynamics import POS
from rollbot_oc.simulation.ekf import NA, NE, ErrorStateEKF, Estimate, EstimatorSettings, error_between
from rollbot_oc.core.errors import ConfigError
from rollbot_oc.model.params import RollbotParams
from rollbot_oc.core.reproducible import dot, solve
from rollbot_oc.simulation.sensors import OnboardSensors, SensingConfig

__all__ = ["OnboardSensing", "EstimationRecord", "nees_bounds"]


@dataclass
class EstimationRecord:
    """The estimate at every control step of a run, with its uncertainty and the sensors' true biases.

    Attributes
    ----------
    mode : str
        The sensing mode (``"imu"`` or ``"imu+mocap"``).
    t : numpy.ndarray (K,)
        Times of the estimates (the control instants), s.
    estimate : numpy.ndarray (19, K)
        Nominal states (``simulation.ekf.AUG``): model state, gyroscope bias,
        accelerometer bias, tilt.
    std : numpy.ndarray (18, K)
        Standard deviations of the error state (``simulation.ekf.ERROR_NAMES``, ``ERROR_UNITS``).
    position_covariance : numpy.ndarray (K, 2, 2)
        Covariance of the estimated shell-centre position, m^2.
    true_bias : numpy.ndarray (6, K)
        The sensors' true gyroscope (rad/s) and accelerometer (m/s^2) biases.
    fused : numpy.ndarray (K,)
        Motion-capture samples fused at each step.
    covariance : numpy.ndarray (K, 18, 18) or None
        Full covariances, if the run kept them (``keep_covariance``).
    """

    mode: str
    t: np.ndarray
    estimate: np.ndarray
    std: np.ndarray
    position_covariance: np.ndarray
    true_bias: np.ndarray
    fused: np.ndarray
    covariance: np.ndarray | None = None

    ARRAYS = ("t", "estimate", "std", "position_covariance", "true_bias", "fused")

    def __len__(self) -> int:
        return self.t.size

    def head(self, n: int) -> "EstimationRecord":
        """The first ``n`` steps."""
        cut = {key: getattr(self, key)[..., :n] if key not in ("position_covariance",) else
               getattr(self, key)[:n] for key in self.ARRAYS}
        return EstimationRecord(self.mode, **cut,
                                covariance=None if self.covariance is None else self.covariance[:n])

    def to_arrays(self) -> dict:
        """The record as arrays named ``estimation_*`` (for ``SimulationResult.save``; full covariances left out)."""
        out = {f"estimation_{key}": getattr(self, key) for key in self.ARRAYS}
        out["estimation_mode"] = np.array(self.mode)
        return out

    @classmethod
    def from_arrays(cls, data: dict, source: str) -> "EstimationRecord | None":
        """The record saved by ``to_arrays`` in ``data``, or None if there is none.

        Raises
        ------
        ConfigError
            If the arrays are there but do not fit together.
        """
        keys = [f"estimation_{key}" for key in cls.ARRAYS] + ["estimation_mode"]
        present = [key for key in keys if key in data]
        if not present:
            return None
        try:
            if len(present) != len(keys):
                raise ValueError(f"missing {', '.join(sorted(set(keys) - set(present)))}")
            arrays = {key: np.asarray(data[f"estimation_{key}"], float) for key in cls.ARRAYS}
            n = arrays["t"].size
            shapes = {"t": (n,), "estimate": (NA, n), "std": (NE, n), "position_covariance": (n, 2, 2),
                      "true_bias": (6, n), "fused": (n,)}
            if any(arrays[key].shape != shape for key, shape in shapes.items()):
                raise ValueError("arrays of inconsistent shapes")
            if not all(np.all(np.isfinite(a)) for a in arrays.values()):
                raise ValueError("non-finite values")
        except (ValueError, TypeError) as exc:
            raise ConfigError(f"{source}: not a saved run (estimation: {exc})") from None
        arrays["fused"] = arrays["fused"].astype(int)
        return cls(str(data["estimation_mode"]), **arrays)

    def position_error(self, x) -> np.ndarray:
        """Distance between the true and the estimated shell-centre position at each step (K,), m.

        ``x`` holds the true states (11, >= K), one column per control instant.
        """
        return np.linalg.norm(np.asarray(x)[POS, :len(self)] - self.estimate[POS], axis=0)

    def truth(self, x, tilt) -> np.ndarray:
        """The true nominal states (19, K) from the true states ``x`` (11, >= K) and the floor's ``tilt`` (2,)."""
        n = len(self)
        return np.vstack([np.asarray(x)[:, :n], self.true_bias, np.repeat(np.reshape(tilt, (2, 1)), n, axis=1)])

    def errors(self, x, tilt) -> np.ndarray:
        """The estimation errors, truth minus estimate as error states (18, K) (``simulation.ekf.ERR``)."""
        truth = self.truth(x, tilt)
        return np.column_stack([error_between(truth[:, k], self.estimate[:, k]) for k in range(len(self))])

    def nees(self, x, tilt, steps=None) -> np.ndarray:
        """Normalised estimation error squared ``e^T P^-1 e`` at ``steps`` (all by default), needs ``covariance``.

        For a consistent filter each value is chi-square distributed with 18 degrees of freedom.
        """
        if self.covariance is None:
            raise ValueError("EstimationRecord.nees needs the full covariances: run with keep_covariance=True")
        steps = np.arange(len(self)) if steps is None else np.asarray(steps)
        truth = self.truth(x, tilt)
        out = []
        for k in steps:
            e = error_between(truth[:, k], self.estimate[:, k])
            out.append(dot(e, solve(self.covariance[k], e)))
        return np.array(out)


def nees_bounds(samples: int, dof: int = NE, level: float = 0.95) -> tuple[float, float]:
    """Two-sided ``level`` bounds of the average of ``samples`` independent chi-square(``dof``) values."""
    tail = (1.0 - level) / 2
    return (stats.chi2.ppf(tail, dof * samples) / samples, stats.chi2.ppf(1 - tail, dof * samples) / samples)


class OnboardSensing:
    """The sensors and the filter of one run (module doc).

    Parameters
    ----------
    config : SensingConfig
        Mode ``"imu"`` or ``"imu+mocap"`` and the sensor models.
    params : RollbotParams
        The robot the filter believes in (its tilt is the prior of the tilt estimate).
    dt : float
        Control period, s.
    seed : int
        Seed of the sensors' random numbers.
    settings : EstimatorSettings, optional
    keep_covariance : bool
        Record the full covariance at every step (for NEES; 2.6 kB a step).
    unknown_start : bool
        Draw the filter's initial error from its prior (seeded by ``seed``, apart
        from the sensors' numbers) instead of starting at the true state: a
        Monte Carlo consistency check (NEES) needs it.
    """

    def __init__(self, config: SensingConfig, params: RollbotParams, dt: float, seed: int = 0,
                 settings: EstimatorSettings | None = None, keep_covariance: bool = False,
                 unknown_start: bool = False):
        if not config.onboard:
            raise ValueError(f"OnboardSensing: mode = {config.mode!r}; it serves the modes 'imu' and 'imu+mocap' "
                             "(mode 'mocap' is simulate.Sensor)")
        self.config, self.params, self.dt = config, params, dt
        self.sensors = OnboardSensors(config, dt, seed)
        self.filter = ErrorStateEKF(params, config, dt, settings)
        self.keep_covariance, self.unknown_start, self.seed = keep_covariance, unknown_start, seed
        self._log: list = []

    @property
    def samples(self) -> int:
        """IMU samples per control period."""
        return self.sensors.samples

    def start(self, x0) -> None:
        """Begin a run at the known state ``x0`` (11,): sensors reseeded, filter at ``x0``, empty record."""
        self.sensors.reset()
        rng = np.random.default_rng([self.seed, 1]) if self.unknown_start else None
        self.filter.reset(x0, rng=rng)
        self._log = []

    def observe(self, k: int, x_k, signals, a_prev: float) -> Estimate:
        """The estimate at control step ``k``.

        Parameters
        ----------
        k : int
            Control step (time ``k dt``).
        x_k : numpy.ndarray (11,)
            The true state now (what motion capture would see).
        signals : numpy.ndarray (7, samples) or None
            Noise-free sensor signals of the period that just ended (None at ``k = 0``).
        a_prev : float
            Motor acceleration commanded for that period, rad/s^2.
        """
        if k > 0:
            self.filter.propagate(a_prev, self.sensors.read_imu(signals))
        self.sensors.capture(k, x_k)
        fused = sum(self.filter.fuse(capture) for capture in self.sensors.arrived(k))
        estimate = self.filter.estimate()
        self._log.append((estimate.t, estimate.augmented, estimate.std, estimate.position_covariance,
                          self.sensors.bias, fused, estimate.covariance if self.keep_covariance else None))
        return estimate

    def record(self) -> EstimationRecord:
        """The record of the run so far."""
        n = len(self._log)
        columns = list(zip(*self._log)) if n else [()] * 7
        return EstimationRecord(
            mode=self.config.mode,
            t=np.array(columns[0], float),
            estimate=np.array(columns[1], float).reshape(n, NA).T,
            std=np.array(columns[2], float).reshape(n, NE).T,
            position_covariance=np.array(columns[3], float).reshape(n, 2, 2),
            true_bias=np.array(columns[4], float).reshape(n, 6).T,
            fused=np.array(columns[5], int),
            covariance=np.array(columns[6], float).reshape(n, NE, NE) if self.keep_covariance else None,
        )
