"""NMPC against the PID baseline on the full plant (1 deg slope, noise, latency), robustness and fallbacks."""

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from rollbot_oc.model.codegen import compiler
from rollbot_oc.missions import Waypoints
from rollbot_oc.control.nmpc import NMPC, NMPCSettings, RTISolver, TiltEstimator, TrackingWeights
from rollbot_oc.control.nmpc.step import TrackingStep
from rollbot_oc.control.nmpc.supervisors import LegKind, StopsSupervisor
from rollbot_oc.planning.min_time import RestToRest, SolveFailed
from rollbot_oc.model.dynamics import FULL, NZ, REDUCED
from rollbot_oc.model.params import PARAM_INDEX, RollbotParams
from rollbot_oc.scenarios.problem import load_problem, make_controller, run_problem

from shared import same_problem

PROBLEMS = Path(__file__).parent.parent / "problems"
# The N-shape's minimum-time bound on its 1 deg slope (s): ``bounds.minimum_time_bound`` on the problem,
# as ``benchmarks/bench_nmpc.py`` computes it (a regression anchor; it takes a minute to compute).
N_SHAPE_BOUND = 14.7


def check_plant_limits(m):
    assert not m["torque_limit_violation"] and not m["speed_limit_violation"]
    assert m["min_normal_force"] > 0 and m["min_slide_margin"] > 0 and not m["events"]


def check_real_time(m):
    """Lateness is judged against the modelled compute time, so it does not depend on the machine's load; the
    measured wall-clock times are only reported (``benchmarks/bench_nmpc.py`` measures them)."""
    assert m["failed_solves"] + m["late_solves"] <= 0.01 * m["solves"]
    assert 0 < m["solve_time_min"] <= m["solve_time_median"] <= m["solve_time_p95"] <= m["solve_time_max"]


def test_n_shape_faster_than_the_pid_with_real_stops(n_shape_runs):
    """Every stop reached by the true trajectory: within 7 cm and at rest (centre below 5 mm/s, motor below
    0.05 rad/s) for 0.5 s; the first command within a second, the legs planned as the robot moves.  (The two runs
    are the session's shared ``n_shape_runs``: the demo's.)"""
    problem, (pid, nmpc) = n_shape_runs
    assert same_problem(problem, load_problem(PROBLEMS / "n_shape.toml"))
    assert (pid.controller, nmpc.controller) == ("pid", "nmpc") and pid.seed == nmpc.seed == 0
    nmpc, pid = nmpc.metrics, pid.metrics
    assert nmpc["completed"] and len(nmpc["stop_errors"]) == 4
    assert max(nmpc["stop_errors"]) <= 0.07
    assert nmpc["completion_time"] <= pid["completion_time"] / 4
    check_plant_limits(nmpc)
    check_real_time(nmpc)
    assert nmpc["plan_failures"] == 0 and max(nmpc["stop_errors"]) <= 0.03  # plan_time: benchmarks/
    # measured 18.1 s, 1.23 (seeds 0 to 4: 17.85 to 18.15 s, median 18.1 s); the issue asks for 1.25
    assert N_SHAPE_BOUND <= nmpc["completion_time"] <= 1.25 * N_SHAPE_BOUND
    # where the time went: the legs followed, past their ends until each stop was reached, waiting for plans
    # (disjoint spans of the run; measured 14.84 + 2.2 + 0 of 18.1 s). A leg moves until its end, so each stop
    # takes at least the rest test's 0.5 s past it (less a solve interval of 0.05 s); the robot arrives with its
    # motor still (``TrackingWeights.arrival_speed``), so hardly more (measured 0.55 s a stop, seeds 0 to 4 alike;
    # without it 0.74 to 0.92 s, here 0.92 s)
    assert 4 * (0.5 - 0.05) <= nmpc["stop_wait"] <= 4 * 0.85
    assert nmpc["plan_duration"] + nmpc["stop_wait"] + nmpc["plan_wait"] <= nmpc["completion_time"]
    # the mode timeline: ridden, then legs tracked and held at each stop, finished, done; the step always solving
    modes = nmpc["modes"]
    assert [m["mode"] for m in modes][:2] == ["ride", "track"] and [m["mode"] for m in modes][-2:] == ["finish", "done"]
    assert sum(m["mode"] == "hold" for m in modes) == 4 and all(a["t"] <= b["t"] for a, b in zip(modes, modes[1:]))
    # finished once the last stop's rest test (0.5 s at rest) has passed, at the next solve instant
    assert 0.5 <= modes[-2]["t"] - nmpc["stop_times"][-1] <= 0.5 + 0.05 + 1e-9
    assert [m["mode"] for m in nmpc["step_modes"]] == ["solve", "off"]


def test_arrival_weights_weigh_only_the_nodes_past_the_leg():
    """The driving speed weighs ``arrival_speed`` and the shell's angular velocity ``arrival_omega`` at the horizon
    nodes past a leg's end (times the terminal factor at the last node); every other weight is the plain
    diagonal's."""
    weights = TrackingWeights.for_waypoints()
    N, speed, omega = 10, REDUCED.theta_dot, np.arange(NZ)[REDUCED.omega]
    plain = weights.diagonal(N)
    per_node = np.array([weights.position] * 2 + [weights.attitude] * 4 + [weights.omega] * 3 + [weights.speed])
    scale = np.r_[np.ones(N), weights.terminal]
    assert np.array_equal(plain, np.r_[np.outer(scale, per_node).ravel(), np.full(N, weights.accel)])
    off = replace(weights, arrival_speed=0.0, arrival_omega=0.0)
    assert not off.arrives and np.array_equal(plain, off.diagonal(N, np.ones(N + 1, bool)))
    ended = np.arange(N + 1) >= 7
    diag = weights.diagonal(N, ended)
    changed = np.flatnonzero(diag != plain)
    assert changed.tolist() == [node * NZ + i for node in range(7, N + 1) for i in (*omega, speed)]
    assert diag[7 * NZ + speed] == weights.arrival_speed
    assert diag[N * NZ + speed] == weights.arrival_speed * weights.terminal
    assert np.all(diag[7 * NZ + omega] == weights.arrival_omega)
    assert np.all(diag[N * NZ + omega] == weights.arrival_omega * weights.terminal)
    # each alone changes its own rows only
    assert np.flatnonzero(replace(weights, arrival_omega=0.0).diagonal(N, ended) != plain).tolist() == \
        [node * NZ + speed for node in range(7, N + 1)]


def test_circle_half_the_pid_deviation(pid_circle_run):
    """The tightest circle (`rollbot-oc compare` measures all four). Each controller measured once settled:
    the PID from the paper's 120 s to the problem's 300 s (the run test_pid measures), the NMPC, which plans
    its entry onto the circle, from 30 s to 75 s (both from reaching the circle if that is later)."""
    problem = load_problem(PROBLEMS / "circle_R020.toml")
    pid = pid_circle_run("circle_R020").metrics
    nmpc_problem = replace(problem, mission=replace(problem.mission, settle_time=30.0), duration=75.0)
    nmpc = run_problem(nmpc_problem, "nmpc").metrics
    assert nmpc["reach_time"] <= 30.0
    assert nmpc["completed"] and pid["completed"]
    assert nmpc["avg_deviation"] <= 0.5 * pid["avg_deviation"]
    check_plant_limits(nmpc)
    check_real_time(nmpc)


def test_random_waypoints_in_a_two_metre_square():
    rng = np.random.default_rng(2026)
    stops = rng.uniform(-1.0, 1.0, size=(3, 2)).tolist()
    base = load_problem(PROBLEMS / "n_shape.toml")
    problem = replace(base, mission=Waypoints(tuple(np.array(s) for s in stops)), start_position=np.zeros(2))
    m = run_problem(problem, "nmpc").metrics
    assert m["completed"] and max(m["stop_errors"]) <= 0.07
    check_plant_limits(m)


@pytest.mark.parametrize("scale", [0.9, 1.1])
def test_model_error_of_ten_percent(scale):
    """The plant's masses and damping 10 % off the controller's model: the N-shape's first stop reached at rest
    (``benchmarks/bench_model_error.py`` runs its first two stops)."""
    base = load_problem(PROBLEMS / "n_shape.toml")
    p = base.params
    plant = p.replace(M_s=scale * p.M_s, m=scale * p.m, m_b=scale * p.m_b, k0=scale * p.k0)
    problem = replace(base, params=plant, mission=base.mission.first(1))
    m = run_problem(problem, "nmpc", params=RollbotParams()).metrics
    assert m["completed"] and max(m["stop_errors"]) <= 0.07
    check_plant_limits(m)


def test_the_tilt_estimate_finds_the_slope_and_the_entry_is_planned_while_moving():
    problem = load_problem(PROBLEMS / "circle_R035.toml").with_duration(30.0)
    nmpc = make_controller("nmpc", problem)
    first = nmpc.prepare(problem.initial_state()).segments[0][0]
    assert first.status == "guess" and first.u.max() > 0  # the ramp: nothing solved before the first command
    m = run_problem(problem, nmpc).metrics
    true = math.sin(math.radians(1.0)) * np.array([math.cos(-math.pi / 4), math.sin(-math.pi / 4)])
    assert np.allclose(m["tilt_estimate"], true, atol=0.002)  # 0.1 deg
    # the entry, planned once as the robot moved, ready in time and followed onto the circle
    assert m["plan_solves"] == 1 and m["plan_late"] == 0 and m["plan_failures"] == 0
    assert [p["status"] for p in m["plans"]] == ["Solve_Succeeded"] and m["reach_time"] is not None


def test_a_far_start_tries_only_entries_long_enough_and_follows_the_first_in_time():
    """approach: the ramp from 1.8 m out revolves about a centre far from the orbit's, so the entry skips the
    durations too short to move it there (``entry.shift_speed``; a shorter one spent its 400 iterations and
    made the next too late); the first tried converges, is ready before its start, and is followed onto the
    circle, without a failed QP or the PID."""
    problem = load_problem(PROBLEMS / "approach.toml").with_duration(20.0)
    nmpc = make_controller("nmpc", problem)
    nmpc.prepare(problem.initial_state())
    s, times = nmpc.settings, nmpc.supervisor._entry_times()
    assert times[0] > min(s.entry.times) and times[0] * s.entry.shift_speed >= nmpc.supervisor._entry_shift
    assert list(times) == [d for d in s.entry.times if d >= times[0]]  # and the longer ones, in turn
    m = run_problem(problem, nmpc).metrics
    assert m["plan_failures"] == 0 and m["plan_late"] == 0 and m["plan_solves"] == 1
    assert [p["T"] for p in m["plans"]] == [pytest.approx(times[0])]
    assert m["reach_time"] is not None and m["failed_solves"] == 0 and m["fallback_pid"] == 0
    check_plant_limits(m)


def _with_solve_stage(monkeypatch, wrap):
    """Every ``TrackingStep`` built in the test evaluates ``wrap(step, solve)(mem, z, window)`` as its solve
    stage (``solve``: the step's own compiled Function)."""
    init = TrackingStep.__init__

    def patched(self, *args, **kwargs):
        init(self, *args, **kwargs)
        self._solve = wrap(self, self._solve)

    monkeypatch.setattr(TrackingStep, "__init__", patched)


def test_failed_solves_fall_back_without_crashing(monkeypatch):
    """Every fourth solve instant fails (its solve stage says so): the loop carries on with shifted plans and,
    when failures pile up, the PID."""
    calls = {"n": 0}
    run = NMPCSettings().recovery.max_failures + 2  # a run of failures longer than the NMPC waits out

    def wrap(step, solve):
        def flaky(mem, z, window):
            calls["n"] += 1
            w, lam_w, lam_g, ok, retried = solve(mem, z, window)
            if calls["n"] % 4 == 0 or 40 <= calls["n"] < 40 + run:
                return w, lam_w, lam_g, np.zeros(1), retried
            return w, lam_w, lam_g, ok, retried
        return flaky

    _with_solve_stage(monkeypatch, wrap)
    problem = load_problem(PROBLEMS / "circle_R050.toml").with_duration(20.0)
    m = run_problem(problem, "nmpc").metrics
    assert m["failed_solves"] >= 8 and m["fallback_shifted"] >= 5 and m["fallback_pid"] >= 1
    assert sum(n for status, n in m["solver_statuses"].items() if status.endswith("failed")) == m["failed_solves"]
    assert not m["events"] and m["duration"] == pytest.approx(20.0)
    # the step's modes say so: the shifted plan, the PID for pid_time once the failures piled up, solving again
    modes = m["step_modes"]
    pid = [i for i, change in enumerate(modes) if change["mode"] == "pid"]
    assert pid and any(change["mode"] == "shifted" for change in modes[:pid[0]])
    assert all(modes[i + 1]["t"] - modes[i]["t"] >= NMPCSettings().recovery.pid_time - 1e-9 for i in pid
               if i + 1 < len(modes))
    assert sum(change["mode"] == "pid" for change in modes) == m["fallback_pid"]


def test_a_failed_warm_start_is_solved_again_from_the_reference(monkeypatch):
    """Every third warm start is broken (its iterate not finite, as one gone bad): the step's solve stage
    solves that instant again from the reference, in the same period, and no solve instant is lost."""
    calls = {"warm": 0, "broken": 0, "retried": 0}

    def wrap(step, solve):
        def bad_warm_starts(mem, z, window):
            mem = np.array(mem)
            if mem[step.memory["warm"]][0]:
                calls["warm"] += 1
                if calls["warm"] % 3 == 0:
                    mem[step.memory["w"]] = np.nan
                    calls["broken"] += 1
            out = solve(mem, z, window)
            calls["retried"] += int(out[4][0])
            return out
        return bad_warm_starts

    _with_solve_stage(monkeypatch, wrap)
    problem = load_problem(PROBLEMS / "circle_R050.toml").with_duration(6.0)
    m = run_problem(problem, "nmpc").metrics
    assert calls["broken"] >= 10 and m["cold_retries"] == calls["broken"] == calls["retried"]
    assert m["failed_solves"] == 0 and m["fallback_shifted"] == 0
    assert m["solver_statuses"].get("cold after failed: success") == m["cold_retries"]


def test_ipopt_route_converges_on_the_same_problem():
    """IPOPT (exact Hessian) is too slow for real time here, so it is studied without the real-time limit
    (on 30 intervals of 0.1 s: the route, not the horizon, is what this checks; the step's other Functions in
    CasADi's virtual machine, not compiled for this one run)."""
    problem = load_problem(PROBLEMS / "circle_R065.toml").with_duration(1.0)  # 10 periods of IPOPT to convergence
    settings = NMPCSettings(horizon={"solver": "ipopt", "N": 30, "h": 0.1, "substeps": 2, "compiled": False},
                            timing={"max_solve_time": 60.0})
    m = run_problem(problem, "nmpc", settings=settings).metrics
    assert m["failed_solves"] == 0 and m["fallback_pid"] == 0
    assert set(m["solver_statuses"]) == {"success"}


@pytest.mark.skipif(compiler() is None, reason="no C compiler: the RTI runs on CasADi's virtual machine")
def test_compiled_and_interpreted_linearisations_agree():
    """The tracking problem's stage derivatives as compiled C equal CasADi's virtual machine on them."""
    from rollbot_oc.control.nmpc.tracking import tracking_problem
    from rollbot_oc.ocp.linearisation import StructuredLinearisation
    from rollbot_oc.ocp.transcription import Transcription

    from rollbot_oc.missions import Circle

    # one RK4 step per interval: the same stage terms in half the C (a cold compile of two stages at -O1)
    tr = Transcription(tracking_problem(N=6, h=0.1, substeps=1, mission=Circle))  # with the circle's own term
    rng = np.random.default_rng(1)
    w = rng.normal(size=tr.layout.size)
    stage = {name: rng.normal(size=(sl.stop - sl.start, 7)) for name, sl in tr.layout.stage_parameters.items()}
    par = tr.parameter_vector(dict(x0=rng.normal(size=10), p=RollbotParams().vector(), circle=[0.1, 0.2, 0.5],
                                   **stage))
    a = StructuredLinearisation(tr, compiled=False)(w, par)
    b = StructuredLinearisation(tr, compiled=True)(w, par)
    for x, y in zip(a, b):
        x, y = (np.array(v.nonzeros()) if hasattr(v, "nonzeros") else np.asarray(v) for v in (x, y))
        assert np.allclose(x, y, rtol=1e-12, atol=1e-12)


def test_settings_every_field_checked():
    """``NMPCSettings``: at most 12 groups, each frozen; every field of every group refuses a value of the wrong
    kind or out of its range in one line naming the group, the field and the value."""
    from dataclasses import FrozenInstanceError, fields

    from rollbot_oc.control.nmpc.settings import _GROUPS

    settings = NMPCSettings()
    assert len(fields(settings)) <= 12 and {f.name for f in fields(settings)} == set(_GROUPS)
    bad = {int: [1.5, -1, True, "3"], float: [float("nan"), -1.0, "x", True], str: ["other"], bool: [1, "yes"],
           tuple: [(0.0,), (-1.0,), 5.0, ("R",)], "weights": [{"position": 1}]}
    checked = 0
    for name, group in _GROUPS.items():
        with pytest.raises(FrozenInstanceError):
            setattr(getattr(settings, name), fields(group)[0].name, None)
        for f in fields(group):
            assert "check" in f.metadata, f"{name}.{f.name} is not checked"
            default = getattr(getattr(settings, name), f.name)
            kind = "weights" if name == "weights" and f.name != "gate" else type(default)
            refused = 0
            for value in bad.get(kind, [object()]):
                try:
                    NMPCSettings(**{name: {f.name: value}})
                except ValueError as exc:
                    message = str(exc)
                    assert "\n" not in message and f"{name}.{f.name}" in message, message
                    refused += 1
            assert refused >= 1, f"{name}.{f.name} accepts every bad value"
            checked += 1
    assert checked >= 50


def test_estimator_and_settings_validation():
    with pytest.raises(ValueError, match="solver"):
        NMPCSettings(horizon={"solver": "fatrop"})
    with pytest.raises(ValueError, match="h = 0.015"):
        NMPC(Waypoints(([0.0, 0.0],)), settings=NMPCSettings(horizon={"h": 0.015}))
    with pytest.raises(ValueError, match="filter.learn = \\('M', 'R'\\) is out of range: valid is names among M, m"):
        NMPCSettings(filter={"learn": ("M", "R")})
    with pytest.raises(ValueError, match="learn_sigma = 0.5"):
        NMPCSettings(filter={"learn_sigma": 0.5})
    with pytest.raises(ValueError, match=r"attitude_gain = 0 is out of range: valid is \(0, 1\]"):
        NMPCSettings(filter={"attitude_gain": 0})
    with pytest.raises(ValueError, match="ride_accels"):
        NMPCSettings(planner={"ride_accels": (2.0, 0.0)})
    for quick in (-0.1, True):
        with pytest.raises(ValueError, match=f"planner.quick = {quick}"):
            NMPCSettings(planner={"quick": quick})
    with pytest.raises(ValueError, match=r"planner.fresh = 1.5 is out of range: valid is whole numbers in \[0, 5\]"):
        NMPCSettings(planner={"fresh": 1.5})
    with pytest.raises(ValueError, match="NMPC horizon has no field 'n': valid are N, h"):
        NMPCSettings(horizon={"n": 30})
    with pytest.raises(ValueError, match="NMPC settings have no group 'plan'"):
        NMPCSettings().replace(plan={"N": 30})
    est = TiltEstimator(RollbotParams(), 0.01)
    assert np.allclose(est.tilt, 0.0) and est.learned() == {}


def _plant_with(nominal: RollbotParams, factors: dict) -> RollbotParams:
    """``nominal`` with its shell mass (``M``: both ``M_s`` and ``m_b``), ``m`` or ``k0`` scaled by ``factors``."""
    scaled = {"m": nominal.m * factors.get("m", 1.0), "k0": nominal.k0 * factors.get("k0", 1.0)}
    f = factors.get("M", 1.0)
    return nominal.replace(M_s=nominal.M_s * f, m_b=nominal.m_b * f, **scaled)


@pytest.mark.parametrize("factors", [{}, {"M": 0.9}, {"m": 1.1, "k0": 0.92}])
def test_the_filter_learns_the_masses_and_damping_the_robot_moves_with(factors):
    """The plant (the full model, ``simulate``) differs from the filter's model by ``factors``; driven open loop
    by a motor-acceleration sweep and measured exactly, the filter learns each factor within 3 % (measured:
    within 0.6 % for the masses, 2 % for the damping, which the sweep excites least; the exact model's stay
    within 0.5 % of 1): what the NMPC then plans and solves with."""
    from rollbot_oc.model.dynamics import rest_state, to_reduced
    from rollbot_oc.simulation.plant import simulate

    nominal = RollbotParams(slope=0.0)
    plant = _plant_with(nominal, factors)
    result = simulate(rest_state(plant), 8.0, params=plant,
                      accel=lambda t: 12.0 * math.sin(2 * math.pi * 0.4 * t) * min(t, 1.0))
    est = TiltEstimator(nominal, 0.01, learn=("M", "m", "k0"))
    for k in range(result.command.size):
        est.update(to_reduced(result.x[:, k]), float(result.command[k]), to_reduced(result.x[:, k + 1]))
    learned = est.learned()
    for name in ("M", "m", "k0"):
        truth = factors.get(name, 1.0)
        assert learned[name] == pytest.approx(truth, abs=0.03 if factors else 0.005), (name, learned)
    assert np.allclose(est.tilt, 0.0, atol=math.radians(0.2))
    p = est.params()
    assert p[PARAM_INDEX["M"]] == pytest.approx(nominal.M * learned["M"])
    with pytest.raises(ValueError, match="cannot learn 'mu'"):
        TiltEstimator(nominal, 0.01, learn=("mu",))


def test_learning_in_closed_loop_is_not_biased_by_the_attitude_noise():
    """Random course 30 (0.6 deg attitude noise, 3 periods of latency, the model 3 to 7 % off) for its first 20 s:
    predicted from the filtered attitude, the learned factors come within 2.5 % of the truth (measured within
    1.4 %). From the measured attitude (``attitude_gain`` 1) its noise, in the prediction, its Jacobian and the
    commands that react to it, biased them (measured: the shell's mass 7.5 % high), and the whole course took 335 s
    instead of 60 s."""
    from rollbot_oc.scenarios.courses import random_course

    course = random_course(seed=0, index=30)
    # its first two stops (the first reached at 14.4 s): the same run for 20 s, without planning legs it never starts
    two = course.problem.mission.first(2)
    problem = replace(course.problem, mission=two, duration=20.0)
    run = run_problem(problem, "nmpc", params=course.believed, seed=course.noise_seed)
    learned = run.metrics["model_learned"]
    for name in ("M", "m", "k0"):
        truth = getattr(course.problem.params, name) / getattr(course.believed, name)
        assert learned[name] == pytest.approx(truth, rel=0.025), (name, learned, truth)


def test_the_shell_arrives_still_on_a_robot_that_sways():
    """Random course 73 (R = 0.147 m, the masses and damping up to 10 % off the model): the first leg ends near
    4.5 s. Weighing the shell's angular velocity past the leg's end (``arrival_omega``), the robot is at rest at
    its first stop sooner than without, and within 7.5 s (the rest test then holds by the run's 8 s).  At commit
    0b6ceff the approach without the weight ended in a sideways sway of the shell (39 mm/s at 6 s, a mode the
    motor cannot damp at rest) and the rest test passed at 18.3 s, against 8.85 s with it; since the first leg's refinement starts from the state the
    tracking NMPC predicts (b0f0160) the approach sways less: 6.01 s without the weight, 5.3 s with it."""
    from rollbot_oc.scenarios.courses import random_course

    course = random_course(seed=0, index=73)
    first = course.problem.mission.first(1)  # the first stop alone: no leg planned ahead
    problem = replace(course.problem, mission=first, duration=8.0)
    firsts = []
    for omega in (TrackingWeights.for_waypoints().arrival_omega, 0.0):
        settings = NMPCSettings(weights={"legs": replace(TrackingWeights.for_waypoints(), arrival_omega=omega)})
        run = run_problem(problem, "nmpc", params=course.believed, seed=course.noise_seed, show_progress=False,
                          settings=settings)
        firsts.append(run.metrics["stop_times"][:1])
    assert firsts[0] and firsts[0][0] <= 7.5 and (firsts[1] == [] or firsts[0][0] < firsts[1][0]), firsts


def test_a_gentle_or_brisk_first_guess_reaches_the_first_stop_without_a_recovery():
    """Random course 10: the first leg starts at once on a quasi-stable guess, ramping at 2 rad/s^2
    (``ride_accels``) or at up to 8 (the planner's starts).  Ridden briskly, the robot used to end its leg 0.15 m
    short and need a recovery (first stop at 19.25 s), which made the gentle ride the default; that recovery came
    from the tracking starting warm after the refinement took over (``bench_robustness_result.md`` item 20).
    Now both reach the stop without one (measured: 5.52 s gentle, 5.3 s brisk)."""
    from rollbot_oc.scenarios.courses import random_course

    course = random_course(seed=0, index=10)
    problem = replace(course.problem, mission=course.problem.mission.first(1), duration=12.0)
    runs = [run_problem(problem, "nmpc", params=course.believed, seed=course.noise_seed, show_progress=False,
                        settings=NMPCSettings(planner={"ride_accels": accels})).metrics for accels in ((2.0,), (2.0, 4.0, 8.0))]
    for m in runs:
        assert m["completed"] and m["brakes"] == 0 and max(m["stop_errors"]) <= 0.07
        assert m["stop_times"][0] <= 7.0  # (19.25 s with the recovery)


def test_the_first_leg_is_refined_also_from_a_fresh_guess():
    """The N-shape's first stop, seed 0: refined from the ridden guess's tail alone, the first leg is a slow
    local optimum (measured: a 4.73 s plan, the stop at 6.25 s); refined also from a fresh quasi-stable guess
    from the same predicted start (``planner.fresh``), ready in time with the guesses' computation charged,
    it is a 3.37 s plan and the stop is reached at 4.9 s."""
    base = load_problem(PROBLEMS / "n_shape.toml")
    problem = replace(base, mission=base.mission.first(1), duration=10.0)
    fresh, tail = [run_problem(problem, "nmpc", show_progress=False, settings=NMPCSettings(planner={"fresh": k})).metrics
                   for k in (1, 0)]
    assert fresh["completed"] and tail["completed"] and fresh["brakes"] == tail["brakes"] == 0
    assert fresh["stop_times"][0] + 1.0 <= tail["stop_times"][0]
    assert fresh["plans"][0]["T"] + 1.0 <= tail["plans"][0]["T"] and fresh["plan_late"] == 0
    # the fresh guesses' computation is charged: at 1.5 s for them the fresh leg is ready after its handover
    # and the tail's leg takes over, as with planner.fresh = 0
    slow = run_problem(problem, "nmpc", show_progress=False,
                       settings=NMPCSettings(planner={"fresh": 1}, timing={"plan_guess": 1.5})).metrics
    assert slow["plans"][0]["T"] == tail["plans"][0]["T"] and slow["stop_times"] == tail["stop_times"]


def test_the_filtered_attitude_ignores_the_quaternion_sign_and_restarts_after_a_gap():
    """The same attitude measured as -q gives the same filter (the model is even in q); after ``lose_track`` the
    prediction starts from the measured attitude again, as a fresh filter's does; gain 1 is the measurement."""
    from rollbot_oc.model.dynamics import rest_state, to_reduced
    from rollbot_oc.simulation.plant import Sensor, simulate

    params = RollbotParams()
    result = simulate(rest_state(params), 0.5, params=params, accel=lambda t: 10.0 * math.sin(8.0 * t))
    sensor = Sensor(angle_noise=math.radians(0.6), seed=2)
    zs = [to_reduced(sensor.measure(0.0, x).state) for x in result.x.T]
    flipped = [z.copy() for z in zs]
    for z in flipped[1::2]:
        z[REDUCED.quaternion] *= -1.0
    a, b = (TiltEstimator(params, 0.01, learn=("M",)) for _ in range(2))
    errors = []  # (filtered, measured) attitude errors, rad
    for k in range(result.command.size):
        a.update(zs[k], float(result.command[k]), zs[k + 1])
        b.update(flipped[k], float(result.command[k]), flipped[k + 1])
        assert abs(float(a.attitude @ b.attitude)) == pytest.approx(1.0, abs=1e-12)
        truth = to_reduced(result.x[:, k + 1])[REDUCED.quaternion]
        errors.append([2 * math.acos(min(1.0, abs(float(q @ truth))))
                       for q in (a.attitude, zs[k + 1][REDUCED.quaternion])])
    assert np.allclose(a.tilt, b.tilt, atol=1e-12) and np.allclose(a.scales, b.scales, atol=1e-12)
    # filtered, the attitude is nearer the truth than the measurement (measured rms 0.12 deg against 0.99 deg)
    rms = np.sqrt(np.mean(np.square(errors[20:]), axis=0))
    assert rms[0] < 0.3 * rms[1]
    a.lose_track()
    fresh = TiltEstimator(params, 0.01, learn=("M",))
    fresh.tilt, fresh.scales, fresh._P = a.tilt.copy(), a.scales.copy(), a._P.copy()
    a.update(zs[10], 1.0, zs[11])
    fresh.update(zs[10], 1.0, zs[11])
    assert np.array_equal(a.tilt, fresh.tilt) and np.array_equal(a.attitude, fresh.attitude)
    measured = TiltEstimator(params, 0.01, attitude_gain=1.0)
    measured.update(zs[0], 0.0, zs[1])
    assert measured.attitude is None  # gain 1: every prediction from the measured attitude


TIMING = ("step_time_min", "step_time_median", "step_time_p95", "step_time_max", "solve_time_min",
          "solve_time_median", "solve_time_p95", "solve_time_max", "wall_time", "plan_time", "plan_solve_time_median",
          "plan_solve_time_max", "solve_time")


def without_timings(value):
    """The record with every measured wall-clock time removed (recursively)."""
    if isinstance(value, dict):
        return {k: without_timings(v) for k, v in value.items() if k not in TIMING}
    if isinstance(value, list):
        return [without_timings(v) for v in value]
    return value


def test_the_same_seed_gives_the_same_json():
    """Late solves are judged by a modelled compute time: two runs agree in everything but the measured timings."""
    from rollbot_oc.core.outputs import to_json

    problem = load_problem(PROBLEMS / "circle_R050.toml").with_duration(8.0)
    runs = [run_problem(problem, "nmpc", seed=3).metrics for _ in range(2)]
    texts = [to_json(without_timings(m)) for m in runs]
    assert texts[0] == texts[1]
    assert runs[0]["solves"] > 0 and all(k in runs[0] for k in TIMING[:-1])


# One closed loop in a fresh interpreter, its metrics as JSON on stdout.
_RUN_SCRIPT = """
import sys
from dataclasses import replace
from pathlib import Path
from rollbot_oc.core.outputs import to_json
from rollbot_oc.scenarios.problem import load_problem, run_problem
problem = load_problem(Path(sys.argv[1]))
problem = replace(problem, mission=problem.mission.first(1), duration=20.0)
print(to_json(run_problem(problem, "nmpc", seed=3).metrics))
"""


def _numpy_openblas() -> bool:
    import platform

    blas = np.show_config(mode="dicts").get("Build Dependencies", {}).get("blas", {})
    return platform.machine().lower() in ("x86_64", "amd64") and "openblas" in str(blas.get("name", "")).lower()


@pytest.mark.skipif(not _numpy_openblas(), reason="needs numpy on OpenBLAS on x86-64 (its kernels chosen by CPU)")
def test_the_same_seed_gives_the_same_json_under_every_blas_kernel():
    """numpy's OpenBLAS picks its kernels by CPU (``OPENBLAS_CORETYPE`` forces one): the first N-shape stop with
    onboard sensing (the estimator, the tilt filter, the planner, the RTI steps) gives the same JSON under the SSE3
    kernels as under this CPU's own. Before ``rollbot_oc.core.reproducible`` its stop error differed at 1e-8 m."""
    import json
    import os
    import subprocess
    import sys

    def run(coretype):
        env = {**os.environ, "OPENBLAS_CORETYPE": coretype}
        out = subprocess.run([sys.executable, "-c", _RUN_SCRIPT, str(PROBLEMS / "n_shape_imu.toml")], env=env,
                             capture_output=True, text=True, check=True, timeout=600).stdout
        return without_timings(json.loads(out))

    old, own = run("Prescott"), run("")
    assert old["completed"] and old["solves"] > 0
    assert old == own


def test_recovers_from_a_spin_and_a_push():
    """A 1 rad/s spin mid-leg and a 0.5 m push before the first stop: the NMPC replans from where the robot is and
    still reaches the stop at rest (without the replanning it never reached it in 120 s).  The first stop alone
    (the run is the two-stop run's until then); ``benchmarks/bench_recovery.py`` runs both stops."""
    from rollbot_oc.simulation.plant import Kick

    base = load_problem(PROBLEMS / "n_shape.toml")
    problem = replace(base, mission=base.mission.first(1), duration=60.0)
    kicks = [Kick(3.0, omega=(0.0, 0.0, 1.0)), Kick(10.0, position=(0.5, 0.0))]
    m = run_problem(problem, "nmpc", kicks=kicks).metrics
    assert m["completed"] and max(m["stop_errors"]) <= 0.07 and m["stop_replans"] >= 1
    assert m["stop_times"][0] > 10.0  # both kicks came before the stop was reached (measured 15.65 s)
    check_plant_limits(m)


def test_a_run_of_failed_solves_on_a_leg_brakes_and_replans_from_rest(monkeypatch):
    """Ten solves in a row fail mid-leg: the motor is ramped to a stop, the robot is brought to rest and
    gets a new leg from there; the stop is still reached at rest."""
    calls = {"n": 0}

    def wrap(step, solve):
        def flaky(mem, z, window):
            calls["n"] += 1
            w, lam_w, lam_g, ok, retried = solve(mem, z, window)
            return (w, lam_w, lam_g, np.zeros(1), retried) if 30 <= calls["n"] < 40 else (w, lam_w, lam_g, ok, retried)
        return flaky

    _with_solve_stage(monkeypatch, wrap)
    base = load_problem(PROBLEMS / "n_shape.toml")
    problem = replace(base, mission=base.mission.first(1), duration=30.0)
    m = run_problem(problem, "nmpc").metrics
    assert m["fallback_brake"] >= 1 and m["fallback_pid"] == 0 and m["brakes"] >= 1
    assert m["completed"] and max(m["stop_errors"]) <= 0.07
    check_plant_limits(m)


def test_a_leg_that_cannot_be_planned_goes_by_a_stepping_stone(monkeypatch):
    """Legs from rest longer than 0.7 m are made to fail: the second leg is planned to a stepping stone
    ``stone_distance`` towards its stop, and from the stone, at rest, to the stop; both stops are reached
    at rest, and the stone is counted, not as a recovery."""
    fastest = RestToRest.fastest
    tried = []

    def short_legs_only(self, start, goal, *args, **kwargs):
        distance = float(np.linalg.norm(np.asarray(goal, float) - np.asarray(start, float)[:2]))
        tried.append(distance)
        if distance > 0.7:
            raise SolveFailed("injected", "Maximum_Iterations_Exceeded", None)
        return fastest(self, start, goal, *args, **kwargs)

    monkeypatch.setattr(RestToRest, "fastest", short_legs_only)
    base = load_problem(PROBLEMS / "n_shape.toml")
    problem = replace(base, mission=base.mission.first(2), duration=60.0)
    m = run_problem(problem, "nmpc").metrics
    stone = NMPCSettings().recovery.stone_distance
    assert any(d > 0.7 for d in tried) and any(abs(d - stone) < 1e-9 for d in tried)
    assert m["stones"] >= 1 and m["brakes"] == 0 and m["plan_failures"] >= 1
    assert m["completed"] and max(m["stop_errors"]) <= 0.07
    check_plant_limits(m)


def test_a_failed_refinement_of_the_first_guess_is_planned_again_further_along(monkeypatch):
    """The first refinement of the first leg's guess is made to fail: the robot goes on on the guess and the
    leg is refined once more from further along it (not followed to the guess's slow end)."""
    solve = RestToRest.solve
    refinements = []

    def first_refinement_fails(self, start, goal, guess=None, *args, **kwargs):
        if guess is not None and guess.status == "guess":  # (the tail and the fresh guesses from one start)
            refinements.append(float(np.asarray(start)[0]))
            if len(set(refinements)) == 1:
                raise SolveFailed("injected", "Maximum_Iterations_Exceeded", None)
        return solve(self, start, goal, guess, *args, **kwargs)

    monkeypatch.setattr(RestToRest, "solve", first_refinement_fails)
    base = load_problem(PROBLEMS / "n_shape.toml")
    problem = replace(base, mission=base.mission.first(1), duration=30.0)
    m = run_problem(problem, "nmpc").metrics
    assert len(set(refinements)) >= 2  # planned again, from elsewhere
    assert m["plan_failures"] >= 1 and m["plans"][0]["status"] == "Solve_Succeeded"
    assert m["completed"] and max(m["stop_errors"]) <= 0.07


def test_the_first_refinement_starts_where_the_robot_will_be_not_where_the_guess_is(monkeypatch):
    """On random course 13 (a robot 10 % off its model) the robot holding to the first leg's guess spins its
    motor at -7.4 rad/s where the guess has -3.0.  The refinement is planned from the state the tracking
    NMPC predicts for its handover: nearer the robot's true state then, in driving speed and position, than
    the guess's state is."""
    from rollbot_oc.scenarios.courses import random_course
    from rollbot_oc.model.dynamics import to_reduced

    launched, launch = [], StopsSupervisor._launch

    def record(self, segment, t_now, t_start, z_start, guess=None, *args):
        if guess is not None:  # a refinement of the guess followed now
            on_guess = self.reference.segments[self.segment][0].state(t_start - self.segment_start)
            launched.append((t_start, np.array(z_start, float), on_guess))
        return launch(self, segment, t_now, t_start, z_start, guess, *args)

    monkeypatch.setattr(StopsSupervisor, "_launch", record)
    course = random_course(seed=0, index=13)
    run = run_problem(course.problem, "nmpc", params=course.believed, seed=course.noise_seed, duration=2.0)
    t_start, planned, on_guess = launched[0]
    true = to_reduced(run.result.x[:, int(round(t_start / run.result.dt))])
    drive, position = REDUCED.theta_dot, REDUCED.position
    assert abs(true[drive] - on_guess[drive]) > 3.0  # the robot is far off the guess's motor speed ...
    assert abs(true[drive] - planned[drive]) < 0.2 * abs(true[drive] - on_guess[drive])  # ... not the plan's
    assert np.linalg.norm(true[position] - planned[position]) < np.linalg.norm(true[position] - on_guess[position])


def test_a_refined_leg_taking_over_is_tracked_from_itself_not_the_warm_start_of_the_guess(monkeypatch):
    """Random course 11: the first leg's refinement takes over from the ridden guess, reversing the motor.
    Warm-started from the solution that tracked the guess (its iterate and multipliers), the RTI steps could
    chatter between the motor's limits and leave the new leg (it once cost a recovery here); the new leg's first
    solve starts from the leg itself (the step's warm start dropped when a plan takes over), and the robot stays
    within 5 cm of it for the second after."""
    from rollbot_oc.scenarios.courses import random_course

    course = random_course(seed=0, index=11)
    problem = replace(course.problem, mission=course.problem.mission.first(1), duration=5.6)
    take = StopsSupervisor._take_pending
    taken = []

    def record(self, k, reason):
        took = take(self, k, reason)
        if took:
            taken.append((self.segment_start, self.reference.segments[self.segment][0],
                          self.c.step.part("warm")[0]))
        return took

    monkeypatch.setattr(StopsSupervisor, "_take_pending", record)
    result = run_problem(problem, "nmpc", params=course.believed, seed=course.noise_seed, show_progress=False)
    start, plan, warm = taken[0]
    assert warm == 0.0  # the next solve starts from the new leg
    t = result.result.t
    after = (t >= start) & (t <= start + 1.0)
    off = [np.linalg.norm(result.result.x[FULL.position, k] - plan.state(t[k] - start)[REDUCED.position])
           for k in np.flatnonzero(after)]
    assert max(off) < 0.05 and result.metrics["brakes"] == 0, (max(off), result.metrics["brakes"])


def test_a_robot_at_rest_away_from_its_stop_is_replanned_after_the_hold_time(monkeypatch):
    """The first leg's guess is aimed 0.3 m short of the stop and its refinements fail: the robot rides the
    guess to its end and comes to rest away from the stop.  It gets a new leg from there ``hold_time`` after
    the guess's end (not before, and not seconds later), and reaches the stop at rest."""
    from rollbot_oc.control.nmpc.supervisors import stops as supervisor

    solve, aim = RestToRest.solve, supervisor.quasi_stable_guess
    base = load_problem(PROBLEMS / "n_shape.toml")
    stop = np.asarray(base.mission.stops[0], float)

    def short_guess(z, goal, *args, **kwargs):
        start = np.asarray(z[REDUCED.position], float)
        towards = np.asarray(goal, float) - start
        return aim(z, goal - 0.3 * towards / np.linalg.norm(towards), *args, **kwargs)

    def refinements_fail(self, start, goal, guess=None, *args, **kwargs):
        moving = np.linalg.norm(np.asarray(start, float)[REDUCED.velocity]) > 0  # (a leg from rest is planned)
        if guess is not None and guess.status == "guess" and moving:
            raise SolveFailed("injected", "Maximum_Iterations_Exceeded", None)
        return solve(self, start, goal, guess, *args, **kwargs)

    brakes, brake = [], StopsSupervisor._brake

    def record(self, z, k, *args, **kwargs):
        plan = self.reference.segments[self.segment][0]
        brakes.append((k * self.c.dt - self.segment_start - plan.T, float(np.linalg.norm(z[REDUCED.position] - stop)),
                       self.kinds[self.segment] is LegKind.GUESS, args[0]))
        return brake(self, z, k, *args, **kwargs)

    monkeypatch.setattr(supervisor, "quasi_stable_guess", short_guess)
    monkeypatch.setattr(RestToRest, "solve", refinements_fail)
    monkeypatch.setattr(StopsSupervisor, "_brake", record)
    problem = replace(base, mission=base.mission.first(1), duration=30.0)
    m = run_problem(problem, "nmpc").metrics
    hold = NMPCSettings().arrival.hold_time
    after, away, provisional, reason = brakes[0]
    assert provisional and away > 0.07  # at the guess's end, outside the tolerance
    assert reason == "at rest outside the stop's tolerance hold_time after the leg's end"
    assert (m["modes"][1]["mode"], m["modes"][1]["reason"]) == ("brake", reason)  # the run's mode timeline says so
    assert hold - 1e-9 <= after <= hold + 0.5  # replanned once the hold time has passed (at rest by then)
    assert m["completed"] and max(m["stop_errors"]) <= 0.07


def test_a_state_no_command_keeps_within_the_limits_gets_a_relaxed_solve():
    """The pendulum swung 60 deg and a torque margin of 1 %: no acceleration within the motor's limit keeps the
    torque that small, so the QP is infeasible; it is solved once more without the path constraints, and the
    status says so."""
    params = RollbotParams()
    settings = NMPCSettings(limits={"torque_margin": 0.01})
    solver = RTISolver(params, settings, settings.weights.legs)
    z0 = np.zeros(10)
    z0[2], z0[3] = math.cos(math.radians(30)), math.sin(math.radians(30))  # 60 deg about the motor axis
    Zr = np.tile(z0[:, None], (1, settings.horizon.N + 1))
    x, _, status, ok, _ = solver.solve(z0, Zr, np.zeros(settings.horizon.N), params.vector())
    assert ok and status.startswith("relaxed (")
    _, U = solver.split(x)
    assert np.all(np.abs(U) <= params.max_accel + 1e-9)
    z0[2], z0[3] = 1.0, 0.0  # hanging: the same solver solves the full problem
    assert solver.solve(z0, Zr * 0 + z0[:, None], np.zeros(settings.horizon.N), params.vector())[2] == "success"


def test_one_constraint_reaches_every_problem_of_the_nmpc():
    """``NMPCSettings.constraints``: one line, and the legs the NMPC plans and its tracking problem keep it."""
    from rollbot_oc.control.nmpc.supervisors.stops import _rest_to_rest
    from rollbot_oc.control.nmpc.tracking import RTISolver
    from rollbot_oc.model.dynamics import rest_state, to_reduced
    from rollbot_oc.planning.rollbot import position_box

    lower, upper = np.array([-0.35, -0.35]), np.array([1.25, 1.25])
    # the tracking problem on CasADi's virtual machine: this test reads its bounds and one relaxed solve, and
    # compiling its stages would take longer than the rest of the test
    settings = NMPCSettings(limits={"constraints": (lambda ocp: position_box(ocp, lower, upper),)},
                            horizon={"compiled": False})
    params = RollbotParams()
    legs = _rest_to_rest(params, settings.planner.legs, settings.limits.constraints)
    start = rest_state(params, position=(-0.3, -0.3))
    free = _rest_to_rest(params, settings.planner.legs, ()).fastest(start, [0.0, 0.0], 2)
    fenced = legs.fastest(start, [0.0, 0.0], 2)
    assert (free.z[0:2] < lower[:, None] - 0.05).any()  # the fastest leg swings out of the box ...
    assert (fenced.z[0:2] >= lower[:, None] - 1e-6).all() and (fenced.z[0:2] <= upper[:, None] + 1e-6).all()
    assert fenced.T >= free.T - 1e-6  # ... and keeping in costs time
    tracking = RTISolver(params, settings, settings.weights.legs).route.transcription
    lbw, ubw = tracking.bounds(tracking.parameter_vector(
        {name: np.zeros(sl.stop - sl.start) for name, sl in tracking.layout.parameters.items()}
        | {name: np.zeros(sl.stop - sl.start) for name, sl in tracking.layout.stage_parameters.items()}
        | {"p": params.vector()}))
    positions = tracking.layout.states(np.arange(tracking.layout.size))[0:2].astype(int)  # their places in w
    assert np.allclose(lbw[positions[:, 1:]], lower[:, None]) and np.allclose(ubw[positions[:, 1:]], upper[:, None])
    assert np.all(np.isinf(lbw[positions[:, 0]]))  # node 0 is the measured state: not bounded
    # 5 cm outside the box at rest: no command brings the robot back within the next 0.1 s, so the QP with the box
    # has no solution; the measured state (node 0) is not bounded, and the QP is solved once more without the box
    solver = RTISolver(params, settings, settings.weights.legs)
    z0 = to_reduced(rest_state(params, position=(-0.40, -0.30)))
    _, _, status, ok, _ = solver.solve(z0, np.tile(z0[:, None], (1, settings.horizon.N + 1)), np.zeros(settings.horizon.N),
                                       params.vector())
    assert ok and status.startswith("relaxed ("), status


def test_the_tightest_of_two_bounds_of_one_entry_holds():
    """Two simple bounds of the same state: the tighter one, whichever comes first."""
    from rollbot_oc.ocp import bounded
    from rollbot_oc.planning.rollbot import driving_speed, rollbot_ocp

    for order in (1, -1):
        ocp = rollbot_ocp(N=3, T=1.0)
        ocp.subject_to(*[driving_speed(ocp, 0.5), bounded(-8.0, ocp.state.theta_dot, 8.0, "loose")][::order])
        tr = ocp.solver("ipopt").transcription
        lbw, ubw = tr.bounds(tr.parameter_vector({"p": RollbotParams().vector()}))
        speeds = tr.layout.states(np.arange(tr.layout.size))[9].astype(int)
        assert np.allclose(ubw[speeds], 0.5 * RollbotParams().max_speed)
        assert np.allclose(lbw[speeds], -0.5 * RollbotParams().max_speed)


def test_settings_presets_by_name():
    """``NMPCSettings.preset`` and ``preset_name`` are inverse on every preset (export-c writes the name into
    step.json and run --controller c reads it back); other settings have no name, an unknown name is refused."""
    from rollbot_oc.control.nmpc.settings import PRESETS
    from rollbot_oc.core.errors import ConfigError

    assert [NMPCSettings.preset(name).preset_name() for name in PRESETS] == list(PRESETS)
    assert NMPCSettings.preset("embedded") == NMPCSettings.embedded() != NMPCSettings.preset("nmpc")
    assert NMPCSettings(horizon={"N": 30}).preset_name() is None
    with pytest.raises(ConfigError, match="valid are nmpc, embedded"):
        NMPCSettings.preset("fast")
