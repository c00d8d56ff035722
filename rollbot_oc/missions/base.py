"""What a mission is: its schema, what the controllers ask of it, its metrics; and the registry of kinds.

A mission kind is one class in one file (``circle``, ``waypoints``,
``open_loop``, ``gates``) registered with ``@register``: it names its table
in the problem file (``kind``, ``keys``), builds itself from that table
(``from_table``) and writes it back (``to_table``), measures a run
(``metrics``), and answers the controllers' questions (``stops``,
``stop_rule``, ``orbit``, ``gates``, ``waypoints``).  ``rollbot_oc.scenarios.problem``
finds a kind by name (``mission_kind``) and never looks at which kind it has.
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np

from rollbot_oc.core.errors import ConfigError
from rollbot_oc.missions.stops import STOP_TOLERANCE, StopRule
from rollbot_oc.core.reproducible import norm
from rollbot_oc.view.text import number as shown  # a value with its unit, as the summaries print it

__all__ = ["Mission", "register", "mission_kind", "KINDS", "centre_of_curvature", "check_point"]

KINDS: dict[str, type] = {}  # kind name -> Mission class, in the order registered


def check_point(value, name: str) -> np.ndarray:
    """``value`` as two finite numbers (x, y), m (a ``ValueError`` naming ``name`` otherwise)."""
    arr = np.asarray(value, float).ravel()
    if arr.shape != (2,) or not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} = {value!r} must be two finite numbers (x, y) in m")
    return arr


def centre_of_curvature(position, heading: float, radius: float) -> np.ndarray:
    """The paper's eqn "ofunc": ``o = s - R0 (cos gamma, sin gamma)``.

    Parameters
    ----------
    position : array_like (2,) or (2, n)
        Shell-centre position s, m.
    heading : float or array_like (n,)
        gamma, the azimuth of the motor axis' horizontal projection, rad.
    radius : float or array_like (n,)
        Quasi-stable revolving radius R0 at the current driving speed, m.
    """
    return np.asarray(position, float) - radius * np.array([np.cos(heading), np.sin(heading)])


class Mission:
    """What a controller is asked to do, and how a run of it is measured (a base class of every kind).

    Class attributes
    ----------------
    kind : str
        Its ``kind`` in a problem file, also the name of its table (``[kind]``).
    keys : frozenset of str
        The keys its table may hold.
    closed_loop : bool
        False for a kind no controller runs (``open_loop``).

    The controllers' questions have neutral answers here (no stops, no orbit,
    no gates); each kind answers those it is about.
    """

    kind: ClassVar[str] = ""
    keys: ClassVar[frozenset] = frozenset()
    closed_loop: ClassVar[bool] = True

    @classmethod
    def from_table(cls, table: dict, where: str, params, duration: float) -> "Mission":
        """The mission of the table ``[kind]`` of a problem file.

        Parameters
        ----------
        table : dict
            The parsed table (its keys already checked against ``keys``).
        where : str
            ``"<file> [<kind>]"``, for the messages.
        params : RollbotParams
            The robot (some ranges depend on it).
        duration : float
            The problem's duration, s (some times must lie within it).

        Raises
        ------
        ConfigError
            A missing key or an impossible value (one line naming ``where``, the key, value and range).
        """
        raise NotImplementedError

    def to_table(self) -> dict:
        """The table ``[kind]`` that builds this mission again (``from_table``), SI units."""
        raise NotImplementedError

    def metrics(self, result) -> dict:
        """The kind's metrics of a run (``SimulationResult``); ``completed`` among them if it can be.

        Truth is measured: the true trajectory, never the robot's estimate.
        """
        return {}

    def verdict(self, metrics: dict) -> list[str]:
        """How a run went, in a few words (``view.text.run_verdict``), from its ``metrics``."""

        return [f"completed in {shown(metrics.get('completion_time'), '.1f', 's')}" if metrics["completed"] else
                f"NOT completed in {shown(metrics['duration'], '.1f', 's')}"]

    # -- what the controllers ask ---------------------------------------------------------------
    @classmethod
    def tracking_terms(cls, ocp) -> list:
        """Least-squares residuals this kind adds to the NMPC's tracking problem (``control.nmpc.tracking``),
        as stage expressions of ``ocp``; none here.

        A class method: they are written once per kind (the problem is built once
        and reused for every mission of the kind), and a mission's own numbers
        enter as parameters declared here (``ocp.parameter``) whose values
        ``tracking_values`` gives.
        The tracking problem weights each residual per node.
        """
        return []

    def tracking_values(self) -> dict:
        """Values of the parameters ``tracking_terms`` declares, by name."""
        return {}

    @property
    def stops(self) -> list:
        """The points to stop at, in order, m (none by default)."""
        return []

    @property
    def stop_rule(self) -> StopRule:
        """When a stop counts as reached."""
        return StopRule(tolerance=STOP_TOLERANCE)

    @property
    def orbit(self):
        """The circle to revolve on (a ``Circle``: ``centre``, m, ``radius``, m), or None."""
        return None

    @property
    def gates(self) -> list:
        """The points to pass through without stopping, in order, m (none by default)."""
        return []

    @property
    def waypoints(self) -> tuple:
        """What the PID's waypoint layer visits in order (``Waypoint`` objects; none for an orbit)."""
        return ()

    @property
    def pass_tolerance(self) -> float:
        """Distance within which a pass-through waypoint counts as passed, m."""
        return STOP_TOLERANCE

    def leg(self, index: int) -> "Mission":
        """What a stand-in controller (the NMPC's PID fallback) is asked while target ``index`` is in
        progress (this mission by default)."""
        return self

    @property
    def targets(self) -> list:
        """Points to mark on a plot of the run, m."""
        return list(self.stops) + list(self.gates)


def register(cls: type) -> type:
    """Class decorator: make ``cls`` (a ``Mission`` with its ``kind`` and ``keys``) a kind of problem file."""
    if not (isinstance(cls.kind, str) and cls.kind.isidentifier()):
        raise ValueError(f"mission kind {cls.kind!r} must be an identifier (it names its table)")
    if cls.kind in KINDS and KINDS[cls.kind] is not cls:
        raise ValueError(f"mission kind {cls.kind!r} is already registered by {KINDS[cls.kind].__name__}")
    cls.keys = frozenset(cls.keys)
    KINDS[cls.kind] = cls
    return cls


def mission_kind(name, source: str = "<problem>") -> type:
    """The mission class of kind ``name``.

    Raises
    ------
    ConfigError
        If no kind of that name is registered (the message lists the valid kinds).
    """
    if not isinstance(name, str) or name not in KINDS:
        raise ConfigError(f"{source}: key 'kind' = {name!r}; valid are {', '.join(KINDS)}")
    return KINDS[name]


def path_length(start, points) -> float:
    """Length of the polyline from ``start`` through ``points``, m."""
    path = [np.asarray(start, float)] + [np.asarray(p, float) for p in points]
    return sum(float(norm(b - a)) for a, b in zip(path[:-1], path[1:]))
