"""Checks shared by the scenario schema and the mission tables: numbers, point lists, tables, keys.

Every check raises a one-line ``ConfigError`` naming the file (``source``),
the key, its value and the valid range.
"""

from __future__ import annotations

import math
import re

import numpy as np

from rollbot_oc.core.errors import ConfigError

__all__ = ["NAME_PATTERN", "POSITION_LIMIT", "number", "points", "point", "table", "check_keys"]

NAME_PATTERN = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_-]{0,63}")  # a scenario or campaign name, also a file stem
POSITION_LIMIT = 1e4  # m: largest coordinate of a start, centre, stop or gate


def number(data, key, source, low=None, high=None, integer=False, required=False, default=None):
    """``data[key]`` as a finite number in ``[low, high]`` (``default`` if absent and not ``required``)."""
    if key not in data:
        if required:
            raise ConfigError(f"{source}: missing required key '{key}'")
        return default
    value = data[key]
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ConfigError(f"{source}: key '{key}' = {value!r} must be a finite number")
    if integer and int(value) != value:
        raise ConfigError(f"{source}: key '{key}' = {value!r} must be a whole number")
    if (low is not None and value < low) or (high is not None and value > high):
        raise ConfigError(f"{source}: key '{key}' = {value!r} is out of range: valid is [{low}, {high}]")
    return int(value) if integer else float(value)


def points(data, key, source, count=None) -> list[np.ndarray]:
    """``data[key]`` as a non-empty list of ``[x, y]`` points (m), each coordinate within ``POSITION_LIMIT``."""
    value = data.get(key)
    ok = isinstance(value, list) and value and all(
        isinstance(p, list) and len(p) == 2
        and all(isinstance(c, (int, float)) and not isinstance(c, bool) and math.isfinite(c)
                and abs(c) <= POSITION_LIMIT for c in p)
        for p in value)
    if not ok or (count is not None and len(value) != count):
        raise ConfigError(f"{source}: key '{key}' = {value!r} must be a list of [x, y] pairs in m, "
                          f"coordinates in [-{POSITION_LIMIT:g}, {POSITION_LIMIT:g}]")
    return [np.array(p, float) for p in value]


def point(data, key, source, default=(0.0, 0.0), label="p") -> np.ndarray:
    """One ``[x, y]`` point (m) at ``data[key]`` (``default`` if absent); the message names ``source key``
    and the point as key ``label``."""
    return points({label: [data.get(key, list(default))]}, label, f"{source} {key}")[0]


def table(data: dict, key: str, source: str) -> dict:
    """The sub-table ``[key]`` (empty if absent)."""
    value = data.get(key, {})
    if not isinstance(value, dict):
        raise ConfigError(f"{source}: '{key}' = {value!r} must be a table ([{key}])")
    return value


def check_keys(data: dict, allowed, source: str):
    """Refuse keys of ``data`` not in ``allowed``, listing the valid ones."""
    unknown = sorted(set(data) - set(allowed))
    if unknown:
        raise ConfigError(f"{source}: unknown key(s) {', '.join(unknown)}; valid keys are {', '.join(sorted(allowed))}")
