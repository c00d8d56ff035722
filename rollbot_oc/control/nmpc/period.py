"""The NMPC's control period as three CasADi Functions: the one description of the step that every caller evaluates.

The tracking step (``control.nmpc.step.TrackingStep``) keeps everything it remembers between periods in one flat
vector, the memory (``Memory``), and does the work of a period with three pure Functions of it:

``measure(mem, meas, k) -> (z, mem')``
    the tilt and model filter's update (``TiltEstimator.update``, written symbolically: the same one-step model,
    noise, learned factors and attitude blending) when the measurement ``meas`` = (its time, s; the full state
    (11,)) follows the previous one, and the delay compensation: the measurement predicted forward to the tick
    ``k`` over the commands issued since (at most ``HISTORY - 1`` periods); ``z`` is the reduced state (10,).
``solve(mem, z, window) -> (w, lam_w, lam_g, ok, retried)``
    one real-time iteration of the tracking problem on the supervisor's ``window`` (``WindowLayout``: reference
    states and accelerations, weights of every decision variable, weights of the mission's residuals), warm
    started from the memory's shifted solution, its QP by ``qrqp`` (the QP solver CasADi generates as C with the
    step), solved once more without the relaxable constraints when it has no solution; a failed warm-started
    iteration is taken once more from the reference (``retried``).
``commit(mem, z, k, w, lam_w, lam_g, ok, late, flags) -> (accel, speed, by_speed, mem', event)``
    the step's modes (``StepMode``) and the command: the solution followed, the previous one after a failed or
    late solve (``SHIFTED``), the brake's speed ramp (``RAMP``) or a speed from the host's fallback (``PID``),
    zero once done (``OFF``); ``speed`` is NaN unless the motor is commanded by speed.

Whether a solve was late is the caller's to judge (the compute-time model in simulation, the wall clock on a
robot), so ``solve`` and ``commit`` are separate calls.  The C project of ``export-c`` is generated from these
same Functions, so the Python NMPC and the C controller run one description.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import casadi as ca
import numpy as np

from rollbot_oc.control.nmpc.estimation import SCALE_RANGE, TiltEstimator
from rollbot_oc.control.nmpc.modes import StepMode
from rollbot_oc.control.nmpc.tracking import RTISolver
from rollbot_oc.model.dynamics import NZ, OMEGA, POS, QUAT, REDUCED, THETA, THETA_DOT
from rollbot_oc.model.params import NP, PARAM_INDEX, TILT
from rollbot_oc.model.rotations import quat_multiply

__all__ = ["HISTORY", "Memory", "WindowLayout", "StepFunctions", "step_functions", "MODE_CODES", "EVENTS", "finite",
           "select", "reduced_state", "placement"]

HISTORY = 50  # commands remembered for the filter and the delay compensation, control periods
MODE_CODES = {mode: i for i, mode in enumerate(StepMode)}  # StepMode <-> the memory's number
# what ``commit`` did this period (its ``event`` output)
EVENTS = ("followed", "solved", "shifted", "brake", "pid", "fallback", "off")


class Memory:
    """Named parts of the step's flat memory vector: ``mem[memory["name"]]``.

    Parameters
    ----------
    parts : sequence of (str, int)
        Name and size of each part, in order.
    """

    def __init__(self, parts):
        self.slices, start = {}, 0
        for name, size in parts:
            self.slices[name] = slice(start, start + size)
            start += size
        self.size = start

    def __getitem__(self, name: str) -> slice:
        return self.slices[name]

    def __contains__(self, name: str) -> bool:
        return name in self.slices


@dataclass(frozen=True)
class WindowLayout:
    """The parts of a ``window`` vector (column-major): ``Zr`` (10, N+1) reference states, ``Ur`` (N,) reference
    accelerations (rad/s^2), ``diag`` the weight of every decision variable (``TrackingWeights.diagonal``:
    10 (N+1) states by node, then N accelerations), ``mission`` (terms, N+1) the weights of the mission's
    residuals at the nodes and ``values`` the mission's values (``Mission.tracking_values``, flattened)."""

    N: int
    terms: int
    values: int = 0

    @property
    def parts(self):
        N = self.N
        return (("Zr", NZ * (N + 1)), ("Ur", N), ("diag", NZ * (N + 1) + N), ("mission", self.terms * (N + 1)),
                ("values", self.values))

    @property
    def size(self) -> int:
        return sum(n for _name, n in self.parts)

    def pack(self, Zr, Ur, diag, mission, values=()) -> np.ndarray:
        """The window vector of its parts (``mission`` (N+1,) or (terms, N+1), broadcast; ``values``: the
        mission's values, flattened column-major)."""
        mission = np.asarray(mission, float)
        mission = np.broadcast_to(mission, (self.terms, self.N + 1)) if mission.size else np.zeros(0)
        return np.concatenate([np.asarray(Zr, float).ravel(order="F"), np.ravel(Ur), np.ravel(diag),
                               mission.ravel(order="F"), np.asarray(values, float).ravel()])

    def split(self, window):
        """The parts of a (symbolic) window vector, shaped."""
        out, start = {}, 0
        for name, n in self.parts:
            out[name] = window[start:start + n]
            start += n
        out["Zr"] = ca.reshape(out["Zr"], NZ, self.N + 1)
        out["mission"] = ca.reshape(out["mission"], self.terms, self.N + 1)
        return out


@dataclass
class StepFunctions:
    """The three Functions of the control period (module doc) and what their callers need to know.

    Attributes
    ----------
    measure, solve, commit : casadi.Function
    memory : Memory
        Layout of ``mem``.
    window : WindowLayout
    initial_memory : numpy.ndarray
        ``mem`` before the first period.
    solver : RTISolver
        The tracking problem's layout (split, shift, default weights).
    learn : tuple of str
        The parameters whose scale factors the filter learns, in the memory's order.
    every : int
        Control periods per interval of the horizon.
    dt : float
        Control period, s.
    """

    measure: ca.Function
    solve: ca.Function
    commit: ca.Function
    memory: Memory
    window: WindowLayout
    initial_memory: np.ndarray
    solver: RTISolver
    learn: tuple
    every: int
    dt: float


def finite(x):
    """1 where every entry of ``x`` is finite, else 0."""
    return ca.sum1(ca.fabs(ca.vec(x))) < math.inf


def select(vector, index):
    """``vector[index]`` for a symbolic whole-number ``index``; 0 where it is out of range, not whole or NaN.

    One indexed read (a loop-free lookup in the generated C), not a comparison per entry: the delay
    compensation reads the command history 50 times a period.  The index is checked before it is used, so
    the C never converts a NaN or an out-of-range value to an integer."""
    valid = ca.logic_and(ca.logic_and(index >= 0, index <= vector.numel() - 1), index == ca.floor(index))
    return ca.if_else(valid, vector[ca.if_else(valid, index, 0)], 0)


def reduced_state(x):
    """Reduced state (10,) of a symbolic full state (11,) (``dynamics.to_reduced``)."""
    half = 0.5 * x[THETA]
    q = quat_multiply(x[QUAT], ca.vertcat(ca.cos(half), 0, 0, ca.sin(half)))
    return ca.vertcat(x[POS], q, x[OMEGA], x[THETA_DOT])


def _blend(predicted, measured, gain: float):
    """``estimation._blend``: the unit quaternion ``gain`` of the way from ``predicted`` to ``measured``."""
    sign = ca.if_else(ca.dot(predicted, measured) < 0, -1, 1)
    q = (1.0 - gain) * predicted + gain * sign * measured
    q = q / ca.norm_2(q)
    return ca.if_else(finite(predicted), ca.if_else(finite(measured), q, predicted), measured)


def step_functions(params, settings, weights, mission, dt: float) -> StepFunctions:
    """The control period's Functions (module doc) for the robot ``params`` believes in.

    Parameters
    ----------
    params : RollbotParams
        The controller's model (its tilt is the filter's prior).
    settings : NMPCSettings
    weights : TrackingWeights
        The mission's default tracking weights.
    mission : Mission
        For the tracking problem's mission terms and values.
    dt : float
        Control period, s.
    """
    s, dt = settings, float(dt)
    every = max(1, int(round(s.horizon.h / dt)))
    f = s.filter
    learn = tuple(f.learn) if f.enabled else ()
    estimator = TiltEstimator(params, dt, f.process_noise, f.gyro_sigma, f.model_error, learn, f.learn_sigma,
                              f.attitude_gain)
    solver = RTISolver(params, s.replace(horizon={"compiled": False}), weights, mission=mission)
    N, n, m = s.horizon.N, solver.n_x, solver.route.transcription.g.numel()
    nf = 2 + len(learn)
    memory = Memory([("p", NP), ("seen", 1), ("z_prev", NZ), ("x_f", nf), ("P", nf * nf), ("attitude", 4), ("tracked", 1),
                     ("hist", HISTORY), ("w", n), ("lam_w", n), ("lam_g", m), ("warm", 1), ("current", 1),
                     ("U", N), ("k_solved", 1), ("failures", 1), ("mode", 1), ("until", 1), ("ramped", 1),
                     ("ramp_t0", 1), ("ramp_speed", 1)])
    terms = solver.layout.stage_parameters["mission_weight"]
    values = sum(np.size(v) for v in solver._mission_values.values())
    window = WindowLayout(N, terms.stop - terms.start, values)
    columns = [PARAM_INDEX[name] for name in learn]

    def model_parameters(p, x_f):
        """The model's parameters: the nominal ``p`` (the memory's) with the estimated tilt and learned factors."""
        p = ca.vertcat(p[:TILT.start], x_f[:2], p[TILT.stop:])
        for i, c in enumerate(columns):
            p = ca.vertcat(p[:c], p[c] * x_f[2 + i], p[c + 1:])
        return p

    measure = _measure(memory, estimator, learn, columns, model_parameters, f.enabled)
    solve = _solve(memory, window, solver, model_parameters, nf)
    commit = _commit(memory, solver, s, dt, every, N)
    initial = np.zeros(memory.size)
    initial[memory["p"]] = estimator.p  # the robot the controller believes in: memory, not code
    initial[memory["seen"]] = -2.0  # none yet
    initial[memory["x_f"]] = np.concatenate([estimator.tilt, estimator.scales])
    initial[memory["P"]] = estimator._P.ravel(order="F")
    initial[memory["until"]] = -1.0
    initial[memory["mode"]] = MODE_CODES[StepMode.SOLVE]
    return StepFunctions(measure, solve, commit, memory, window, initial, solver, learn, every, dt)


def _measure(memory, estimator, learn, columns, model_parameters, enabled) -> ca.Function:
    nf = 2 + len(learn)
    mem, meas, k = ca.MX.sym("mem", memory.size), ca.MX.sym("meas", 1 + 11), ca.MX.sym("k")

    def part(name):
        return mem[memory[name]]

    one_step = estimator.step.fun  # (z, u, p) -> (z_next, d omega_next / d (tilt, learned))
    z_meas = reduced_state(meas[1:])
    seen = ca.floor(meas[0] / estimator.dt + 0.5)
    hist = part("hist")
    x_f, P = part("x_f"), ca.reshape(part("P"), nf, nf)
    # 1. the filter, when this measurement follows the previous one
    follows = ca.logic_and(seen == part("seen") + 1, 1 if enabled else 0)
    z_prev = part("z_prev")
    start = ca.vertcat(z_prev[:REDUCED.quaternion.start],
                       ca.if_else(part("tracked"), part("attitude"), z_prev[REDUCED.quaternion]),
                       z_prev[REDUCED.quaternion.stop:])
    u_prev = select(hist, k - 1 - part("seen"))  # the command issued at the previous measurement's tick
    p_nominal = part("p")
    zn, J = one_step(start, u_prev, model_parameters(p_nominal, x_f))
    gain = estimator.attitude_gain
    attitude = _blend(zn[REDUCED.quaternion], z_meas[REDUCED.quaternion], gain) if gain < 1.0 else \
        ca.MX.zeros(4)
    scale = ca.vertcat(1.0, 1.0, *[p_nominal[c] for c in columns]).T
    H = J * ca.repmat(scale, 3, 1)  # per unit of each factor
    residual = z_meas[REDUCED.omega] - zn[REDUCED.omega]
    P1 = P + ca.diag(ca.DM([estimator.q] * 2 + [0.0] * len(learn)))
    change = ca.norm_2(zn[REDUCED.omega] - z_prev[REDUCED.omega])
    HP = ca.mtimes(H, P1)
    S = ca.mtimes(HP, H.T) + ca.DM.eye(3) * (estimator.r + (estimator.model_error * change) ** 2)
    K = ca.solve(S, HP).T
    P2 = ca.mtimes(ca.DM.eye(nf) - ca.mtimes(K, H), P1)
    x1 = x_f + ca.mtimes(K, residual)
    x1 = ca.vertcat(ca.fmin(ca.fmax(x1[:2], -0.5), 0.5), ca.fmin(ca.fmax(x1[2:], SCALE_RANGE[0]), SCALE_RANGE[1])) \
        if learn else ca.fmin(ca.fmax(x1, -0.5), 0.5)
    learned = ca.logic_and(follows, ca.logic_and(finite(residual), finite(H)))  # nothing from a broken one
    x_f = ca.if_else(learned, x1, x_f)
    P = ca.if_else(learned, 0.5 * (P2 + P2.T), P)
    tracked = ca.logic_and(follows, 1 if gain < 1.0 else 0)  # else the next update starts from its measurement
    attitude = ca.if_else(tracked, attitude, part("attitude"))
    # 2. the delay compensation over the commands issued since the measurement
    p = model_parameters(p_nominal, x_f)
    z_d, u_d, p_d = ca.MX.sym("z", NZ), ca.MX.sym("u"), ca.MX.sym("p", NP)
    active = ca.MX.sym("active")
    predict = ca.Function("predict_if", [z_d, u_d, p_d, active],
                          [ca.if_else(active, one_step(z_d, u_d, p_d)[0], z_d, True)])
    delay = k - seen
    z = z_meas
    for j in range(HISTORY - 1):  # the command of tick seen + j is hist[delay - 1 - j]
        z = predict(z, select(hist, delay - 1 - j), p, j < delay)
    z = ca.if_else(finite(z), z, z_meas)  # never act on a broken prediction
    updates = {"seen": seen, "z_prev": z_meas, "x_f": x_f, "P": ca.vec(P), "attitude": attitude,
               "tracked": tracked}
    mem_next = ca.vertcat(*[updates.get(name, mem[sl]) for name, sl in memory.slices.items()])
    return ca.Function("rollbot_measure", [mem, meas, k], [z, mem_next], ["mem", "meas", "k"], ["z", "mem_next"])


def placement(values: dict):
    """``(V, ids)``: every symbolic value flattened (column-major) into one MX vector ``V``, and for each
    name an array of the same shape holding the index of each entry in ``V`` (to pass through a numeric
    function that only places entries, e.g. ``Transcription.parameter_vector``)."""
    pieces, ids, start = [], {}, 0
    for name, value in values.items():
        n = value.numel()
        pieces.append(ca.vec(value))
        ids[name] = np.arange(start, start + n, dtype=float).reshape(value.shape, order="F")
        start += n
    return ca.vertcat(*pieces), ids


def _solve(memory, window, solver, model_parameters, nf) -> ca.Function:
    N, h = solver.settings.horizon.N, solver.settings.horizon.h
    tr = solver.route.transcription
    n, m = tr.w.numel(), tr.g.numel()
    mem, z0, win = ca.MX.sym("mem", memory.size), ca.MX.sym("z", NZ), ca.MX.sym("window", window.size)

    def part(name):
        return mem[memory[name]]

    parts = window.split(win)
    Zr = parts["Zr"]
    # q and -q are the same attitude: give the (continuous) reference the measurement's sign
    sign = ca.if_else(ca.dot(Zr[REDUCED.quaternion, 0], z0[REDUCED.quaternion]) < 0, -1, 1)
    Zs = ca.vertcat(Zr[:REDUCED.quaternion.start, :], sign * Zr[REDUCED.quaternion, :],
                    Zr[REDUCED.quaternion.stop:, :])
    node = ca.DM(np.append(np.ones(N), h)).T  # path terms are integrals, the terminal one is not
    diag = parts["diag"]
    values = {"x0": z0, "p": model_parameters(part("p"), part("x_f")[:nf]), "reference": Zs,
              "accel_reference": ca.horzcat(parts["Ur"].T, 0),
              "state_weight": ca.sqrt(ca.reshape(diag[:NZ * (N + 1)], NZ, N + 1) * ca.repmat(node, NZ, 1)),
              "accel_weight": ca.horzcat(ca.sqrt(diag[NZ * (N + 1):]).T, 0),
              "mission_weight": ca.sqrt(parts["mission"] * ca.repmat(node, window.terms, 1))}
    start = 0
    for name, value in solver._mission_values.items():  # the mission's values (a circle's centre and radius)
        shape = np.atleast_2d(value).shape if np.ndim(value) < 2 else np.shape(value)
        size = int(np.prod(shape))
        values[name] = ca.reshape(parts["values"][start:start + size], *shape)
        start += size
    V, ids = placement(values)
    par = V[tr.parameter_vector(ids).astype(int).tolist()]
    guess_values, guess_ids = placement({"Z": ca.horzcat(z0, Zs[:, 1:]), "U": parts["Ur"].T})
    guess = guess_values[solver._guess(guess_ids["Z"][:, 0], guess_ids["Z"], guess_ids["U"]).astype(int).tolist()]
    step = solver.route.to_function(relax=solver.relax)
    warm = part("warm")
    w0 = ca.if_else(warm, part("w"), guess)
    w1, lam_w1, lam_g1, violation, _relaxed = step(w0, ca.if_else(warm, part("lam_w"), ca.MX.zeros(n)),
                                                   ca.if_else(warm, part("lam_g"), ca.MX.zeros(m)), par)
    ok = ca.logic_and(violation <= solver.route.qp_feasibility, finite(w1))
    # a warm start gone bad (an iterate that diverged linearises to a QP no solver can solve): once more from the
    # reference, in the same period
    retry = ca.logic_and(warm, ca.logic_not(ok))
    args = [guess, ca.MX.zeros(n), ca.MX.zeros(m), par]
    names = ["w", "lam_w", "lam_g", "par"]
    inputs = [ca.MX.sym(name, a.sparsity()) for name, a in zip(names, args)]
    again = ca.Function("rollbot_rti_cold", inputs, step(*inputs)[:4])
    skip = ca.Function("rollbot_rti_kept", inputs, [ca.MX.zeros(n), ca.MX.zeros(n), ca.MX.zeros(m), ca.MX(0)])
    w2, lam_w2, lam_g2, violation2 = ca.Function.conditional("rollbot_rti_retry", [skip], again)(retry, *args)
    ok2 = ca.logic_and(violation2 <= solver.route.qp_feasibility, finite(w2))
    w_out = ca.if_else(retry, w2, w1)
    return ca.Function("rollbot_solve", [mem, z0, win],
                       [w_out, ca.if_else(retry, lam_w2, lam_w1), ca.if_else(retry, lam_g2, lam_g1),
                        ca.if_else(retry, ok2, ok), retry],
                       ["mem", "z", "window"], ["w", "lam_w", "lam_g", "ok", "retried"])


def _commit(memory, solver, s, dt, every, N) -> ca.Function:
    tr = solver.route.transcription
    n, m = tr.w.numel(), tr.g.numel()
    mem, z, k = ca.MX.sym("mem", memory.size), ca.MX.sym("z", NZ), ca.MX.sym("k")
    w, lam_w, lam_g = ca.MX.sym("w", n), ca.MX.sym("lam_w", n), ca.MX.sym("lam_g", m)
    ok, late, solving = ca.MX.sym("ok"), ca.MX.sym("late"), ca.MX.sym("solving")
    done, fallback_pid, pid_speed = ca.MX.sym("done"), ca.MX.sym("fallback_pid"), ca.MX.sym("pid_speed")

    def part(name):
        return mem[memory[name]]

    code = {mode: float(i) for mode, i in MODE_CODES.items()}
    t_now = k * dt
    mode, until = part("mode"), part("until")
    off = ca.logic_or(done, mode == code[StepMode.OFF])
    in_fallback = ca.logic_and(ca.logic_not(off), t_now < until)
    solved = ca.logic_and(ca.logic_and(solving, ca.logic_not(in_fallback)), ca.logic_not(off))
    success = ca.logic_and(solved, ca.logic_and(ok, ca.logic_not(late)))
    missed = ca.logic_and(solved, ca.logic_not(success))
    failures = ca.if_else(success, 0, ca.if_else(missed, part("failures") + 1, part("failures")))
    shifted = ca.logic_and(missed, ca.logic_and(part("current"), failures < s.recovery.max_failures))
    gave_up = ca.logic_and(missed, ca.logic_not(shifted))
    brake = ca.logic_and(gave_up, ca.logic_not(fallback_pid))
    pid = ca.logic_and(gave_up, fallback_pid)
    index = np.arange(n, dtype=float)
    U_new = w[solver.split(index)[1].astype(int).tolist()]
    speed0 = z[REDUCED.theta_dot]
    updates = {
        "w": ca.if_else(success, w[solver.shift(index).astype(int).tolist()], part("w")),
        "lam_w": ca.if_else(success, lam_w, part("lam_w")), "lam_g": ca.if_else(success, lam_g, part("lam_g")),
        # a failed solve (the retry from the reference failed too) is no use starting from again
        "warm": ca.if_else(success, 1, ca.if_else(ca.logic_or(gave_up, ca.logic_and(missed, ca.logic_not(ok))), 0,
                                                  part("warm"))),
        "current": ca.if_else(success, 1, ca.if_else(gave_up, 0, part("current"))),
        "U": ca.if_else(success, U_new, part("U")), "k_solved": ca.if_else(success, k, part("k_solved")),
        "failures": ca.if_else(gave_up, 0, failures),
        "ramped": ca.if_else(brake, 1, ca.if_else(pid, 0, part("ramped"))),
        "ramp_t0": ca.if_else(brake, t_now, part("ramp_t0")),
        "ramp_speed": ca.if_else(brake, speed0, part("ramp_speed")),
        "until": ca.if_else(brake, t_now + ca.fabs(speed0) / s.recovery.brake_accel + s.horizon.h,
                            ca.if_else(pid, t_now + s.recovery.pid_time, until)),
    }
    new_mode = ca.if_else(off, code[StepMode.OFF],
                          ca.if_else(success, code[StepMode.SOLVE],
                                     ca.if_else(shifted, code[StepMode.SHIFTED],
                                                ca.if_else(brake, code[StepMode.RAMP],
                                                           ca.if_else(pid, code[StepMode.PID], mode)))))
    updates["mode"] = new_mode
    # the command: the followed solution's acceleration, or the fallback's speed
    current = updates["current"]
    planned = select(updates["U"], ca.fmin(ca.floor((k - updates["k_solved"]) / every), N - 1))
    by_speed = ca.logic_and(ca.logic_not(off), ca.logic_or(in_fallback, ca.logic_and(solved,
                                                                                      ca.logic_not(current))))
    t0, s0 = updates["ramp_t0"], updates["ramp_speed"]
    ramp = ca.sign(s0) * ca.fmax(0.0, ca.fabs(s0) - s.recovery.brake_accel * (t_now - t0))
    speed = ca.if_else(new_mode == code[StepMode.PID], pid_speed, ramp)
    limit = part("p")[PARAM_INDEX["max_accel"]]  # the plant's motor cannot follow faster either
    speed_accel = ca.fmin(ca.fmax((speed - z[REDUCED.theta_dot]) / dt, -limit), limit)
    accel = ca.if_else(off, 0.0, ca.if_else(by_speed, speed_accel, planned))
    updates["hist"] = ca.vertcat(accel, part("hist")[:HISTORY - 1])
    event = ca.if_else(off, EVENTS.index("off"),
                       ca.if_else(in_fallback, EVENTS.index("fallback"),
                                  ca.if_else(success, EVENTS.index("solved"),
                                             ca.if_else(shifted, EVENTS.index("shifted"),
                                                        ca.if_else(brake, EVENTS.index("brake"),
                                                                   ca.if_else(pid, EVENTS.index("pid"),
                                                                              EVENTS.index("followed")))))))
    mem_next = ca.vertcat(*[updates.get(name, mem[sl]) for name, sl in memory.slices.items()])
    return ca.Function("rollbot_commit", [mem, z, k, w, lam_w, lam_g, ok, late, solving, done, fallback_pid,
                                          pid_speed],
                       [accel, ca.if_else(by_speed, speed, np.nan), by_speed, mem_next, event],
                       ["mem", "z", "k", "w", "lam_w", "lam_g", "ok", "late", "solving", "done", "fallback_pid",
                        "pid_speed"], ["accel", "speed", "by_speed", "mem_next", "event"])
