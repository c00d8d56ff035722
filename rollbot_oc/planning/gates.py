"""The NMPC's plan through gates: minimum time from a state through each gate in order, without stopping.

Written on the optimal-control layer (``rollbot_oc.ocp``): one phase per gate,
each of free duration and ``GATE_INTERVALS`` shooting intervals, the shell
centre on gate i at the end of phase i, the motor's torque, speed and
acceleration limits and the contact margins of ``OCPSettings`` on the path,
the total time plus a little motor effort minimised.  Solved by IPOPT from a
physical guess: the quasi-stable guesses (``planning.guesses.quasi_stable_guess``)
of rest-to-rest legs from gate to gate, chained; the solver then keeps the
momentum through each gate that the guess loses at it.
"""

from __future__ import annotations

import functools

import numpy as np

from rollbot_oc.planning.min_time import OCPSettings, Plan, SolveFailed, quasi_stable_guess
from rollbot_oc.ocp import FreeTime
from rollbot_oc.planning.rollbot import robot_limits, rollbot_ocp
from rollbot_oc.model.params import TILT, RollbotParams

__all__ = ["GatePlan", "plan_gates", "GATE_INTERVALS"]

GATE_INTERVALS = 20  # shooting intervals per gate (phase)
EFFORT = 1e-2  # weight of the squared motor acceleration, scaled by its limit, integrated over time (s)


class GatePlan(Plan):
    """A ``Plan`` whose intervals differ in length from phase to phase (one phase per gate)."""

    def accel(self, t: float) -> float:
        """Planned motor acceleration at time ``t`` (s), rad/s^2; 0 after the end."""
        if t >= self.T or t < 0:
            return 0.0
        k = int(np.searchsorted(self.t, t + 1e-9, side="right")) - 1
        return float(self.u[min(max(k, 0), len(self.u) - 1)])


@functools.lru_cache(maxsize=8)
def _gate_route(count: int, settings: OCPSettings, constraints: tuple = ()):
    """The ipopt route of the problem through ``count`` gates (built once per count, settings and extra
    constraints, functions of the ``OCP`` as ``NMPCSettings.constraints``)."""
    s = settings
    ocp = rollbot_ocp(N=[GATE_INTERVALS] * count, T=[FreeTime(guess=2.0, lower=0.1, upper=s.T_max)] * count,
                      substeps=s.substeps)
    x, u = ocp.state, ocp.control
    ocp.initial_state()
    gates = ocp.parameter("gates", 2 * count)
    ocp.minimize_time()
    ocp.add_least_squares(u.accel / ocp.params.max_accel, weight=EFFORT)
    ocp.subject_to(*robot_limits(ocp, s.torque_margin, s.normal_margin, s.friction_margin, s.speed_margin,
                                 s.accel_margin, constraints))
    for i in range(count):
        ocp.subject_to(x.position == gates[2 * i:2 * i + 2], at=("end", i), name=f"gate {i + 1}")
    return ocp.solver("ipopt", hessian=s.hessian, max_iter=s.max_iter, tol=1e-6)


def _guess(z0, gates, params: RollbotParams):
    """Chained quasi-stable rest-to-rest legs through the gates: states (10, n+1), accelerations (n,), durations."""
    states, accels, durations, z = [], [], [], np.asarray(z0, float)
    for gate in gates:
        leg = quasi_stable_guess(z, np.asarray(gate, float), params, GATE_INTERVALS)
        states.append(leg.z[:, :-1])
        accels.append(leg.u)
        durations.append(leg.T)
        z = leg.z[:, -1]
    return np.hstack(states + [z[:, None]]), np.concatenate(accels), durations


def plan_gates(z0, gates, params: RollbotParams, settings: OCPSettings | None = None, tilt=None,
               constraints: tuple = ()) -> GatePlan:
    """The minimum-time plan from the reduced state ``z0`` (10,) through ``gates`` (m) in order.

    ``params`` is the robot the plan believes in; ``tilt`` (2,), the floor's
    tilt vector (in-plane gravity per g), replaces its slope.  The
    plan's ``extra`` holds the ``gates`` and the planned ``gate_times`` (s).

    Raises
    ------
    SolveFailed
        If IPOPT does not converge.
    """
    settings = settings or OCPSettings()
    gates = [np.asarray(g, float) for g in gates]
    route = _gate_route(len(gates), settings, tuple(constraints))
    states, accels, durations = _guess(z0, gates, params.replace(slope=0.0))
    w0 = route.transcription.layout.pack(states, accels[None, :], durations)
    p = params.vector()
    if tilt is not None:
        p[TILT] = tilt
    sol = route.attempt(w0, x0=np.asarray(z0, float), gates=np.concatenate(gates), p=p)
    times = sol.times
    plan = GatePlan(times, sol.states, sol.controls[0], float(times[-1]), sol.status, sol.success, sol.iterations,
                    sol.solve_time, {"gates": [g.tolist() for g in gates],
                                     "gate_times": np.cumsum(sol.durations).tolist()})
    if not sol.success:
        raise SolveFailed(f"plan through {len(gates)} gates", sol.status, plan)
    return plan
