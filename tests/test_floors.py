"""Floors the shell can slide on: the contact model against the no-slip model, textbook cases and energy.

Analytic cases use the prototype's shell (R, M, I) with a passive pendulum of
negligible mass (1e-10 kg) and no bead damping (k0 = 0), so the robot is a
ball of inertia I: a ball launched sliding stops sliding at
``t = |v_slip0| / (mu g (1 + M R^2 / I))`` with the speed
``(M R^2 v0 + I R omega0) / (M R^2 + I)`` (angular momentum about the
contact point is kept); rolling against a resistance torque ``c_rr N`` it
decelerates at ``c_rr g / (R (1 + I / (M R^2)))``; against floor damping
``c_d`` its rolling rate decays as ``exp(-c_d t / (I + M R^2))``.
"""

import warnings

import numpy as np
import pytest

from rollbot_oc.model.contact import NXC, SLIDE, STICK, contact_model
from rollbot_oc.model.dynamics import NW, NX, OMEGA, POS, QUAT, THETA_DOT, rest_state, symbolic_model
from rollbot_oc.core.errors import ConfigError
from rollbot_oc.simulation.floor import Floor, FloorPatch, RollbotDeprecationWarning
from rollbot_oc.model.params import RollbotParams
from rollbot_oc.scenarios.problem import compute_metrics, problem_from_dict
from rollbot_oc.scenarios.bundled import bundled_table
from rollbot_oc.simulation.floor_plant import simulate

BALL = RollbotParams(m=1e-10, k0=0.0)
COULOMB = Floor("coulomb")


def ball_state(v0, omega0, params=BALL):
    """The ball at the origin: centre velocity (v0, 0) m/s, spin omega0 rad/s about y (rolling along +x)."""
    x = rest_state(params)
    x[OMEGA] = [0.0, omega0, 0.0]
    return np.concatenate([x, [v0, 0.0]])


def random_state(rng):
    x = rng.normal(size=NX)
    x[QUAT] /= np.linalg.norm(x[QUAT])
    x[OMEGA] *= 3.0
    x[THETA_DOT] *= 5.0
    return x


@pytest.mark.parametrize("params", [RollbotParams(), RollbotParams(slope=0.05, slope_dir=0.7, phi=0.3, m=0.8)])
def test_stick_mode_is_the_no_slip_model(params):
    """Newton-Euler with the ground force unknown and the rolling constraint = the paper's closed form."""
    sym, contact = symbolic_model(), contact_model()
    rng = np.random.default_rng(5)
    fl = [params.mu, 0.0, 0.0]
    for _ in range(10):
        x, u, w = random_state(rng), rng.normal() * 5, rng.normal(size=NW)
        X = np.concatenate([x, [x[7] * params.R, -x[6] * params.R]])
        p = params.vector()
        xdot = np.array(sym.plant_rhs(x, u, p, w)).ravel()
        Xdot = np.array(contact.rhs[STICK](X, u, p, w, fl, [1, 0])).ravel()
        assert np.allclose(Xdot[:NX], xdot, rtol=1e-10, atol=1e-10 * np.abs(xdot).max())
        assert np.allclose(Xdot[NX:], [Xdot[7] * params.R, -Xdot[6] * params.R], rtol=1e-10, atol=1e-12)
        u_applied, tau, N, margins, slip = (np.array(v).ravel() for v in contact.diag[STICK](X, u, p, w, fl, [1, 0]))
        assert np.allclose(N, np.array(sym.reaction(x, u_applied, p, w)).ravel(), rtol=1e-10, atol=1e-10)
        assert tau == pytest.approx(float(sym.motor_torque(x, u_applied, p, w)), rel=1e-9, abs=1e-12)
        assert np.allclose(margins, np.array(sym.margins(x, u_applied, p, w)).ravel(), rtol=1e-9, atol=1e-10)
        assert np.allclose(slip, 0.0, atol=1e-15)
        assert float(contact.energy(X, p)) == pytest.approx(float(sym.energy(x, p)), rel=1e-13)


@pytest.mark.parametrize("v0, omega0", [(0.5, 0.0), (0.0, 8.0), (0.3, -4.0)],
                         ids=["launched-sliding", "launched-spinning", "backspin"])
def test_sliding_ball_sticks_at_the_textbook_time_and_speed(v0, omega0):
    M, I, R, g, mu = BALL.M, BALL.I, BALL.R, BALL.g, BALL.mu
    slip0 = v0 - omega0 * R
    t_end = abs(slip0) / (mu * g * (1 + M * R**2 / I))
    v_end = (M * R**2 * v0 + I * R * omega0) / (M * R**2 + I)
    result = simulate(ball_state(v0, omega0), 0.2, params=BALL, floor=COULOMB, accel=0.0)
    contact = result.contact
    assert [kind for _, kind in contact.transitions] == ["stick"]
    assert contact.transitions[0][0] == pytest.approx(t_end, rel=1e-8)
    assert contact.time_sliding == pytest.approx(t_end, rel=1e-8)
    assert contact.centre_velocity[0, -1] == pytest.approx(v_end, rel=1e-8)
    assert contact.max_slip_speed <= abs(slip0) and contact.mode[0] == SLIDE and contact.mode[-1] == STICK
    assert np.abs(contact.slip[:, -1]).max() <= 1e-12
    # rolling on without resistance after the slip ended: constant speed
    assert result.x[POS][0, -1] - result.x[POS][0, -6] == pytest.approx(5 * result.dt * v_end, rel=1e-9)


@pytest.mark.parametrize("mu, v0, omega0", [(0.1, 0.8, 0.0), (0.15, 0.6, 8.0)])
def test_energy_balance_of_the_robot_sliding(mu, v0, omega0):
    """E(t) - E(0) = integral of damping, friction, rolling-resistance and floor-damping power.

    The whole robot (pendulum included, motor locked) launched sliding across its motor axis: the
    pendulum rocks in the plane of the motion, the slip stays on one line, ends, and the robot rolls on.
    """
    params = RollbotParams(mu=mu)
    floor = Floor("coulomb", rolling_resistance=0.002, damping=0.004)
    x0 = rest_state(params)
    x0[OMEGA] = [omega0, 0.0, 0.0]
    dt = 0.004
    result = simulate(np.concatenate([x0, [0.0, v0]]), 2.0, params=params, floor=floor, dt=dt, accel=0.0)
    contact = result.contact
    assert [kind for _, kind in contact.transitions] == ["stick"] and contact.time_sliding > 0.2
    model = contact_model()
    X = np.vstack([result.x, contact.centre_velocity])
    p, w, fl = params.vector(), np.zeros(NW), [params.mu, floor.rolling_resistance, floor.damping]

    def power(k, u):
        return np.array(model.power[contact.mode[k]](X[:, k], u, p, w, fl, [1, 0])).ravel()

    u = result.applied_accel
    steps = result.t.size - 1
    start = np.array([power(k, u[k]) for k in range(steps)])
    end = np.array([power(k + 1, u[k]) for k in range(steps)])
    parts = 0.5 * (start + end) * dt  # trapezoid over each period
    work = np.concatenate([[0.0], np.cumsum(parts.sum(axis=1))])
    E = np.array([float(model.energy(X[:, k], p)) for k in range(steps + 1)])
    losses = np.abs(parts[:, 1:]).sum()
    friction, resistance, damping = (-parts[:, i].sum() for i in (3, 4, 5))
    assert friction > 0.2 and resistance > 0.02 and damping > 0.005  # every loss is real
    assert abs(sum(loss for _, loss in contact.stick_losses)) <= 1e-9 * friction  # a straight slip ends cleanly
    assert np.abs((E - E[0]) - work).max() <= 2e-4 * losses


def test_large_friction_agrees_with_the_no_slip_plant():
    """With mu = 10 the contact never slides: the Coulomb plant is the no-slip plant (same RK4 steps)."""
    params = RollbotParams(mu=10.0)
    x0 = rest_state(params, heading=0.4)
    speed = lambda t: 5.0 * np.sin(1.3 * t) + 2.0  # noqa: E731
    rigid = simulate(x0, 4.0, params=params, speed=speed, substeps=8)
    coulomb = simulate(x0, 4.0, params=params, speed=speed, substeps=8, floor=COULOMB)
    assert coulomb.contact.transitions == [] and coulomb.contact.time_sliding == 0.0
    assert np.abs(coulomb.x - rigid.x).max() <= 1e-10
    assert np.abs(coulomb.diag - rigid.diag).max() <= 1e-8
    assert np.ptp(rigid.x[POS][0]) > 0.05  # it moved


def test_large_friction_agrees_closed_loop():
    """The PID on the N-shape for 3 s: the same run on the rigid floor and on a floor of mu = 10."""
    problem = problem_from_dict(bundled_table("n_shape"), "n_shape")
    from rollbot_oc.scenarios.problem import run_problem

    rigid = run_problem(problem.__class__(**{**problem.__dict__, "params": problem.params.replace(mu=10.0)}),
                        "pid", duration=3.0, show_progress=False)
    table = bundled_table("n_shape")
    table["floor"]["mu"] = 10.0
    slippery = problem_from_dict(table, "n_shape mu 10")
    assert not slippery.floor.rigid
    coulomb = run_problem(slippery, "pid", duration=3.0, show_progress=False)
    # the rigid run's RK4 step is dt/2, the contact plant's dt/8: agreement to the integrators' error
    assert np.abs(coulomb.result.x - rigid.result.x).max() <= 1e-6
    assert coulomb.metrics["time_sliding"] == 0.0 and "time_sliding" not in rigid.metrics


def test_rolling_resistance_decelerates_at_the_analytic_rate():
    c_rr = 0.004
    floor = Floor("coulomb", rolling_resistance=c_rr)
    M, I, R, g = BALL.M, BALL.I, BALL.R, BALL.g
    v0 = 0.5
    result = simulate(ball_state(v0, v0 / R), 1.0, params=BALL, floor=floor, accel=0.0)
    v = result.contact.centre_velocity[0]
    expected = v0 - c_rr * g / (R * (1 + I / (M * R**2))) * result.t
    assert np.abs(v - expected).max() <= 1e-9 * v0
    assert result.contact.transitions == []  # it rolled, never slid


def test_floor_damping_decays_the_rolling_rate_exponentially():
    c_d = 0.01
    floor = Floor("coulomb", damping=c_d)
    M, I, R = BALL.M, BALL.I, BALL.R
    omega0 = 4.0
    result = simulate(ball_state(omega0 * R, omega0), 2.0, params=BALL, floor=floor, accel=0.0)
    expected = omega0 * np.exp(-c_d * result.t / (I + M * R**2))
    assert np.abs(result.x[OMEGA.start + 1] - expected).max() <= 1e-8 * omega0


def test_a_patch_resists_only_where_it_is():
    patch = FloorPatch(((0.2, -1.0), (3.0, -1.0), (3.0, 1.0), (0.2, 1.0)), rolling_resistance=0.004)
    floor = Floor("coulomb", patches=(patch,))
    assert floor.values_at((0.5, 0.0), 0.5).tolist() == [0.5, 0.004, 0.0]
    assert floor.values_at((0.1, 0.0), 0.5).tolist() == [0.5, 0.0, 0.0]
    v0 = 0.5
    result = simulate(ball_state(v0, v0 / BALL.R), 1.0, params=BALL, floor=floor, accel=0.0)
    v, x = result.contact.centre_velocity[0], result.x[POS][0]
    entered = np.flatnonzero(x >= 0.2)[0]
    assert np.abs(v[:entered + 1] - v0).max() <= 1e-9 * v0  # before the patch: no loss (the 1e-10 kg pendulum)
    assert v[-1] < v0 - 0.05  # on it: slowed down
    assert result.contact.floor_values[1, entered - 1] == 0.0 and result.contact.floor_values[1, entered] == 0.004


def test_polygon_lookup_even_odd():
    square = FloorPatch(((0, 0), (1, 0), (1, 1), (0, 1)))
    assert square.contains(0.5, 0.5) and not square.contains(1.5, 0.5) and not square.contains(0.5, -0.1)
    ell = FloorPatch(((0, 0), (2, 0), (2, 1), (1, 1), (1, 2), (0, 2)))  # an L: its notch is outside
    assert ell.contains(0.5, 1.5) and ell.contains(1.5, 0.5) and not ell.contains(1.5, 1.5)


def test_without_floor_keys_the_plant_runs_its_no_slip_path():
    """A scenario without the new [floor] keys: Floor(), bit-identical runs, no slip keys in the JSON."""
    problem = problem_from_dict(bundled_table("n_shape"), "n_shape")
    assert problem.floor == Floor() and problem.floor.rigid
    x0 = problem.initial_state()
    speed = lambda t: 3.0 * np.sin(t)  # noqa: E731
    plain = simulate(x0, 2.0, params=problem.params, speed=speed)
    with_floor = simulate(x0, 2.0, params=problem.params, speed=speed, floor=problem.floor)
    assert plain.contact is None and with_floor.contact is None
    for name in ("t", "x", "command", "diag"):
        assert np.array_equal(getattr(plain, name), getattr(with_floor, name))
    assert not {"max_slip_speed", "time_sliding"} & set(compute_metrics(problem, plain))


def test_floor_keys_in_a_scenario():
    table = bundled_table("n_shape")
    table["floor"].update(mu=0.25, rolling_resistance=0.003, damping=0.02,
                          patches=[{"polygon": [[0, 0], [1, 0], [1, 1]], "mu": 0.8}])
    problem = problem_from_dict(table, "s.toml")
    assert problem.params.mu == 0.25 and problem.params.slope == pytest.approx(np.radians(1.0))
    assert problem.floor.contact == "coulomb" and problem.floor.rolling_resistance == 0.003
    assert problem.floor.values_at((0.7, 0.2), problem.params.mu).tolist() == [0.8, 0.003, 0.02]


def test_params_mu_still_works_with_a_one_line_deprecation_warning():
    table = bundled_table("n_shape")
    table["params"] = {"mu": 0.3}
    with pytest.warns(RollbotDeprecationWarning, match=r"\[params\] mu is deprecated") as caught:
        problem = problem_from_dict(table, "s.toml")
    assert "\n" not in str(caught[0].message)
    assert problem.params.mu == 0.3 and problem.floor.rigid  # as before: the no-slip plant
    table["floor"]["mu"] = 0.4
    with warnings.catch_warnings(), pytest.raises(ConfigError, match=r"both \[floor\] and \[params\]"):
        warnings.simplefilter("ignore")
        problem_from_dict(table, "s.toml")


@pytest.mark.parametrize("floor, message", [
    ({"mu": -0.1}, r"s.toml \[floor\]: key 'mu' = -0.1 is out of range"),
    ({"rolling_resistance": 0.5}, r"key 'rolling_resistance' = 0.5 is out of range: valid is \[0.0, 0.05\]"),
    ({"damping": "a lot"}, r"key 'damping' = 'a lot' must be a finite number"),
    ({"carpet": 1}, r"\[floor\]: unknown key\(s\) carpet"),
    ({"patches": [{"polygon": [[0, 0], [1, 0]]}]}, r"#1: key 'polygon' .* at least 3"),
    ({"patches": [{"mu": 0.3}]}, r"#1: missing required key 'polygon'"),
    ({"patches": [{"polygon": [[0, 0], [1, 0], [1, 1]], "mu": 11}]}, r"#1: key 'mu' = 11 is out of range"),
    ({"patches": [{"polygon": [[0, 0], [1, 0], [1, 1]], "sand": 1}]}, r"#1: unknown key\(s\) sand"),
    ({"patches": {"polygon": []}}, r"patches = .* must be an array of tables"),
])
def test_bad_floor_keys_get_one_line_errors(floor, message):
    table = bundled_table("n_shape")
    table["floor"].update(floor)
    with pytest.raises(ConfigError, match=message) as caught:
        problem_from_dict(table, "s.toml")
    assert "\n" not in str(caught.value)


def test_contact_state_sizes():
    assert NXC == NX + 2
    with pytest.raises(ValueError, match="method = 'cvodes'"):
        simulate(rest_state(), 0.1, floor=COULOMB, method="cvodes")
