"""Writing result files: whole files only (temporary file, then rename), with versions."""

from __future__ import annotations

import io
import json
import os
import platform
import tempfile
from pathlib import Path

import numpy as np

__all__ = ["atomic_write_bytes", "atomic_write_text", "write_json", "save_npz", "versions"]


def atomic_write_bytes(path: str | Path, data: bytes) -> Path:
    """Write ``data`` to ``path`` through a temporary file in the same folder, then rename.

    A reader never sees a half-written file, and an interrupted write leaves
    the previous file (if any) intact.  Parent folders are created.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as handle:
            handle.write(data)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    return path


def atomic_write_text(path: str | Path, text: str) -> Path:
    """Write UTF-8 text atomically (see ``atomic_write_bytes``)."""
    return atomic_write_bytes(path, text.encode("utf-8"))


def _json_default(obj):
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, (np.floating, np.integer, np.bool_)):
        return obj.item()
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"cannot write {type(obj).__name__} to JSON")


def to_json(obj, indent: int | None = 2) -> str:
    """JSON text of ``obj``; numpy arrays and scalars become lists and numbers."""
    return json.dumps(obj, indent=indent, default=_json_default, allow_nan=True)


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
    import casadi
    import scipy

    from rollbot_oc import __version__

    found = {"python": platform.python_version(), "rollbot_oc": __version__,
             "casadi": casadi.__version__, "numpy": np.__version__, "scipy": scipy.__version__}
    try:
        import control

        found["control"] = control.__version__
    except ImportError:  # optional at this level
        pass
    return found
