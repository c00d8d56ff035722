"""The NMPC's control period as CasADi Functions (``control.nmpc.period``) against independent routes: the
filter against ``TiltEstimator``'s numpy update, the delay compensation against its one-step model, and one
solve against the tracking problem's own RTI route."""

from pathlib import Path

import numpy as np
import pytest

from rollbot_oc.control.nmpc.estimation import TiltEstimator
from rollbot_oc.control.nmpc.period import step_functions
from rollbot_oc.control.nmpc.settings import NMPCSettings
from rollbot_oc.control.nmpc.supervisors import supervisor_for
from rollbot_oc.model.dynamics import REDUCED, to_reduced
from rollbot_oc.core.fastcall import FastFunction
from rollbot_oc.planning.rollbot import rollbot_model
from rollbot_oc.model.params import RollbotParams
from rollbot_oc.scenarios.problem import load_problem

PROBLEMS = Path(__file__).resolve().parents[1] / "problems"
DT = 0.01


@pytest.fixture(scope="module")
def period():
    problem = load_problem(PROBLEMS / "n_shape.toml")
    s = NMPCSettings()
    weights = supervisor_for(problem.mission).tracking_weights(s)
    return step_functions(RollbotParams(), s, weights, problem.mission, DT), s


def _trajectory(periods: int):
    """Full states (11,) and accelerations of the robot on a 1.1 deg floor under a sinusoidal command."""
    F = rollbot_model().interval(4)
    p = RollbotParams().replace(slope=0.02).vector()
    z, states, commands = np.array([0, 0, 1, 0, 0, 0, 0, 0, 0, 0.0]), [], []
    for k in range(periods):
        u = 5.0 * np.sin(0.05 * k)
        states.append(np.concatenate([z[:9], [0.0], z[9:]]))  # the motor angle 0: reduced = full's attitude
        commands.append(u)
        z = np.array(F(z, u, DT, p)).ravel()
    return states, commands


def test_the_filter_is_the_tilt_estimators_update(period):
    """Learned masses and damping, attitude blending: the Function's estimate equals the numpy filter's."""
    f, s = period
    fl = s.filter
    assert f.learn and fl.attitude_gain < 1.0  # the defaults exercise every part of the filter
    reference = TiltEstimator(RollbotParams(), DT, fl.process_noise, fl.gyro_sigma, fl.model_error, fl.learn,
                              fl.learn_sigma, fl.attitude_gain)
    measure, mem = FastFunction(f.measure), f.initial_memory.copy()
    states, commands = _trajectory(300)
    previous = None
    for k, (x, u) in enumerate(zip(states, commands)):
        z = to_reduced(x)
        if k:
            reference.update(previous, commands[k - 1], z)
        _z, mem = (a.copy() for a in measure(mem, np.concatenate([[k * DT], x]), k))
        mem[f.memory["hist"]] = np.concatenate([[u], mem[f.memory["hist"]][:-1]])  # as ``commit`` remembers
        previous = z
    x_f = mem[f.memory["x_f"]]
    assert abs(reference.tilt[0] - 0.02) < 2e-3  # it learned the floor
    assert np.allclose(x_f, np.concatenate([reference.tilt, reference.scales]), rtol=0, atol=1e-10)
    assert np.allclose(mem[f.memory["P"]], reference._P.ravel(order="F"), rtol=0, atol=1e-12)


@pytest.mark.parametrize("delay", [0, 1, 3])
def test_the_delay_compensation_predicts_over_the_commands_since(period, delay):
    """A measurement ``delay`` periods old is carried forward by the filter's one-step model over the commands
    issued since (the newest first in the memory)."""
    f, s = period
    measure, mem = FastFunction(f.measure), f.initial_memory.copy()
    states, commands = _trajectory(40)
    k = 30
    hist = np.zeros(f.memory["hist"].stop - f.memory["hist"].start)
    hist[:k] = commands[k - 1::-1]
    mem[f.memory["hist"]] = hist
    z, _mem = measure(mem, np.concatenate([[(k - delay) * DT], states[k - delay]]), k)
    estimator = TiltEstimator(RollbotParams(), DT, learn=f.learn)
    expected = to_reduced(states[k - delay])
    for j in range(k - delay, k):
        expected = estimator.step(expected, commands[j], estimator.params())[0].copy()
    assert np.allclose(z, expected, rtol=0, atol=1e-12)
    if delay:  # and the prediction is nearer the robot now than the measurement it started from
        now, stale = to_reduced(states[k]), to_reduced(states[k - delay])
        assert np.linalg.norm(z[REDUCED.omega] - now[REDUCED.omega]) < \
            0.5 * np.linalg.norm(stale[REDUCED.omega] - now[REDUCED.omega])


def test_one_solve_is_the_tracking_problems_rti_step(period):
    """From the reference (cold), the Function's iterate equals one real-time iteration of the same problem by
    the route's own Python loop (``RTIRoute.attempt``)."""
    f, s = period
    solver, N = f.solver, s.horizon.N
    states, commands = _trajectory(N + 1)
    Zr = np.column_stack([to_reduced(x) for x in states])
    Ur = np.array(commands[:N])
    z0 = Zr[:, 0] + 1e-3  # off the reference
    window = f.window.pack(Zr, Ur, solver.diag, np.zeros(f.window.terms))  # (stops: no mission values)
    w, _lam_w, _lam_g, ok, retried = (a.copy() for a in FastFunction(f.solve)(f.initial_memory, z0, window))
    x, _lam, status, success, _t = solver.solve(z0, Zr, Ur, RollbotParams().vector())
    assert ok[0] == 1 and retried[0] == 0 and success, status
    assert np.max(np.abs(w - x)) < 1e-8
