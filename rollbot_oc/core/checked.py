"""Frozen settings groups whose every field is checked when the group is built.

A group is a frozen dataclass deriving from ``Checked`` whose fields are made by the functions here
(``number``, ``choice``, ``flag``, ``numbers``, ``names``, ``functions``, ``typed``): each keeps its check in
the field's metadata, and ``Checked.__post_init__`` runs them all.  A value of the wrong kind or out of range
raises ``ConfigError`` (a ``ValueError``) in one line naming the owner, the group and field, the value and
the valid range: ``NMPC horizon.N = 1 is out of range: valid is whole numbers in [2, 400]``.
"""

from __future__ import annotations

import math
from dataclasses import field, fields

from rollbot_oc.core.errors import ConfigError

__all__ = ["Checked", "number", "choice", "flag", "numbers", "names", "functions", "typed", "out_of_range"]


def out_of_range(owner: str, name: str, value, valid: str) -> ConfigError:
    """The one-line error of ``owner``'s field ``name`` holding ``value``, where ``valid`` is what it may hold."""
    return ConfigError(f"{owner} {name} = {value!r} is out of range: valid is {valid}")


def _interval(low, high, open_low, open_high) -> str:
    left = "(" if open_low or low == -math.inf else "["
    right = ")" if open_high or high == math.inf else "]"
    return f"{left}{low:g}, {high:g}{right}"


def number(default, low=-math.inf, high=math.inf, *, open_low=False, open_high=False, integer=False,
           optional=False):
    """A field holding a number in ``[low, high]`` (ends open as asked; whole numbers only if ``integer``;
    ``None`` too if ``optional``); a bool is no number."""
    def check(owner, name, value):
        if value is None and optional:
            return value
        kind = int if integer else (int, float)
        if isinstance(value, bool) or not isinstance(value, kind) or not math.isfinite(value) \
                or value < low or value > high or (open_low and value == low) or (open_high and value == high):
            valid = ("whole numbers in " if integer else "") + _interval(low, high, open_low, open_high)
            raise out_of_range(owner, name, value, valid + (" or None" if optional else ""))
        return value
    return field(default=default, metadata={"check": check})


def choice(default, *valid):
    """A field holding one of ``valid``."""
    def check(owner, name, value):
        if not any(value is v or (type(value) is type(v) and value == v) for v in valid):
            raise out_of_range(owner, name, value, "one of " + ", ".join(map(repr, valid)))
        return value
    return field(default=default, metadata={"check": check})


def flag(default: bool):
    """A field holding True or False."""
    def check(owner, name, value):
        if not isinstance(value, bool):
            raise out_of_range(owner, name, value, "True or False")
        return value
    return field(default=default, metadata={"check": check})


def _sequence(value):
    try:
        return None if isinstance(value, str) else tuple(value)
    except TypeError:
        return None


def numbers(default, low=0.0, high=math.inf, *, open_low=True):
    """A field holding a non-empty tuple of numbers in ``(low, high]`` (``[low`` if not ``open_low``)."""
    def check(owner, name, value):
        seq = _sequence(value)
        ok = bool(seq) and all(not isinstance(v, bool) and isinstance(v, (int, float)) and math.isfinite(v)
                               and (v > low if open_low else v >= low) and v <= high for v in seq)
        if not ok:
            raise out_of_range(owner, name, value, "a non-empty sequence of numbers in "
                               + _interval(low, high, open_low, False))
        return seq
    return field(default=default, metadata={"check": check})


def names(default, valid):
    """A field holding a tuple of names among ``valid``."""
    def check(owner, name, value):
        seq = _sequence(value)
        if seq is None or not all(v in valid for v in seq):
            raise out_of_range(owner, name, value, f"names among {', '.join(valid)}")
        return seq
    return field(default=default, metadata={"check": check})


def functions(default):
    """A field holding a tuple of functions."""
    def check(owner, name, value):
        seq = _sequence(value)
        if seq is None or not all(callable(v) for v in seq):
            raise out_of_range(owner, name, value, "a sequence of functions")
        return seq
    return field(default=default, metadata={"check": check})


def typed(factory, cls):
    """A field holding an instance of ``cls`` (``factory()`` by default)."""
    def check(owner, name, value):
        if not isinstance(value, cls):
            raise out_of_range(owner, name, value, f"a {cls.__name__}")
        return value
    return field(default_factory=factory, metadata={"check": check})


class Checked:
    """Runs the check of every field (``metadata["check"]``) when a frozen dataclass deriving from it is built.

    Class attributes ``owner`` (who the settings are for, e.g. ``"NMPC"``) and ``group`` (the group's name)
    begin each error message.
    """

    owner = ""
    group = ""

    def __post_init__(self):
        for f in fields(self):
            check = f.metadata.get("check")
            if check is not None:
                where = f"{self.group}.{f.name}" if self.group else f.name
                object.__setattr__(self, f.name, check(self.owner, where, getattr(self, f.name)))
