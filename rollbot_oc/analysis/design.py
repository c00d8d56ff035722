"""The paper's hardware-design trade-off: range of revolving radius against recovery time.

Paper, section "Hardware Design": a larger ``r0``, ``m``, ``phi`` and ``k0``
make Rollbot recover faster from transients, while a smaller ``phi`` and
``m`` let the revolving radius change more with the driving speed; the
prototype balances the two.  ``design_point`` measures both for one
parameter set from the quasi-stable states and their linearised stability
over ``[0, max_speed]``; ``sweep`` varies one parameter.  Sweeps in two or
more dimensions are campaigns (``rollbot_oc.campaign``, kind ``design``);
``pareto_mask`` picks the designs no other beats in every objective and
``grid_trend`` counts how a metric moves along one axis of a grid.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from rollbot_oc.core.errors import ConfigError
from rollbot_oc.model.params import RollbotParams
from rollbot_oc.core.progress import progress_bar
from rollbot_oc.analysis.quasi_stable import quasi_stable_curve
from rollbot_oc.analysis.stability import stability_curve

__all__ = ["DesignPoint", "design_point", "sweep", "robot_record", "pareto_mask", "grid_trend", "SWEEPABLE"]

SWEEPABLE = ("phi", "m", "r0", "k0", "R", "I", "M_s")


@dataclass(frozen=True)
class DesignPoint:
    """Steering range and recovery of one design (SI units).

    Attributes
    ----------
    params : RollbotParams
    R0_min, R0_max : float
        Revolving radius at rest and at ``max_speed`` on the slow branch, m
        (``R0_max`` is NaN if the branch ends before ``max_speed``).
    reach : float
        Highest driving speed the slow branch reaches, rad/s.
    tau_max : float
        Worst (longest) recovery time over the driving speeds, s (inf if unstable).
    stable : bool
        Every quasi-stable state up to ``reach`` is stable.
    """

    params: RollbotParams
    R0_min: float
    R0_max: float
    reach: float
    tau_max: float
    stable: bool

    @property
    def radius_range(self) -> float:
        """``R0_max - R0_min``, m: how far the driving speed can move the revolving radius."""
        return self.R0_max - self.R0_min


def design_point(params: RollbotParams, speeds: int = 30) -> DesignPoint:
    """Steering range and worst recovery time of ``params`` over ``speeds`` driving speeds in ``[0, max_speed]``."""
    omegas = np.linspace(0.0, params.max_speed, speeds)
    states = quasi_stable_curve(omegas, params)
    good = [s for s in states[1:] if s.converged]
    reach = max((s.omega0 for s in good), default=0.0)
    contiguous = [s.omega0 for s in states[1:] if s.converged and s.omega0 <= reach]
    results = stability_curve(contiguous, params) if contiguous else []
    taus = [r.tau for r in results]
    R0_max = states[-1].R0 if states[-1].converged else math.nan
    return DesignPoint(params, states[0].R0, R0_max, reach, max(taus, default=math.inf),
                       bool(results) and all(r.stable for r in results))


def sweep(base: RollbotParams, field: str, values, speeds: int = 30,
          show_progress: bool | None = None) -> list[DesignPoint]:
    """``design_point`` for ``base`` with ``field`` (SI units, radians) set to each of ``values``.

    ``show_progress``: a progress bar (tqdm, on stderr; a widget in notebooks):
    True shows it, False hides it, None (default) shows it only where stderr
    is a terminal or in a notebook.

    Raises
    ------
    ConfigError
        If ``field`` is not one of ``SWEEPABLE`` or a value is invalid (the parameter check names it).
    """
    if field not in SWEEPABLE:
        raise ConfigError(f"sweep: field = {field!r}; valid are {', '.join(SWEEPABLE)}")
    points = []
    for value in progress_bar(values, show_progress, desc=f"sweeping {field}"):
        # derived defaults follow (the paper's k0 = 0.4 1/s M R^2 and M_max = r0 m g) unless base sets them
        points.append(design_point(base.with_changes(**{field: float(value)}), speeds))
    return points


def robot_record(params: RollbotParams, given=(), robot: str = "prototype") -> dict:
    """A robot at a glance: its parameters with units and sources, and what follows from them.

    Parameters
    ----------
    params : RollbotParams
    given : collection of str
        The TOML keys a parameter file set (``params.read_params_table``).
    robot : str
        What the robot is called (the file it came from).

    Returns
    -------
    dict
        ``robot``; ``params``: ``RollbotParams.described(given)`` (file
        units); ``derived``: records ``key``, ``value`` (SI), ``unit``,
        ``meaning``, ``source`` (``"derived"``) for the body and total mass and,
        from ``design_point``, the revolving radius at rest and at
        ``max_speed`` (None where the slow branch ends before it), the highest
        driving speed with a quasi-stable state, the worst recovery time and
        whether every state is stable.  Without damping (``k0 = 0``) these
        are None and each has a ``note``.
    """
    try:
        point = design_point(params)
        note = None
    except ConfigError as exc:  # k0 = 0: simulation and optimal control work, the quasi-stable analysis does not
        point, note = None, f"no quasi-stable analysis: {exc}"
    values = [
        ("M", params.M, "kg", "shell body mass M_s + m_b"),
        ("total_mass", params.total_mass, "kg", "whole robot M_s + m_b + m"),
        ("R0_min", point and point.R0_min, "m", "revolving radius at rest (R tan phi)"),
        ("R0_max", point and (None if math.isnan(point.R0_max) else point.R0_max), "m",
         "revolving radius at max_speed (slow branch)"),
        ("reach", point and point.reach, "rad/s", "highest driving speed with a quasi-stable state"),
        ("tau_max", point and point.tau_max, "s", "worst recovery time over the driving speeds"),
        ("stable", point and point.stable, "", "every quasi-stable state is stable"),
    ]
    derived = [{"key": key, "value": value, "unit": unit, "meaning": meaning, "source": "derived"}
               for key, value, unit, meaning in values]
    if note:
        for record in derived[2:]:
            record["note"] = note
    return {"robot": robot, "params": params.described(given), "derived": derived}


def pareto_mask(values, maximise) -> np.ndarray:
    """Which rows of ``values`` are Pareto-optimal: no other row is at least as good in every objective and
    better in one.

    Parameters
    ----------
    values : array_like (n, k)
        The objectives of ``n`` designs (rows with a NaN are never optimal).
    maximise : sequence of bool (k,)
        For each objective, True if more is better.

    Returns
    -------
    numpy.ndarray of bool (n,)
    """
    v = np.array(values, float, ndmin=2)
    v = np.where(np.asarray(maximise, bool), -v, v)  # every objective minimised
    finite = np.isfinite(v).all(axis=1)
    better_or_equal = (v[:, None, :] <= v[None, :, :]).all(axis=2)  # [i, j]: i at least as good as j everywhere
    strictly = (v[:, None, :] < v[None, :, :]).any(axis=2)
    dominated = (better_or_equal & strictly & finite[:, None]).any(axis=0)
    return finite & ~dominated


def grid_trend(table, axes, axis: str, metric: str) -> dict:
    """How ``metric`` moves as ``axis`` grows along every line of a grid (the other axes held).

    Parameters
    ----------
    table : pandas.DataFrame
        One row per grid point, with the grid's axes and the metric as columns
        (a design campaign's table; rows with a missing metric are left out).
    axes : sequence of str
        The grid's axes (columns).
    axis, metric : str
        The axis along which to step, and the metric (column names).

    Returns
    -------
    dict
        ``up``, ``down``, ``flat``: how many steps between neighbouring grid
        values of ``axis`` (same other axes) raise, lower or keep ``metric``
        (to 1e-9 relative); ``steps``: their total.
    """
    others = [c for c in axes if c != axis]
    data = table.dropna(subset=[metric])
    counts = {"up": 0, "down": 0, "flat": 0}
    for _, line in (data.groupby(others, sort=True) if others else [(None, data)]):
        y = line.sort_values(axis)[metric].to_numpy(float)
        step = np.diff(y)
        tolerance = 1e-9 * np.maximum(np.abs(y[1:]), np.abs(y[:-1]))
        counts["up"] += int((step > tolerance).sum())
        counts["down"] += int((step < -tolerance).sum())
        counts["flat"] += int((np.abs(step) <= tolerance).sum())
    return {**counts, "steps": sum(counts.values())}
