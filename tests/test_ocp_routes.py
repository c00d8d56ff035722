"""The routes agree: one fixed-time OCP, solved by IPOPT (exact and limited-memory Hessian), Gauss-Newton SQP and
fatrop, has one solution; an RTI step from it stays there; a failed solve says so.

The problem is a minimum-energy leg of Rollbot from rest to rest on a goal 0.4 m ahead in a fixed 5.2 s, with a
least-squares effort cost (so Gauss-Newton is exact in the cost) and every named limit, on 12 intervals: fixed
durations and no global variables, so fatrop applies too.  Every route starts from the same quasi-stable guess
and is asked for a tolerance of 1e-10 (IPOPT's and fatrop's default 1e-8 leaves the limited-memory IPOPT 4e-6
away from the exact one, too near the 1e-5 this file asks for).
"""

import casadi as ca
import numpy as np
import pytest

from rollbot_oc.planning.min_time import quasi_stable_guess
from rollbot_oc.model.dynamics import rest_state, to_reduced
from rollbot_oc.core.errors import NotConverged
from rollbot_oc.model.params import RollbotParams

from legs import leg_problem

PARAMS = RollbotParams()
GOAL = np.array([0.0, 0.4])  # m
T, N = 5.2, 12               # s, intervals
TOL = 1e-10                  # every route's convergence tolerance
HAS_FATROP = ca.has_nlpsol("fatrop")

ROUTES = {  # label -> (route, options)
    "ipopt-limited-memory": ("ipopt", dict(hessian="limited-memory", tol=TOL)),
    "sqp": ("sqp", dict(tol=TOL)),
    "fatrop": ("fatrop", dict(tol=TOL)),
}


@pytest.fixture(scope="module")
def leg():
    """The problem, its parameters, the shared guess and IPOPT's (exact Hessian) solution."""
    ocp = leg_problem(N, T)  # minimum effort in a fixed time
    ipopt = ocp.solver("ipopt", tol=TOL)
    z0 = to_reduced(rest_state(PARAMS))
    guess = quasi_stable_guess(z0, GOAL, PARAMS, N)  # states and accelerations of a simulated quasi-stable leg
    w0 = ipopt.transcription.layout.pack(guess.z, guess.u[None, :])
    parameters = dict(x0=z0, goal=GOAL, p=PARAMS.vector())
    return ocp, parameters, w0, ipopt.solve(w0, **parameters)


@pytest.fixture(scope="module")
def solutions(leg):
    """Every other route's solution from the same guess (fatrop only where CasADi has its plugin)."""
    ocp, parameters, w0, _ = leg
    return {label: ocp.solver(route, **options).attempt(w0, **parameters)
            for label, (route, options) in ROUTES.items() if route != "fatrop" or HAS_FATROP}


def _route(label):
    if label == "fatrop" and not HAS_FATROP:
        pytest.skip("this CasADi has no fatrop plugin (casadi.has_nlpsol('fatrop') is False)")
    return label


def test_ipopt_solves_the_leg(leg):
    _, _, _, reference = leg
    assert reference.success and reference.status == "Solve_Succeeded"
    assert reference.iterations > 0 and reference.solve_time > 0
    assert np.abs(reference.states[0:2, -1] - GOAL).max() < 1e-8
    assert reference.T == pytest.approx(T)


@pytest.mark.parametrize("label", ROUTES)
def test_route_agrees_with_ipopt(leg, solutions, label):
    """Cost to 1e-6 relative, states and controls to 1e-5 absolute (SI units: m, rad, rad/s, rad/s^2).

    Measured: cost within 1e-14 relative for every route; states and controls within 7e-9 (limited-memory
    IPOPT), 3e-7 (SQP, whose Gauss-Newton steps converge only linearly) and 1e-14 (fatrop).
    """
    _, _, _, reference = leg
    solution = solutions[_route(label)]
    assert solution.success, solution.status
    assert isinstance(solution.status, str) and not solution.status.isdigit()  # a name, not a bare code
    assert solution.iterations > 0 and solution.solve_time > 0
    assert abs(solution.cost - reference.cost) <= 1e-6 * abs(reference.cost)
    assert np.abs(solution.states - reference.states).max() < 1e-5
    assert np.abs(solution.controls - reference.controls).max() < 1e-5


def test_an_rti_step_from_ipopts_solution_stays_there(leg):
    """One Gauss-Newton step from IPOPT's converged solution moves it by less than 1e-8 (measured 2e-10).

    The step starts from IPOPT's multipliers reduced to the active constraints (an interior point's small
    multipliers on inactive rows would make the active-set QP's first KKT system singular).
    """
    ocp, parameters, _, reference = leg
    step = ocp.solver("rti").attempt(warm=reference, **parameters)
    assert step.success and step.status == "success" and step.iterations == 1  # the QP's status
    assert np.abs(step.w - reference.w).max() < 1e-8


@pytest.mark.parametrize("route", ["ipopt", "sqp", "fatrop"])
def test_a_failed_solve_is_reported_not_returned(leg, route):
    """One iteration from rest everywhere (far from the leg) does not converge: ``attempt`` says so with the
    solver's status, and ``solve`` raises ``NotConverged`` carrying that status and the failed solution."""
    ocp, parameters, _, _ = leg
    _route(route)
    solver = ocp.solver(route, max_iter=1)
    z0 = parameters["x0"]
    at_rest_guess = solver.transcription.layout.pack(np.tile(z0[:, None], (1, N + 1)), np.zeros((1, N)))
    failed = solver.attempt(at_rest_guess, **parameters)
    assert not failed.success and failed.status and failed.iterations >= 1
    assert failed.status not in ("Solve_Succeeded", "Success", "converged")
    with pytest.raises(NotConverged) as raised:
        solver.solve(at_rest_guess, **parameters)
    assert raised.value.status == failed.status and raised.value.result.success is False
