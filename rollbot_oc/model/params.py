"""Physical parameters of Rollbot, their validation and their TOML files.

Defaults are the prototype of the paper (Table "Physical parameters").  Inside
the toolkit every quantity is SI with angles in radians; the TOML file keys
that hold angles end in ``_deg`` and are in degrees.

TOML schema (every key optional; a missing key keeps its default)::

    R             = 0.12    # shell outer radius, m
    M_s           = 0.840   # shell mass, kg
    m_b           = 0.040   # mass of the damping beads, kg (added to the shell)
    I             = 0.0053  # shell moment of inertia (isotropic), kg m^2
    phi_deg       = 45.0    # angle between the motor axis and the pendulum arm, deg
    r0            = 0.093   # distance from shell centre to pendulum mass, m
    m             = 0.306   # pendulum mass, kg
    k0            = ...     # rotational damping, N m s; default 0.4 1/s * M * R^2 (0 is allowed for
                            # simulation and optimal control; the quasi-stable analysis needs k0 > 0)
    g             = 9.81    # gravity, m/s^2
    mu            = 0.5     # friction coefficient between shell and floor
    max_torque    = ...     # motor torque limit, N m; default r0 * m * g
    max_speed     = 9.42..  # driving-speed limit, rad/s; default 3 pi
    max_accel     = 30.0    # motor acceleration limit, rad/s^2
    slope_deg     = 0.0     # floor inclination, deg
    slope_dir_deg = 0.0     # azimuth of the downhill direction in the floor frame, deg

Derived defaults: ``k0`` and ``max_torque`` follow the values they derive
from (``M_s``, ``m_b``, ``R``; ``r0``, ``m``, ``g``) unless they are set
explicitly.  The same rule holds for a parameter file (``--params``) and for
a problem file's ``[params]`` table on top of its base robot
(``RollbotParams.from_file_dict``).
"""

from __future__ import annotations

import dataclasses
import math
import tomllib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rollbot_oc.core.errors import ConfigError
from rollbot_oc.core.outputs import atomic_write_text, user_path

__all__ = ["RollbotParams", "PARAM_VECTOR_FIELDS", "PARAM_INDEX", "NP", "TILT", "ParamView", "load_params",
           "read_params_table", "save_params", "read_toml"]

# Order of the numeric parameter vector ``p`` fed to every symbolic Function.  The floor's slope enters
# as its tilt vector (tilt_x, tilt_y) = sin(slope) (cos slope_dir, sin slope_dir): the in-plane part of
# gravity per g, smooth at zero slope (so it can be estimated and differentiated there).
PARAM_VECTOR_FIELDS = (
    "R", "M", "I", "phi", "r0", "m", "k0", "g", "mu",
    "max_torque", "max_speed", "max_accel", "tilt_x", "tilt_y",
)

NP = len(PARAM_VECTOR_FIELDS)
PARAM_INDEX = {name: i for i, name in enumerate(PARAM_VECTOR_FIELDS)}
TILT = slice(PARAM_INDEX["tilt_x"], PARAM_INDEX["tilt_y"] + 1)  # the floor's tilt vector in ``p``


class ParamView:
    """Named access to a parameter vector ``p`` (numpy array or CasADi symbol), the one accessor of ``p``.

    ``P = ParamView(p)`` gives ``P.mu``, ``P.max_speed``, ... (entries of ``p``
    by their names in ``PARAM_VECTOR_FIELDS``), ``P.tilt`` (the tilt vector,
    2 entries) and ``P.weight``, the robot's weight ``(M + m) g`` in N.
    """

    __slots__ = ("vector",)

    def __init__(self, p):
        self.vector = p

    def __getattr__(self, name):
        if name == "tilt":
            return self.vector[TILT]
        if name == "weight":
            return (self.vector[PARAM_INDEX["M"]] + self.vector[PARAM_INDEX["m"]]) * self.vector[PARAM_INDEX["g"]]
        try:
            return self.vector[PARAM_INDEX[name]]
        except KeyError:
            raise AttributeError(f"the parameter vector has no entry {name!r}; valid are "
                                 f"{', '.join(PARAM_VECTOR_FIELDS)}, tilt, weight") from None


# File key -> (attribute, scale from file units to SI, unit in the file, meaning).
_FILE_KEYS = {
    "R": ("R", 1.0, "m", "shell outer radius"),
    "M_s": ("M_s", 1.0, "kg", "shell mass"),
    "m_b": ("m_b", 1.0, "kg", "bead mass (added to the shell)"),
    "I": ("I", 1.0, "kg m^2", "shell moment of inertia"),
    "phi_deg": ("phi", math.pi / 180.0, "deg", "motor axis to pendulum arm"),
    "r0": ("r0", 1.0, "m", "shell centre to pendulum mass"),
    "m": ("m", 1.0, "kg", "pendulum mass"),
    "k0": ("k0", 1.0, "N m s", "damping (default 0.4 1/s M R^2)"),
    "g": ("g", 1.0, "m/s^2", "gravity"),
    "mu": ("mu", 1.0, "1", "friction coefficient"),
    "max_torque": ("max_torque", 1.0, "N m", "motor torque limit (default r0 m g)"),
    "max_speed": ("max_speed", 1.0, "rad/s", "driving-speed limit"),
    "max_accel": ("max_accel", 1.0, "rad/s^2", "motor acceleration limit"),
    "slope_deg": ("slope", math.pi / 180.0, "deg", "floor inclination"),
    "slope_dir_deg": ("slope_dir", math.pi / 180.0, "deg", "downhill direction"),
}

_K0_RATE = 0.4  # 1/s, the paper's k0 = (0.4 1/s) M R^2

# Fields whose default derives from others: the paper's k0 = (0.4 1/s) M R^2 and M_max = r0 m g.
_DERIVED_DEFAULTS = {
    "k0": lambda p: _K0_RATE * (p.M_s + p.m_b) * p.R**2,
    "max_torque": lambda p: p.r0 * p.m * p.g,
}

MAX_FILE_BYTES = 1 << 20  # a parameter or problem file is small text; refuse anything bigger


@dataclass(frozen=True)
class RollbotParams:
    """Physical parameters of a single-pendulum spherical robot (SI units).

    Parameters
    ----------
    R : float
        Outer radius of the shell, m.
    M_s : float
        Mass of the shell, kg.
    m_b : float
        Mass of the glass beads that damp the shell, kg.  The equations use the
        shell body mass ``M = M_s + m_b``.
    I : float
        Moment of inertia of the shell about any axis through its centre,
        kg m^2 (the shell is isotropic).
    phi : float
        Angle between the motor axis and the line from the shell centre to the
        pendulum mass, rad, in (0, pi/2).
    r0 : float
        Distance from the shell centre to the pendulum mass, m, below ``R``.
    m : float
        Pendulum (point) mass, kg.
    k0 : float or None
        Rotational damping coefficient of the shell, N m s (torque
        ``-k0 * omega``).  ``None`` selects the paper's ``0.4 1/s * M * R^2``.
    g : float
        Gravitational acceleration, m/s^2.
    mu : float
        Coulomb friction coefficient between shell and floor (dimensionless).
        The default 0.5 is a typical value for a hard plastic shell on a lab
        floor; the paper does not report one.
    max_torque : float or None
        Motor torque limit, N m.  ``None`` selects the paper's
        ``M_max = r0 * m * g`` (0.28 N m for the prototype).
    max_speed : float
        Driving-speed limit of the motor, rad/s (paper: 3 pi).
    max_accel : float
        Motor acceleration limit, rad/s^2 (a property of the motor driver; the
        paper does not report one).
    slope : float
        Inclination of the floor, rad, in [0, pi/6].
    slope_dir : float
        Azimuth of the downhill direction, measured in the floor plane from the
        floor frame's x axis, rad.
    """

    R: float = 0.12
    M_s: float = 0.840
    m_b: float = 0.040
    I: float = 0.0053
    phi: float = math.pi / 4
    r0: float = 0.093
    m: float = 0.306
    k0: float | None = None
    g: float = 9.81
    mu: float = 0.5
    max_torque: float | None = None
    max_speed: float = 3 * math.pi
    max_accel: float = 30.0
    slope: float = 0.0
    slope_dir: float = 0.0

    def __post_init__(self):
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if value is None and f.name in _DERIVED_DEFAULTS:
                continue
            if isinstance(value, bool) or not isinstance(value, (int, float, np.floating, np.integer)):
                raise ConfigError(f"parameter {f.name}: expected a number, got {value!r}")
            if not math.isfinite(value):
                raise ConfigError(f"parameter {f.name}: {value!r} is not finite")
            object.__setattr__(self, f.name, float(value))
        derived = frozenset(name for name in _DERIVED_DEFAULTS if getattr(self, name) is None)
        object.__setattr__(self, "_derived", derived)  # which defaults follow the others (not a field)
        self._validate_given()
        for name in derived:
            try:
                value = _DERIVED_DEFAULTS[name](self)
            except OverflowError:
                value = math.inf  # refused just below, naming the field
            object.__setattr__(self, name, value)
        self._validate()

    def _check(self, name, ok, valid):
        if not ok:
            raise ConfigError(f"parameter {name} = {getattr(self, name)!r} is out of range: valid is {valid}")

    def _validate_given(self):
        """Ranges of the values the derived defaults are computed from (so they are never computed from junk)."""
        for name in ("R", "M_s", "r0", "m", "g"):
            self._check(name, getattr(self, name) > 0, "> 0")
        self._check("m_b", self.m_b >= 0, ">= 0")

    def _validate(self):
        check = self._check
        for name in self._derived:
            check(name, math.isfinite(getattr(self, name)), "finite (derived from the other parameters)")
        for name in ("I", "max_torque", "max_speed", "max_accel"):
            check(name, getattr(self, name) > 0, "> 0")
        for name in ("k0", "mu"):
            check(name, getattr(self, name) >= 0, ">= 0")
        check("phi", 0 < self.phi < math.pi / 2, "(0, pi/2) rad, i.e. phi_deg in (0, 90)")
        check("r0", self.r0 < self.R, f"(0, R) = (0, {self.R}) m: the mass is inside the shell")
        check("slope", 0 <= self.slope <= math.pi / 6, "[0, pi/6] rad, i.e. slope_deg in [0, 30]")

    @property
    def M(self) -> float:
        """Shell body mass used in the equations, ``M_s + m_b``, kg."""
        return self.M_s + self.m_b

    @property
    def tilt_x(self) -> float:
        """In-plane gravity along the floor's x axis, per g: ``sin(slope) cos(slope_dir)``."""
        return math.sin(self.slope) * math.cos(self.slope_dir)

    @property
    def tilt_y(self) -> float:
        """In-plane gravity along the floor's y axis, per g: ``sin(slope) sin(slope_dir)``."""
        return math.sin(self.slope) * math.sin(self.slope_dir)

    @property
    def total_mass(self) -> float:
        """Mass of the whole robot, ``M_s + m_b + m``, kg."""
        return self.M + self.m

    def vector(self) -> np.ndarray:
        """The numeric parameter vector ``p`` in the order of ``PARAM_VECTOR_FIELDS``."""
        return np.array([float(getattr(self, name)) for name in PARAM_VECTOR_FIELDS])

    @property
    def derived(self) -> frozenset:
        """Names of the fields that hold their derived default (``k0``, ``max_torque``), not a given value."""
        return self._derived

    def with_changes(self, **changes) -> "RollbotParams":
        """A copy with some fields changed (SI units) in which derived defaults follow the new values.

        ``k0`` and ``max_torque``, where they hold their derived default here
        and are not in ``changes``, are derived again from the new values
        (the rule of parameter and problem files); given values stay.
        """
        following = {name: None for name in self._derived if name not in changes}
        return dataclasses.replace(self, **changes, **following)

    def replace(self, **changes) -> "RollbotParams":
        """A copy with some fields changed (SI units), validated again.

        ``k0`` and ``max_torque`` keep their current values unless given; pass
        ``k0=None`` to recompute the paper's default from the new M and R.  A
        derived default whose value the change leaves as it was stays derived.
        """
        new = self.with_changes(**changes)
        moved = {name: getattr(self, name) for name in self._derived - set(changes)
                 if getattr(new, name) != getattr(self, name)}
        return new.with_changes(**moved) if moved else new

    def to_file_dict(self) -> dict[str, float]:
        """The parameters under their TOML keys, in file units (degrees for ``_deg``)."""
        return {key: getattr(self, attr) / scale for key, (attr, scale, *_) in _FILE_KEYS.items()}

    def described(self, given=()) -> list[dict]:
        """Every parameter under its TOML key with its unit, meaning and where its value came from.

        Parameters
        ----------
        given : collection of str
            The TOML keys a file set (``read_params_table``).

        Returns
        -------
        list of dict
            One per key, in the file's order: ``key``, ``value`` (file units,
            degrees for ``_deg``), ``unit``, ``meaning`` and ``source``:
            ``"file"`` for a key in ``given``, ``"derived"`` for a derived
            default that follows the other values (``derived``), else ``"default"``.
        """
        values = self.to_file_dict()
        return [{"key": key, "value": values[key], "unit": unit, "meaning": meaning,
                 "source": "file" if key in given else "derived" if attr in self._derived else "default"}
                for key, (attr, _, unit, meaning) in _FILE_KEYS.items()]

    @classmethod
    def from_file_dict(cls, data: dict, source: str = "parameters",
                       base: "RollbotParams | None" = None) -> "RollbotParams":
        """Build parameters from a mapping of TOML keys (file units) on top of ``base``.

        Keys missing from ``data`` keep ``base``'s values (the paper's
        prototype by default), except derived defaults (``k0``,
        ``max_torque``), which follow the new values unless ``data`` or
        ``base`` set them explicitly.

        Raises
        ------
        ConfigError
            On a mapping that is not a table, an unknown key (listing the
            valid ones), a non-number or a value out of its range.
        """
        if not isinstance(data, dict):
            raise ConfigError(f"{source}: expected a table of parameters, got {data!r}")
        unknown = sorted(map(str, set(data) - set(_FILE_KEYS)))
        if unknown:
            raise ConfigError(
                f"{source}: unknown key(s) {', '.join(unknown)}; valid keys are {', '.join(_FILE_KEYS)}"
            )
        kwargs = {}
        for key, (attr, scale, *_) in _FILE_KEYS.items():
            if key not in data:
                continue
            value = data[key]
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(float(value)):
                raise ConfigError(f"{source}: key {key} = {value!r} must be a finite number")
            kwargs[attr] = float(value) * scale
        try:
            return (base or cls()).with_changes(**kwargs)
        except ConfigError as exc:
            raise ConfigError(f"{source}: {exc}") from None


def read_toml(path: str | Path, what: str) -> dict:
    """The contents of a small UTF-8 TOML file (a byte-order mark is allowed).

    Parameters
    ----------
    path : str or Path
    what : str
        What the file is, for messages (``"parameter file"``).

    Raises
    ------
    ConfigError
        Naming the file: an empty path, a missing or unreadable file, a
        folder, a file larger than 1 MiB, text that is not UTF-8, or invalid TOML.
    """
    path = user_path(path, what)
    try:
        with open(path, "rb") as handle:  # a pipe works too (--params <(...)); the size bound keeps /dev/zero out
            raw = handle.read(MAX_FILE_BYTES + 1)
    except FileNotFoundError:
        raise ConfigError(f"{what} {path} does not exist") from None
    except IsADirectoryError:
        raise ConfigError(f"{what} {path} is a folder, not a file") from None
    except OSError as exc:
        raise ConfigError(f"{what} {path} cannot be read ({exc.strerror or exc})") from None
    if len(raw) > MAX_FILE_BYTES:
        raise ConfigError(f"{what} {path} is larger than {MAX_FILE_BYTES >> 20} MiB: not a {what}")
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{what} {path} is not UTF-8 text (byte {exc.start})") from None
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{what} {path} is not valid TOML: {exc}") from None
    except RecursionError:
        raise ConfigError(f"{what} {path} is not valid TOML: nested too deeply") from None


def read_params_table(path: str | Path) -> dict:
    """The parameter table of a TOML file: its top level, or its ``[params]`` table if it has one.

    Raises
    ------
    ConfigError
        If the file is missing or unreadable or is not valid TOML (see ``read_toml``).
    """
    data = read_toml(path, "parameter file")
    return data["params"] if "params" in data and isinstance(data["params"], dict) else data


def load_params(path: str | Path | None) -> RollbotParams:
    """Load parameters from a TOML file; ``None`` gives the paper's prototype.

    Parameters
    ----------
    path : str, Path or None
        TOML file with any subset of the documented keys, at top level or in
        a ``[params]`` table.

    Returns
    -------
    RollbotParams

    Raises
    ------
    ConfigError
        If the file is missing or unreadable, is not valid TOML, or holds a
        bad key or value.
    """
    if path is None:
        return RollbotParams()
    return RollbotParams.from_file_dict(read_params_table(path), source=f"parameter file {path}")


def save_params(params: RollbotParams, path: str | Path) -> None:
    """Write parameters to a TOML file (all keys, file units), atomically."""
    lines = ["# Rollbot parameters (rollbot_oc); SI units, angles in degrees for *_deg keys"]
    lines += [f"{key} = {value!r}" for key, value in params.to_file_dict().items()]
    atomic_write_text(Path(path), "\n".join(lines) + "\n")
