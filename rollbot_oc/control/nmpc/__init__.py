"""Nonlinear MPC: track minimum-time plans over the full dynamics, in real time, offset-free on a slope.

Structure (do-mpc's separation: model, controller, estimator and simulator over one model; acados' split
of the solver from its supervision):

* **The control step** (``step.TrackingStep``), the work of every control period, written once as three CasADi
  Functions of one memory vector (``period``): ``measure`` (the filter on the floor's tilt and the model's
  masses and damping, the symbolic form of ``estimation.TiltEstimator``, and the delay compensation: a
  measurement ``L`` periods old predicted forward over the commands issued since), ``solve`` (at each solve
  instant, every ``horizon.h``, one real-time iteration of the tracking problem ``tracking.tracking_problem``:
  the predicted reduced state kept near the reference over ``horizon.N`` intervals, with the motor's torque,
  speed and acceleration limits and the contact margins as constraints, warm started from the previous
  solution shifted by one interval, its QP by ``qrqp``) and ``commit`` (the step's modes ``modes.StepMode``
  and the command: a failed or late solve falls back to the previous solution; after
  ``recovery.max_failures`` the motor's speed is ramped to zero (stops) or the paper's PID takes over
  (circles, gates)).  Where a C compiler exists the NMPC runs their generated C (``source``), the same file
  ``export-c`` writes.
* **A supervisor per mission kind** (``supervisors``), an explicit machine of modes with one table of
  transitions (``modes.TRANSITIONS``): for stops, legs ridden on a quasi-stable guess, refined and tracked,
  held at the stop, braked and planned again from rest (``StopsMode``); for circles, a ramp, a planned
  entry and the orbit (``OrbitMode``); for gates, plans through the gates left and the motor stopped after
  them (``GatesMode``).  The supervisor decides the reference window and the weights each solve gets.
* **One planner** (``planner.Planner``) with a typed queue of pending plans and one compute-time model:
  modelled from the plans' iterations in simulation, so that results are the same on any machine, or the
  wall clock on a robot (``timing.realtime``).
* **Settings** (``settings.NMPCSettings``), nested by concern, frozen, every field checked.
* **Telemetry** (``telemetry.Telemetry``), a typed record of solves, fallbacks and plans; every run also
  reports the mode timelines (``modes``, ``step_modes``: mode, start time, reason).

Measured (what a real Rollbot would know): the pose from motion capture (position, orientation), the shell
angular velocity from a gyroscope and the motor angle and speed from the encoder; that is the whole state.

Solvers: the tracking problem is written once on the optimal-control layer and solved by its routes:
``"rti"`` (one Gauss-Newton SQP step per period, its Hessian and gradients from the AD Jacobians of the
least-squares residuals, QPs by qrqp, generated as C with the step) or ``"ipopt"`` (converged every period,
exact Hessian, in Python: no C); ``benchmarks/bench_nmpc.py`` measures both.
"""

from rollbot_oc.control.nmpc.estimation import TiltEstimator
from rollbot_oc.control.nmpc.loop import NMPC
from rollbot_oc.control.nmpc.modes import GatesMode, OrbitMode, StepMode, StopsMode
from rollbot_oc.control.nmpc.reference import Reference
from rollbot_oc.control.nmpc.settings import NMPCSettings, TrackingWeights
from rollbot_oc.control.nmpc.tracking import RTISolver, TrackingSolver

__all__ = ["NMPCSettings", "TrackingWeights", "NMPC", "TrackingSolver", "RTISolver", "TiltEstimator", "Reference",
           "StopsMode", "OrbitMode", "GatesMode", "StepMode"]
