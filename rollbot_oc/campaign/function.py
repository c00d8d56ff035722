"""User-function cases: any function of plain inputs that returns its metrics.

Spec table::

    [function]
    target = "mypackage.study:evaluate"     # module:function, importable where the workers run
    [function.grid]                          # every combination of these inputs ...
    x = { from = 0.0, to = 1.0, steps = 11 }
    # ... or an explicit list of cases instead of a grid:
    # cases = [{ x = 0.1, label = "a" }, { x = 0.2, label = "b" }]

The function is called as ``function(**inputs)``, with ``seed=`` (the
case's own seed) as well if it takes a ``seed`` argument.  It returns a
mapping of metric names to plain values (numbers, strings, booleans, None,
lists of numbers), or a single number (the metric ``value``).  A mapping
with a ``failure`` entry that is not None makes the case *failed* with that
cause; an exception makes it an *error* row.  From Python, any picklable
function works (``Campaign.of_function``).
"""

from __future__ import annotations

import importlib
import inspect
import math
from collections.abc import Mapping

import numpy as np

from rollbot_oc.campaign.case import Outcome, register
from rollbot_oc.campaign.grid import grid_cases
from rollbot_oc.core.errors import ConfigError
from rollbot_oc.missions.schema import check_keys as _check_keys
from rollbot_oc.campaign import figures

__all__ = ["FunctionKind", "plain", "resolve_target"]


def plain(value, name: str = "value"):
    """``value`` as a plain value for a results table (numpy scalars and arrays become Python ones).

    Raises
    ------
    TypeError
        If it is none of: None, bool, int, float, str, or a flat list of numbers.
    """
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, np.ndarray):
        value = value.tolist()
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    if isinstance(value, (list, tuple)) and all(isinstance(v, (int, float, np.number)) and not isinstance(v, bool)
                                                for v in value):
        return [float(v) for v in value]
    raise TypeError(f"metric {name!r} = {value!r} is not a plain value (number, string, boolean, None or a "
                    "list of numbers)")


def resolve_target(target, where: str = "function"):
    """The function a ``"module:qualified.name"`` string names.

    Raises
    ------
    ConfigError
        If the text has the wrong form, the module cannot be imported or the name is not a callable in it.
    """
    if not (isinstance(target, str) and target.count(":") == 1 and all(target.split(":"))):
        raise ConfigError(f"{where}: key 'target' = {target!r} must be 'module:function'")
    module_name, qualname = target.split(":")
    try:
        obj = importlib.import_module(module_name)
    except ImportError as exc:
        raise ConfigError(f"{where}: key 'target' = {target!r}: cannot import {module_name} ({exc})") from None
    for part in qualname.split("."):
        obj = getattr(obj, part, None)
    if not callable(obj):
        raise ConfigError(f"{where}: key 'target' = {target!r}: {qualname} is not a function of {module_name}")
    return obj


@register
class FunctionKind:
    """Cases that call a user function (see the module doc).

    Parameters
    ----------
    function : callable
        Called with each case's inputs.
    cases : list of dict
        The inputs of every case.
    """

    name = "function"
    group = None
    metric_columns = ()

    def __init__(self, function, cases: list[dict]):
        self.function, self.cases = function, cases
        self.input_columns = tuple(dict.fromkeys(key for case in cases for key in case))
        self.target = f"{getattr(function, '__module__', '?')}:{getattr(function, '__qualname__', repr(function))}"
        try:
            parameters = inspect.signature(function).parameters
        except (TypeError, ValueError):  # a builtin without a signature
            parameters = {}
        self.takes_seed = "seed" in parameters or any(p.kind is p.VAR_KEYWORD for p in parameters.values())

    @classmethod
    def from_spec(cls, table: dict, source: str, seed: int = 0) -> "FunctionKind":
        """The kind from its ``[function]`` table (see the module doc)."""
        _check_keys(table, {"target", "grid", "cases"}, source)
        function = resolve_target(table.get("target"), source)
        if ("grid" in table) == ("cases" in table):
            raise ConfigError(f"{source}: give either a [grid] table or a 'cases' list, not both or neither")
        if "grid" in table:
            return cls(function, grid_cases(table["grid"], f"{source} [grid]"))
        cases = table["cases"]
        if not (isinstance(cases, list) and cases and all(isinstance(c, dict) for c in cases)):
            raise ConfigError(f"{source}: key 'cases' = {cases!r} must be a non-empty list of tables of inputs")
        for number, case in enumerate(cases):
            for key, value in case.items():
                try:
                    plain(value, key)
                except TypeError:
                    raise ConfigError(f"{source}: cases[{number}] key '{key}' = {value!r} must be a number, string "
                                      "or boolean") from None
                if isinstance(value, float) and not math.isfinite(value):
                    raise ConfigError(f"{source}: cases[{number}] key '{key}' = {value!r} must be finite")
        return cls(function, cases)

    def settings(self) -> dict:
        """The function's name (``module:qualified.name``)."""
        return {"target": self.target}

    def case_inputs(self) -> list[dict]:
        """The given cases."""
        return [dict(case) for case in self.cases]

    def run(self, inputs: dict, seed: int) -> Outcome:
        """Call the function and read its metrics (and ``failure``)."""
        result = self.function(**inputs, **({"seed": seed} if self.takes_seed else {}))
        if not isinstance(result, Mapping):
            return Outcome({"value": plain(result)})
        metrics = {str(key): plain(value, str(key)) for key, value in result.items() if key != "failure"}
        failure = result.get("failure")
        return Outcome(metrics, cause=None if failure is None else str(failure))

    def summarise(self, table) -> dict:
        """Nothing beyond the campaign's counts."""
        return {}

    def figures(self, table, folder) -> list:
        """Success rate against each varied input."""

        return [figures.plot_success_rates(table, self.input_columns, None, folder / "success_rates.png")]
