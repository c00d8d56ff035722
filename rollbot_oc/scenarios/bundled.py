"""The bundled scenario files: the paper's experiments, shipped with the package.

The files live in the source tree's top-level ``problems/`` folder; the build
maps that folder into the package as ``rollbot_oc.problems_data`` (see
``pyproject.toml``), so an installed copy (wheel or editable) reads them
through ``importlib.resources``.  A source checkout that is used without
being installed reads the ``problems/`` folder beside the package.
"""

from __future__ import annotations

import importlib.resources
import tomllib
from pathlib import Path

from rollbot_oc.core.errors import ConfigError
from rollbot_oc.core.outputs import user_path
from rollbot_oc.missions.schema import NAME_PATTERN

__all__ = ["bundled_names", "bundled_text", "bundled_table", "list_bundled", "load_bundled", "load_scenario",
           "file_or_bundled", "NAME_PATTERN"]

PACKAGE = "rollbot_oc.problems_data"


def _folder():
    """The folder of the bundled ``*.toml`` files (a ``Traversable``)."""
    try:
        return importlib.resources.files(PACKAGE)
    except ModuleNotFoundError:  # a source checkout on sys.path, not installed
        checkout = Path(__file__).resolve().parents[2] / "problems"
        if checkout.is_dir():
            return checkout
        raise ConfigError("the bundled scenarios are missing from this installation of rollbot_oc: "
                          "reinstall it") from None


def bundled_names() -> list[str]:
    """Names of the bundled scenarios (file stems), sorted."""
    return sorted(entry.name[:-5] for entry in _folder().iterdir()
                  if entry.name.endswith(".toml") and NAME_PATTERN.fullmatch(entry.name[:-5]))


def bundled_text(name: str) -> str:
    """The TOML text of the bundled scenario ``name``.

    Raises
    ------
    ConfigError
        If there is no bundled scenario of that name (the valid names are listed).
    """
    if not (isinstance(name, str) and NAME_PATTERN.fullmatch(name) and name in bundled_names()):
        raise ConfigError(f"no bundled scenario {name!r}; bundled are {', '.join(bundled_names())}")
    return _folder().joinpath(f"{name}.toml").read_text(encoding="utf-8")


def bundled_table(name: str) -> dict:
    """The parsed TOML of the bundled scenario ``name`` (see ``bundled_text``)."""
    return tomllib.loads(bundled_text(name))


def list_bundled() -> list[dict]:
    """``name``, ``kind`` and ``description`` of every bundled scenario (what ``rollbot-oc problems`` prints)."""
    tables = {name: bundled_table(name) for name in bundled_names()}
    return [{"name": name, "kind": t.get("kind"), "description": t.get("description", "")}
            for name, t in tables.items()]


def load_bundled(name: str, base=None):
    """The bundled scenario ``name`` as a validated ``Problem`` (``base``: see ``load_problem``).

    Raises
    ------
    ConfigError
        If there is no bundled scenario of that name (the valid names are listed).
    """
    from rollbot_oc.scenarios.problem import problem_from_dict  # start-up: listing needs no controller (seconds)

    return problem_from_dict(bundled_table(name), f"bundled scenario {name}", base)


def file_or_bundled(text: str, what: str, names, folders: tuple) -> tuple[Path | None, str | None]:
    """What a command-line argument names: an existing file, or else one of the bundled ``names``.

    Parameters
    ----------
    text : str
        The argument.
    what : str
        What it is, for messages (``"problem"``).
    names : collection of str
        The bundled names.
    folders : tuple of str
        Folders that may precede a bundled name (``"problems"``), beside none.

    Returns
    -------
    (Path, None) for an existing file, (None, name) for a bundled name
    (with or without ``.toml``), (None, None) for neither.
    """
    path = user_path(text, what)
    if path.exists():
        return path, None
    stem = path.name[:-5] if path.name.endswith(".toml") else path.name
    if path.parent in (Path("."), *map(Path, folders)) and stem in names:
        return None, stem
    return None, None


def load_scenario(text: str, base=None):
    """The problem a ``PROBLEM`` argument names: a scenario file, or else a bundled scenario.

    An existing path is read as a file; otherwise a bundled scenario's name
    (with or without ``.toml``, with or without ``problems/`` in front) is
    that scenario.

    Parameters
    ----------
    text : str
        The argument.
    base : RollbotParams, optional
        The robot the scenario's ``[params]`` apply to (see ``load_problem``).

    Returns
    -------
    Problem

    Raises
    ------
    ConfigError
        If it is neither (the bundled scenarios are listed), or the file is bad.
    """
    from rollbot_oc.scenarios.problem import load_problem  # start-up: as in load_bundled

    path, name = file_or_bundled(text, "problem", bundled_names(), ("problems",))
    if path is not None:
        return load_problem(path, base)
    if name is not None:
        return load_bundled(name, base)
    raise ConfigError(f"problem {text!r}: no such file, and no bundled scenario of that name; bundled are "
                      f"{', '.join(bundled_names())} (see rollbot-oc problems)")
