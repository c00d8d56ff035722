"""The paper's waypoint layer: from a mission to a centre-of-curvature target and stop timing.

Paper, last paragraph of "Control Design": to pass a point ``s_g`` with
velocity ``v_g``, compute the radius ``R_g`` whose quasi-stable speed is
``|v_g|`` and the centre ``o_g = s_g - R_g e(gamma_g)`` (eqn "ofunc", with
``gamma_g`` such that the revolving velocity at ``s_g`` is ``v_g``), and revolve
about ``o_g``; to stop at ``s_g``, revolve about a suitable ``o_g`` and
gradually stop the motor while approaching ``s_g``.

Stopping, made precise with the quasi-stable model: braking from driving
speed ``w`` at a constant rate ``b`` the robot keeps rolling along a spiral,
and its rest position relative to where braking starts is a fixed
displacement ``D(w)`` in the robot's own frame (``e(gamma)``, its normal).
``StopPredictor`` integrates that spiral once, from the quasi-stable
revolving rate and radius, into a table.  Revolving about ``o_g`` at ``R_g``,
the predicted rest points lie on a circle of radius ``rho = |R_g x + D|``
about ``o_g``; so ``o_g`` is placed at distance ``rho`` from ``s_g``, and
braking starts when the predicted rest point passes closest to ``s_g``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from rollbot_oc.missions import PassMonitor, StopMonitor
from rollbot_oc.analysis.quasi_stable import RadiusMap
from rollbot_oc.core.reproducible import norm

__all__ = ["StopPredictor", "Target", "WaypointLayer"]


def _rotate(angle: float, v) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([c * v[0] - s * v[1], s * v[0] + c * v[1]])


class StopPredictor:
    """Where a revolving robot comes to rest when it brakes at a constant rate.

    Parameters
    ----------
    radius_map : RadiusMap
        Quasi-stable radius and revolving rate of the robot.
    decel : float
        Braking rate of the driving speed, rad/s^2.
    """

    def __init__(self, radius_map: RadiusMap, decel: float):
        if not (math.isfinite(decel) and decel > 0):
            raise ValueError(f"stop deceleration = {decel!r} must be > 0 rad/s^2")
        self.decel = decel
        self.speeds = np.linspace(0.0, radius_map.omega_max, 97)
        fine = np.linspace(0.0, radius_map.omega_max, 4001)  # driving speed during braking, rad/s
        dt = (fine[1] - fine[0]) / decel  # s per fine step
        rate = radius_map.rate(fine)
        speed = rate * radius_map.radius(fine)  # quasi-stable speed of the centre, m/s
        # integrate from rest upwards: the state at speed w brakes through all lower speeds
        turn = np.concatenate([[0.0], np.cumsum(0.5 * (rate[1:] + rate[:-1]) * dt)])
        self._table = np.empty((len(self.speeds), 2))
        for i, w in enumerate(self.speeds):
            k = int(round(w / (fine[1] - fine[0])))
            if k == 0:
                self._table[i] = 0.0
                continue
            angle = turn[k] - turn[: k + 1]  # heading change since braking began, rad
            vel = speed[: k + 1] * np.array([-np.sin(angle), np.cos(angle)])  # in the robot's starting frame
            self._table[i] = np.trapezoid(vel[:, ::-1], dx=dt, axis=1)

    def displacement(self, omega0: float) -> np.ndarray:
        """Rest position minus braking position (m), in the frame (e(gamma), normal) of the robot."""
        return np.array([np.interp(omega0, self.speeds, self._table[:, j]) for j in range(2)])

    def rest_point(self, position, heading: float, omega0: float) -> np.ndarray:
        """Predicted rest position (m) of a robot at ``position`` (m), ``heading`` (rad), speed ``omega0`` (rad/s)."""
        return np.asarray(position, float) + _rotate(heading, self.displacement(omega0))


@dataclass(frozen=True)
class Target:
    """What the layer asks the centre-of-curvature controller for at one step.

    Attributes
    ----------
    centre : numpy.ndarray (2,)
        Target centre of curvature o_g, m.
    radius : float
        Target revolving radius R_g, m.
    braking : bool
        True while the motor is being stopped (the controller ramps the speed to zero).
    """

    centre: np.ndarray
    radius: float
    braking: bool = False


class WaypointLayer:
    """Turns a mission into centre targets, stop timing and stop records.

    Parameters
    ----------
    mission : Mission
        An orbit (``mission.orbit``) to revolve on, or ``mission.waypoints`` to visit in order.
    radius_map : RadiusMap
    stop_radius : float
        Revolving radius while lining up a stop, m (small: short, predictable braking).
    decel : float
        Braking rate of the driving speed for stops, rad/s^2.
    align_tolerance : float
        How close (m) the centre must be to its target, and the predicted rest
        point to the waypoint, before braking may start.

    A stop is left only once it is reached by the mission's ``StopRule``
    (within ``stop_tolerance`` and at rest for 0.5 s); coming to rest away
    from it starts a new approach of the same stop (counted in ``retries``).
    """

    def __init__(self, mission, radius_map: RadiusMap, *, stop_radius: float = 0.2, decel: float = 1.0,
                 align_tolerance: float = 0.02):
        self.points = mission.waypoints
        if mission.orbit is None and not self.points:
            raise ValueError(f"mission {mission.kind!r} gives the waypoint layer neither an orbit nor waypoints")
        if not radius_map.R_min < stop_radius < radius_map.R_max:
            raise ValueError(f"stop_radius = {stop_radius} m is out of range: valid is "
                             f"({radius_map.R_min:.3f}, {radius_map.R_max:.3f}) m")
        self.mission, self.radius_map = mission, radius_map
        self.stop_radius, self.align_tolerance = stop_radius, align_tolerance
        self.rule = mission.stop_rule
        self.predictor = StopPredictor(radius_map, decel)
        self.reset()

    def reset(self):
        """Start the mission again."""
        self.index = 0
        self.phase = "track"  # track -> braking -> resting -> (next waypoint) ... -> done
        self.stops: list[dict] = []
        self._last_miss = math.inf
        self._goal = None  # centre target of the current stop, chosen when its leg starts
        self._monitor = None
        self._pass = None  # watches the pass-through waypoint in progress
        self.retries = 0

    @property
    def done(self) -> bool:
        """True once every waypoint has been visited (never on an orbit)."""
        return self.phase == "done"

    def _stop_centre(self, wp_point, centre_now) -> np.ndarray:
        w = float(self.radius_map.omega(self.stop_radius))
        rho = float(norm(np.array([self.stop_radius, 0.0]) + self.predictor.displacement(w)))
        away = centre_now - wp_point
        distance = norm(away)
        direction = away / distance if distance > 1e-9 else np.array([1.0, 0.0])
        return wp_point + rho * direction

    def target(self, t: float, position, heading: float, centre, omega0: float, centre_speed: float,
               driving_speed: float) -> Target:
        """The target for this step.

        Parameters
        ----------
        t : float
            Time, s.
        position : array_like (2,)
            Measured shell-centre position, m.
        heading : float
            Measured gamma, rad.
        centre : array_like (2,)
            Current centre of curvature estimate o, m.
        omega0 : float
            Current driving-speed command, rad/s.
        centre_speed : float
            Measured shell-centre speed, m/s (to detect rest).
        driving_speed : float
            Measured driving speed, rad/s (to detect rest).
        """
        orbit = self.mission.orbit
        if orbit is not None:
            return Target(orbit.centre, orbit.radius)
        if self.phase == "done":
            return Target(np.asarray(position, float), self.radius_map.R_min, braking=True)
        wp = self.points[self.index]
        if not wp.stop:
            return self._pass_target(wp, position)
        if self.phase == "track":
            if self._goal is None:
                self._goal = self._stop_centre(wp.point, np.asarray(centre, float))
            aligned = norm(np.asarray(centre) - self._goal) < self.align_tolerance
            miss = float(norm(self.predictor.rest_point(position, heading, omega0) - wp.point))
            closest = miss > self._last_miss  # the predicted rest point just passed its closest approach
            self._last_miss = miss
            if aligned and closest and miss < self.align_tolerance:
                self.phase = "braking"
            return Target(self._goal, self.stop_radius, braking=self.phase == "braking")
        if self.phase == "braking" and omega0 <= 0.0:
            self.phase = "resting"
            self._monitor = StopMonitor(wp.point, self.rule)
        target = Target(self._goal, self.stop_radius, braking=True)
        if self.phase == "resting":
            if self._monitor.update(t, position, centre_speed, driving_speed):
                self.stops.append(self._monitor.record(position))
                self._advance()
            elif self._monitor.settled_away:
                # at rest away from the stop: never move on from here, approach the same stop again
                self.phase, self._goal, self._last_miss = "track", None, math.inf
                self.retries += 1
        return target

    def _pass_target(self, wp, position) -> Target:
        v = float(norm(wp.velocity))
        omega0 = _speed_to_omega(self.radius_map, v)
        radius = float(self.radius_map.radius(omega0))
        # revolving counter-clockwise, velocity = Omega z x (s - o): s - o points 90 deg clockwise of v
        direction = np.array([wp.velocity[1], -wp.velocity[0]]) / v
        if self._pass is None:
            self._pass = PassMonitor(wp.point, self.mission.pass_tolerance)
        if self._pass.update(position):  # passed at its closest approach within the tolerance
            self._advance()
        return Target(wp.point - radius * direction, radius)

    def _advance(self):
        self.index += 1
        self._last_miss = math.inf
        self._goal = None
        self._pass = None
        self.phase = "done" if self.index >= len(self.points) else "track"


def _speed_to_omega(radius_map: RadiusMap, speed: float) -> float:
    """Driving speed (rad/s) whose quasi-stable centre speed is ``speed`` (m/s)."""
    w = radius_map.omegas
    v = radius_map.rate(w) * radius_map.radius(w)
    if not 0 < speed <= v.max():
        raise ValueError(f"pass-through speed {speed!r} m/s is out of range: valid is (0, {v.max():.3f}] m/s")
    return float(np.interp(speed, v, w))
