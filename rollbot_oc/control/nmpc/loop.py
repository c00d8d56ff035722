"""The NMPC controller: a supervisor of the mission, one planner and the control step (see the package doc).

Each control period (``NMPC.__call__``): the step's filter and delay compensation (``TrackingStep.measure``),
the supervisor's monitors (``watch``); at each solve instant the supervisor's transitions (``advance``); then
the step's command (``TrackingStep.act``): zero once the mission is done, the step's fallback while it lasts,
else, at a solve instant or with nothing to follow, one solve on the supervisor's window, and the followed
solution's acceleration.
"""

from __future__ import annotations

import time

import numpy as np

from rollbot_oc.control.nmpc.planner import Planner
from rollbot_oc.control.nmpc.reference import Reference
from rollbot_oc.control.nmpc.settings import NMPCSettings
from rollbot_oc.control.nmpc.step import TrackingStep
from rollbot_oc.control.nmpc.supervisors import GATE_REPLANS, Context, supervisor_for
from rollbot_oc.control.nmpc.telemetry import Telemetry
from rollbot_oc.model.dynamics import REDUCED
from rollbot_oc.model.params import RollbotParams
from rollbot_oc.analysis.quasi_stable import RadiusMap
from rollbot_oc.control.protocol import Command, ControllerBase, Observation

__all__ = ["NMPC", "GATE_REPLANS"]

class NMPC(ControllerBase):
    """Tracking NMPC with minimum-time plans (package doc); a ``Controller`` for ``simulate``.

    Parameters
    ----------
    mission : Mission
        Stops (``mission.stops``), an orbit (``mission.orbit``) or gates (``mission.gates``).
    params : RollbotParams, optional
        The robot the controller believes in (level floor by default: the slope is estimated).
    dt : float
        Control period of the loop, s (the plant's 100 Hz).
    settings : NMPCSettings, optional
    step_library : str or Path, optional
        A folder written by ``rollbot-oc export-c`` and built: the control step runs its C library (the same
        source as the NMPC's own compiled step; the run's JSON gives its ``library_sha256``).
    """

    def __init__(self, mission, params: RollbotParams | None = None, dt: float = 0.01,
                 settings: NMPCSettings | None = None, step_library=None):
        if mission.orbit is None and not mission.stops and not mission.gates:
            raise ValueError(f"mission {mission.kind!r}: the NMPC needs stops, an orbit or gates")
        if not mission.gates and any(not w.stop for w in mission.waypoints):
            raise ValueError("the NMPC plans stops; pass-through waypoints are for the PID's waypoint layer")
        self.mission = mission
        self.params = params or RollbotParams()
        self.dt = dt
        self.settings = s = settings or NMPCSettings()
        kind = supervisor_for(mission)
        self.weights = kind.tracking_weights(s)
        self.telemetry = Telemetry()
        self.step = TrackingStep(self.params, s, self.weights, mission, dt, self.telemetry, step_library)
        self.every = self.step.every
        self.planner = Planner(s.horizon.h, s.timing, self.telemetry)
        self.supervisor = kind(Context(mission, self.params, s, dt, self.step, self.planner, self.telemetry))
        self.map = None  # set with the plans (for centre-of-curvature plots)
        self.plan_time = 0.0
        self.k = 0
        self.reset()

    @property
    def solver(self):
        """The tracking problem's solver (``RTISolver`` or ``TrackingSolver``)."""
        return self.step.solver

    @property
    def estimator(self):
        """The tilt and model filter's estimate (``step.Estimate``)."""
        return self.step.estimator

    @property
    def reference(self) -> Reference | None:
        """What the NMPC follows now."""
        return self.supervisor.reference

    @property
    def stops(self) -> list:
        """The stops reached so far, as their monitors recorded them."""
        return self.supervisor.stops

    def prepare(self, x0) -> Reference:
        """What to follow first, from the full state ``x0`` (11,); called by ``run_problem`` before the run.
        ``plan_time`` is the computation before the first command, s (the routes are built with the
        controller, before)."""
        start = time.perf_counter()
        self.map = RadiusMap(self.params.replace(slope=0.0))
        self.step.radius_map = self.map
        reference = self.supervisor.prepare(x0, self.map)
        self.plan_time = time.perf_counter() - start
        return reference

    def reset(self):
        """Forget the run; a mission prepared (``prepare``) and not yet run is kept."""
        if self.k > 0 or self.supervisor.reference is None:
            self.telemetry = Telemetry()
            self.supervisor.c.telemetry = self.telemetry
            self.planner.reset(self.telemetry)
            self.supervisor.reset()
        self.k = 0
        self.step.reset(self.telemetry)
        self.references = []  # the run's log (not its metrics): see _keep
        self._kept_plan = None

    @property
    def done(self) -> bool:
        """True once the mission is done (``arrival.finish_hold`` after the last stop; never on a circle)."""
        return self.supervisor.done

    def __call__(self, obs: Observation) -> Command:
        if self.supervisor.reference is None:
            self.prepare(obs.state)
        k, step, supervisor = self.k, self.step, self.supervisor
        self.k += 1
        z = step.measure(obs, k)
        reached = supervisor.watch(obs, k)
        if k % self.every == 0:  # stops are left at the solve instants, so legs start on the grid
            supervisor.advance(k, obs, reached, z)
        return step.act(k, obs, z, supervisor, self._keep)

    def _keep(self, k: int, window) -> None:
        """Keep for the run's log (``references``, one dict per solve; not in the metrics) the reference solved
        on at tick ``k``: its nodes' positions (m) and driving speeds (rad/s), ``h`` s apart from ``k * dt``, and
        accelerations (rad/s^2); with, under ``plan``, the plan it samples the first time it is followed (its
        summary and its nodes' times, positions and driving speeds)."""
        Zr, r = window.Zr, REDUCED
        record = {"k": k, "h": self.settings.horizon.h, "x": Zr[r.position.start].copy(),
                  "y": Zr[r.position.start + 1].copy(), "theta_dot": Zr[r.theta_dot].copy(),
                  "accel": np.array(window.Ur, float).ravel()}
        reference, segment = self.supervisor.reference, self.supervisor.segment
        plan = reference.segments[segment] if reference is not None and segment < len(reference.segments) else None
        if plan is not None and plan[0] is not self._kept_plan:
            self._kept_plan = plan = plan[0]
            record["plan"] = {**plan.to_dict(), "t": plan.t.copy(), "x": plan.z[r.position.start].copy(),
                              "y": plan.z[r.position.start + 1].copy(), "theta_dot": plan.z[r.theta_dot].copy()}
        self.references.append(record)

    def report(self) -> dict:
        """Solve-time statistics (s), solver statuses, fallback counts, stops, plans and mode timelines."""
        log, supervisor = self.telemetry.report(), self.supervisor.report()
        return {
            "stops": list(self.stops), "solver": self.settings.horizon.solver,
            **{key: log[key] for key in ("solves", "solve_time_min", "solve_time_median", "solve_time_p95",
                                         "solve_time_max", "solver_statuses", "failed_solves", "cold_retries",
                                         "late_solves", "fallback_shifted", "fallback_pid", "fallback_brake")},
            "plan_time": self.plan_time, "stop_replans": log["stop_replans"], "brakes": log["brakes"],
            "stones": log["stones"], "plans_unfit": log["plans_unfit"], "plans": supervisor["plans"],
            "plan_duration": supervisor["plan_duration"],
            **{key: log[key] for key in ("plan_solves", "plan_failures", "plan_late", "plan_wait", "stop_wait",
                                         "plan_solve_time_median", "plan_solve_time_max")},
            "tilt_estimate": self.estimator.tilt.tolist(),
            "model_learned": self.estimator.learned(),
            "modes": self.supervisor.modes.report(self.dt),
            "step_modes": self.step.modes.report(self.dt),
            **({"library_sha256": self.step.library_sha256} if self.step.library_sha256 else {}),
        }
