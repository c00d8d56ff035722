"""The result of an optimal-control solve: named status, iterations, timing, and the trajectory."""

from __future__ import annotations

from dataclasses import dataclass, field

import casadi as ca
import numpy as np

from rollbot_oc.core.errors import NotConverged

__all__ = ["OCPSolution"]


@dataclass
class OCPSolution:
    """What a route returns (SI units).

    Attributes
    ----------
    route : str
        The route that solved it (``"ipopt"``, ``"sqp"``, ``"rti"``, ``"fatrop"``).
    status : str
        The solver's named status.
    success : bool
        Converged (``status`` says how).
    iterations : int
    solve_time : float
        Wall-clock time of the solve, s (the SQP and RTI routes: the whole call, parameters and bounds
        included; IPOPT and fatrop: the solver's call).
    cost : float
        Objective value (RTI: where its step was linearised, before the step).
    w : numpy.ndarray
        Decision vector (``Transcription.layout`` says where what is).
    lam_w, lam_g : numpy.ndarray
        Multipliers of the bounds and of the constraints.
    parameters : numpy.ndarray
        The parameter vector it was solved for.
    """

    route: str
    status: str
    success: bool
    iterations: int
    solve_time: float
    cost: float
    w: np.ndarray
    lam_w: np.ndarray
    lam_g: np.ndarray
    parameters: np.ndarray
    transcription: object = field(repr=False)

    @property
    def states(self) -> np.ndarray:
        """States at the nodes (nx, N+1)."""
        return self.transcription.layout.states(self.w)

    @property
    def controls(self) -> np.ndarray:
        """Controls on the intervals (nu, N)."""
        return self.transcription.layout.controls(self.w)

    @property
    def durations(self) -> np.ndarray:
        """Phase durations, s."""
        return self.transcription.durations_of(self.w)

    @property
    def T(self) -> float:
        """Total duration, s."""
        return float(self.durations.sum())

    @property
    def times(self) -> np.ndarray:
        """Node times (N+1,), s from 0."""
        steps = np.concatenate([np.full(n, d / n) for n, d in zip(self.transcription.layout.N, self.durations)])
        return np.concatenate([[0.0], np.cumsum(steps)])

    def variable(self, name: str) -> np.ndarray:
        """A global decision variable's value."""
        return self.w[self.transcription.layout.variables[name]]

    def value(self, expr, at: str = "nodes") -> np.ndarray:
        """An SX expression of the OCP's stage symbols evaluated along the solution.

        ``at="nodes"`` evaluates at every node (the last with the control held
        at zero), ``"intervals"`` on every interval (with its control).
        """
        tr = self.transcription
        ocp, L = tr.ocp, tr.layout
        qs = ca.vertcat(*ocp.parameters.values()) if ocp.parameters else ca.SX(0, 1)
        sqs = ca.vertcat(*ocp.stage_parameters.values()) if ocp.stage_parameters else ca.SX(0, 1)
        vs = ca.vertcat(*[s for s, *_ in ocp.variables.values()]) if ocp.variables else ca.SX(0, 1)
        fun = ca.Function("value", [ocp.x, ocp.u, ocp.p, qs, sqs, vs], [ca.SX(expr)])
        X, U = self.states, self.controls
        par = self.parameters
        SQ = np.asarray(par[L.stage_block]).reshape(L.intervals + 1, L.n_stage).T
        if at == "nodes":
            U = np.hstack([U, np.zeros((L.nu, 1))])
        elif at == "intervals":
            X, SQ = X[:, :-1], SQ[:, :-1]
        else:
            raise ValueError(f"at = {at!r}; valid are 'nodes', 'intervals'")
        q = np.concatenate([par[L.parameters[name]] for name in ocp.parameters]) if ocp.parameters else np.zeros(0)
        v = np.concatenate([self.variable(name) for name in ocp.variables]) if ocp.variables else np.zeros(0)
        out = fun.map(X.shape[1])(X, U, par[L.parameters["p"]], q, SQ, v)
        return np.array(out)

    def check(self) -> "OCPSolution":
        """Return self if it converged, else raise ``NotConverged`` carrying the status and this solution."""
        if not self.success:
            raise NotConverged(f"{self.route} solve", self.status, self)
        return self

    def summary(self) -> dict:
        """Status, iterations, timing and durations, for JSON."""
        return {"route": self.route, "status": self.status, "success": self.success,
                "iterations": self.iterations, "solve_time": self.solve_time, "cost": self.cost,
                "durations": self.durations.tolist()}
