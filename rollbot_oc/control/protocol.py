"""The controller protocol: what a controller sees (``Observation``), what it returns (``Command``), its members.

The plant (``simulation.plant.simulate``) calls a ``Controller`` once per control period with an
``Observation`` and applies the ``Command`` it returns; every controller of the toolkit (the PID
baseline, the NMPC, open-loop schedules, the NMPC with its exported C step)
implements it, and ``ControllerBase`` gives its members neutral defaults.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from rollbot_oc.model.dynamics import heading

__all__ = ["Observation", "Command", "Controller", "ControllerBase"]


@dataclass(frozen=True)
class Observation:
    """What a controller sees at one control step (SI units, floor frame).

    Attributes
    ----------
    t : float
        Time, s.
    position : numpy.ndarray (2,)
        Measured shell-centre position, m (motion capture).
    quaternion : numpy.ndarray (4,)
        Measured orientation, body -> floor, scalar first (motion capture).
    omega : numpy.ndarray (3,)
        Measured shell angular velocity, rad/s (a gyroscope, in the floor frame).
    theta : float
        Motor angle, rad (encoder).
    theta_dot : float
        Driving speed, rad/s (encoder).
    estimate : estimation.Estimate or None
        With onboard sensing (``onboard.OnboardSensing``) the fields above are
        the filter's estimate, and this is the whole of it: biases, floor
        tilt and covariance; None when they are measurements.
    """

    t: float
    position: np.ndarray
    quaternion: np.ndarray
    omega: np.ndarray
    theta: float
    theta_dot: float
    estimate: object = None

    @property
    def state(self) -> np.ndarray:
        """The observation as a model state vector (11,)."""
        return np.concatenate([self.position, self.quaternion, self.omega, [self.theta, self.theta_dot]])

    @property
    def heading(self) -> float:
        """Azimuth of the motor axis' horizontal projection, rad (the paper's gamma)."""
        return float(heading(self.state))


@dataclass(frozen=True)
class Command:
    """A controller's output: a driving-speed command or a motor-acceleration command.

    Attributes
    ----------
    speed : float, optional
        Target driving speed, rad/s; the motor's speed loop turns it into an
        acceleration.
    accel : float, optional
        Motor acceleration, rad/s^2.
    """

    speed: float | None = None
    accel: float | None = None

    def __post_init__(self):
        if (self.speed is None) == (self.accel is None):
            raise ValueError("Command: give exactly one of speed (rad/s) and accel (rad/s^2)")
        value = self.speed if self.speed is not None else self.accel
        if not math.isfinite(value):
            raise ValueError(f"Command: {'speed' if self.speed is not None else 'accel'} = {value!r} is not finite")

    def acceleration(self, theta_dot: float, dt: float) -> float:
        """The motor acceleration (rad/s^2) this command asks for over a period ``dt`` (s)."""
        return self.accel if self.accel is not None else (self.speed - theta_dot) / dt


class Controller(Protocol):
    """Interface every controller implements (PID baseline, NMPC, open-loop schedules).

    ``ControllerBase`` gives every member but ``__call__`` a neutral default.

    Attributes
    ----------
    map : RadiusMap or None
        The quasi-stable radius map the controller believes in (the centres of
        curvature of a run are computed with it), or None for the plant's.
    """

    map: object

    def reset(self) -> None:
        """Forget any internal state before a new run."""

    def __call__(self, obs: Observation) -> Command:
        """Return the command for the next control period from an observation."""

    def prepare(self, x0) -> None:
        """Plan offline from the start state ``x0`` (11,), before the run starts (``scenarios.problem.run_problem``)."""

    @property
    def done(self) -> bool:
        """True once the mission is complete: the simulation stops there."""

    def report(self) -> dict:
        """What the controller has to say about its run (JSON-ready; ``SimulationResult.info``)."""


class ControllerBase:
    """A ``Controller``'s neutral members: nothing to plan, never done, nothing to report, no radius map.

    A controller class derives from it and writes ``__call__`` (and what else it needs).
    """

    map = None

    def reset(self) -> None:
        """Nothing to forget."""

    def __call__(self, obs: Observation) -> Command:
        raise NotImplementedError

    def prepare(self, x0) -> None:
        """Nothing to plan."""

    @property
    def done(self) -> bool:
        """Never done: the run lasts its duration."""
        return False

    def report(self) -> dict:
        """Nothing to report."""
        return {}
