"""The paper's quasi-stable controller: PID on the centre of curvature, output a driving speed.

Paper, section "Control Design".  The controller does not steer the position
``s`` but the centre of curvature ``o = s - R0(omega0) e(gamma)`` (eqn "ofunc",
``e(gamma) = (cos gamma, sin gamma)`` the horizontal direction of the motor
axis, ``R0(omega0)`` the quasi-stable radius).  Changing the radius at a rate
``v_R`` moves the centre by ``o' = -v_R e(gamma)``, so the radius-rate law

    v_R = -k_p (o_g - o) . e(gamma)                                (eqn "simplecontrol")

moves ``o`` towards ``o_g`` on average over a revolution.  Upgraded as the
paper's control diagram says:

* PID instead of P: the error is the centre error ``o_g - o`` as a floor-frame
  vector, integrated and differentiated in the floor frame, then projected on
  ``e(gamma)``.  (An integral of the projected scalar error would average
  away over each revolution and could not cancel the slope's steady drift.)
* a pull of the radius towards the target radius, ``+ k_r (R_g - R0)``, so the
  robot ends on the target circle and not just around its centre;
* a limit on the revolving radius (so on the driving speed), and a limit on
  the rate of change of the driving speed, which keeps Rollbot near its
  quasi-stable state (recovery time about 7 s);
* conditional integration (no wind-up) while a limit is active.

The radius rate becomes a driving-speed rate through the quasi-stable slope,
``omega0' = v_R / (dR0/domega0)``, and the output is the target driving speed
``omega0`` (the motor's speed loop follows it), as on the robot.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, replace

import numpy as np

from rollbot_oc.control.waypoints import WaypointLayer
from rollbot_oc.missions import centre_of_curvature
from rollbot_oc.model.params import RollbotParams
from rollbot_oc.analysis.quasi_stable import RadiusMap
from rollbot_oc.core.reproducible import dot
from rollbot_oc.control.protocol import Command, ControllerBase, Observation

__all__ = ["PIDGains", "QuasiStablePID"]


@dataclass(frozen=True)
class PIDGains:
    """Gains and limits of the quasi-stable PID (SI units).

    The defaults are the best of a grid search (``benchmarks/tune_pid.py``,
    result in ``benchmarks/tune_pid_result.txt``) over ``kp``, ``ki``, ``kr``
    and ``max_accel`` on the full plant with the 1 deg slope and sensor noise:
    shortest N-shape time with every stop within 5 cm, then the circle
    deviations.  ``kd`` stays 0: the centre estimate ``o`` carries the
    pendulum's transient oscillation, which a derivative term amplifies.
    The radius limits, 0.13 to 0.9 m, keep the driving speed between 1.04 and
    7.8 rad/s: below that the robot hardly revolves and its centre barely
    moves; the top keeps a margin below the motor's 3 pi rad/s.

    Attributes
    ----------
    kp : float
        Radius rate per metre of centre error along gamma, 1/s.
    ki : float
        Radius rate per metre-second of integrated centre error, 1/s^2.
    kd : float
        Radius rate per metre/second of centre-error rate (dimensionless).
    kr : float
        Pull of the radius towards the target radius, 1/s.
    max_accel : float
        Limit on the driving-speed rate, rad/s^2 (keeps the robot quasi-stable).
    min_radius, max_radius : float or None
        Limits on the commanded revolving radius, m (they bound the driving
        speed).  None follows the robot's own radius map (``radius_limits``):
        the prototype's 0.13 and 0.9 m are 1.08 times its radius at rest and
        its radius at 0.83 of the top driving speed.
    integral_limit : float
        Bound on each component of the integrated centre error, m s.
    stop_radius : float or None
        Revolving radius while lining up a stop, m; None follows the radius map
        (5/3 of the radius at rest: the prototype's 0.2 m).
    stop_decel : float
        Braking rate of the driving speed at a stop, rad/s^2.
    stop_align : float
        Braking starts only when the centre is this close to its target and the
        predicted rest point this close to the waypoint, m.
    """

    kp: float = 1.2
    ki: float = 0.2
    kd: float = 0.0
    kr: float = 0.6
    max_accel: float = 2.0
    min_radius: float | None = None
    max_radius: float | None = None
    integral_limit: float = 2.0
    stop_radius: float | None = None
    stop_decel: float = 1.0
    stop_align: float = 0.02

    def __post_init__(self):
        for name, value in asdict(self).items():
            if value is None and name in _FROM_MAP:
                continue
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0):
                raise ValueError(f"PID gain {name} = {value!r} must be a finite number >= 0")
        for name in ("max_accel", "min_radius", "max_radius", "stop_radius", "stop_decel", "stop_align"):
            if getattr(self, name) is not None and getattr(self, name) <= 0:
                raise ValueError(f"PID {name} = {getattr(self, name)!r} must be > 0")
        if None not in (self.min_radius, self.max_radius) and self.min_radius >= self.max_radius:
            raise ValueError(f"PID min_radius = {self.min_radius} m must be below max_radius = {self.max_radius} m")

    def radius_limits(self, radius_map: RadiusMap) -> "PIDGains":
        """These gains with the radius limits the map decides (where they are None) filled in, m."""
        top = float(radius_map.radius(0.83 * radius_map.omega_max))
        chosen = {"min_radius": 1.08 * radius_map.R_min, "max_radius": top, "stop_radius": 5.0 / 3.0 * radius_map.R_min}
        return replace(self, **{k: v for k, v in chosen.items() if getattr(self, k) is None})


_FROM_MAP = ("min_radius", "max_radius", "stop_radius")


class QuasiStablePID(ControllerBase):
    """The paper's baseline controller (see module doc), with its waypoint layer.

    Parameters
    ----------
    mission : Mission
        What to do: an orbit or waypoints (``rollbot_oc.missions``).
    params : RollbotParams, optional
        The robot the controller believes in (its quasi-stable map).
    gains : PIDGains, optional
    dt : float
        Control period, s.
    radius_map : RadiusMap, optional
        Reuse an existing map (building one costs a curve of quasi-stable states).
    """

    def __init__(self, mission, params: RollbotParams | None = None, gains: PIDGains | None = None,
                 dt: float = 0.01, radius_map: RadiusMap | None = None):
        self.params = params or RollbotParams()
        self.dt = dt
        self.map = radius_map or RadiusMap(self.params)
        self.gains = g = (gains or PIDGains()).radius_limits(self.map)
        if not self.map.R_min < g.min_radius < g.max_radius <= self.map.R_max:
            raise ValueError(f"PID radius limits [{g.min_radius}, {g.max_radius}] m must lie within the robot's "
                             f"quasi-stable range ({self.map.R_min:.3f}, {self.map.R_max:.3f}] m")
        self.speed_limits = (float(self.map.omega(g.min_radius)), float(self.map.omega(g.max_radius)))
        self.layer = WaypointLayer(mission, self.map, stop_radius=g.stop_radius, decel=g.stop_decel,
                                   align_tolerance=g.stop_align)
        self.reset()

    def reset(self):
        """Start again from rest."""
        self.omega_cmd = 0.0
        self.integral = np.zeros(2)
        self.previous_error = None
        self.layer.reset()
        self.references = []  # the run's log (not its metrics): per period, the target followed

    @property
    def done(self) -> bool:
        """True once the mission is complete (waypoints visited)."""
        return self.layer.done

    def report(self) -> dict:
        """Stop records of the waypoint layer and its repeated approaches."""
        return {"stops": list(self.layer.stops), "stop_retries": self.layer.retries}

    def __call__(self, obs: Observation) -> Command:
        g, dt = self.gains, self.dt
        heading = obs.heading
        direction = np.array([math.cos(heading), math.sin(heading)])
        measured_speed = min(max(obs.theta_dot, 0.0), self.map.omega_max)
        radius = float(self.map.radius(measured_speed))
        centre = centre_of_curvature(obs.position, heading, radius)
        centre_speed = self.params.R * math.hypot(obs.omega[0], obs.omega[1])
        target = self.layer.target(obs.t, obs.position, heading, centre, self.omega_cmd, centre_speed, obs.theta_dot)
        self.references.append({"k": len(self.references), "centre": np.array(target.centre, float),
                                "radius": float(target.radius), "braking": bool(target.braking)})
        if target.braking:
            self.omega_cmd = max(0.0, self.omega_cmd - self.layer.predictor.decel * dt)
            self.integral[:] = 0.0
            self.previous_error = None
            return Command(speed=self.omega_cmd)
        error = target.centre - centre
        derivative = np.zeros(2) if self.previous_error is None else (error - self.previous_error) / dt
        self.previous_error = error
        pid = g.kp * error + g.ki * self.integral + g.kd * derivative
        radius_rate = -dot(pid, direction) + g.kr * (target.radius - radius)
        low, high = self.speed_limits
        if self.omega_cmd < low:  # spin up from rest to the least speed that steers
            accel, limited = g.max_accel, True
        else:
            accel = radius_rate / max(float(self.map.slope(self.omega_cmd)), 1e-6)
            limited = abs(accel) > g.max_accel
            accel = float(np.clip(accel, -g.max_accel, g.max_accel))
        new = self.omega_cmd + accel * dt
        if self.omega_cmd >= low:
            limited |= not low <= new <= high
            new = min(max(new, low), high)
        self.omega_cmd = new
        if not limited:
            self.integral = np.clip(self.integral + error * dt, -g.integral_limit, g.integral_limit)
        return Command(speed=self.omega_cmd)
