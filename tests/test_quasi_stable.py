"""Quasi-stable states: the paper's anchors, the full equations, the simulator and the inverse map."""

import math

import numpy as np
import pytest

from rollbot_oc.model.dynamics import RollbotModel
from rollbot_oc.core.errors import ConfigError, NumericalFailure
from rollbot_oc.analysis.experiments import open_loop_run
from rollbot_oc.analysis import quasi_stable
from rollbot_oc.model.params import RollbotParams
from rollbot_oc.analysis.quasi_stable import FULL_RESIDUAL_TOL, RadiusMap, quasi_stable_curve, quasi_stable_state

OMEGAS = np.linspace(0.0, 3 * np.pi, 200)


@pytest.fixture(scope="module")
def slow():
    return quasi_stable_curve(OMEGAS)


def test_paper_anchors_on_the_slow_branch(slow):
    params = RollbotParams()
    assert all(s.converged and s.branch == "slow" for s in slow)
    assert slow[0].R0 == pytest.approx(params.R * math.tan(params.phi), abs=1e-3)  # 0.120 m
    assert slow[0].xi == pytest.approx(params.phi, abs=1e-12)
    assert slow[-1].R0 == pytest.approx(1.28, rel=0.02)  # paper: 0.12 m to 1.28 m over [0, 3 pi]
    xi = np.array([s.xi for s in slow])
    assert np.all(np.diff(xi) > 0) and xi[-1] < math.pi / 2 and xi[-1] > math.radians(75)  # rises toward 90 deg
    assert max(abs(s.theta0) for s in slow) < math.radians(20)  # pendulum stays near the bottom
    assert np.all(np.diff([s.R0 for s in slow]) > 0)


def test_every_state_is_a_relative_equilibrium_of_the_full_equations(slow):
    assert max(s.full_residual for s in slow) <= FULL_RESIDUAL_TOL
    # ...and the check can fail: a slightly wrong tilt is not an equilibrium
    state = slow[100]
    model = RollbotModel()
    x = state.state()
    x_wrong = state.state()
    assert np.linalg.norm(model.xdot(x)[6:9] - np.cross([0, 0, state.Omega], x[6:9])) < 1e-9
    wrong = quasi_stable_state(state.omega0 * 1.01)
    x_wrong[6:9] = wrong.state()[6:9]
    assert np.linalg.norm(model.xdot(x_wrong)[6:9] - np.cross([0, 0, state.Omega], x_wrong[6:9])) > 1e-3


def test_quasi_state_is_consistent_kinematics(slow):
    s = slow[120]
    x = s.state(centre=(0.3, -0.2), phase=1.0)
    assert s.R0 == pytest.approx(s.omega0 * 0.12 * math.sin(s.xi) / s.Omega, rel=1e-12)
    # the robot sits at centre + R0 (cos phase, sin phase) and moves tangentially at the quasi-stable speed
    assert np.allclose(x[:2], [0.3 + s.R0 * math.cos(1.0), -0.2 + s.R0 * math.sin(1.0)], atol=1e-12)
    v = np.cross(x[6:9], [0, 0, 0.12])[:2]
    assert np.linalg.norm(v) == pytest.approx(s.speed, rel=1e-12)
    assert abs(v @ [math.cos(1.0), math.sin(1.0)]) < 1e-12
    assert s.normal_force == pytest.approx(RollbotParams().total_mass * 9.81, rel=1e-12)
    assert s.slide_margin > 0 and s.motor_torque > 0  # the motor feeds the damping


def test_fast_branch_revolves_the_other_way_on_a_small_circle(slow):
    fast = quasi_stable_curve(OMEGAS, branch="fast")
    assert all(s.converged and s.branch == "fast" for s in fast)
    assert all(abs(s.theta0 - math.pi) < math.radians(5) for s in fast)
    assert all(s.Omega < 0 for s in fast[1:])
    assert abs(fast[-1].R0) < 0.1 * slow[-1].R0
    assert max(s.full_residual for s in fast) <= FULL_RESIDUAL_TOL


@pytest.mark.parametrize("omega0", [1.0, 3.0, 6.0])
def test_open_loop_simulation_settles_on_the_quasi_stable_circle(omega0):
    measured, _ = open_loop_run(omega0)
    theory = quasi_stable_state(omega0)
    assert measured.settled
    assert measured.R0 == pytest.approx(theory.R0, rel=0.02)
    assert measured.Omega == pytest.approx(theory.Omega, rel=0.02)
    assert measured.xi == pytest.approx(theory.xi, abs=math.radians(0.5))


def test_radius_map_inverse_and_slope():
    radius_map = RadiusMap()
    for R in (0.2, 0.35, 0.5, 0.65, 1.2):
        w = radius_map.omega(R)
        assert radius_map.radius(w) == pytest.approx(R, abs=1e-9)
        R_exact, slope_exact = radius_map.exact(w)
        assert R_exact == pytest.approx(R, abs=1e-7)
        assert radius_map.slope(w) == pytest.approx(slope_exact, rel=1e-5)
        # AD through Newton against a finite-difference spot check of the direct solve
        h = 1e-4
        fd = (radius_map.exact(w + h)[0] - radius_map.exact(w - h)[0]) / (2 * h)
        assert slope_exact == pytest.approx(fd, rel=1e-6)
    assert radius_map.R_min == pytest.approx(0.12, abs=1e-12)
    assert np.allclose(radius_map.omega(np.array([0.2, 0.5])), [radius_map.omega(0.2), radius_map.omega(0.5)])


@pytest.mark.parametrize("params", [
    RollbotParams(phi=math.radians(30)), RollbotParams(m=0.5, r0=0.08), RollbotParams(R=0.15, I=0.009),
    RollbotParams(k0=0.02),
])
def test_other_robots_have_consistent_states(params):
    states = quasi_stable_curve(np.linspace(0.0, 3 * np.pi, 40), params)
    good = [s for s in states if s.converged]
    assert len(good) >= 10
    assert good[0].R0 == pytest.approx(params.R * math.tan(params.phi), rel=1e-9)
    assert max(s.full_residual for s in good) <= FULL_RESIDUAL_TOL


def test_a_branch_that_ends_is_reported_not_invented():
    heavy_damping = RollbotParams(k0=2.0 * 0.88 * 0.12**2)  # 5x the prototype's: the pendulum is lifted
    states = quasi_stable_curve([2.0, 6.0, 9.0], heavy_damping)
    assert states[0].converged and states[1].converged
    assert not states[2].converged and states[2].residual > 1e-9  # the branch folds near 8.2 rad/s
    with pytest.raises((ConfigError, NumericalFailure), match="R0 stops|could not be followed"):
        RadiusMap(heavy_damping)  # a fold is a numerical end of the branch (or, past it, a property of the robot)


@pytest.mark.parametrize("call, match", [
    (lambda: quasi_stable_state(-1.0), "omega0 = -1.0"),
    (lambda: quasi_stable_state(12.0), r"valid is \[0, max_speed\]"),
    (lambda: quasi_stable_state(float("nan")), "out of range"),
    (lambda: quasi_stable_state(1.0, branch="medium"), "branch"),
    (lambda: quasi_stable_state(1.0, RollbotParams(k0=0.0)), "k0"),
    (lambda: RadiusMap().omega(2.0), "radius = 2.0 m is out of range"),
])
def test_bad_requests_are_clear_errors(call, match):
    with pytest.raises(ValueError, match=match):
        call()


def test_damping_hardly_moves_the_quasi_stable_states():
    """Paper: 'as long as k0 is not excessively large, it has little impact on the results'."""
    base = RollbotParams()
    speeds = [1.0, 3.0, 3 * np.pi]
    nominal = [s.R0 for s in quasi_stable_curve(speeds, base)]
    for factor in (0.5, 2.0):
        changed = [s.R0 for s in quasi_stable_curve(speeds, base.replace(k0=factor * base.k0))]
        assert np.allclose(changed, nominal, rtol=0.02)  # measured: at most 1 % for half or twice the damping
    heavy = [s.R0 for s in quasi_stable_curve(speeds, base.replace(k0=4.0 * base.k0))]
    assert not np.allclose(heavy, nominal, rtol=0.01)  # ... and the check can tell a difference


def _count_continuations(monkeypatch):
    calls = []
    original = quasi_stable._continue

    def counting(z, w_from, w_to, params, **kwargs):
        calls.append(w_to)
        return original(z, w_from, w_to, params, **kwargs)

    monkeypatch.setattr(quasi_stable, "_continue", counting)
    return calls


def test_the_batched_route_needs_no_continuation_on_a_regular_branch(monkeypatch):
    calls = _count_continuations(monkeypatch)
    for branch in ("slow", "fast"):
        assert all(s.converged for s in quasi_stable_curve(OMEGAS, branch=branch))
    RadiusMap()
    assert calls == []
    folding = quasi_stable_curve(OMEGAS, RollbotParams(k0=0.02534))  # the fold near 8.2 rad/s
    assert calls and min(calls) > 7.5  # only the last stretch before the fold and the speeds beyond it
    assert {s.omega0 for s in folding if not s.converged} <= set(calls)


def test_a_point_that_leaves_its_predictor_is_solved_by_continuation(monkeypatch):
    """A predictor far off (as if Newton had jumped) is caught, and continuation gives the same state."""
    reference = quasi_stable_curve(OMEGAS)
    original = quasi_stable._coarse

    def bad_predictor(w_max, z_start, p):
        w_trusted, spline = original(w_max, z_start, p)
        return w_trusted, lambda w: spline(w) + np.where(np.isclose(w, OMEGAS[150]), 0.05, 0.0)[:, None]

    monkeypatch.setattr(quasi_stable, "_coarse", bad_predictor)
    calls = _count_continuations(monkeypatch)
    again = quasi_stable_curve(OMEGAS)
    assert calls == [OMEGAS[150]]
    assert all(s.converged for s in again)
    assert max(abs(a.xi - b.xi) + abs(a.kappa - b.kappa) for a, b in zip(again, reference)) < 1e-10
