"""Offline trajectory optimisation: constraints hold, plans are feasible in the plant, guesses are physical."""


from dataclasses import replace

import numpy as np
import pytest

from rollbot_oc.planning.min_time import (
    OCPSettings, OrbitEntry, RestToRest, SolveFailed, orbit_state, plan_waypoints, quasi_stable_guess,
)
from rollbot_oc.model.dynamics import RollbotModel, from_reduced, reduced_model, rest_state, to_reduced
from rollbot_oc.model.params import RollbotParams
from rollbot_oc.simulation.plant import simulate

PARAMS = RollbotParams()


@pytest.fixture(scope="module")
def leg():
    ocp = RestToRest(PARAMS)
    start = rest_state(PARAMS, position=(0.0, 0.0))
    return ocp, start, ocp.solve(start, [0.0, 1.2])


def test_minimum_time_leg_ends_at_rest_on_the_goal(leg):
    ocp, start, plan = leg
    s = ocp.settings
    assert plan.success and plan.status in ("Solve_Succeeded", "Solved_To_Acceptable_Level")
    assert 2.0 < plan.T < 10.0  # the PID needs about 45 s per leg
    end = plan.z[:, -1]
    assert np.abs(end[0:2] - [0.0, 1.2]).max() <= s.goal_tolerance + 1e-6
    assert np.abs(end[6:10]).max() < 1e-6  # shell and motor still
    # pendulum straight down: a rest state of the full model
    assert np.abs(RollbotModel(PARAMS).xdot(from_reduced(end))).max() < 1e-5


def test_constraints_hold_at_every_node(leg):
    ocp, _, plan = leg
    s, red, p = ocp.settings, reduced_model(), PARAMS.vector()
    z, u = plan.z[:, :-1], plan.u
    torque = np.array(red.motor_torque(z, u[None, :], p, np.zeros(6))).ravel()
    margins = np.array(red.margins(z, u[None, :], p, np.zeros(6)))
    assert np.abs(torque).max() <= s.torque_margin * PARAMS.max_torque * (1 + 1e-6)
    assert np.abs(plan.driving_speed).max() <= s.speed_margin * PARAMS.max_speed * (1 + 1e-6)  # IPOPT tolerance
    assert np.abs(u).max() <= PARAMS.max_accel * (1 + 1e-6)
    assert margins[0].min() >= s.normal_margin * PARAMS.total_mass * PARAMS.g * (1 - 1e-6)
    reaction = np.array(red.reaction(z, u[None, :], p, np.zeros(6)))
    assert np.all(np.hypot(reaction[0], reaction[1]) <= s.friction_margin * PARAMS.mu * reaction[2] * (1 + 1e-6))


def test_the_plan_is_locally_time_optimal(leg):
    """Asked to do the same in 80 % of the time, from the optimum as the guess, the solver must fail."""
    ocp, start, plan = leg
    with pytest.raises(SolveFailed):
        RestToRest(PARAMS, OCPSettings(max_iter=150)).solve(start, [0.0, 1.2], guess=plan, duration=0.8 * plan.T)


def test_plan_flies_in_the_plant(leg):
    """The planned accelerations, replayed open loop in the full plant (RK4, contact and motor model), end on the goal.

    The plant's period divides the plan's interval, so the switching instants of the piecewise-constant plan are
    kept (measured: 7 mm; quantised to the 10 ms control grid the same bang-bang plan misses by 4 to 8 cm,
    which the NMPC's feedback is there to absorb).
    """
    _, start, plan = leg
    N = plan.u.size
    run = simulate(start, plan.T, dt=plan.T / N / 10, accel=lambda t: plan.u[min(int(t / (plan.T / N) + 1e-6), N - 1)])
    assert run.completed
    assert np.linalg.norm(run.position[:, -1] - [0.0, 1.2]) < 0.01
    assert np.abs(run.motor_torque).max() <= PARAMS.max_torque


def test_initial_guess_comes_from_the_quasi_stable_theory():
    guess = quasi_stable_guess(to_reduced(rest_state(PARAMS)), np.array([0.0, 1.2]), PARAMS, 60)
    assert np.abs(guess.z[9]).max() > 1.0  # the motor turns: not a guess of zeros
    assert guess.extra["miss"] < 0.5  # its simulated end lands near the goal


def test_quasi_stable_guesses_ramp_at_the_rates_asked():
    """The guesses' speed profiles ramp at ``accels`` (rad/s^2): the NMPC rides a gentle one (``ride_accels``)."""
    z0, goal = to_reduced(rest_state(PARAMS)), np.array([0.0, 1.2])
    gentle = quasi_stable_guess(z0, goal, PARAMS, 60, accels=(2.0,))
    assert np.abs(gentle.u).max() <= 2.0 + 1e-9 and np.abs(gentle.z[9]).max() > 1.0
    assert np.abs(quasi_stable_guess(z0, goal, PARAMS, 60).u).max() > 2.0 + 1e-9  # the default also ramps faster


def test_the_last_start_can_be_the_quickest_guess_near_the_best():
    """``quick``: the last of the starts is the shortest simulated profile whose score is within ``quick`` of
    the best's (the others stay the best by score); without it, or for one start, the ranking is unchanged."""
    from rollbot_oc.planning.min_time import quasi_stable_guesses

    z0, goal = to_reduced(rest_state(PARAMS, heading=2.0)), np.array([0.0, 1.2])
    ranked = quasi_stable_guesses(z0, goal, PARAMS, 40, 6)  # all six simulated, best score first
    scores = [g.extra["miss"] for g in ranked]
    assert scores == sorted(scores)
    for quick in (0.0, 0.25, 10.0):
        starts = quasi_stable_guesses(z0, goal, PARAMS, 40, 3, quick=quick)
        near = [g.T for g in ranked[2:] if g.extra["miss"] <= scores[0] + quick]
        assert [g.T for g in starts[:2]] == [g.T for g in ranked[:2]]
        assert starts[2].T == (min(near) if near else ranked[2].T)
    assert quasi_stable_guesses(z0, goal, PARAMS, 40, 3, quick=10.0)[2].T == min(g.T for g in ranked[2:])
    assert quasi_stable_guesses(z0, goal, PARAMS, 40, 1, quick=10.0)[0].T == ranked[0].T


def test_waypoint_chain_and_fixed_time_variant():
    ocp = RestToRest(PARAMS)
    start = rest_state(PARAMS, position=(-0.3, -0.3))
    plans = plan_waypoints(start, [[0.0, 0.0], [0.6, 0.3]], ocp=ocp, starts=1)
    assert len(plans) == 2 and np.allclose(plans[1].z[0:2, 0], plans[0].z[0:2, -1])
    slower = ocp.solve(start, [0.0, 0.0], duration=plans[0].T * 1.3)
    assert slower.T == pytest.approx(plans[0].T * 1.3)
    assert np.sum(slower.u**2) < np.sum(plans[0].u**2)  # more time, less effort


@pytest.fixture(scope="module")
def nmpc_leg():
    """The NMPC's legs' settings, a start and a goal, and the fastest of two starts between them (uncapped)."""
    settings = OCPSettings(N=40, accel_margin=0.85, expand=True)  # the NMPC's legs
    start, goal = rest_state(PARAMS, position=(-0.3, -0.3)), [0.0, 0.0]
    return settings, start, goal, RestToRest(PARAMS, settings).fastest(start, goal, starts=2)


def test_the_fastest_of_several_starts_is_no_slower_than_the_first(nmpc_leg):
    """``fastest`` keeps the quickest local optimum; its first start is the single-start guess."""
    settings, start, goal, best = nmpc_leg
    assert goal == [0.0, 0.0]
    single = RestToRest(PARAMS, settings).solve(start, [0.0, 0.0])
    assert best.success and best.T <= single.T + 1e-6
    assert best.iterations >= single.iterations  # the total over the starts


def test_failed_starts_resumed_from_where_they_stopped_reach_the_same_plan(nmpc_leg):
    """``fastest(resumes=...)``: starts cut off by the iteration limit are solved again from their last
    iterates; the first to converge is the leg the uncapped solver finds, and its iterations count them all.
    Without resumes the same starts fail."""
    settings, start, goal, uncapped = nmpc_leg  # the NMPC's legs
    capped = RestToRest(PARAMS, replace(settings, max_iter=30))
    with pytest.raises(SolveFailed, match="Maximum_Iterations_Exceeded"):
        capped.fastest(start, goal, starts=2)
    resumed = capped.fastest(start, goal, starts=2, resumes=2)
    assert resumed.success and resumed.T == pytest.approx(uncapped.T, abs=1e-4)
    assert np.abs(resumed.z[0:2, -1] - goal).max() <= settings.goal_tolerance + 1e-6
    assert 2 * 30 < resumed.iterations <= 4 * 30  # both failed starts, and the resumed ones
    # the chain of legs (the minimum-time bound's) resumes its legs the same way
    chained, = plan_waypoints(start, [goal], ocp=capped, starts=2, resumes=2)
    assert chained.T == pytest.approx(resumed.T, abs=1e-9)
    with pytest.raises(SolveFailed, match="Maximum_Iterations_Exceeded"):
        plan_waypoints(start, [goal], ocp=capped, starts=2)
    with pytest.raises(ValueError, match="resumes"):
        capped.fastest(start, goal, starts=2, resumes=-1)


def test_a_gentler_plan_keeps_to_its_scaled_motor_limits_and_takes_longer(leg):
    """``motor_scale`` scales the driving-speed and acceleration limits of one solve (the NMPC's caution after a
    recovery): the plan stays within them, and a slower motor cannot be faster."""
    ocp, start, plan = leg
    gentle = ocp.solve(start, [0.0, 1.2], motor_scale=0.7)  # from the quasi-stable guess, as the NMPC does
    s = ocp.settings
    assert gentle.success and gentle.T > plan.T
    assert np.abs(gentle.u).max() <= 0.7 * s.accel_margin * PARAMS.max_accel + 1e-6
    assert np.abs(gentle.z[9]).max() <= 0.7 * s.speed_margin * PARAMS.max_speed + 1e-6
    assert np.abs(plan.u).max() > 0.7 * s.accel_margin * PARAMS.max_accel  # the full plan uses more
    with pytest.raises(ValueError, match="motor_scale"):
        ocp.solve(start, [0.0, 1.2], guess=plan, motor_scale=1.5)


def test_a_balanced_state_stays_at_rest_on_a_slope():
    """``imbalance`` = 0 is a static equilibrium of the full model on a 3 deg slope: released there with
    the motor still, the robot stays put, while the level floor's rest state (pendulum straight down)
    rolls away.  Independent of any OCP: the balanced attitude is found by a root-finder."""
    import casadi as ca

    from rollbot_oc.model.dynamics import imbalance
    from rollbot_oc.model.rotations import quat_multiply

    slope = PARAMS.replace(slope=np.radians(3.0), slope_dir=np.radians(30.0))
    level_rest = to_reduced(rest_state(slope, heading=0.4))
    q = level_rest[2:6]
    tilt = ca.SX.sym("tilt", 2)  # small turns of the whole robot about the floor's x and y axes

    turn_x = ca.vertcat(ca.cos(tilt[0] / 2), ca.sin(tilt[0] / 2), 0, 0)
    turn_y = ca.vertcat(ca.cos(tilt[1] / 2), 0, ca.sin(tilt[1] / 2), 0)
    turned = quat_multiply(turn_y, quat_multiply(turn_x, ca.DM(q)))
    solve = ca.rootfinder("balance", "newton", ca.Function("r", [tilt], [imbalance(turned, slope.vector())]))
    angles = np.array(solve(np.zeros(2))).ravel()
    assert 0 < np.abs(angles).max() < 0.5
    balanced = level_rest.copy()
    balanced[2:6] = np.array(ca.Function("q", [tilt], [turned])(angles)).ravel()

    def drift(z):
        run = simulate(from_reduced(z), 2.0, params=slope, speed=lambda t: 0.0, stop_on_event=False)
        return float(np.linalg.norm(run.position[:, -1] - run.position[:, 0]))

    assert drift(balanced) < 1e-4  # m in 2 s
    assert drift(level_rest) > 100 * max(drift(balanced), 1e-6)


def test_orbit_entry_reaches_the_quasi_stable_orbit():
    entry = OrbitEntry(0.65, PARAMS, OCPSettings(N=50))
    start = rest_state(PARAMS, position=(0.65, 0.0))
    plan = entry.solve(start, [0.0, 0.0], duration=5.0)
    target = np.array(orbit_state(entry.qs_reduced, np.zeros(2), plan.extra["phase"])).ravel()
    end = plan.z[:, -1]
    assert np.abs(end[[0, 1, 6, 7, 8, 9]] - target[[0, 1, 6, 7, 8, 9]]).max() < 1e-5
    assert min(np.abs(end[2:6] - target[2:6]).max(), np.abs(end[2:6] + target[2:6]).max()) < 1e-5
    assert np.hypot(*end[0:2]) == pytest.approx(entry.quasi.R0, abs=1e-6)


def test_an_impossible_plan_is_reported_with_its_status():
    ocp = RestToRest(PARAMS, OCPSettings(N=20, T_max=1.0, max_iter=30))
    with pytest.raises(SolveFailed) as info:
        ocp.solve(rest_state(PARAMS), [3.0, 0.0])  # 3 m in at most 1 s
    assert info.value.status != "Solve_Succeeded" and info.value.plan is not None


def test_bad_start_state():
    with pytest.raises(ValueError, match="expected 11"):
        RestToRest(PARAMS, OCPSettings(N=10)).solve(np.zeros(4), [1.0, 0.0])
