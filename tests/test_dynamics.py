"""The equations of motion against independent references and exact identities."""

import casadi as ca
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from reference import newton_euler, quat_matrix, rollbot_mass

from rollbot_oc.model.dynamics import (
    NW, NX, OMEGA, POS, QUAT, REDUCED, RollbotModel, PointMass, imbalance, rest_attitude, rest_state, shell_dynamics,
    symbolic_model, to_reduced,
)
from rollbot_oc.model.params import RollbotParams
from rollbot_oc.model.rotations import matrix_to_quat_np, quat_to_matrix_np, rot_z_np


def random_state(rng, spin=3.0):
    x = rng.normal(size=NX)
    x[QUAT] /= np.linalg.norm(x[QUAT])
    x[OMEGA] *= spin
    x[10] *= 5.0
    return x


SLOPED = RollbotParams(slope=np.radians(3.0), slope_dir=0.7)


def gravity(params):
    s, d = params.slope, params.slope_dir
    return params.g * np.array([np.sin(s) * np.cos(d), np.sin(s) * np.sin(d), -np.cos(s)])


def test_rest_with_mass_down_is_an_equilibrium():
    params = RollbotParams()
    model = RollbotModel(params)
    x = rest_state(params, position=(0.3, -0.2), heading=1.1, theta=0.4)
    assert np.allclose(model.xdot(x), 0.0, atol=1e-13)
    N = model.reaction(x)
    assert N[2] == pytest.approx(params.total_mass * params.g, rel=1e-14)
    assert np.allclose(N[:2], 0.0, atol=1e-13)
    assert model.motor_torque(x) == pytest.approx(0.0, abs=1e-14)
    # the mass hangs straight below the centre
    r = quat_to_matrix_np(x[QUAT]) @ np.array([params.r0 * np.sin(params.phi) * np.cos(0.4),
                                               params.r0 * np.sin(params.phi) * np.sin(0.4),
                                               -params.r0 * np.cos(params.phi)])
    assert np.allclose(r, [0, 0, -params.r0], atol=1e-14)


@pytest.mark.parametrize("params", [RollbotParams(), SLOPED, RollbotParams(phi=0.3, m=0.8, r0=0.05, k0=0.0)])
def test_closed_form_matches_newton_euler(params):
    """Paper eqn 'motion' against Newton-Euler with explicit constraint forces, at random states."""
    model = RollbotModel(params)
    rng = np.random.default_rng(7)
    for _ in range(20):
        x, u, w = random_state(rng), rng.normal() * 10, rng.normal(size=NW)
        T = quat_matrix(x[QUAT])
        omega_dot, s_ddot, forces, N = newton_euler(
            T, x[OMEGA], [rollbot_mass(x[9], x[10], u, params.m, params.r0, params.phi)], params.M, params.I,
            params.R, gravity(params), w[:3], w[3:] - params.k0 * x[OMEGA])
        xdot = model.xdot(x, u, w)
        assert np.allclose(xdot[OMEGA], omega_dot, rtol=1e-9, atol=1e-9 * np.abs(omega_dot).max())
        assert np.allclose(model.reaction(x, u, w), N, rtol=1e-9, atol=1e-9)
        # motor torque: the axial moment of the internal force about the centre
        r = T @ rollbot_mass(x[9], x[10], u, params.m, params.r0, params.phi)[1]
        assert model.motor_torque(x, u, w) == pytest.approx((T[:, 2] @ np.cross(r, forces[0])), rel=1e-9, abs=1e-12)


def test_general_point_masses_match_newton_euler():
    """Eqn 'generalmotion' with two masses on independent body trajectories."""
    rng = np.random.default_rng(3)
    T_sym, w_sym = ca.SX.sym("T", 3, 3), ca.SX.sym("w", 3)
    specs = [(0.2, rng.normal(size=3) * 0.05, rng.normal(size=3), rng.normal(size=3)),
             (0.4, rng.normal(size=3) * 0.05, rng.normal(size=3), rng.normal(size=3))]
    masses = [PointMass(m, ca.DM(r), ca.DM(v), ca.DM(a)) for m, r, v, a in specs]
    g = np.array([0.1, -0.2, -9.8])
    dyn = shell_dynamics(T_sym, w_sym, masses, M=0.9, I=0.006, R=0.11, gravity=ca.DM(g),
                         force=ca.DM([0.1, 0.2, -0.3]), torque=ca.DM([0.01, 0.0, -0.02]))
    fun = ca.Function("f", [T_sym, w_sym], [dyn.omega_dot, dyn.reaction])
    T = quat_matrix(rng.normal(size=4))
    omega = rng.normal(size=3) * 2
    omega_dot, _, _, N = newton_euler(T, omega, specs, 0.9, 0.006, 0.11, g, np.array([0.1, 0.2, -0.3]),
                                      np.array([0.01, 0.0, -0.02]))
    got_w, got_N = (np.array(v).ravel() for v in fun(T, omega))
    assert np.allclose(got_w, omega_dot, rtol=1e-10, atol=1e-12)
    assert np.allclose(got_N, N, rtol=1e-10, atol=1e-12)


def test_energy_rate_equals_power_identically():
    """dE/dt (AD directional derivative along f) = motor power + damping power + external power."""
    sym = symbolic_model()
    x, u = ca.SX.sym("x", NX), ca.SX.sym("u")
    p, w = ca.SX.sym("p", SLOPED.vector().size), ca.SX.sym("w", NW)
    residual = ca.jtimes(sym.energy(x, p), x, sym.f(x, u, p, w)) - ca.sum1(sym.power(x, u, p, w))
    fun = ca.Function("balance", [x, u, p, w], [residual, ca.sum1(sym.power(x, u, p, w))])
    rng = np.random.default_rng(11)
    for _ in range(20):
        res, pw = fun(random_state(rng), rng.normal() * 10, SLOPED.vector(), rng.normal(size=NW))
        assert abs(float(res)) <= 1e-12 * max(1.0, abs(float(pw)))


def test_ad_jacobian_matches_finite_differences():
    """A spot check of CasADi's AD against central differences (never used in the toolkit itself)."""
    sym = symbolic_model()
    x, u = ca.SX.sym("x", NX), ca.SX.sym("u")
    pv = SLOPED.vector()
    jac = ca.Function("J", [x, u], [ca.jacobian(sym.f(x, u, pv, ca.DM.zeros(NW)), ca.vertcat(x, u))])
    hess = ca.Function("H", [x, u], [ca.hessian(sym.energy(x, pv), x)[0]])
    model = RollbotModel(SLOPED)
    rng = np.random.default_rng(5)
    x0, u0 = random_state(rng), 2.0
    J = np.array(jac(x0, u0))
    h = 1e-6
    for i in range(NX + 1):
        e = np.zeros(NX + 1)
        e[i] = h
        fd = (model.xdot(x0 + e[:NX], u0 + e[NX]) - model.xdot(x0 - e[:NX], u0 - e[NX])) / (2 * h)
        assert np.allclose(J[:, i], fd, rtol=1e-6, atol=1e-6)
    H = np.array(hess(x0, u0))
    assert np.allclose(H, H.T, atol=1e-12)
    grad = lambda z: np.array(ca.Function("g", [x], [ca.gradient(sym.energy(x, pv), x)])(z)).ravel()  # noqa: E731
    for i in (6, 10):
        e = np.zeros(NX)
        e[i] = h
        assert np.allclose(H[:, i], (grad(x0 + e) - grad(x0 - e)) / (2 * h), rtol=1e-6, atol=1e-6)


def test_dynamics_equivariant_under_floor_rotations():
    """On a level floor, rotating the state about the vertical rotates its derivative."""
    model = RollbotModel()
    rng = np.random.default_rng(2)
    Rz = rot_z_np(0.9)
    for _ in range(5):
        x, u = random_state(rng), rng.normal()
        y = x.copy()
        y[POS] = Rz[:2, :2] @ x[POS] + [1.0, -2.0]
        y[QUAT] = matrix_to_quat_np(Rz @ quat_to_matrix_np(x[QUAT]))
        y[OMEGA] = Rz @ x[OMEGA]
        fx, fy = model.xdot(x, u), model.xdot(y, u)
        assert np.allclose(fy[OMEGA], Rz @ fx[OMEGA], atol=1e-12)
        assert np.allclose(fy[POS], Rz[:2, :2] @ fx[POS], atol=1e-12)
        assert np.allclose(model.reaction(y, u), Rz @ model.reaction(x, u), atol=1e-12)


def test_slope_rolls_the_resting_robot_downhill():
    params = RollbotParams(slope=np.radians(1.0), slope_dir=np.radians(30))
    model = RollbotModel(params)
    x = rest_state(params)
    xdot = model.xdot(x)
    downhill = np.array([np.cos(params.slope_dir), np.sin(params.slope_dir), 0.0])
    s_ddot = np.cross(xdot[OMEGA], [0, 0, params.R])
    assert s_ddot @ downhill > 0
    # the friction force holds the shell: tangential reaction points uphill
    assert model.reaction(x)[:2] @ downhill[:2] < 0


def test_torque_is_affine_in_acceleration_and_bounds_respect_limit():
    params = RollbotParams(max_accel=1e4)  # so the torque limit binds
    model = RollbotModel(params)
    rng = np.random.default_rng(9)
    for _ in range(10):
        x = random_state(rng, spin=1.0)
        lo, hi = model.accel_bounds(x)
        taus = [model.motor_torque(x, a) for a in (lo, hi)]
        a_mid = 0.5 * (lo + hi)
        assert model.motor_torque(x, a_mid) == pytest.approx(0.5 * sum(taus), rel=1e-10, abs=1e-12)
        assert taus[0] == pytest.approx(-params.max_torque, rel=1e-10)
        assert taus[1] == pytest.approx(params.max_torque, rel=1e-10)
        assert lo < hi


@given(st.lists(st.floats(-1.0, 1.0), min_size=4, max_size=4).filter(lambda v: np.linalg.norm(v) > 0.1),
       st.floats(0.5, 1.1), st.floats(0.0, 0.05), st.floats(-np.pi, np.pi))
def test_rest_attitude_balances_the_robot_and_keeps_the_heading(q, phi, slope, slope_dir):
    """Any attitude (the mass swung over the top included) rests balanced (the statics' ``imbalance`` is zero:
    on a level floor the mass straight below the centre, the motor axis tilted by ``phi`` with the same
    heading; on a slope of up to 3 deg tilted uphill a little), on the sign of the given quaternion; a rest
    attitude is its own."""
    q = np.asarray(q) / np.linalg.norm(q)
    level, sloped = RollbotParams(phi=phi), RollbotParams(phi=phi, slope=slope, slope_dir=slope_dir)
    for params in (level, sloped):
        rest = rest_attitude(q, params)
        assert np.linalg.norm(rest) == pytest.approx(1.0, abs=1e-12) and rest @ q >= 0
        assert np.allclose(np.array(ca.DM(imbalance(ca.DM(rest), ca.DM(params.vector())))).ravel(), 0.0, atol=1e-9)
        assert np.allclose(rest_attitude(rest, params), rest, atol=1e-9)  # at rest already
    rest, before = quat_to_matrix_np(rest_attitude(q, level))[:, 2], quat_to_matrix_np(q)[:, 2]
    assert np.arccos(np.clip(rest[2], -1, 1)) == pytest.approx(phi, abs=1e-9)
    if np.hypot(before[0], before[1]) > 1e-6:
        assert np.arctan2(rest[1], rest[0]) == pytest.approx(np.arctan2(before[1], before[0]), abs=1e-9)
    at_rest = to_reduced(rest_state(level, heading=float(q[1] * 3), theta=float(q[2] * 3)))[REDUCED.quaternion]
    assert np.allclose(rest_attitude(at_rest, level), at_rest, atol=1e-12)
