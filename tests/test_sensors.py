"""Onboard sensor models: what the IMU, the encoder and motion capture measure, their noise, seeds and outages."""

import math

import numpy as np
import pytest

from rollbot_oc.model.dynamics import OMEGA, POS, QUAT, rest_state
from rollbot_oc.core.errors import ConfigError
from rollbot_oc.model.params import RollbotParams
from rollbot_oc.model.rotations import quat_to_matrix_np
from rollbot_oc.simulation.sensors import (
    G0, EncoderModel, ImuModel, MocapModel, OnboardSensors, SensingConfig, body_signals,
)
from rollbot_oc.simulation.plant import plant_step, simulate


def signals(x, a, params):
    return np.array(body_signals()(x, a, params.vector(), np.zeros(6))).ravel()


def test_at_rest_the_imu_feels_gravity_and_no_rotation():
    params = RollbotParams()
    x = rest_state(params, heading=0.4, theta=1.1)  # in equilibrium on a level floor
    s = signals(x, 0.0, params)
    T = quat_to_matrix_np(x[QUAT])
    assert np.allclose(s[0:3], 0.0)
    assert np.allclose(s[3:6], T.T @ [0.0, 0.0, params.g], atol=1e-12)  # the floor's push, "up", in the body frame
    assert s[6] == pytest.approx(1.1)
    # on a slope the same pose is no equilibrium: the shell starts rolling downhill, which the IMU feels
    sloped = RollbotParams(slope=math.radians(3.0))
    assert np.linalg.norm(signals(x, 0.0, sloped)[3:6] - T.T @ [0.0, 0.0, sloped.g]) > 0.1


def test_accelerometer_sees_the_centre_acceleration_of_the_simulated_motion():
    """The specific force minus gravity is the second derivative of the simulated centre path (independent check)."""
    params = RollbotParams(slope=math.radians(1.0))
    result = simulate(rest_state(params), 4.0, params=params, speed=lambda t: min(5.0, 2.0 * t), dt=0.002)
    k = np.arange(500, 1500, 97)
    s = result.position
    accel_fd = (s[:, k + 1] - 2 * s[:, k] + s[:, k - 1]) / result.dt**2
    gravity = params.g * np.array([params.tilt_x, params.tilt_y, -math.sqrt(1 - params.tilt_x**2 - params.tilt_y**2)])
    for j, i in enumerate(k):
        x = result.x[:, i]
        f_body = signals(x, result.applied_accel[i], params)[3:6]
        accel = quat_to_matrix_np(x[QUAT]) @ f_body + gravity
        assert accel[2] == pytest.approx(0.0, abs=1e-9)  # rolling on the floor: no vertical acceleration
        assert np.allclose(accel[:2], accel_fd[:, j], atol=2e-3 * np.abs(accel_fd).max() + 1e-6)
        # and the gyroscope sees the shell's rate in the body frame
        assert np.allclose(quat_to_matrix_np(x[QUAT]) @ signals(x, 0.0, params)[0:3], x[OMEGA], atol=1e-12)


def test_plant_samples_the_imu_inside_the_period():
    params = RollbotParams()
    x = rest_state(params)
    x[OMEGA] = [0.3, -0.2, 0.5]
    step = plant_step(0.01, 2, samples=2)
    x_next, _, sig = (np.array(v) for v in step(x, 3.0, params.vector(), np.zeros(6)))
    assert sig.shape == (7, 2)
    assert np.allclose(sig[:, 1], signals(x_next.ravel(), 3.0, params), atol=1e-12)  # the last at the period's end
    with pytest.raises(ValueError, match="rk4"):
        plant_step(0.01, 2, method="cvodes", samples=1)


def test_encoder_counts_and_quantisation():
    enc = EncoderModel(4096)
    q = 2 * math.pi / 4096
    assert enc.resolution == pytest.approx(q) and enc.sigma == pytest.approx(q / math.sqrt(12))
    theta = np.random.default_rng(1).uniform(-50, 50, 2000)
    read = np.array([enc.read(t) for t in theta])
    assert np.allclose(np.round(read / q), read / q) and np.abs(read - theta).max() <= q / 2 + 1e-12
    assert np.std(read - theta) == pytest.approx(enc.sigma, rel=0.05)
    assert EncoderModel(None).read(0.123456) == 0.123456
    with pytest.raises(ConfigError, match="counts"):
        EncoderModel(3)


def test_imu_noise_bias_and_seed():
    imu = ImuModel()
    config = SensingConfig("imu", imu)
    quiet = np.tile(np.array([[0, 0, 0, 0, 0, G0, 0.0]]).T, (1, 1))
    a = OnboardSensors(config, 0.01, seed=3)
    readings = [a.read_imu(quiet)[0] for _ in range(4000)]
    gyro = np.array([r.gyro for r in readings])
    accel = np.array([r.accel for r in readings])
    sigma_g, sigma_a = imu.sample_noise(0.01)
    assert sigma_g == pytest.approx(math.radians(0.005) * 10) and sigma_a == pytest.approx(150e-6 * G0 * 10)
    assert np.std(np.diff(gyro, axis=0)) / math.sqrt(2) == pytest.approx(sigma_g, rel=0.05)
    assert np.std(np.diff(accel, axis=0)) / math.sqrt(2) == pytest.approx(sigma_a, rel=0.05)
    b = OnboardSensors(config, 0.01, seed=3)
    assert np.abs(b.gyro_bias).max() <= imu.gyro_bias and np.abs(b.accel_bias).max() <= imu.accel_bias
    assert np.array_equal(gyro[0], b.read_imu(quiet)[0].gyro)  # same seed, same numbers
    assert not np.array_equal(OnboardSensors(config, 0.01, seed=4).gyro_bias, b.gyro_bias)
    # the mean of the readings is the signal plus the (walking) bias
    assert np.allclose(gyro.mean(axis=0), a.gyro_bias, atol=5 * sigma_g / math.sqrt(len(gyro))
                       + 3 * imu.gyro_bias_walk * math.sqrt(40))


def test_motion_capture_rate_latency_and_outages():
    mocap = MocapModel(rate=50.0, latency=0.025, position_noise=0.0, angle_noise=0.0,
                       outage_length=1.0, outage_every=10.0, outage_times=(3.0,))
    sensors = OnboardSensors(SensingConfig("imu+mocap", mocap=mocap), 0.01)
    x = rest_state()
    arrived = {}
    for k in range(2500):
        x[POS] = [k, 0.0]
        sensors.capture(k, x)
        for c in sensors.arrived(k):
            arrived[c.step] = k
            assert c.position[0] == c.step  # the state at its capture, not at its arrival
    steps = np.array(sorted(arrived))
    assert np.all(steps % 2 == 0)  # 50 Hz of a 100 Hz loop
    assert all(arrived[s] - s == 3 for s in steps)  # 25 ms late: the first control instant after arrival
    lost = [k for k in range(0, 2490, 2) if k not in arrived]  # control steps of 10 ms
    assert all(300 <= k < 400 or (k >= 1000 and k % 1000 < 100) for k in lost)
    assert len(lost) == 3 * 50  # the outages at 3, 10 and 20 s, 1 s each
    with pytest.raises(ConfigError, match="whole number of control periods"):
        SensingConfig("imu+mocap", mocap=MocapModel(rate=30.0)).check_period(0.01)
    with pytest.raises(ConfigError, match="whole multiple"):
        SensingConfig("imu", ImuModel(rate=150.0)).check_period(0.01)
    with pytest.raises(ConfigError, match="outage_every"):
        MocapModel(outage_length=2.0, outage_every=1.0)
    with pytest.raises(ConfigError, match="latency.*out of range"):
        MocapModel(latency=5.0)
    with pytest.raises(ConfigError, match="mode"):
        SensingConfig("gps")
