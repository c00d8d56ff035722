"""The error-state EKF on onboard sensors: exactness, bias convergence, consistency (NEES), and the closed loop."""

import math
from dataclasses import replace

import numpy as np
import pytest

from rollbot_oc.missions import Waypoints
from rollbot_oc.model.dynamics import QUAT
from rollbot_oc.simulation.ekf import AUG, ERR, NE, EstimatorSettings, boxminus, boxplus, error_between, imu_model
from rollbot_oc.simulation.onboard import EstimationRecord, OnboardSensing, nees_bounds
from rollbot_oc.scenarios.problem import make_controller, problem_from_dict, run_problem
from rollbot_oc.scenarios.bundled import bundled_table, load_bundled
from rollbot_oc.simulation.sensors import EncoderModel, ImuModel, MocapModel, SensingConfig
from rollbot_oc.simulation.plant import SimulationResult, simulate

PERFECT_MOCAP = MocapModel(latency=0.0, position_noise=0.0, angle_noise=0.0)


def n_shape():
    return load_bundled("n_shape")


def onboard_run(config, duration, *, seed=0, params=None, settings=None, substeps=2, **kwargs):
    """The PID on the N-shape, driving on the estimate of ``config``'s sensors."""
    problem = n_shape()
    sensing = OnboardSensing(config, params or problem.params, problem.dt, seed=seed, settings=settings, **kwargs)
    result = simulate(problem.initial_state(), duration, params=problem.params,
                      controller=make_controller("pid", problem), dt=problem.dt, sensor=sensing, substeps=substeps)
    return problem, result


def true_tilt(problem):
    return np.array([problem.params.tilt_x, problem.params.tilt_y])


def test_error_state_algebra():
    rng = np.random.default_rng(0)
    xa = np.concatenate([n_shape().initial_state(), rng.normal(size=8) * 0.01])
    dx = rng.normal(size=NE) * 0.05
    moved = np.array(boxplus(xa, dx)).ravel()
    assert np.linalg.norm(moved[QUAT]) == pytest.approx(1.0)
    assert np.allclose(np.array(boxminus(moved, xa)).ravel(), dx, atol=1e-12)  # [-] undoes [+]
    assert np.allclose(error_between(xa, xa), 0.0)
    f = imu_model(0.01, 2)
    assert f.size_out("Ah") == (NE, NE) and f.size_out("H") == (7, NE)


@pytest.mark.parametrize("rate, mode", [(100.0, "imu"), (200.0, "imu"), (100.0, "imu+mocap")])
def test_perfect_sensors_give_the_true_state(rate, mode):
    """No noise, no bias, ideal encoder, the plant's own model and tilt: the estimate is the plant's state."""
    config = SensingConfig(mode, ImuModel.perfect(rate), EncoderModel(None), PERFECT_MOCAP)
    problem, result = onboard_run(config, 12.0)
    record = result.estimation
    errors = record.errors(result.x, true_tilt(problem))
    assert np.ptp(result.position[0]) > 0.1 and np.abs(result.x[10]).max() > 2.0  # it really drove
    assert record.position_error(result.x).max() <= 1e-9  # m
    assert np.abs(errors[ERR.attitude]).max() <= 1e-9 and np.abs(errors[ERR.omega]).max() <= 1e-8
    assert np.abs(errors[ERR.gyro_bias]).max() <= 1e-9 and np.abs(errors[ERR.tilt]).max() <= 1e-9


def test_perfect_sensors_with_a_finer_plant_stay_within_integration_accuracy():
    """The plant takes 1.25 ms RK4 steps, the filter 5 ms: the estimate differs by the integration error only."""
    config = SensingConfig("imu", ImuModel.perfect(), EncoderModel(None))
    problem, result = onboard_run(config, 12.0, substeps=8)
    assert 0 < result.estimation.position_error(result.x).max() <= 1e-6  # m, over a run of about 1.5 m


@pytest.mark.parametrize("seed", [0, 1])
def test_gyro_bias_converges_with_motion_capture(seed):
    """Default consumer IMU (initial bias up to 0.5 deg/s), 100 Hz motion capture, the robot believed on a
    level floor: within 5 s every axis of the bias estimate is within 0.02 deg/s of the truth, and stays."""
    problem = n_shape()
    _, result = onboard_run(SensingConfig("imu+mocap"), 10.0, seed=seed, params=problem.params.replace(slope=0.0))
    record = result.estimation
    error = np.degrees(np.abs(record.estimate[AUG.gyro_bias] - record.true_bias[0:3])).max(axis=0)  # deg/s
    assert error[0] >= 0.2  # the filter starts from zero bias: something to learn
    assert error[record.t >= 5.0].max() <= 0.02
    assert np.all(error[-1] <= 3 * np.degrees(record.std[ERR.gyro_bias, -1]))  # and it knows how well


@pytest.mark.parametrize("mode", ["imu", "imu+mocap"])
def test_nees_is_consistent(mode):
    """Monte Carlo consistency: 8 seeded runs, each starting from an estimate drawn from the filter's prior, the
    filter's noise model that of the simulation (EstimatorSettings.exact_model).  NEES of the 18 error states at
    every 0.5 s; its average lies within the 95 % chi-square bounds of the average of 8 independent runs (several
    times per run only narrow the spread of a run's average, so the bounds are, if anything, generous)."""
    runs = 8
    problem = n_shape()
    values = []
    for seed in range(runs):
        _, result = onboard_run(SensingConfig(mode), 6.0, seed=seed, settings=EstimatorSettings.exact_model(),
                                keep_covariance=True, unknown_start=True)
        record = result.estimation
        values.append(record.nees(result.x, true_tilt(problem), np.arange(0, len(record), 50)))
    average = float(np.mean(values))
    low, high = nees_bounds(runs)
    assert low <= average <= high, f"average NEES {average:.1f} outside [{low:.1f}, {high:.1f}]"


def test_nees_bounds():
    low, high = nees_bounds(1, dof=2)
    assert (low, high) == pytest.approx((0.0506, 7.378), abs=1e-3)
    low, high = nees_bounds(1000)
    assert low < NE < high and high - low < 1.0


def test_record_is_saved_and_loaded(tmp_path):
    config = SensingConfig("imu+mocap", mocap=MocapModel(outage_length=0.5, outage_every=1.0))
    _, result = onboard_run(config, 3.0)
    record = result.estimation
    assert len(record) == result.command.size and record.fused.sum() > 0
    assert np.all(record.fused[(record.t % 1.0 > 0.02) & (record.t % 1.0 < 0.5) & (record.t > 1.0)] == 0)  # outages
    loaded = SimulationResult.load(result.save(tmp_path / "run.npz"))
    assert isinstance(loaded.estimation, EstimationRecord) and loaded.estimation.mode == "imu+mocap"
    for key in EstimationRecord.ARRAYS:
        assert np.array_equal(getattr(loaded.estimation, key), getattr(record, key))
    assert SimulationResult.load(simulate(n_shape().initial_state(), 0.1, speed=1.0).save(tmp_path / "o.npz")
                                 ).estimation is None


def test_problem_schema_for_sensing(tmp_path):
    table = bundled_table("n_shape_imu")
    problem = problem_from_dict(table, "n_shape_imu.toml")
    assert problem.sensing.mode == "imu" and problem.sensing.encoder.counts == 4096
    assert problem.sensing.imu.gyro_noise_density == pytest.approx(math.radians(0.005))
    outages = load_bundled("n_shape_outages").sensing
    assert outages.mode == "imu+mocap" and outages.mocap.outage_every == 10.0 and outages.mocap.outage_length == 1.0
    assert n_shape().sensing.mode == "mocap"
    base = {k: v for k, v in table.items() if k != "sensor"}
    bad = [
        ({"mode": "gps"}, r"bad.toml \[sensor\]: key 'mode' = 'gps'; valid are 'mocap', 'imu', 'imu\+mocap'"),
        ({"mode": "imu", "position_noise": 0.001}, r"key 'position_noise' is not used in mode 'imu'.*mode 'mocap'"),
        ({"imu": {"rate": 100.0}}, r"key 'imu' is not used in mode 'mocap'"),
        ({"mode": "imu", "mocap": {}}, r"key 'mocap' is not used in mode 'imu'.*'imu\+mocap'"),
        ({"mode": "imu", "imu": {"gyro_bias_deg": -1}}, r"bad.toml \[sensor.imu\]: key 'gyro_bias_deg' = -1 is out of "
                                                         r"range: valid is \[0.0, 100.0\]"),
        ({"mode": "imu", "imu": {"rate": 150.0}}, r"\[sensor\]: IMU rate = 150 Hz must be a whole multiple"),
        ({"mode": "imu", "imu": {"wobble": 1}}, r"\[sensor.imu\]: unknown key\(s\) wobble"),
        ({"mode": "imu", "encoder_counts": 100.5}, r"key 'encoder_counts' = 100.5 must be a whole number"),
        ({"mode": "imu+mocap", "mocap": {"outage_times": [1, "x"]}}, r"\[sensor.mocap\]: key 'outage_times'"),
        ({"mode": "imu+mocap", "mocap": {"outage_length": 2.0, "outage_every": 1.0}}, r"outage_every = 1.0 s must be"),
        ({"mode": "imu+mocap", "mocap": {"rate": 30.0}}, r"motion-capture rate = 30 Hz"),
        ({"mode": "imu", "imu": 3}, r"'imu' = 3 must be a table"),
    ]
    for sensor, message in bad:
        with pytest.raises(ValueError, match=message):
            problem_from_dict({**base, "sensor": sensor}, "bad.toml")


def test_pid_drives_on_the_estimate_and_metrics_report_true_stop_errors():
    problem = load_bundled("n_shape_imu")
    problem = replace(problem, mission=Waypoints((problem.mission.stops[0],)))
    run = run_problem(problem, "pid", seed=0, duration=60.0)
    m = run.metrics
    assert m["completed"] and m["sensing"] == "imu" and len(m["stop_errors"]) == 1
    stop = int(round(m["stop_times"][0] / problem.dt))
    true_error = np.linalg.norm(run.result.x[0:2, stop] - problem.mission.stops[0])
    assert m["stop_errors"][0] == pytest.approx(true_error) and m["stop_errors"][0] <= 0.07
    assert abs(m["stop_errors"][0] - m["estimated_stop_errors"][0]) <= m["estimation_errors"][0] + 1e-12
    assert m["max_estimation_error"] == max(m["estimation_errors"]) <= m["estimation_error_max"]
    assert 0 < m["stop_position_std"][0] < 0.05


@pytest.mark.slow
def test_nmpc_drives_on_the_estimate():
    """The NMPC consumes the same Observation: a first leg of the N-shape with the IMU alone (not tuned here)."""
    problem = load_bundled("n_shape_imu")
    problem = replace(problem, mission=Waypoints((problem.mission.stops[0],)))
    m = run_problem(problem, "nmpc", seed=0, duration=20.0).metrics
    assert m["completed"] and m["stop_errors"][0] <= 0.07 and m["max_estimation_error"] <= 0.01
