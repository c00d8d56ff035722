"""The optimal-control layer: one description, transcribed once, solved by its routes; checks against physics."""

import math
from pathlib import Path

import casadi as ca
import numpy as np
import pytest

from rollbot_oc.planning.min_time import quasi_stable_guess
from rollbot_oc.model.dynamics import REDUCED, RollbotModel, from_reduced, rest_state, to_reduced
from rollbot_oc.core.errors import ConfigError
from rollbot_oc.ocp import OCP, FreeTime, OCPModel, bounded
from rollbot_oc.planning.rollbot import (at_rest, driving_speed, motor_accel, motor_torque, no_jump, no_slide,
                                        rollbot_model, rollbot_ocp)
from rollbot_oc.model.params import RollbotParams
from rollbot_oc.simulation.plant import simulate

from legs import leg_problem as shared_leg

ROOT = Path(__file__).resolve().parents[1]
PARAMS = RollbotParams(slope=math.radians(1.0), slope_dir=0.5)
GOAL = np.array([0.0, 0.4])
N = 12


def leg_problem():
    """Minimum time (plus a little effort) from rest to rest at a goal 0.4 m away, on a 1 deg slope."""
    return shared_leg(N, FreeTime(guess=3.0, lower=0.5, upper=10.0), substeps=4, minimum_time=True, effort=1e-2)


@pytest.fixture(scope="module")
def leg():
    ocp = leg_problem()
    ipopt = ocp.solver("ipopt")
    start = to_reduced(rest_state(PARAMS))
    # a physical guess from the quasi-stable theory (trapezoidal speed profiles, the best one simulated)
    guess = quasi_stable_guess(start, GOAL, PARAMS.replace(slope=0.0), N)
    w0 = ipopt.transcription.layout.pack(guess.z, guess.u[None, :], [guess.T])
    parameters = dict(x0=start, goal=GOAL, p=PARAMS.vector())
    return ocp, ipopt, ipopt.solve(w0, **parameters), parameters


def test_ipopt_leg_ends_at_rest_on_the_goal_and_keeps_every_limit(leg):
    ocp, _, sol, _ = leg
    assert sol.success and sol.route == "ipopt" and sol.iterations > 0 and sol.solve_time > 0
    end = sol.states[:, -1]
    assert np.abs(end[0:2] - GOAL).max() < 1e-6
    # at rest on the sloped floor: a static equilibrium of the full model (independent of the OCP's formula)
    assert np.abs(RollbotModel(PARAMS).xdot(from_reduced(end))).max() < 1e-6
    for constraint, bound in ((motor_torque(ocp, 0.9), 0.9), (driving_speed(ocp, 0.95), 0.95)):
        assert np.abs(sol.value(constraint.expr, at="intervals")).max() <= bound + 1e-6
    assert sol.value(no_jump(ocp, 0.2).expr, at="intervals").min() >= 0.2 - 1e-6
    assert 0.5 < sol.T < 10.0 and sol.times[-1] == pytest.approx(sol.T)


def test_plan_flies_in_the_plant(leg):
    """The planned accelerations replayed open loop in the plant (its own RK4, contact and motor model) end on the goal.

    The plant's period divides the plan's interval, so the switching instants of the piecewise-constant
    plan are kept exactly (quantising them to a 10 ms grid costs about 9 cm on this aggressive plan).
    """
    _, _, sol, parameters = leg
    u, T = sol.controls[0], sol.T
    dt = T / N / 30
    run = simulate(from_reduced(parameters["x0"]), T, params=PARAMS, dt=dt,
                   accel=lambda t: u[min(int(t / (T / N) + 1e-6), N - 1)])
    assert not run.events
    assert np.linalg.norm(run.position[:, -1] - GOAL) < 0.01


def test_an_rti_step_from_the_converged_solution_stays_there(leg):
    ocp, _, sol, parameters = leg
    step = ocp.solver("rti", compiled=False).attempt(warm=sol, **parameters)
    # relative to each entry's size.  The Gauss-Newton curvature of the accelerations is only the small effort
    # weight, so the QP is nearly an LP in them and small KKT errors move them: measured 1.9e-4 relative (5.5e-4
    # rad/s^2 of 14) with IPOPT's tol 1e-8, 8e-5 with 1e-10 or 1e-12 (the limits as bounds of the QP; 1.2e-5 as
    # its rows).  The Gauss-Newton route agrees to 1e-6 on a problem with real curvature (test_ocp_routes).
    assert step.success and (np.abs(step.w - sol.w) / (1.0 + np.abs(sol.w))).max() < 1e-3


def test_constraint_jacobian_agrees_with_finite_differences(leg):
    """AD against a central-difference spot check along a random direction."""
    _, ipopt, sol, parameters = leg
    tr = ipopt.transcription
    fun = ca.Function("gJ", [tr.w, tr.par], [tr.g, ca.jacobian(tr.g, tr.w)])
    par = tr.parameter_vector(parameters)
    direction = np.random.default_rng(3).normal(size=sol.w.size)
    eps = 1e-6
    plus, minus = (np.array(fun(sol.w + s * eps * direction, par)[0]).ravel() for s in (1, -1))
    J = fun(sol.w, par)[1]
    assert np.abs(np.array(J @ direction).ravel() - (plus - minus) / (2 * eps)).max() < 1e-5


def test_relations_become_constraints():
    ocp = rollbot_ocp(N=3, T=1.0)
    x = ocp.state
    ocp.subject_to(x.theta_dot <= 2.0, 1.0 >= x.omega[0], x.position == ocp.parameter("goal", 2), at="end")
    (le, _), (ge, _), (eq, _) = ocp.constraints
    assert le.upper[0] == 2.0 and le.lower[0] == -np.inf
    assert ge.upper[0] == 1.0
    assert np.all(eq.lower == 0.0) and np.all(eq.upper == 0.0)
    box = bounded(-1.0, x.theta_dot, 1.0)
    assert box.lower[0] == -1.0 and box.upper[0] == 1.0


@pytest.mark.parametrize("build, message", [
    (lambda: OCP(None, N=5), "model = None must be an OCPModel"),
    (lambda: rollbot_ocp(N=0), "N = 0"),
    (lambda: rollbot_ocp(N=(5, 5), T=(1.0,)), "2 phases"),
    (lambda: rollbot_ocp(N=5, T=-1.0), "T = -1.0"),
    (lambda: FreeTime(guess=5.0, lower=6.0), "FreeTime"),
    (lambda: rollbot_ocp(N=5, T=1.0).subject_to(rollbot_ocp(N=5).control.accel <= 1, at="middle"), "at = 'middle'"),
    (lambda: rollbot_ocp(N=5, T=1.0).solver("magic"), "solver route"),
])
def test_bad_descriptions_are_one_clear_error(build, message):
    with pytest.raises(ConfigError, match=message):
        build()


def test_missing_parameter_is_named():
    ocp = OCP(rollbot_model(), N=3, T=1.0)
    ocp.initial_state()
    with pytest.raises(ConfigError, match="'x0'"):
        ocp.solver("ipopt").solve(p=RollbotParams().vector())


def test_the_structured_linearisation_equals_the_nlps_ad(leg):
    """The QP data the SQP routes assemble stage by stage equal CasADi's AD of the whole NLP."""
    from rollbot_oc.ocp.linearisation import StructuredLinearisation

    _, ipopt, sol, parameters = leg
    tr = ipopt.transcription
    Jr = ca.jacobian(tr.residuals, tr.w)
    reference = ca.Function("reference", [tr.w, tr.par], [
        ca.mtimes(Jr.T, Jr) + ca.hessian(tr.general, tr.w)[0],
        ca.gradient(tr.general, tr.w) + ca.mtimes(Jr.T, tr.residuals), tr.g, ca.jacobian(tr.g, tr.w), tr.f])
    par = tr.parameter_vector(parameters)
    w = sol.w + 1e-3 * np.random.default_rng(5).normal(size=sol.w.size)  # away from the optimum
    H, grad, g, J, f = StructuredLinearisation(tr, regularisation=0.0, compiled=False)(w, par)
    rH, rgrad, rg, rJ, rf = reference(w, par)
    assert float(ca.norm_inf(H - rH)) < 1e-9 * max(1.0, float(ca.norm_inf(rH)))
    assert np.abs(grad - np.array(rgrad).ravel()).max() < 1e-10
    assert np.abs(g - np.array(rg).ravel()).max() < 1e-12
    assert float(ca.norm_inf(J - rJ)) < 1e-12
    assert f == pytest.approx(float(rf), rel=1e-12)


def test_qps_through_buffers_equal_qps_called_by_name():
    """The SQP routes call their QP solvers through numpy buffers with the nonzeros (no DM per call): on a
    sequence of different tracking QPs (the N-shape NMPC's, its reference moved step by step; cold, then
    warm-started from the previous multipliers as every real-time step is) each solution and its multipliers
    equal the named call's, for HPIPM and qrqp (HPIPM with its arrays bound once to one buffer and refilled
    in place: the step's largest entry off by 5, 10 and 15 on the second to fourth QP), and the Jacobian
    product of the feasibility check equals CasADi's.  Unknown inputs are refused by name."""
    from rollbot_oc.scenarios.problem import load_problem, make_controller

    problem = load_problem(ROOT / "problems" / "n_shape.toml")
    solver = make_controller("nmpc", problem).solver
    route, tr, N = solver.route, solver.route.transcription, solver.settings.horizon.N
    lin = route.linearisation
    z0 = to_reduced(problem.initial_state())
    for buffered, named in zip(route._buffered, route.qps):  # HPIPM, then qrqp
        warm = {}
        for k in range(4):
            Zr = np.tile(z0[:, None], (1, N + 1))
            Zr[REDUCED.position] += np.array([[0.05], [0.03]]) * k
            par = tr.parameter_vector(solver._parameters(z0, Zr, np.zeros(N), solver.params.vector(), None, None))
            lbw, ubw = tr.bounds(par)
            w = np.clip(solver._guess(z0, Zr, np.zeros(N)), lbw, ubw)
            H, grad, g, J, _f = lin.nonzeros(w, par)
            args = dict(g=grad, lba=tr.lbg - g, uba=tr.ubg - g, lbx=lbw - w, ubx=ubw - w, **warm)
            fast = buffered(h=H, a=J, **args)
            slow = named(h=ca.DM(lin.H_sparsity, H), a=ca.DM(lin.J_sparsity, J), **args)
            assert buffered.stats()["success"] and named.stats()["success"]
            for key in ("x", "lam_x", "lam_a"):
                assert np.abs(fast[key] - np.array(slow[key]).ravel()).max() <= 1e-12, key
            d = fast["x"]
            assert np.abs(lin.J_times(J, d) - np.array(ca.mtimes(ca.DM(lin.J_sparsity, J), d)).ravel()).max() < 1e-12
            warm = dict(lam_x0=fast["lam_x"], lam_a0=fast["lam_a"])
        with pytest.raises(ValueError, match="lam_g0"):
            buffered(h=H, a=J, lam_g0=np.zeros(3))


def test_stage_parameters_take_a_column_per_node_and_refuse_a_transposed_array():
    ocp = rollbot_ocp(N=4, T=1.0)
    reference = ocp.stage_parameter("reference", 2)
    ocp.add_least_squares(ocp.state.position - reference)
    tr = ocp.solver("ipopt").transcription
    values = np.arange(10.0).reshape(2, 5)  # (entries, nodes)
    par = tr.parameter_vector({"p": PARAMS.vector(), "reference": values})
    # node k's column sits at the k-th place of the stage block, as the NLP and the linearisation read it
    assert np.array_equal(par[tr.layout.stage_block].reshape(5, 2).T, values)
    assert np.array_equal(tr.parameter_vector({"p": PARAMS.vector(), "reference": [1.0, 2.0]})[tr.layout.stage_block],
                          np.tile([1.0, 2.0], 5))
    with pytest.raises(ConfigError, match="reference.*shape"):
        tr.parameter_vector({"p": PARAMS.vector(), "reference": values.T})


# -- the layer on a system it was not written for ------------------------------------------------------------------

def double_integrator() -> OCPModel:
    """``s'' = a / m``: position ``s`` (m), velocity ``v`` (m/s), force ``a`` (N), mass ``m`` (kg) a parameter."""
    s, v, a, m = (ca.SX.sym(name) for name in ("s", "v", "a", "m"))
    return OCPModel.ode("double_integrator", ca.vertcat(s, v), a, ca.vertcat(v, a / m), m)


@pytest.mark.parametrize("route", ["ipopt", "sqp"])
def test_the_layer_solves_a_system_it_was_not_written_for(route):
    """Least effort from rest at 0 to rest at 1 m in 1 s: the continuous optimum is ``s = 3 t^2 - 2 t^3``,
    ``a = m (6 - 12 t)``, effort ``0.5 int a^2 dt = 6 m^2``.  Held constant on ``N`` intervals of ``h`` (and
    integrated exactly: RK4 is exact on this quadratic-in-time motion), the optimum is that line at the
    intervals' midpoints ``t_k`` times ``1 / (1 - h^2)`` (the two end conditions fix both coefficients of a
    control linear in ``t_k``, which the optimality conditions ask for), effort ``6 m^2 / (1 - h^2)``."""
    N, mass = 20, 2.0
    h = 1.0 / N
    model = double_integrator()
    ocp = OCP(model, N=N, T=1.0)
    assert (model.state_names, model.control_names, model.parameter_names) == (("s", "v"), ("a",), ("m",))
    ocp.initial_state()
    ocp.add_least_squares(ocp.control.a)
    ocp.subject_to(ocp.state.s == 1.0, ocp.state.v == 0.0, at="end")
    sol = ocp.solver(route).solve(x0=[0.0, 0.0], p=[mass])
    midpoints = (np.arange(N) + 0.5) * h
    assert np.abs(sol.controls[0] - mass * (6 - 12 * midpoints) / (1 - h ** 2)).max() < 1e-6
    assert sol.cost == pytest.approx(6 * mass ** 2 / (1 - h ** 2), rel=1e-8)
    t = sol.times
    assert np.abs(sol.states[0] - (3 * t ** 2 - 2 * t ** 3)).max() < h ** 2   # the cubic, to O(h^2)
    # the velocity, the integral of that line, is the continuous one (scaled) at the nodes
    assert np.abs(sol.states[1] - (6 * t - 6 * t ** 2) / (1 - h ** 2)).max() < 1e-8
    assert np.abs(sol.value(ocp.params.m * ocp.state.v)[0, -1]) < 1e-8       # named parameters, at rest at the end


def test_a_model_is_checked_and_names_its_parts():
    model = double_integrator()
    ocp = OCP(model, N=2, T=1.0)
    assert set(vars(ocp.state)) == {"s", "v"} and set(vars(ocp.control)) == {"a"}
    assert ca.is_equal(ocp.params.vector, ocp.p)
    grouped = OCPModel("grouped", model.f, ("s", "v"), ("a",), ("m",), state_parts={"all": slice(0, 2)},
                       control_parts={"force": 0})
    ocp = OCP(grouped, N=2, T=1.0)
    assert ocp.state.all.numel() == 2 and ca.is_equal(ocp.control.force, ocp.u[0])
    for build, message in [
            (lambda: OCPModel("m", model.f, ("s",), ("a",), ("m",)), "sizes"),
            (lambda: OCPModel("m", model.f, ("s", "s"), ("a",), ("m",)), "repeat"),
            (lambda: OCPModel("m", model.f, ("s", "v"), ("a",), ("m",), state_parts={"v": 0}), "not the state"),
            (lambda: OCPModel("m", model.f, ("s", "v"), ("a",), ("m",), state_parts={"far": 2}), "index")]:
        with pytest.raises(ConfigError, match=message):
            build()


def test_old_paths_of_the_rollbot_model_and_limits_still_import():
    """``rollbot_oc.ocp.rollbot_model`` and ``rollbot_oc.ocp.constraints`` moved above the generic layer
    (``rollbot_oc.MOVED_NAMES``, ``MOVED``): the same objects through the old paths."""
    import rollbot_oc.planning.rollbot as rollbot
    from rollbot_oc.ocp import rollbot_model as old_model
    from rollbot_oc.ocp.constraints import robot_limits as old_limits

    assert old_model is rollbot.rollbot_model and old_limits is rollbot.robot_limits
    with pytest.raises(AttributeError, match="no attribute 'nothing'"):
        import rollbot_oc.ocp
        rollbot_oc.ocp.nothing
