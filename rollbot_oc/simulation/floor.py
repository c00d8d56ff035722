"""The floor the robot rolls on: friction, rolling resistance, damping, and patches where they differ.

The floor's friction coefficient has one home, ``RollbotParams.mu`` (it is
in the parameter vector every model, margin and planner reads); a ``Floor``
adds what the no-slip model does not have: whether the contact may slide
(Coulomb friction, ``contact``), rolling resistance, viscous damping, and
polygonal patches with their own values.  ``Floor()`` is the rigid floor of
the no-slip model: the plant then runs ``simulate``'s no-slip path
unchanged, where a slide is an event that ends the run.  Any other floor is
simulated by ``floor_plant`` with Coulomb contact (stick and slide, the
transitions events, not failures).

Scenario files (``problems``): the ``[floor]`` table's keys ::

    [floor]
    slope_deg          = 1.0    # floor inclination, deg (the no-slip plant too)
    slope_dir_deg      = -45.0  # downhill direction, deg
    mu                 = 0.25   # friction coefficient (was [params] mu)
    rolling_resistance = 0.002  # m: the normal force acts this far ahead of the contact point
    damping            = 0.01   # N m s: viscous torque against the rolling rate

    [[floor.patches]]           # a region with its own values (later patches win where they overlap)
    polygon            = [[0.2, 0.2], [0.8, 0.2], [0.8, 0.6], [0.2, 0.6]]   # m, >= 3 vertices
    mu                 = 0.6    # each key optional: the floor's value where absent
    rolling_resistance = 0.01
    damping            = 0.05

Any of ``mu``, ``rolling_resistance``, ``damping`` or ``patches`` selects
the Coulomb-contact plant.  The plant looks the floor up under the contact
point (the shell centre's position) once per control period, at its start.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from rollbot_oc.core.errors import ConfigError

__all__ = ["Floor", "FloorPatch", "FLOOR_KEYS", "PATCH_KEYS", "RollbotDeprecationWarning", "MU_RANGE", "ROLLING_RESISTANCE_RANGE", "DAMPING_RANGE"]

MU_RANGE = (0.0, 10.0)  # 1
ROLLING_RESISTANCE_RANGE = (0.0, 0.05)  # m: at most ~0.4 R of the prototype
DAMPING_RANGE = (0.0, 10.0)  # N m s
PATCH_KEYS = ("polygon", "mu", "rolling_resistance", "damping")
FLOOR_KEYS = ("slope_deg", "slope_dir_deg", "mu", "rolling_resistance", "damping", "patches")


class RollbotDeprecationWarning(DeprecationWarning):
    """A setting that still works but has moved (the command line shows these as one-line warnings)."""


def _check(name, value, low, high, where):
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ConfigError(f"{where}: {name} = {value!r} must be a finite number")
    if not low <= value <= high:
        raise ConfigError(f"{where}: {name} = {value!r} is out of range: valid is [{low:g}, {high:g}]")
    return float(value)


@dataclass(frozen=True)
class FloorPatch:
    """A polygonal region of the floor with its own values.

    Attributes
    ----------
    polygon : tuple of (float, float)
        Vertices (x, y) in m, at least 3, in order (either sense); the region
        is the polygon's interior by the even-odd rule.
    mu : float or None
        Friction coefficient there (None: the floor's).
    rolling_resistance : float or None
        Rolling resistance there, m (None: the floor's).
    damping : float or None
        Floor damping there, N m s (None: the floor's).
    """

    polygon: tuple
    mu: float | None = None
    rolling_resistance: float | None = None
    damping: float | None = None

    def __post_init__(self):
        vertices = tuple((float(x), float(y)) for x, y in self.polygon)
        if len(vertices) < 3 or not all(math.isfinite(c) for v in vertices for c in v):
            raise ConfigError(f"floor patch: polygon = {list(self.polygon)!r} must have >= 3 finite [x, y] vertices")
        object.__setattr__(self, "polygon", vertices)
        for name, (low, high) in (("mu", MU_RANGE), ("rolling_resistance", ROLLING_RESISTANCE_RANGE),
                                  ("damping", DAMPING_RANGE)):
            if getattr(self, name) is not None:
                object.__setattr__(self, name, _check(name, getattr(self, name), low, high, "floor patch"))

    def contains(self, x: float, y: float) -> bool:
        """Whether the point (x, y) (m) is inside the polygon (even-odd rule; a crossing count along +x)."""
        inside = False
        poly = self.polygon
        x0, y0 = poly[-1]
        for x1, y1 in poly:
            if (y1 > y) != (y0 > y) and x < x0 + (y - y0) * (x1 - x0) / (y1 - y0):
                inside = not inside
            x0, y0 = x1, y1
        return inside


@dataclass(frozen=True)
class Floor:
    """What the floor adds to the no-slip model (the friction coefficient is ``RollbotParams.mu``).

    Attributes
    ----------
    contact : {"rolling", "coulomb"}
        ``"rolling"``: the no-slip model's rigid floor, a slide ends the run
        (only with no resistance, damping or patches).  ``"coulomb"``: the
        contact sticks or slides by Coulomb's law (``contact``).
    rolling_resistance : float
        Rolling resistance, m: a torque ``c_rr N_z`` opposing rolling.
    damping : float
        Viscous floor damping, N m s: a torque ``-damping * omega_h`` against
        the rolling rate.
    patches : tuple of FloorPatch
        Regions with their own values; where they overlap the later wins.
    """

    contact: str = "rolling"
    rolling_resistance: float = 0.0
    damping: float = 0.0
    patches: tuple = ()

    def __post_init__(self):
        if self.contact not in ("rolling", "coulomb"):
            raise ConfigError(f"floor: contact = {self.contact!r}; valid are 'rolling', 'coulomb'")
        object.__setattr__(self, "rolling_resistance", _check("rolling_resistance", self.rolling_resistance,
                                                              *ROLLING_RESISTANCE_RANGE, "floor"))
        object.__setattr__(self, "damping", _check("damping", self.damping, *DAMPING_RANGE, "floor"))
        object.__setattr__(self, "patches", tuple(self.patches))
        if self.contact == "rolling" and (self.rolling_resistance or self.damping or self.patches):
            raise ConfigError("floor: rolling resistance, damping and patches need contact = 'coulomb' "
                              "(the no-slip plant has none)")

    @property
    def rigid(self) -> bool:
        """True for the no-slip model's floor (``Floor()``): ``simulate`` runs its no-slip path."""
        return self.contact == "rolling"

    def values_at(self, position, mu: float) -> np.ndarray:
        """The floor vector ``(mu, rolling_resistance, damping)`` at ``position`` (x, y in m).

        ``mu`` is the floor's friction coefficient (``RollbotParams.mu``); the
        last patch that contains the point overrides the values it sets.
        """
        values = [float(mu), self.rolling_resistance, self.damping]
        x, y = float(position[0]), float(position[1])
        for patch in self.patches:
            if patch.contains(x, y):
                for i, name in enumerate(("mu", "rolling_resistance", "damping")):
                    value = getattr(patch, name)
                    if value is not None:
                        values[i] = value
        return np.array(values)

    def describe(self) -> dict:
        """The floor as JSON-ready data (what a run's metrics record about it)."""
        return {"contact": self.contact, "rolling_resistance": self.rolling_resistance, "damping": self.damping,
                "patches": [{"polygon": [list(v) for v in p.polygon], "mu": p.mu,
                             "rolling_resistance": p.rolling_resistance, "damping": p.damping}
                            for p in self.patches]}
