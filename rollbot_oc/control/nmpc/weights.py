"""The weights of the NMPC's least-squares tracking cost, and their presets for each mode."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rollbot_oc.core.checked import Checked, number
from rollbot_oc.model.dynamics import REDUCED

__all__ = ["TrackingWeights"]


@dataclass(frozen=True)
class TrackingWeights(Checked):
    """Weights of the NMPC's least-squares tracking cost (each >= 0).

    Attributes
    ----------
    position : float
        Position deviation from the plan, 1/m^2.
    attitude : float
        Pendulum-frame quaternion deviation.
    omega : float
        Shell angular-velocity deviation, s^2/rad^2.
    speed : float
        Driving-speed deviation, s^2/rad^2.
    accel : float
        Motor-acceleration deviation, s^4/rad^4.
    radial : float
        Circles: distance from the target circle, 1/m^2 (0 for stops).
    terminal : float
        Factor on the state weights at the end of the horizon.
    arrival_speed : float
        Stops: driving-speed weight at the horizon nodes past the end of the leg, s^2/rad^2 (``speed`` if
        that is larger): the motor stands still on arrival instead of swinging back and rocking the shell.
    arrival_omega : float
        Stops: shell angular-velocity weight at those nodes, s^2/rad^2 (``omega`` if that is larger): the
        shell arrives still, since a sideways sway at rest is uncontrollable (``tests/test_stability.py``).
    """

    owner, group = "NMPC", "weights"
    position: float = number(400.0, 0.0)
    attitude: float = number(20.0, 0.0)
    omega: float = number(0.2, 0.0)
    speed: float = number(0.02, 0.0)
    accel: float = number(0.02, 0.0, open_low=True)
    radial: float = number(0.0, 0.0)
    terminal: float = number(5.0, 0.0)
    arrival_speed: float = number(0.0, 0.0)
    arrival_omega: float = number(0.0, 0.0)

    @classmethod
    def for_waypoints(cls) -> "TrackingWeights":
        """Stops: a firm hold on position, most of all at the end of the horizon, and the motor and the
        shell still on arrival."""
        return cls(position=1500.0, terminal=20.0, omega=40.0, arrival_speed=2000.0, arrival_omega=400.0)

    @classmethod
    def for_holding(cls) -> "TrackingWeights":
        """At a stop, once its leg has ended: damp the motion and keep the motor quiet rather than chase
        the last centimetres (a firm hold on position turns measurement noise into motor jitter)."""
        return cls(position=200.0, terminal=20.0, omega=40.0, speed=2.0, accel=0.5)

    @classmethod
    def for_braking(cls) -> "TrackingWeights":
        """Recovery: bring the robot to rest wherever that happens (the motion weighted, position and attitude
        only a little, to keep the QP's Hessian regular; the motor's acceleration as at a stop, so that the
        brake of a heavy pendulum does not chatter between the motor's limits)."""
        return cls(position=1.0, attitude=0.1, omega=40.0, speed=1.0, accel=0.5, terminal=20.0)

    @classmethod
    def for_circles(cls) -> "TrackingWeights":
        """Circles: the distance from the circle matters, not the point on it (the reference is re-phased)."""
        return cls(position=400.0, radial=4000.0, terminal=5.0)

    @property
    def arrives(self) -> bool:
        """Whether an arrival weight is set (``arrival_speed`` or ``arrival_omega`` above 0)."""
        return self.arrival_speed > 0 or self.arrival_omega > 0

    def diagonal(self, N: int, ended: np.ndarray | None = None) -> np.ndarray:
        """Gauss-Newton weights of every decision variable.

        Parameters
        ----------
        N : int
            Intervals of the horizon.
        ended : array_like (N+1,) of bool, optional
            The nodes past the end of a leg: their driving speed weighs ``arrival_speed`` (or ``speed`` if
            that is larger), their shell angular velocity ``arrival_omega`` (or ``omega``).

        Returns
        -------
        numpy.ndarray (10 (N+1) + N,)
            The state weights node by node (each in the units of its field), the terminal factor on the
            last node, then the N acceleration weights (``accel``).
        """
        wz = np.array([self.position] * 2 + [self.attitude] * 4 + [self.omega] * 3 + [self.speed])
        weights = np.tile(wz, (N + 1, 1))
        if ended is not None and self.arrives:
            ended = np.asarray(ended, bool)
            weights[ended, REDUCED.theta_dot] = max(self.speed, self.arrival_speed)
            weights[ended, REDUCED.omega] = max(self.omega, self.arrival_omega)
        weights[-1] *= self.terminal
        return np.concatenate([weights.ravel(), np.full(N, self.accel)])
