"""What a campaign is made of: cases, their outcomes, and the protocol every kind of case follows.

A *case* is one independent computation: its inputs (plain numbers,
strings and booleans), its own seed and an identity.  A *case kind*
(``CaseKind``) knows how to list the cases of a spec, run one and summarise
and draw a finished table; each kind is one class in one module
(``closed_loop``, ``design_points``, ``function``) and registers itself in
``KINDS`` under the name a spec's ``kind`` gives.  The engine only ever
calls the protocol.

Seeds and identities:

* a case's seed is ``numpy.random.SeedSequence(campaign_seed,
  spawn_key=...)`` with the spawn key taken from a hash of the case's inputs,
  so it depends on what the case is, not on its position in the list (adding
  cases or controllers to a spec leaves the others' seeds as they were);
* a case's id (16 hex digits) hashes the kind, the kind's settings, the
  campaign seed and the inputs: everything that determines its result.  The
  result store keys finished cases by it, so a campaign started again skips
  them, and a changed setting runs them again.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field
from typing import ClassVar, Protocol, runtime_checkable

import numpy as np

__all__ = ["Case", "Outcome", "CaseKind", "KINDS", "register", "canonical", "case_seed", "case_id", "describe",
           "STATUSES"]

STATUSES = ("succeeded", "failed", "error")  # ran and met its criterion / ran and did not (cause) / raised


def canonical(obj) -> str:
    """Canonical JSON of ``obj`` (sorted keys, no spaces): the text hashed into seeds and ids."""
    return json.dumps(obj, sort_keys=True, separators=(",", ":"), allow_nan=False)


def case_seed(campaign_seed: int, inputs: dict) -> int:
    """The seed of a case, in [0, 2^32): ``SeedSequence(campaign_seed, spawn_key=hash(inputs))``."""
    digest = hashlib.sha256(canonical(inputs).encode()).digest()
    key = tuple(int.from_bytes(digest[i:i + 4], "little") for i in range(0, 16, 4))
    return int(np.random.SeedSequence(campaign_seed, spawn_key=key).generate_state(1)[0])


def case_id(kind: str, settings: dict, campaign_seed: int, inputs: dict) -> str:
    """The identity of a case: 16 hex digits of a hash of all that determines its result."""
    text = canonical({"kind": kind, "settings": settings, "seed": campaign_seed, "inputs": inputs})
    return hashlib.sha256(text.encode()).hexdigest()[:16]


@dataclass(frozen=True)
class Case:
    """One case of a campaign.

    Attributes
    ----------
    index : int
        Its position in the campaign (the table's order).
    id : str
        Its identity (``case_id``).
    seed : int
        Its own seed (``case_seed``).
    inputs : dict
        What the kind needs to run it (plain values).
    """

    index: int
    id: str
    seed: int
    inputs: dict


@dataclass
class Outcome:
    """What running a case gave.

    Attributes
    ----------
    metrics : dict
        Measured values (plain numbers, strings, booleans, lists of numbers, None).
    inputs : dict
        Inputs the run derived (for example a random course's robot), added to the case's.
    cause : str or None
        Why the case did not meet its kind's success criterion (status ``failed``).
    error : str or None
        The exception that stopped it (status ``error``), ``"Type: message"``.
    """

    metrics: dict = field(default_factory=dict)
    inputs: dict = field(default_factory=dict)
    cause: str | None = None
    error: str | None = None

    @property
    def status(self) -> str:
        """``"error"``, ``"failed"`` or ``"succeeded"``."""
        return "error" if self.error else "failed" if self.cause else "succeeded"


@runtime_checkable
class CaseKind(Protocol):
    """The protocol of a kind of case (a class per kind, registered in ``KINDS``).

    Attributes
    ----------
    name : str
        The spec's ``kind`` (and the spec's table of settings, ``[name]``).
    input_columns, metric_columns : tuple of str
        The table's columns for the case's inputs (given and derived) and its
        metrics, in order (a kind whose metrics are not known in advance gives
        an empty tuple: the table then has the metrics the cases returned).
    group : str or None
        An input column that splits the summary (the closed loop's ``controller``).
    """

    name: ClassVar[str]
    input_columns: tuple
    metric_columns: tuple
    group: str | None

    @classmethod
    def from_spec(cls, table: dict, source: str, seed: int = 0) -> "CaseKind":
        """The kind configured by its spec table ``[name]`` and the campaign's ``seed``, validated.

        Raises ``ConfigError`` naming ``source``, the key, the value and the valid range.
        """

    def settings(self) -> dict:
        """Everything beside a case's inputs that determines its result (plain values, hashed into ids)."""

    def case_inputs(self) -> list[dict]:
        """The inputs of every case, in order."""

    def run(self, inputs: dict, seed: int) -> Outcome:
        """Run one case (in a worker); exceptions become ``error`` rows (the engine catches them)."""

    def summarise(self, table) -> dict:
        """The kind's part of the summary of a finished table (a ``pandas.DataFrame``)."""

    def figures(self, table, folder) -> list:
        """Write the kind's figures of a finished table into ``folder`` (an ``OutputFolder``); their paths."""


KINDS: dict[str, type] = {}


def register(cls: type) -> type:
    """Class decorator: make a case kind available to specs under ``cls.name``."""
    KINDS[cls.name] = cls
    return cls


def describe(exc: BaseException) -> str:
    """An exception as one line for a results table: ``"Type: message"`` (solver status included)."""
    text = " ".join(str(exc).split()) or repr(exc)
    status = getattr(exc, "status", None)
    if status and str(status) not in text:
        text += f" (status {status})"
    return f"{type(exc).__name__}: {text}"
