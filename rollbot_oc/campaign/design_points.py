"""Design-point cases: the steering range, the worst recovery time and the N-shape bound of one robot.

Spec table::

    [design]
    speeds        = 30          # driving speeds in [0, max_speed] of each analysis, in [3, 400]
    n_shape_bound = false       # also the minimum-time N-shape bound (an OCP: seconds per design)
    reference     = true        # also the base robot itself, as the first case (marked in the figures)
    [design.grid]               # the varied parameters (parameter-file keys, file units), every combination
    phi_deg = { from = 30, to = 60, steps = 7 }
    m       = [0.2, 0.25, 0.3, 0.35, 0.4, 0.45]
    [design.params]             # the base robot (parameter-file keys); default: the paper's prototype

Derived defaults follow the varied values (``k0 = 0.4 M R^2`` unless
``k0`` is varied or set, the torque limit ``r0 m g``), as in parameter
files.  Every grid point is validated on load.  A design *fails* (its row
says why) when its slow branch ends before the full driving speed, when a
quasi-stable state is unstable, or when its N-shape bound cannot be
planned; its measured values stay in the row.
"""

from __future__ import annotations

import math

from rollbot_oc.campaign.case import Outcome, register
from rollbot_oc.campaign.grid import grid_cases
from rollbot_oc.core.errors import ConfigError, NumericalFailure
from rollbot_oc.model.params import RollbotParams
from rollbot_oc.missions.schema import check_keys as _check_keys
from rollbot_oc.missions.schema import number as _number
from rollbot_oc.missions.schema import table as _table
from rollbot_oc.scenarios.problem import _check_damping
from rollbot_oc.analysis.design import design_point
from rollbot_oc.analysis.design import grid_trend
from rollbot_oc.analysis.design import pareto_mask
from rollbot_oc.campaign import figures
from rollbot_oc.core.outputs import json_ready
from rollbot_oc.scenarios.bounds import n_shape_bound

__all__ = ["DesignKind", "OBJECTIVES"]

# the trade-off: (metric, True if more is better)
OBJECTIVES = (("radius_range", True), ("tau_max", False), ("n_shape_bound", False))


@register
class DesignKind:
    """Design points over a grid of parameters (see the module doc).

    Parameters
    ----------
    base : RollbotParams
        The robot the grid varies.
    grid : list of dict
        The varied values of every case (parameter-file keys).
    speeds : int
        Driving speeds of each analysis.
    n_shape_bound : bool
        Also compute the minimum-time N-shape bound.
    reference : bool
        Also analyse ``base`` itself (the first case, ``reference`` true).
    """

    name = "design"
    group = None
    metric_columns = ("R0_min", "R0_max", "radius_range", "radius_ratio", "reach", "tau_max", "stable", "k0_used",
                      "max_torque_used", "n_shape_bound", "n_shape_legs")

    def __init__(self, base: RollbotParams, grid: list[dict], speeds: int = 30, n_shape_bound: bool = False,
                 reference: bool = True):
        self.base, self.grid, self.speeds = base, grid, speeds
        self.n_shape_bound, self.reference = n_shape_bound, reference
        self.axes = tuple(grid[0]) if grid else ()
        self.input_columns = self.axes + ("reference",)

    @classmethod
    def from_spec(cls, table: dict, source: str, seed: int = 0) -> "DesignKind":
        """The kind from its ``[design]`` table, every grid point checked (see the module doc)."""
        _check_keys(table, {"speeds", "n_shape_bound", "reference", "grid", "params"}, source)
        speeds = _number(table, "speeds", source, 3, 400, integer=True, default=30)
        flags = {}
        for key, default in (("n_shape_bound", False), ("reference", True)):
            flags[key] = table.get(key, default)
            if not isinstance(flags[key], bool):
                raise ConfigError(f"{source}: key '{key}' = {flags[key]!r} must be true or false")
        base = RollbotParams.from_file_dict(_table(table, "params", source), f"{source} [params]")
        valid = RollbotParams().to_file_dict()
        grid_table = table.get("grid")
        if not isinstance(grid_table, dict):
            raise ConfigError(f"{source}: missing required table [grid] (the varied parameters)")
        for key in grid_table:
            if key not in valid or key in ("slope_deg", "slope_dir_deg"):
                raise ConfigError(f"{source} [grid]: unknown key {key!r}; valid are parameter-file keys "
                                  f"{', '.join(k for k in valid if not k.startswith('slope'))}")
        grid = grid_cases(grid_table, f"{source} [grid]")
        kind = cls(base, grid, speeds, flags["n_shape_bound"], flags["reference"])
        for values in grid:  # every design valid before anything runs
            where = f"{source} [grid] point {values}"
            _check_damping(kind.params(values, where), where)
        return kind

    def params(self, values: dict, where: str = "design") -> RollbotParams:
        """The robot of a grid point: ``base`` with ``values`` (parameter-file keys), derived defaults following."""
        return RollbotParams.from_file_dict(values, where, base=self.base)

    def settings(self) -> dict:
        """The base robot (which defaults are derived included), the speeds and whether the bound is computed."""
        return {"base": self.base.to_file_dict(), "derived": sorted(self.base.derived), "speeds": self.speeds,
                "n_shape_bound": self.n_shape_bound}

    def case_inputs(self) -> list[dict]:
        """The base robot (if ``reference``), then every grid point."""
        reference = [{**{axis: self.base.to_file_dict()[axis] for axis in self.axes}, "reference": True}]
        return (reference if self.reference else []) + [{**values, "reference": False} for values in self.grid]

    def run(self, inputs: dict, seed: int) -> Outcome:
        """Analyse one design (and plan its N-shape bound if asked)."""

        values = {key: value for key, value in inputs.items() if key != "reference"}
        params = self.base if inputs["reference"] else self.params(values)
        point = design_point(params, self.speeds)
        metrics = {"R0_min": point.R0_min, "R0_max": point.R0_max, "radius_range": point.radius_range,
                   "radius_ratio": point.R0_max / point.R0_min, "reach": point.reach, "tau_max": point.tau_max,
                   "stable": point.stable, "k0_used": params.k0, "max_torque_used": params.max_torque,
                   "n_shape_bound": None, "n_shape_legs": None}
        causes = []
        if not math.isfinite(point.R0_max):
            causes.append(f"the slow branch ends at omega0 = {point.reach:.3f} rad/s, before max_speed = "
                          f"{params.max_speed:.3f} rad/s")
        if not point.stable:
            causes.append("a quasi-stable state is unstable")
        if self.n_shape_bound:
            try:
                bound = n_shape_bound(params)
                metrics.update(n_shape_bound=bound.total, n_shape_legs=list(bound.legs))
            except NumericalFailure as exc:
                causes.append(f"N-shape bound: {exc}")
        return Outcome(metrics, cause="; ".join(causes) or None)

    def summarise(self, table) -> dict:
        """The reference design, the Pareto front of the designs that succeeded (objectives ``OBJECTIVES``
        that were computed) and how each metric moves along each axis of the grid (``grid_trend``)."""

        shown = list(self.axes) + ["radius_range", "radius_ratio", "tau_max", "n_shape_bound"]
        reference = table[table["reference"] == True]  # noqa: E712 (a column of booleans)
        front = pareto_front(table)
        grid = table[table["reference"] == False]  # noqa: E712
        trends = {}
        for metric in ("radius_range", "radius_ratio", "tau_max", "n_shape_bound"):
            if grid[metric].notna().sum() > 1:
                trends[metric] = {axis: _trend_text(grid_trend(grid, self.axes, axis, metric)) for axis in self.axes}
        return {"reference": _records(reference[shown])[0] if len(reference) else None,
                "pareto_front": _records(front[shown + ["reference"]]), "trends": trends}

    def figures(self, table, folder) -> list:
        """A 2-D map of the metrics (for two varied axes) and the Pareto front, reference marked."""

        paths = [figures.plot_pareto(table, pareto_front(table), folder / "pareto.png")]
        if len(self.axes) == 2:
            paths.append(figures.plot_design_map(table, self.axes, [m for m, _ in OBJECTIVES],
                                                 folder / "design_map.png"))
        return paths


def objectives(table) -> list[tuple[str, bool]]:
    """The objectives of ``OBJECTIVES`` that the table has values of."""
    return [(metric, more) for metric, more in OBJECTIVES if table[metric].notna().any()]


def pareto_front(table):
    """The rows of the designs that succeeded and that no other beats in every objective, by radius range."""

    ok = table[table["status"] == "succeeded"]
    chosen = objectives(ok) if len(ok) else []
    if not chosen:
        return ok
    mask = pareto_mask(ok[[m for m, _ in chosen]].to_numpy(float), [more for _, more in chosen])
    return ok[mask].sort_values("radius_range")


def _trend_text(trend: dict) -> str:
    return f"up {trend['up']}, down {trend['down']}, flat {trend['flat']} of {trend['steps']} steps"


def _records(frame) -> list[dict]:
    """Rows as plain dicts (NaN as None)."""

    return json_ready([{k: (v.item() if hasattr(v, "item") else v) for k, v in row.items()}
                       for row in frame.to_dict("records")])
