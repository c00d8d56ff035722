"""The plant: conservation laws, constraints, limits, events and its integrator."""

import numpy as np
import pytest

from rollbot_oc.model.dynamics import OMEGA, POS, QUAT, THETA_DOT, RollbotModel, rest_state
from rollbot_oc.model.params import RollbotParams
from rollbot_oc.model.rotations import matrix_to_quat_np, quat_to_matrix_np, rot_x_np, rot_z_np
from rollbot_oc.control.protocol import Command, ControllerBase
from rollbot_oc.simulation.plant import Sensor, SimulationResult, plant_step, simulate


def tilted_spinning_state(params):
    x = rest_state(params)
    x[QUAT] = matrix_to_quat_np(rot_x_np(0.5) @ quat_to_matrix_np(x[QUAT]))
    x[OMEGA] = [0.5, -1.0, 2.0]
    return x


def kinetic(params, x):
    return RollbotModel(params).energy(x) - RollbotModel(params.replace(k0=0.0)).energy(rest_state(params))


def test_energy_conserved_without_damping_and_motor_locked():
    params = RollbotParams(k0=0.0)
    x0 = tilted_spinning_state(params)
    result = simulate(x0, 20.0, params=params, accel=0.0)
    assert result.completed
    E = result.energy()
    drift = np.abs(E - E[0]).max() / abs(E[0])
    assert drift <= 1e-6
    # also against the motion's own energy scale (kinetic + potential above rest), stricter
    scale = E[0] - RollbotModel(params).energy(rest_state(params))
    assert np.abs(E - E[0]).max() <= 1e-6 * scale
    assert np.ptp(result.position[0]) > 0.01  # it really rolled


def test_energy_balance_with_motor_and_damping():
    """E(t) - E(0) = integral of (motor power - k0 |omega|^2) along a driven trajectory."""
    params = RollbotParams()
    model = RollbotModel(params)
    result = simulate(rest_state(params), 10.0, params=params, speed=lambda t: 4.0 * np.sin(0.8 * t))
    x, u = result.x[:, :-1], result.applied_accel
    power = model.power(x, u).sum(axis=0)
    E = result.energy()
    # trapezoid on power needs the applied acceleration at both ends of each period (held within a period)
    p_end = model.power(result.x[:, 1:], u).sum(axis=0)
    work = np.concatenate([[0.0], np.cumsum(0.5 * (power + p_end) * result.dt)])
    scale = np.abs(model.power(x, u)[0]).sum() * result.dt
    assert np.abs((E - E[0]) - work).max() <= 1e-3 * scale
    assert scale > 0.1  # the motor did real work


def test_no_slip_centre_velocity_is_omega_cross_Rz():
    params = RollbotParams(slope=np.radians(1))
    result = simulate(tilted_spinning_state(params), 5.0, params=params, speed=lambda t: min(5.0, t))
    dt = result.dt
    s = result.position
    v_fd = (s[:, 2:] - s[:, :-2]) / (2 * dt)
    omega = result.x[OMEGA, 1:-1]
    v_roll = np.cross(omega.T, [0.0, 0.0, params.R]).T[:2]
    assert np.abs(v_fd - v_roll).max() <= 2e-4 * np.abs(v_roll).max()


def test_rk4_agrees_with_cvodes():
    params = RollbotParams(slope=np.radians(1))
    x0 = tilted_spinning_state(params)
    x0[THETA_DOT] = 4.0
    a = simulate(x0, 5.0, params=params, speed=lambda t: 4.0 + 2 * np.sin(t))
    b = simulate(x0, 5.0, params=params, speed=lambda t: 4.0 + 2 * np.sin(t), method="cvodes")
    assert np.abs(a.x - b.x).max() <= 1e-6


def test_rotated_and_translated_start_gives_rotated_trajectory():
    params = RollbotParams()
    x0 = tilted_spinning_state(params)
    Rz, shift = rot_z_np(2.1), np.array([0.7, -1.3])
    y0 = x0.copy()
    y0[POS] = Rz[:2, :2] @ x0[POS] + shift
    y0[QUAT] = matrix_to_quat_np(Rz @ quat_to_matrix_np(x0[QUAT]))
    y0[OMEGA] = Rz @ x0[OMEGA]
    profile = lambda t: 3.0 * min(1.0, t / 2)  # noqa: E731
    a = simulate(x0, 8.0, params=params, speed=profile)
    b = simulate(y0, 8.0, params=params, speed=profile)
    assert np.allclose(b.position, Rz[:2, :2] @ a.position + shift[:, None], atol=1e-9)
    assert np.allclose(b.x[OMEGA], Rz @ a.x[OMEGA], atol=1e-9)
    assert np.allclose(b.x[THETA_DOT], a.x[THETA_DOT], atol=1e-12)


def test_motor_limits_hold_in_the_plant():
    params = RollbotParams()
    result = simulate(rest_state(params), 6.0, params=params, speed=lambda t: 100.0 if t < 3 else -100.0)
    assert np.abs(result.driving_speed).max() <= params.max_speed * (1 + 1e-12)
    assert np.abs(result.applied_accel).max() <= params.max_accel * (1 + 1e-12)
    assert np.abs(result.motor_torque).max() <= params.max_torque * (1 + 1e-9)
    assert np.abs(result.driving_speed).max() == pytest.approx(params.max_speed)
    # a strong motor with a low torque limit: the torque limit binds
    weak = params.replace(max_torque=0.1, max_accel=1e3)
    result = simulate(rest_state(weak), 2.0, params=weak, accel=500.0)
    assert np.abs(result.motor_torque).max() == pytest.approx(0.1, rel=1e-9)


def test_slide_and_jump_are_reported_as_events():
    slippery = RollbotParams(mu=0.02)
    result = simulate(rest_state(slippery), 20.0, params=slippery, speed=lambda t: min(9.0, 0.5 * t))
    assert not result.completed and result.events[0].kind == "slide"
    assert result.t[-1] < 20.0 and result.slide_margin[-1] < 0 <= result.slide_margin[:-1].min()
    grippy = simulate(rest_state(), 20.0, speed=lambda t: min(9.0, 0.5 * t))  # mu = 0.5
    assert grippy.completed and grippy.slide_margin.min() > 0
    violent = RollbotParams(max_speed=60.0, max_torque=10.0, max_accel=1e3, mu=5.0)
    result = simulate(rest_state(violent), 5.0, params=violent, speed=60.0)
    assert result.events and result.events[0].kind == "jump"
    assert result.normal_force[-1] <= 0 < result.normal_force[:-1].min()
    kept = simulate(rest_state(violent), 5.0, params=violent, speed=60.0, stop_on_event=False)
    assert kept.t[-1] == pytest.approx(5.0) and kept.events


class Ramp(ControllerBase):
    def __init__(self):
        self.calls = 0

    def reset(self):
        self.calls = 0

    def __call__(self, obs):
        self.calls += 1
        return Command(speed=min(3.0, 0.5 * obs.t))


def test_closed_loop_matches_open_loop_and_noise_is_seeded():
    params = RollbotParams()
    x0 = rest_state(params)
    ctrl = Ramp()
    closed = simulate(x0, 10.0, params=params, controller=ctrl)
    opened = simulate(x0, 10.0, params=params, speed=lambda t: min(3.0, 0.5 * t))
    assert ctrl.calls == 1000
    assert np.abs(closed.x - opened.x).max() <= 1e-12
    noisy = [simulate(x0, 2.0, params=params, controller=Ramp(), sensor=Sensor(position_noise=1e-3, seed=s))
             for s in (1, 1)]
    assert np.array_equal(noisy[0].x, noisy[1].x)


def test_latency_delays_what_the_controller_sees():
    seen = []

    class Recorder(ControllerBase):
        def reset(self):
            seen.clear()

        def __call__(self, obs):
            seen.append(obs.t)
            return Command(speed=1.0)

    simulate(rest_state(), 0.1, controller=Recorder(), sensor=Sensor(latency=3))
    assert seen[:5] == [0.0, 0.0, 0.0, 0.0, 0.01]


def test_save_writes_npz(tmp_path):
    result = simulate(rest_state(), 1.0, speed=1.0)
    path = result.save(tmp_path / "run.npz")
    data = np.load(path)
    assert np.array_equal(data["x"], result.x) and data["diag"].shape == result.diag.shape
    assert isinstance(result, SimulationResult)


@pytest.mark.parametrize("kwargs, match", [
    (dict(duration=-1.0), "duration"),
    (dict(duration=float("nan")), "duration"),
    (dict(duration=1.0, dt=0.0), "dt"),
    (dict(duration=1.0, speed=1.0, accel=1.0), "one of"),
    (dict(duration=1.0, speed=np.ones(3)), "speed has 3 values"),
])
def test_bad_simulation_input(kwargs, match):
    with pytest.raises(ValueError, match=match):
        simulate(rest_state(), **kwargs)


def test_bad_state_and_command():
    with pytest.raises(ValueError, match="x0 has 3 entries"):
        simulate(np.zeros(3), 1.0)
    x = rest_state()
    x[QUAT] = 0.0
    with pytest.raises(ValueError, match="quaternion"):
        simulate(x, 1.0)
    with pytest.raises(ValueError, match="exactly one"):
        Command()
    with pytest.raises(ValueError, match="not finite"):
        Command(speed=float("inf"))
    with pytest.raises(ValueError, match="method"):
        plant_step(0.01, 2, "euler")
