"""A grid of inputs: the values of each axis (a list, or ``{from, to, steps}``) and every combination of them.

Shared by the campaign kinds that sweep inputs (``function``, ``design``); every check raises a one-line
``ConfigError`` naming where the value is, the value and the valid form or range.
"""

from __future__ import annotations

import itertools
import math

import numpy as np

from rollbot_oc.core.errors import ConfigError
from rollbot_oc.missions.schema import check_keys, number

__all__ = ["grid_values", "grid_cases", "MAX_STEPS"]

MAX_STEPS = 10_000  # points of one grid axis


def grid_values(value, where: str, low: float = -math.inf, high: float = math.inf) -> list[float]:
    """The values of one grid axis: a non-empty list of numbers, or ``{from, to, steps}`` (evenly spaced).

    Raises
    ------
    ConfigError
        Naming ``where``, the value and the valid form or range.
    """
    if isinstance(value, dict):
        check_keys(value, {"from", "to", "steps"}, where)
        first = number(value, "from", where, low, high, required=True)
        last = number(value, "to", where, low, high, required=True)
        steps = number(value, "steps", where, 1, MAX_STEPS, integer=True, required=True)
        return [float(v) for v in np.linspace(first, last, steps)]
    if not (isinstance(value, list) and value):
        raise ConfigError(f"{where} = {value!r} must be a non-empty list of numbers or a table "
                          "{from = ..., to = ..., steps = ...}")
    for v in value:
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise ConfigError(f"{where}: value {v!r} must be a finite number")
        if not low <= v <= high:
            raise ConfigError(f"{where}: value {v!r} is out of range: valid is [{low:g}, {high:g}]")
    return [float(v) for v in value]


def grid_cases(grid: dict, where: str, check=None) -> list[dict]:
    """Every combination of a grid's axes (the first axis varies slowest), as input dicts.

    ``check(key, values, where)`` reads one axis (default ``grid_values`` without a range).
    """
    if not isinstance(grid, dict) or not grid:
        raise ConfigError(f"{where}: must be a table of at least one axis (key = [values] or "
                          "{from, to, steps})")
    axes = {key: (check or (lambda k, v, w: grid_values(v, w)))(key, value, f"{where} key '{key}'")
            for key, value in grid.items()}
    return [dict(zip(axes, combination)) for combination in itertools.product(*axes.values())]
