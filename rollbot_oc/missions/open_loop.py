"""Kind ``open_loop``: constant driving speeds, each measured in simulation against the quasi-stable theory.

Table::

    [open_loop]
    speeds    = [0.5, 1.0, 3.0]      # rad/s
    ramp_rate = 0.5                  # rad/s^2

No controller runs it (``closed_loop`` is False): ``run`` is its whole run.
"""

from __future__ import annotations

from dataclasses import dataclass

from rollbot_oc.core.errors import ConfigError, NumericalFailure
from rollbot_oc.missions.base import Mission, register
from rollbot_oc.missions.schema import number
from rollbot_oc.analysis.experiments import OpenLoopMeasurement, check_open_loop, open_loop_run
from rollbot_oc.analysis.quasi_stable import quasi_stable_curve
from rollbot_oc.core.progress import progress_bar

__all__ = ["OpenLoop"]


@register
@dataclass(frozen=True)
class OpenLoop(Mission):
    """Drive at each speed in turn from rest and measure the steady revolving motion.

    Attributes
    ----------
    speeds : tuple of float
        Driving speeds, rad/s.
    ramp_rate : float
        Driving-speed ramp from rest, rad/s^2.
    """

    kind = "open_loop"
    keys = frozenset({"speeds", "ramp_rate"})
    closed_loop = False

    speeds: tuple
    ramp_rate: float = 0.5

    @classmethod
    def from_table(cls, table, where, params, duration):
        speeds = table.get("speeds")
        if not (isinstance(speeds, list) and speeds):
            raise ConfigError(f"{where}: key 'speeds' = {speeds!r} must be a non-empty list of driving speeds "
                              "in rad/s")
        speeds = tuple(number({"s": s}, "s", f"{where} speeds", 1e-3, params.max_speed) for s in speeds)
        return cls(speeds, number(table, "ramp_rate", where, 1e-3, 100.0, default=0.5))

    def to_table(self) -> dict:
        return {"speeds": list(self.speeds), "ramp_rate": float(self.ramp_rate)}

    def run(self, problem, show_progress: bool | None = None) -> dict:
        """Each driving speed measured in simulation against the quasi-stable theory (``problem.run_open_loop``).

        Returns
        -------
        dict
            ``runs``: for each speed the measured ``R0``, ``Omega``, ``xi`` and
            ``settled``, the theory's values (``*_theory``) and the relative errors
            ``R0_error`` and ``Omega_error``; ``max_R0_error`` over all speeds.
            A speed whose run left the no-slip model has nulls and an ``error``
            (and ``completed`` is False).
        """

        for speed in self.speeds:
            check_open_loop(speed, problem.params, ramp_rate=self.ramp_rate)
        theory = quasi_stable_curve(self.speeds, problem.params.replace(slope=0.0))
        runs = []
        for speed, qs in progress_bar(list(zip(self.speeds, theory)), show_progress, desc=f"{problem.name}",
                                      unit="speed"):
            try:
                measured, _ = open_loop_run(speed, problem.params, ramp_rate=self.ramp_rate, dt=problem.dt)
            except NumericalFailure as exc:
                runs.append({**OpenLoopMeasurement.failed_dict(speed, str(exc)), "R0_theory": qs.R0,
                             "Omega_theory": qs.Omega, "xi_theory": qs.xi, "R0_error": None, "Omega_error": None,
                             "xi_error": None})
                continue
            row = measured.to_dict()
            row.update(R0_theory=qs.R0, Omega_theory=qs.Omega, xi_theory=qs.xi,
                       R0_error=measured.R0 / qs.R0 - 1.0, Omega_error=measured.Omega / qs.Omega - 1.0,
                       xi_error=measured.xi - qs.xi)
            runs.append(row)
        errors = [abs(r["R0_error"]) for r in runs if r["R0_error"] is not None]
        return {"problem": problem.name, "runs": runs, "max_R0_error": max(errors) if errors else None,
                "completed": all(r["settled"] for r in runs)}
