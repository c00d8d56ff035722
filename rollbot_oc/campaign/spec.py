"""Campaign specs (TOML): load and validate them into a ``Campaign``, its cases listed.

Schema (the README documents every kind's table)::

    name        = "robustness"     # required: letters, digits, _ and -, at most 64
    description = "..."            # optional
    kind        = "closed_loop"    # required: closed_loop | design | function
    seed        = 0                # optional: the campaign's seed, in [0, 2^32 - 1] (default 0)

    [closed_loop]                  # the kind's settings: a table named after the kind
    ...

Everything is checked on load: an unknown key or table, a missing key, a
value of the wrong type or out of its range raises a ``ConfigError`` (a
``ValueError``) in one line naming the file, the key, the value and the valid
range, before any case runs.  A grid of values (a list, or ``{from, to, steps}``) is read by
``campaign.grid``.
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass
from pathlib import Path

from rollbot_oc.campaign.case import KINDS, Case, case_id, case_seed
from rollbot_oc.campaign.function import FunctionKind
from rollbot_oc.campaign.grid import grid_cases, grid_values
from rollbot_oc.core.errors import ConfigError
from rollbot_oc.model.params import read_toml
from rollbot_oc.missions.schema import check_keys as _check_keys
from rollbot_oc.missions.schema import table as _table
from rollbot_oc.scenarios.problem import _check_name
from rollbot_oc.scenarios.bundled import _folder
from rollbot_oc.scenarios.bundled import file_or_bundled

__all__ = ["Campaign", "load_campaign", "campaign_from_dict", "load_campaign_spec", "bundled_campaigns",
           "bundled_campaign_table",
           "grid_values", "grid_cases", "MAX_SEED", "MAX_CASES"]

MAX_SEED = 2**32 - 1
MAX_CASES = 1_000_000  # a campaign's cases are listed up front: a bound that catches a typo, not a real study


@dataclass(frozen=True)
class Campaign:
    """A list of independent cases of one kind, with the seed they derive theirs from.

    Attributes
    ----------
    name : str
        A plain identifier.
    kind : CaseKind
        The kind of its cases, configured.
    seed : int
        The campaign's seed, in [0, 2^32 - 1].
    description : str
    source : str
        Where it came from (the spec file), for messages.
    """

    name: str
    kind: object
    seed: int = 0
    description: str = ""
    source: str = "<campaign>"

    def cases(self) -> list[Case]:
        """Every case, in order, with its seed and id.

        Raises
        ------
        ConfigError
            If two cases have the same inputs (they would be one case), or there are none.
        """
        settings = self.kind.settings()
        cases, seen = [], {}
        for index, inputs in enumerate(self.kind.case_inputs()):
            identity = case_id(self.kind.name, settings, self.seed, inputs)
            if identity in seen:
                raise ConfigError(f"{self.source}: cases {seen[identity]} and {index} have the same inputs "
                                  f"{inputs}; every case must differ")
            seen[identity] = index
            cases.append(Case(index, identity, case_seed(self.seed, inputs), inputs))
        if not cases:
            raise ConfigError(f"{self.source}: the campaign has no cases")
        return cases

    @classmethod
    def of_function(cls, name: str, function, cases: list[dict], seed: int = 0,
                    description: str = "") -> "Campaign":
        """A campaign that calls ``function(**inputs)`` (and ``seed=`` if it takes one) for each of ``cases``.

        The function must be importable by the workers (a module on their
        path) or picklable by value; see ``rollbot_oc.campaign.function``.
        """
        _check_name(name, "campaign")
        return cls(name, FunctionKind(function, [dict(c) for c in cases]), _seed(seed, "campaign"), description,
                   f"campaign {name}")


def _seed(value, where: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= MAX_SEED:
        raise ConfigError(f"{where}: key 'seed' = {value!r} is out of range: valid is a whole number in "
                          f"[0, {MAX_SEED}]")
    return value


def campaign_from_dict(data: dict, source: str = "<campaign>") -> Campaign:
    """Validate a spec given as a mapping (the parsed TOML); see ``load_campaign``."""
    kind = data.get("kind")
    if kind not in KINDS:
        raise ConfigError(f"{source}: key 'kind' = {kind!r}; valid are {', '.join(KINDS)}")
    _check_keys(data, {"name", "description", "kind", "seed", kind}, source)
    if "name" not in data:
        raise ConfigError(f"{source}: missing required key 'name'")
    name = _check_name(data["name"], source)
    description = data.get("description", "")
    if not isinstance(description, str):
        raise ConfigError(f"{source}: key 'description' = {description!r} must be a string")
    seed = _seed(data.get("seed", 0), source)
    configured = KINDS[kind].from_spec(_table(data, kind, source), f"{source} [{kind}]", seed)
    campaign = Campaign(name, configured, seed, description, source)
    count = len(campaign.kind.case_inputs())
    if count > MAX_CASES:
        raise ConfigError(f"{source}: {count} cases is out of range: valid is [1, {MAX_CASES}]")
    return campaign


def load_campaign(path: str | Path) -> Campaign:
    """Read and validate a campaign spec file (schema in the module doc and the README).

    Raises
    ------
    ConfigError
        Missing or unreadable file, invalid TOML, unknown or missing keys, impossible values.
    """
    return campaign_from_dict(read_toml(path, "campaign spec"), str(path))


def _bundled_folder():
    return _folder().joinpath("campaigns")


def bundled_campaigns() -> list[str]:
    """Names of the bundled campaign specs (``problems/campaigns/*.toml``), sorted."""
    folder = _bundled_folder()
    return sorted(entry.name[:-5] for entry in folder.iterdir() if entry.name.endswith(".toml")) \
        if folder.is_dir() else []


def bundled_campaign_table(name: str) -> dict:
    """The parsed TOML of the bundled campaign spec ``name`` (to run it with changes).

    Raises
    ------
    ConfigError
        If there is no bundled spec of that name (the valid names are listed).
    """
    if name not in bundled_campaigns():
        raise ConfigError(f"no bundled campaign {name!r}; bundled are {', '.join(bundled_campaigns()) or 'none'}")
    return tomllib.loads(_bundled_folder().joinpath(f"{name}.toml").read_text(encoding="utf-8"))


def load_campaign_spec(text: str) -> Campaign:
    """The campaign a ``SPEC`` argument names: a spec file, or else a bundled spec's name.

    Raises
    ------
    ConfigError
        If it is neither (the bundled specs are listed), or the file is bad.
    """

    path, name = file_or_bundled(text, "campaign spec", bundled_campaigns(), ("campaigns", "problems/campaigns"))
    if path is not None:
        return load_campaign(path)
    if name is not None:
        return campaign_from_dict(bundled_campaign_table(name), f"bundled campaign {name}")
    raise ConfigError(f"campaign spec {text!r}: no such file, and no bundled spec of that name; bundled are "
                      f"{', '.join(bundled_campaigns()) or 'none'}")
