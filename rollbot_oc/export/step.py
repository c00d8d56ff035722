"""One control period of the embedded controller as one CasADi Function, the source of every use of it.

``control_step(...)`` builds ``rollbot_period(mem, meas, ref) -> (cmd, mem_next, status)``:

* ``mem`` (``Memory``): everything the controller remembers between periods, one flat vector: the step
  counter, the leg in progress and the step it started on, the previous measurement, the tilt estimate and
  its covariance, the last commands, the RTI iterate and multipliers, the current plan of motor
  accelerations, the stop monitor, the hold and the fallback's state;
* ``meas`` (12,): the measurement's time, s, and the measured full state (11,) (``Observation.t`` and
  ``Observation.state``);
* ``ref`` (``reference_size``): two reference windows (``EmbeddedReference.window``): the leg in progress
  from the current solve instant, and the next leg from its start; each the reduced states (10, N+1) by
  column, the motor accelerations (N,), the leg's stop (2), its duration (s) and 1 if it is the last leg.

What it does, in order, as the NMPC (``control.nmpc``: its step and its stops supervisor) does for a course
of stops:

1. the tilt estimator's update (``control.nmpc.estimation.TiltEstimator.update``, the same filter written
   symbolically with the same one-step model and noise settings, on the tilt alone and from the measured
   attitude: ``attitude_gain`` 1, no learned factors) when the measurement follows the previous one;
2. delay compensation: the measurement predicted forward over the commands issued since it was taken
   (up to ``HISTORY - 1`` periods);
3. the stop in progress watched on the measurement (``missions.stops.StopMonitor``'s rule); at a solve
   instant after the leg's planned end, once the stop is reached, the next leg starts (cold: from its
   reference, as the NMPC's legs do), or after the last stop the run ends ``finish_hold`` later; past a
   leg's end within the stop's tolerance (at least ``hold_radius``) the robot is held where it arrived with
   the hold weights (``StopsSupervisor._settle``);
4. at a solve instant (every ``h``; or when there is no plan): one real-time iteration of the NMPC's
   tracking problem (``control.nmpc.tracking.tracking_problem``, the robot's limits of
   ``ocp.constraints.robot_limits`` in it): the structured linearisation and the QP by ``qrqp``, solved
   once more without the relaxable constraints when it has no solution (``ocp.routes.sqp.SQPRoute.
   to_function``); the solution and its multipliers shifted for the next warm start;
5. the command: the plan's acceleration for the current interval, clipped to the motor's speed,
   acceleration and torque limits (``dynamics.motor_speed_clip`` and the model's ``accel_bounds``);
6. fallback: a QP whose step violates its constraints (or is not finite) keeps the previous plan for up
   to ``max_failures - 1`` solves; then the motor's speed is ramped to zero at ``brake_accel`` for
   ``|speed| / brake_accel + h`` seconds and the next solve starts cold.  Once done the command is 0.
   (Unlike the NMPC's loop, a failed warm-started QP is not solved once more from the reference in the
   same period: that would double the step's worst case on the robot's processor.)

``status`` says which: ``STATUS`` names the codes.  The Python embedded controller
(``export.embedded``), the C export (``export.project``) and the closed loop through C
(``export.library``) all evaluate this one Function.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import casadi as ca
import numpy as np

from rollbot_oc.control.nmpc.estimation import TiltEstimator
from rollbot_oc.control.nmpc.period import Memory, finite, placement, reduced_state, select
from rollbot_oc.control.nmpc.settings import NMPCSettings
from rollbot_oc.control.nmpc.tracking import RTISolver, tracking_problem
from rollbot_oc.model.dynamics import NZ, OMEGA, POS, REDUCED, THETA_DOT, motor_speed_clip, symbolic_model
from rollbot_oc.missions.stops import StopRule
from rollbot_oc.model.params import TILT, ParamView, RollbotParams

__all__ = ["EMBEDDED_SETTINGS", "STATUS", "Memory", "StepFunction", "control_step", "HISTORY"]

# The exported step's settings: the NMPC's weights, limits and fallbacks over the same 3 s horizon with 25
# intervals of 0.12 s and one integration step each, a filter on the tilt alone from the measured attitude
# (``NMPCSettings.embedded``; ``benchmarks/bench_export_c_result.txt`` compares other grids).
EMBEDDED_SETTINGS = NMPCSettings.embedded()

HISTORY = 4  # commands remembered: delay compensation over up to HISTORY - 1 periods of latency
STATUS = {0: "solved", 1: "between solves", 2: "QP failed: previous plan", 3: "brake", 4: "done"}
QP_FEASIBILITY = 1e-6  # largest violation of the QP's constraints by its step that counts as solved


@dataclass
class StepFunction:
    """The control step Function and what its callers need to know about it.

    Attributes
    ----------
    function : casadi.Function
        ``rollbot_period(mem, meas, ref) -> (cmd, mem_next, status)`` (module doc).
    memory : Memory
        Layout of ``mem``.
    initial_memory : numpy.ndarray
        ``mem`` before the first period.
    N, every : int
        Intervals of the horizon, and control periods per interval.
    dt, h : float
        Control period and interval, s.
    """

    function: ca.Function
    memory: Memory
    initial_memory: np.ndarray
    N: int
    every: int
    dt: float
    h: float

    @property
    def window_size(self) -> int:
        """Entries of one reference window: states (10, N+1), accelerations (N,), the stop (2), the leg's
        duration (s) and 1 if it is the last leg (``EmbeddedReference.window``)."""
        return NZ * (self.N + 1) + self.N + 4

    @property
    def reference_size(self) -> int:
        """Entries of ``ref``: the window of the leg in progress, then that of the next leg from its start."""
        return 2 * self.window_size


def _estimator_update(estimator: TiltEstimator) -> ca.Function:
    """``TiltEstimator.update`` as an SX Function ``(tilt, P, z_prev, u_prev, z_now) -> (tilt, P)``."""
    one_step = estimator.step.fun
    tilt, P = ca.SX.sym("tilt", 2), ca.SX.sym("P", 2, 2)
    z_prev, u_prev, z_now = ca.SX.sym("z_prev", NZ), ca.SX.sym("u_prev"), ca.SX.sym("z_now", NZ)
    p = ca.SX(ca.DM(estimator.p))
    p[TILT] = tilt
    zn, H = one_step(z_prev, u_prev, p)
    residual = z_now[REDUCED.omega] - zn[REDUCED.omega]
    P1 = P + ca.SX.eye(2) * estimator.q
    change = ca.norm_2(zn[REDUCED.omega] - z_prev[REDUCED.omega])
    S = ca.mtimes([H, P1, H.T]) + ca.SX.eye(3) * (estimator.r + (estimator.model_error * change) ** 2)
    K = ca.solve(S, ca.mtimes(H, P1)).T
    tilt1 = ca.fmin(ca.fmax(tilt + ca.mtimes(K, residual), -0.5), 0.5)
    P2 = ca.mtimes(ca.SX.eye(2) - ca.mtimes(K, H), P1)
    ok = ca.logic_and(finite(residual), finite(H))  # nothing to learn from a broken prediction
    return ca.Function("tilt_update", [tilt, P, z_prev, u_prev, z_now],
                       [ca.if_else(ok, tilt1, tilt), ca.if_else(ok, P2, P)])


class _RTI:
    """One real-time iteration of the tracking problem as an MX Function of the controller's quantities:
    ``(w, lam_w, lam_g, warm, z0, Zr, Ur, hold, ended, tilt) -> (w_shifted, lam_w, lam_g, U, ok)`` (``hold``,
    ``ended``: (1, N+1) rows, 1 at the nodes that take the hold weights, and the nodes past the leg's end)."""

    def __init__(self, params: RollbotParams, settings: NMPCSettings):
        s = settings
        # the NMPC's own tracking solver: its parameters of a solve, guess, split and shift (placements)
        self.solver = solver = RTISolver(params, s.replace(horizon={"compiled": False}), s.weights.legs)
        lim = s.limits
        ocp = tracking_problem(s.horizon.N, s.horizon.h, s.horizon.substeps, lim.torque_margin, lim.normal_margin,
                               lim.friction_margin,
                               s.limits.speed_margin, constraints=tuple(s.limits.constraints))
        self.route = ocp.solver("rti", qp_solver="qrqp", compiled=False)
        self.tr = tr = self.route.transcription
        self.n, self.m = tr.w.numel(), tr.g.numel()
        self.p_nominal = params.vector()
        self.N = s.horizon.N
        dummy = np.zeros((NZ, s.horizon.N + 1))
        track = solver._parameters(dummy[:, 0], dummy, np.zeros(s.horizon.N), self.p_nominal, None, None)
        arrival = solver._parameters(dummy[:, 0], dummy, np.zeros(s.horizon.N), self.p_nominal, None,
                                     s.weights.legs.diagonal(s.horizon.N, np.ones(s.horizon.N + 1, bool)))
        hold = solver._parameters(dummy[:, 0], dummy, np.zeros(s.horizon.N), self.p_nominal, None,
                                  s.weights.hold.diagonal(s.horizon.N))
        self.weights = {name: (track[name], arrival[name], hold[name]) for name in ("state_weight", "accel_weight",
                                                                                    "mission_weight")}
        self.mission_values = solver._mission_values

    def _row_shift(self) -> np.ndarray:
        """Rows of ``g`` moved on by one interval (as ``shift`` moves the decision vector): each stage's rows take
        the next stage's, the initial state's rows and the last stage's stay."""
        tr = self.tr
        fixed = set(tr.rows_of("initial state").tolist())
        order = np.arange(self.m)
        for stage, following in zip(tr.stages[:-1], tr.stages[1:]):
            rows = [r for r in range(stage.rows.start, stage.rows.stop) if r not in fixed]
            later = list(range(following.rows.start, following.rows.stop))
            if len(rows) == len(later):
                order[rows] = later
        return order

    def function(self) -> ca.Function:
        N, n, m = self.N, self.n, self.m
        w, lam_w, lam_g = ca.MX.sym("w", n), ca.MX.sym("lam_w", n), ca.MX.sym("lam_g", m)
        warm, z0 = ca.MX.sym("warm"), ca.MX.sym("z0", NZ)
        Zr, Ur, hold = ca.MX.sym("Zr", NZ, N + 1), ca.MX.sym("Ur", 1, N), ca.MX.sym("hold", 1, N + 1)
        ended = ca.MX.sym("ended", 1, N + 1)  # the nodes past the leg's end (``TrackingWeights.arrives``)
        tilt = ca.MX.sym("tilt", 2)
        # q and -q are the same attitude: give the reference the measurement's sign
        sign = ca.if_else(ca.dot(Zr[REDUCED.quaternion, 0], z0[REDUCED.quaternion]) < 0, -1, 1)
        Zs = ca.vertcat(Zr[:REDUCED.quaternion.start, :], sign * Zr[REDUCED.quaternion, :],
                        Zr[REDUCED.quaternion.stop:, :])
        p = ca.MX(ca.DM(self.p_nominal))
        p[TILT] = tilt
        values = {"x0": z0, "p": p, "reference": Zs, "accel_reference": ca.horzcat(Ur, 0)}
        for name, (track, arrival, hold_value) in self.weights.items():
            track, arrival, hold_value = (ca.DM(np.atleast_2d(v)) for v in (track, arrival, hold_value))
            if track.numel():
                moving = track if np.array_equal(np.array(arrival), np.array(track)) else \
                    track + (arrival - track) * ca.repmat(ended, track.size1(), 1)
                values[name] = moving + (hold_value - moving) * ca.repmat(hold, track.size1(), 1)
            else:
                values[name] = ca.MX(track.sparsity())
        values.update({k: ca.MX(ca.DM(v)) for k, v in self.mission_values.items()})
        V, ids = placement(values)
        par = V[self.tr.parameter_vector(ids).astype(int).tolist()]
        guess_values, guess_ids = placement({"Z": ca.horzcat(z0, Zs[:, 1:]), "U": Ur})
        guess = guess_values[self.solver._guess(guess_ids["Z"][:, 0], guess_ids["Z"], guess_ids["U"])
                             .astype(int).tolist()]
        w0 = ca.if_else(warm, w, guess)
        zero_w, zero_g = ca.MX.zeros(n), ca.MX.zeros(m)
        step = self.route.to_function(relax=self.solver.relax)
        w1, lam_w1, lam_g1, violation, _relaxed = step(w0, ca.if_else(warm, lam_w, zero_w),
                                                       ca.if_else(warm, lam_g, zero_g), par)
        ok = ca.logic_and(violation <= QP_FEASIBILITY, finite(w1))
        index = np.arange(n, dtype=float)
        shift = self.solver.shift(index).astype(int).tolist()
        shifted = w1[shift]
        lam_w1, lam_g1 = lam_w1[shift], lam_g1[self._row_shift().tolist()]  # the active set moves on with it
        U = w1[self.solver.split(index)[1].astype(int).tolist()]
        return ca.Function("rollbot_rti", [w, lam_w, lam_g, warm, z0, Zr, Ur, hold, ended, tilt],
                           [shifted, lam_w1, lam_g1, U, ok])


def control_step(params: RollbotParams, settings: NMPCSettings | None = None, dt: float = 0.01,
                 rule: StopRule | None = None) -> StepFunction:
    """The control step Function (module doc) for the robot ``params`` believes in.

    Parameters
    ----------
    params : RollbotParams
        The controller's model (its tilt is the estimator's prior).
    settings : NMPCSettings, optional
        Horizon, weights, limits, estimator, hold and fallback settings (the NMPC's; ``EMBEDDED_SETTINGS``
        by default).
    dt : float
        Control period, s.
    rule : StopRule, optional
        When a stop counts as reached (the mission's ``stop_rule``; the default rule).
    """
    return _control_step(params, settings or EMBEDDED_SETTINGS, float(dt), rule or StopRule())


@functools.lru_cache(maxsize=4)
def _control_step(params: RollbotParams, s: NMPCSettings, dt: float, rule: StopRule) -> StepFunction:
    every = max(1, int(round(s.horizon.h / dt)))
    if abs(every * dt - s.horizon.h) > 1e-9:
        raise ValueError(f"NMPC h = {s.horizon.h} s must be a whole number of control periods dt = {dt} s")
    if s.filter.learn or s.filter.attitude_gain != 1.0:
        raise ValueError(f"exported step: learn = {list(s.filter.learn)!r} and attitude_gain = "
                         f"{s.filter.attitude_gain!r}; its "
                         f"filter learns the tilt alone from the measured attitude: valid are [] and 1")
    estimator = TiltEstimator(params, dt, s.filter.process_noise, s.filter.gyro_sigma, s.filter.model_error,
                              attitude_gain=1.0)
    update = _estimator_update(estimator)
    predict = estimator.step.fun
    rti = _RTI(params, s)
    N, n, m = s.horizon.N, rti.n, rti.m
    memory = Memory([("k", 1), ("segment", 1), ("segment_k", 1), ("prev_seen", 1), ("prev_z", NZ), ("tilt", 2),
                     ("P", 4), ("hist", HISTORY), ("w", n), ("lam_w", n), ("lam_g", m), ("warm", 1), ("U", N),
                     ("k_solved", 1), ("current", 1), ("failures", 1), ("ramp_t0", 1), ("ramp_speed", 1),
                     ("brake_until", 1), ("since", 1), ("anchored", 1), ("anchor", 2), ("finished_at", 1)])
    window = NZ * (N + 1) + N + 4
    mem, meas, ref = ca.MX.sym("mem", memory.size), ca.MX.sym("meas", 12), ca.MX.sym("ref", 2 * window)

    def part(name):
        return mem[memory[name]]

    k, t_now = part("k"), part("k") * dt
    hist = part("hist")
    x_meas = meas[1:]
    z_meas = reduced_state(x_meas)
    seen = ca.floor(meas[0] / dt + 0.5)
    # 1. the estimator, when this measurement follows the previous one
    prev_seen = part("prev_seen")
    tilt, P = part("tilt"), ca.reshape(part("P"), 2, 2)
    u_prev = select(hist, k - 1 - prev_seen)  # the command issued at the previous measurement's step
    tilt1, P1 = update(tilt, P, part("prev_z"), u_prev, z_meas)
    follows = ca.logic_and(seen == prev_seen + 1, 1 if s.filter.enabled else 0)
    tilt, P = ca.if_else(follows, tilt1, tilt), ca.if_else(follows, P1, P)
    p = ca.MX(ca.DM(params.vector()))
    p[TILT] = tilt
    P_view = ParamView(p)
    # 2. delay compensation over the commands issued since the measurement
    delay = k - seen
    z = z_meas
    for j in range(HISTORY - 1):
        z = ca.if_else(j < delay, predict(z, select(hist, delay - 1 - j), p)[0], z)
    z = ca.if_else(finite(z), z, z_meas)  # never act on a broken prediction
    # 3. the stop in progress (``StopMonitor`` on the measurement); left, at a solve instant, once reached
    cur, nxt = ref[:window], ref[window:]
    stop, T, last = cur[window - 4:window - 2], cur[window - 2], cur[window - 1]
    centre_speed = P_view.R * ca.norm_2(x_meas[OMEGA][:2])
    at_rest = ca.logic_and(centre_speed < rule.rest_speed, ca.fabs(x_meas[THETA_DOT]) < rule.rest_drive)
    holds = ca.logic_and(ca.norm_2(x_meas[POS] - stop) <= rule.tolerance, at_rest)
    since = ca.if_else(holds, ca.if_else(part("since") >= 0, part("since"), meas[0]), -1)
    reached = ca.logic_and(holds, meas[0] - since >= rule.hold - 1e-9)
    instant = ca.fmod(k, every) == 0
    local = (k - part("segment_k")) * dt
    leave = ca.logic_and(ca.logic_and(instant, reached), local >= T - 1e-9)
    switch = ca.logic_and(leave, ca.logic_not(last))
    finished_at = ca.if_else(ca.logic_and(ca.logic_and(leave, last), part("finished_at") < 0), t_now,
                             part("finished_at"))
    done = ca.logic_and(finished_at >= 0, t_now >= finished_at + s.arrival.finish_hold - 1e-9)
    segment = part("segment") + switch
    segment_k = ca.if_else(switch, k, part("segment_k"))
    since = ca.if_else(switch, -1, since)
    follow = ca.if_else(switch, nxt, cur)
    T = ca.if_else(switch, nxt[window - 2], T)
    stop = ca.if_else(switch, nxt[window - 4:window - 2], stop)
    local = (k - segment_k) * dt
    Zr = ca.reshape(follow[:NZ * (N + 1)], NZ, N + 1)
    Ur = follow[NZ * (N + 1):NZ * (N + 1) + N].T
    # past the leg's end near its stop: hold where the robot arrived (``StopsSupervisor._settle``), gently; near is
    # within
    # the stop's tolerance (the NMPC's smaller ``hold_radius`` leaves a robot further off to a new leg, which
    # this controller cannot plan: chasing the last centimetres at rest keeps its motor from settling)
    hold_radius = max(s.arrival.hold_radius, rule.tolerance)
    ended = local >= T - 1e-9
    was = ca.logic_and(part("anchored"), ca.logic_not(switch))
    anchored = ca.logic_and(ended, ca.logic_or(was, ca.norm_2(z[REDUCED.position] - stop) <= hold_radius))
    anchor = ca.if_else(was, part("anchor"), z[REDUCED.position])
    Zr = ca.vertcat(ca.if_else(anchored, ca.repmat(anchor, 1, N + 1), Zr[REDUCED.position, :]),
                    Zr[REDUCED.position.stop:, :])
    # 4. one real-time iteration at a solve instant (or with no plan to follow)
    braking = t_now < part("brake_until")
    current_in = ca.if_else(switch, 0, part("current"))
    warm_in = ca.if_else(switch, 0, part("warm"))  # a new leg starts from its reference (as the NMPC's)
    solve = ca.logic_and(ca.logic_and(ca.logic_or(instant, current_in == 0), ca.logic_not(braking)),
                         ca.logic_not(done))
    past_end = local + ca.DM(s.horizon.h * np.arange(N + 1)).T > T  # the horizon's nodes past the leg's end
    rti_args = [part("w"), part("lam_w"), part("lam_g"), warm_in, z, Zr, Ur, ca.repmat(anchored, 1, N + 1), past_end,
                tilt]
    rti_fun = rti.function()
    skip = ca.Function("rollbot_no_rti", rti_fun.mx_in(), [rti_fun.mx_in(0), rti_fun.mx_in(1), rti_fun.mx_in(2),
                                                            ca.MX.zeros(N), ca.MX(0)])
    w1, lam_w1, lam_g1, U1, ok = ca.Function.conditional("rollbot_rti_if", [skip], rti_fun)(solve, *rti_args)
    solved = ca.logic_and(solve, ok)
    failed = ca.logic_and(solve, ca.logic_not(ok))
    failures = ca.if_else(solved, 0, ca.if_else(failed, part("failures") + 1, part("failures")))
    keep = ca.logic_and(current_in, failures < s.recovery.max_failures)  # a failed solve: the previous plan
    brake = ca.logic_and(failed, ca.logic_not(keep))
    speed0 = z[REDUCED.theta_dot]
    ramp_t0 = ca.if_else(brake, t_now, part("ramp_t0"))
    ramp_speed = ca.if_else(brake, speed0, part("ramp_speed"))
    brake_until = ca.if_else(brake, t_now + ca.fabs(speed0) / s.recovery.brake_accel + s.horizon.h, part("brake_until"))
    current = ca.if_else(solved, 1, ca.if_else(brake, 0, current_in))
    warm = ca.if_else(solved, 1, ca.if_else(brake, 0, warm_in))
    U = ca.if_else(solved, U1, part("U"))
    k_solved = ca.if_else(solved, k, part("k_solved"))
    failures = ca.if_else(brake, 0, failures)
    # 5. the command: the plan's, or the brake's speed ramp; within the motor's limits
    ramp = ca.sign(ramp_speed) * ca.fmax(0, ca.fabs(ramp_speed) - s.recovery.brake_accel * (t_now - ramp_t0))
    ramp_accel = ca.fmin(ca.fmax((ramp - z[REDUCED.theta_dot]) / dt, -P_view.max_accel), P_view.max_accel)
    braking_now = t_now < brake_until
    planned = select(U, ca.fmin(ca.floor((k - k_solved) / every), N - 1))
    accel = ca.if_else(braking_now, ramp_accel, planned)
    accel = motor_speed_clip(accel, x_meas[THETA_DOT], P_view.max_speed, dt)
    bounds = symbolic_model().accel_bounds(x_meas, p, ca.DM.zeros(6))
    accel = ca.fmin(ca.fmax(accel, bounds[0]), bounds[1])
    accel = ca.if_else(done, 0, ca.if_else(finite(accel), accel, 0))
    status = ca.if_else(done, 4, ca.if_else(braking_now, 3, ca.if_else(solved, 0, ca.if_else(failed, 2, 1))))
    # the memory of the next period
    updates = {"k": k + 1, "segment": segment, "segment_k": segment_k, "prev_seen": seen, "prev_z": z_meas,
               "tilt": tilt, "P": ca.vec(P), "hist": ca.vertcat(accel, hist[:HISTORY - 1]),
               "w": ca.if_else(solved, w1, ca.if_else(brake, ca.MX.zeros(n), part("w"))),
               "lam_w": ca.if_else(solved, lam_w1, part("lam_w")), "lam_g": ca.if_else(solved, lam_g1, part("lam_g")),
               "warm": warm, "U": U, "k_solved": k_solved, "current": current, "failures": failures,
               "ramp_t0": ramp_t0, "ramp_speed": ramp_speed, "brake_until": brake_until, "since": since,
               "anchored": ca.if_else(solve, anchored, was), "anchor": anchor, "finished_at": finished_at}
    mem_next = ca.vertcat(*[updates[name] for name in memory.slices])
    fun = ca.Function("rollbot_period", [mem, meas, ref], [accel, mem_next, status], ["mem", "meas", "ref"],
                      ["cmd", "mem_next", "status"])
    initial = np.zeros(memory.size)
    for name, value in (("prev_seen", -2.0), ("brake_until", -1.0), ("since", -1.0), ("finished_at", -1.0)):
        initial[memory[name]] = value  # none yet
    initial[memory["tilt"]] = estimator.p[TILT]
    estimator.reset()
    initial[memory["P"]] = estimator.P.ravel(order="F")
    return StepFunction(fun, memory, initial, N, every, dt, s.horizon.h)
