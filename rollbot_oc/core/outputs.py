"""Writing result files: whole files only (temporary file, then rename), inside their output folder.

* ``output_folder`` checks (and creates) a folder given by the user before
  anything is computed; ``OutputFolder.file`` names a file inside it and
  refuses any name that would leave it.
* ``atomic_path``, ``atomic_write_bytes``, ``atomic_write_text``,
  ``write_json`` and ``save_npz`` write whole files: a temporary file in the
  same folder, renamed over the target, with the permissions the user's umask
  gives a new file (``0o666 & ~umask``, not the temporary file's 0600).
* ``to_json`` writes strict JSON (RFC 8259): NaN and infinities become
  ``null``, numpy arrays and scalars become lists and numbers.
"""

from __future__ import annotations

import io
import json
import math
import os
import platform
import tempfile
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from rollbot_oc.core.errors import ConfigError
from rollbot_oc import __version__

__all__ = ["atomic_path", "atomic_write_bytes", "atomic_write_text", "write_json", "save_npz", "versions",
           "to_json", "json_ready", "output_folder", "OutputFolder", "file_mode", "user_path"]


def user_path(text: str | Path, what: str) -> Path:
    """A path the user gave (an option or argument), as a Path.

    Raises
    ------
    ConfigError
        If it is empty or holds a NUL character (``what`` names it in the message).
    """
    text = str(text)
    if not text.strip():
        raise ConfigError(f"{what}: the path is empty")
    if "\0" in text:
        raise ConfigError(f"{what} {text!r}: a path cannot hold a NUL character")
    return Path(text)


def file_mode() -> int:
    """Permission bits of a new file under the current umask, ``0o666 & ~umask``."""
    mask = os.umask(0)  # reading the umask means setting it: put it straight back
    os.umask(mask)
    return 0o666 & ~mask


@contextmanager
def atomic_path(path: str | Path, mode: str | None = "wb"):
    """Yield an open temporary file beside ``path``; on success it becomes ``path`` whole.

    The temporary file lives in the target's folder (so the rename is atomic)
    and gets the permissions of a new file under the umask before the rename.
    On any error (Ctrl-C included) it is removed and a previous ``path``
    stays intact.  The parent folder is created.

    Parameters
    ----------
    path : str or Path
        The file to write.
    mode : str
        ``"wb"`` (bytes) or ``"w"`` (UTF-8 text); ``None`` yields the
        temporary file's path instead of an open file (for writers that open
        the path themselves, such as matplotlib's animation writers).
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=f".tmp{path.suffix}")
    try:
        os.fchmod(fd, file_mode())
        if mode is None:
            os.close(fd)
            yield Path(tmp)
        else:
            with os.fdopen(fd, mode, **({} if "b" in mode else {"encoding": "utf-8"})) as handle:
                yield handle
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def atomic_write_bytes(path: str | Path, data: bytes) -> Path:
    """Write ``data`` to ``path`` whole (see ``atomic_path``); returns ``path``."""
    with atomic_path(path) as handle:
        handle.write(data)
    return Path(path)


def atomic_write_text(path: str | Path, text: str) -> Path:
    """Write UTF-8 text atomically (see ``atomic_write_bytes``)."""
    return atomic_write_bytes(path, text.encode("utf-8"))


def json_ready(obj):
    """``obj`` with NaN and infinities as None and numpy values as Python ones, recursively.

    Dicts, lists, tuples, numpy arrays and scalars are converted; paths become
    strings; other objects are returned unchanged (``json`` then rejects them).
    """
    if isinstance(obj, dict):
        return {key: json_ready(value) for key, value in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [json_ready(value) for value in obj]
    if isinstance(obj, np.ndarray):
        return json_ready(obj.tolist())
    if isinstance(obj, np.generic):
        return json_ready(obj.item())
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    if isinstance(obj, Path):
        return str(obj)
    return obj


def to_json(obj, indent: int | None = 2) -> str:
    """Strict JSON text of ``obj`` (see ``json_ready``): never ``NaN`` or ``Infinity``."""
    return json.dumps(json_ready(obj), indent=indent, allow_nan=False)


def write_json(path: str | Path, obj) -> Path:
    """Write ``obj`` as JSON atomically, with a ``versions`` record if ``obj`` is a dict."""
    if isinstance(obj, dict) and "versions" not in obj:
        obj = {**obj, "versions": versions()}
    return atomic_write_text(path, to_json(obj) + "\n")


def save_npz(path: str | Path, **arrays) -> Path:
    """Save arrays to a compressed ``.npz`` file atomically."""
    buffer = io.BytesIO()
    np.savez_compressed(buffer, **arrays)
    return atomic_write_bytes(path, buffer.getvalue())


def versions() -> dict[str, str]:
    """Versions of Python, rollbot_oc and the numerical packages, for reproducible outputs."""
    import casadi  # start-up: these are imported here, where a result is written, not by every user of outputs
    import scipy

    found = {"python": platform.python_version(), "rollbot_oc": __version__,
             "casadi": casadi.__version__, "numpy": np.__version__, "scipy": scipy.__version__}
    try:
        import control  # slow to import; see above

        found["control"] = control.__version__
    except ImportError:  # optional at this level
        pass
    return found


class OutputFolder:
    """A folder the user named for a command's files, checked and created up front.

    Parameters
    ----------
    path : str or Path
        The folder; missing parents are created.
    option : str
        How the user gave it (``"--out"``), for error messages.

    Raises
    ------
    ConfigError
        If ``path`` is a file, a parent is a file, or the folder cannot be
        created or written to.
    """

    def __init__(self, path: str | Path, option: str = "--out"):
        self.option = option
        self.path = user_path(path, option)
        if self.path.exists() and not self.path.is_dir():
            raise ConfigError(f"{option} {self.path}: exists and is not a folder")
        for parent in self.path.parents:
            if parent.exists() and not parent.is_dir():
                raise ConfigError(f"{option} {self.path}: {parent} is a file, not a folder")
        try:
            self.path.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise ConfigError(f"{option} {self.path}: cannot create the folder ({exc.strerror})") from None
        if not os.access(self.path, os.W_OK | os.X_OK):
            raise ConfigError(f"{option} {self.path}: the folder is not writable")

    def file(self, name: str) -> Path:
        """The path of the file ``name`` inside the folder.

        Raises
        ------
        ConfigError
            If ``name`` is not a plain file name (a separator, ``..``, empty):
            nothing is ever written outside the folder.
        """
        if not name or name in (".", "..") or "/" in name or os.sep in name or (os.altsep and os.altsep in name) \
                or "\0" in name:
            raise ConfigError(f"{self.option} {self.path}: {name!r} is not a plain file name")
        return self.path / name

    def __truediv__(self, name: str) -> Path:
        return self.file(name)

    def __str__(self) -> str:
        return str(self.path)


def output_folder(path: str | Path | None, option: str = "--out") -> OutputFolder | None:
    """``OutputFolder(path, option)``, or None when no folder was asked for."""
    return None if path is None else OutputFolder(path, option)
