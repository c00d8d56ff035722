"""Linearised stability: the paper's anchors, the symmetry mode, and agreement with direct simulation."""

import math

import control
import numpy as np
import pytest

from rollbot_oc.analysis.experiments import damped_modes
from rollbot_oc.model.params import RollbotParams
from rollbot_oc.analysis.quasi_stable import _curve, _states, quasi_stable_state
from rollbot_oc.simulation.plant import simulate
from rollbot_oc.analysis.stability import linearise, perturbed_state, stability, stability_curve, state_space


@pytest.fixture(scope="module")
def curve():
    return stability_curve(np.linspace(0.0, 3 * np.pi, 200)[1:])


def test_paper_anchors(curve):
    re2 = np.array([r.lambda2.real for r in curve])
    assert np.all((-0.2 <= re2) & (re2 <= -0.1))  # the paper: Re(lambda2) within [-0.2, -0.1]
    taus = np.array([r.tau for r in curve])
    assert 5.0 < taus.min() and taus.max() < 8.0 and abs(np.median(taus) - 7.0) < 1.0  # "about 7 s"
    assert all(r.stable for r in curve)


def test_symmetry_mode_is_exact_and_removed(curve):
    for r in curve[::40]:
        A7, B7, Aq, Bq, v0 = linearise(r.state)
        assert np.abs(A7 @ v0).max() <= 1e-12 * np.abs(A7).max()
        assert abs(r.symmetry_eigenvalue) < 1e-10
        full = np.sort_complex(np.linalg.eigvals(A7[:6, :6]))
        kept = np.sort_complex(np.append(r.eigenvalues, r.symmetry_eigenvalue))
        assert np.allclose(full, kept, atol=1e-9)


def test_state_space_export(curve):
    r = curve[60]
    sys = state_space(r)
    assert isinstance(sys, control.StateSpace) and sys.nstates == 6 and sys.ninputs == 1
    poles = np.sort_complex(sys.poles())
    assert np.allclose(poles, np.sort_complex(np.append(r.eigenvalues, 0.0)), atol=1e-9)
    assert np.linalg.matrix_rank(control.ctrb(sys.A, sys.B)) == 6  # the motor reaches every mode


@pytest.mark.parametrize("omega0", [3.0, 6.0])
def test_decay_and_frequency_match_direct_simulation(omega0):
    """Kick a quasi-stable state in the full simulator and read its modes off the tilt response."""
    state = quasi_stable_state(omega0)
    linear = stability(state)
    x0 = state.state()
    x0[6:9] += [0.02, -0.01, 0.03]  # a generic kick of the shell (rad/s)
    run = simulate(x0, 30.0, speed=omega0)
    rates = damped_modes((run.tilt - state.xi)[::5], 5 * run.dt, order=7)
    for lam in linear.eigenvalues[linear.eigenvalues.imag >= 0]:
        fitted = rates[np.argmin(np.abs(rates - lam))]
        assert fitted.real == pytest.approx(lam.real, rel=0.10)
        assert fitted.imag == pytest.approx(lam.imag, rel=0.10, abs=0.02)
    lam2 = linear.lambda2
    fitted2 = rates[np.argmin(np.abs(rates - lam2))]
    assert abs(fitted2 - lam2) < 0.01 * abs(lam2)  # in fact far better than 10 %


def test_linear_response_tracks_the_nonlinear_one():
    state = quasi_stable_state(3.0)
    y0 = np.array([0.0, 0.01, 0.0, 0.0, 0.0, 0.0])  # 0.01 rad more tilt
    run = simulate(perturbed_state(state, y0), 10.0, speed=3.0)
    linear = control.initial_response(state_space(stability(state)), T=run.t, X0=y0)
    tilt_change = run.tilt - state.xi
    assert np.abs(tilt_change - linear.outputs[1]).max() <= 0.02 * np.abs(linear.outputs[1]).max()


def test_fast_branch_is_unstable_and_the_simulation_agrees():
    state = quasi_stable_state(6.0, branch="fast")
    result = stability(state)
    assert not result.stable and result.tau == math.inf
    growth = result.lambda2.real
    assert growth > 1.0
    x0 = state.state()
    x0[6] += 1e-7
    run = simulate(x0, 4.0, speed=6.0, stop_on_event=False)
    rates = damped_modes((run.tilt - state.xi)[::2], 2 * run.dt, order=6)
    fitted = rates[np.argmin(np.abs(rates - result.lambda2))]
    assert fitted.real == pytest.approx(growth, rel=0.10)
    assert fitted.imag == pytest.approx(abs(result.lambda2.imag), rel=0.10)


def test_other_robots_report_their_stability():
    for params in (RollbotParams(phi=math.radians(30)), RollbotParams(m=0.5), RollbotParams(k0=0.002)):
        results = stability_curve([1.0, 4.0], params)
        assert all(r.stable and r.tau > 0 for r in results)
    light_damping = stability_curve([3.0], RollbotParams(k0=0.0005))[0]
    assert light_damping.tau > 3 * stability_curve([3.0])[0].tau  # less damping, slower recovery


def test_bad_input():
    with pytest.raises(ValueError, match="omega0"):
        stability_curve([-1.0])
    with pytest.raises(ValueError, match="expected 6"):
        perturbed_state(quasi_stable_state(1.0), np.zeros(3))


@pytest.mark.parametrize("branch", ["slow", "fast"])
@pytest.mark.parametrize("params", [
    RollbotParams(), RollbotParams(phi=math.radians(30)), RollbotParams(phi=math.radians(60)), RollbotParams(m=0.2),
    RollbotParams(m=0.45), RollbotParams(k0=0.02534),  # strong damping: the slow branch folds near 8.2 rad/s
], ids=["prototype", "phi30", "phi60", "m0.2", "m0.45", "k0_fold"])
def test_batched_route_equals_the_continuation(params, branch):
    """The batched solve and eigenvalues against the speed-by-speed continuation and per-state linearisation."""
    omegas = np.linspace(0.0, 3 * np.pi, 200)
    _, Z, rows, ok = _curve(omegas, params, branch)
    _, Z_ref, rows_ref, ok_ref = _curve(omegas, params, branch, batched=False)
    assert np.array_equal(ok, ok_ref)  # the same points converge (all but those beyond a fold)
    assert np.abs(Z - Z_ref)[ok].max() <= 1e-10  # kappa, theta0, xi
    assert np.abs(rows[:, 6:] - rows_ref[:, 6:])[ok].max() <= 1e-10  # Omega, R0, speed, forces, torque
    reference = _states(omegas, Z_ref, rows_ref, ok_ref, params, branch)
    converged = [s for s in reference if s.converged and s.omega0 > 0]
    batched = stability_curve([s.omega0 for s in converged], params, branch)
    for state, result in zip(converged, batched):
        eig = np.linalg.eigvals(linearise(state)[2][:5, :5])
        eig = eig[np.argsort(-eig.real, kind="stable")]
        assert np.abs(result.eigenvalues - eig).max() <= 1e-10
    if params.k0 > 0.02:
        assert branch == "fast" or (ok[:150].all() and not ok[175:].any())
    else:
        assert ok.all()


def test_sideways_sway_is_uncontrollable_at_rest():
    """At rest, one of the two rocking modes (the paper's lambda2, tau about 7 s) cannot be reached by the
    motor (PBH test on the AD linearisation of the pendulum-frame model); while moving it can (above).
    Why the NMPC must arrive without sway: held at rest, a swaying robot only waits for the sway to decay."""
    import casadi as ca

    from rollbot_oc.model.dynamics import NZ, reduced_model, rest_state, to_reduced

    params = RollbotParams()
    model = reduced_model()
    z, u = ca.SX.sym("z", NZ), ca.SX.sym("u")
    w = np.zeros(model.f.size1_in(3))
    f = model.f(z, u, params.vector(), w)
    jac = ca.Function("rest_linearisation", [z, u], [ca.jacobian(f, z), ca.jacobian(f, u)])
    A, B = (np.array(m) for m in jac(to_reduced(rest_state(params, heading=0.7)), 0.0))
    eigenvalues = np.linalg.eigvals(A)
    rocking = eigenvalues[eigenvalues.imag > 1.0]
    assert rocking.size == 2 and abs(rocking[0] - rocking[1]) < 1e-9  # the two rocking directions: one frequency
    lam = rocking[0]
    assert -0.2 <= lam.real <= -0.1  # the paper's lambda2 band, decay time about 7 s

    def rank(matrix):
        singular = np.linalg.svd(matrix, compute_uv=False)
        return int(np.sum(singular > 1e-9 * singular[0]))

    assert rank(A - lam * np.eye(NZ)) == NZ - 2  # two independent rocking directions
    assert rank(np.hstack([A - lam * np.eye(NZ), B])) == NZ - 1  # PBH: the motor reaches one of them, not both
