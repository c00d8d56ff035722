"""Nonlinear MPC: track minimum-time plans over the full dynamics, in real time, offset-free on a slope.

Structure (do-mpc's separation: model, controller, simulator over one model):

* **Plans** (``control.ocp``), computed as the robot moves: for stops, the
  first leg starts at once on its quasi-stable guess (a simulation of the
  model, a fraction of a second); once the tilt estimate has settled
  (``tilt_settle``) minimum-time legs are refined from where the tracking
  NMPC predicts the robot will be each of ``plan_handovers`` later, and the
  one ready in time that arrives first takes over where it starts (else it
  is planned again from further along).  The next ``legs_ahead`` legs are planned ahead, one after the
  other by one modelled planner (each the fastest of ``plan_starts`` starts,
  failed starts resumed where they stopped (``plan_resumes``), from the rest
  state the leg before ends in, on the tilt estimated by then),
  and each is used only once its modelled compute time has passed; legs end
  balanced on the estimated floor.
* **Recovery**: a robot pushed off its plan is first brought to rest where
  it is (the tracking NMPC with ``brake_weights``: motion only), then gets a
  new leg from there, as at the start.  For circles: at once a ramp up to
  the orbit's speed (a simulation of the model), and, planned from where the
  ramp will be ``entry_handover`` later, an entry onto the quasi-stable orbit
  of the target circle in a fixed time (5 s, else 7 or 10 s; from the
  shortest in which the ramp's revolving centre can reach the orbit's at
  ``entry_shift_speed``) with the least effort, then the orbit itself.
  For gates (``gates``): one minimum-time plan through every gate on
  ``rollbot_oc.ocp``, followed once its modelled compute time has passed,
  the position weighted more at each planned gate passage; after the last
  gate the motor's speed is ramped to zero; a missed gate is planned again
  from rest.
* **Tracking NMPC**: every ``h = 0.05`` s it solves a multiple-shooting
  problem over ``N = 60`` intervals (3 s, about half a revolution period and
  half the 7 s recovery time) that keeps the predicted reduced state near the
  plan, with the motor's torque, speed and acceleration limits and the
  contact margins as constraints.  The first interval's motor acceleration
  is applied (the plant's motor follows it at 100 Hz).
* **Offset-free, and learning its model**: a Kalman filter estimates the
  floor's tilt vector and scale factors of the shell's mass, the pendulum's
  mass and the rolling damping (``NMPCSettings.learn``) from the mismatch
  between the measured and the predicted shell angular velocity (its
  Jacobian by AD); every later solve, rest and leg plan uses the estimate.
  (A robot 10 % off its model arrives at its stops swaying sideways, a mode
  its motor cannot damp at rest: learning the model is what stops most of
  that; the rest, by weighing the shell's angular velocity and the motor's
  speed at the horizon nodes past a leg's end, ``TrackingWeights.arrival_omega``
  and ``arrival_speed``, so that the approach itself ends still.)
* **Delay compensation**: a measurement that is ``L`` periods old is
  predicted forward over the commands applied since.
* **Warm start**: the previous solution shifted by one interval (primal and,
  for IPOPT, dual values).
* **Never crash the loop**: a QP made infeasible by the state (no command
  keeps the torque or contact limits) is solved once more without the path
  constraints (status ``relaxed (...)``); a failed or late solve (longer than
  ``h``) falls back to the shifted previous solution; after ``max_failures``
  consecutive failures the motor's speed is ramped to zero and the robot is
  brought to rest (``fallback = "brake"``, stops) or the paper's PID takes
  over for ``pid_time`` seconds (``"pid"``, circles).  Every solve's status
  and time, and every fallback, is counted in ``report()``.

Measured (what a real Rollbot would know): the pose from motion capture
(position, orientation), the shell angular velocity from a gyroscope and the
motor angle and speed from the encoder; that is the whole state.

Solvers: the tracking problem is written once on the optimal-control layer
(``tracking.tracking_problem``) and solved by its routes: ``"ipopt"`` (exact
Hessian, warm-started; converges every period) or ``"rti"``, a real-time
iteration (one Gauss-Newton SQP step per sample, its Hessian and gradients
from the AD Jacobians of the least-squares residuals, QPs by HPIPM with qrqp
behind it), much faster; ``benchmarks/bench_nmpc.py`` measures both and the
default is chosen from it.

The package follows those concepts, one module each: ``settings`` (weights,
horizon, limits, fallbacks), ``tracking`` (the tracking problem and its
solvers), ``estimation`` (the filter on the floor's tilt and the model's masses and damping), ``reference`` (what is
tracked: legs, holds, orbits), ``gates`` (the plan through gates) and ``loop`` (the controller and its
fallbacks).  What the mission asks (stops, an orbit, gates) the loop learns from the mission's own answers
(``rollbot_oc.missions``).
"""

from rollbot_oc.control.nmpc.estimation import TiltEstimator
from rollbot_oc.control.nmpc.loop import NMPC
from rollbot_oc.control.nmpc.reference import Reference
from rollbot_oc.control.nmpc.settings import NMPCSettings, TrackingWeights
from rollbot_oc.control.nmpc.tracking import RTISolver, TrackingSolver

__all__ = ["NMPCSettings", "TrackingWeights", "NMPC", "TrackingSolver", "RTISolver", "TiltEstimator", "Reference"]
