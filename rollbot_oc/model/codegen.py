"""Optional speed-up: CasADi Functions generated as C, compiled once, and loaded back.

CasADi evaluates SX Functions in its virtual machine; the same Function
generated as C and compiled runs several times faster (``benchmarks/`` and
the README give the figures).  Compiling takes seconds to a minute, so the shared library is cached on disk under a name derived
from the Function's serialised expression graph (so a changed model compiles anew), in
``$ROLLBOT_OC_CACHE`` or ``~/.cache/rollbot_oc``.

The cache is safe to share and hard to break:

* a library is written whole (temporary file, then rename) and is followed
  by a checksum file; only a library whose checksum matches is loaded, and
  one that fails to match or to load is rebuilt;
* processes compiling the same Function into one cache take turns (a file
  lock beside the library), so the work is done once;
* where no C compiler is found (``$CC``, ``gcc``, ``clang``, ``cc``), the
  compiler fails, or the cache folder cannot be used, ``compiled`` warns in
  one line and returns the Function unchanged: the toolkit runs everywhere,
  only slower.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import shutil
import subprocess
import tempfile
import warnings
from pathlib import Path

import casadi as ca

from rollbot_oc.core.outputs import atomic_write_bytes

try:
    import fcntl
except ImportError:  # not POSIX: no lock (the writes stay atomic)
    fcntl = None

__all__ = ["compiler", "compiled", "compiled_source", "cache_dir", "CompiledCodeWarning"]

COMPILE_TIMEOUT = 300.0  # s


class CompiledCodeWarning(UserWarning):
    """The compiled code could not be built or loaded; the (slower) uncompiled Function is used."""


def compiler() -> str | None:
    """Path of the C compiler (``$CC``, else ``gcc``, ``clang`` or ``cc``), or None if there is none."""
    for name in (os.environ.get("CC"), "gcc", "clang", "cc"):
        if name and shutil.which(name):
            return shutil.which(name)
    return None


def cache_dir() -> Path:
    """Folder of the compiled libraries (``$ROLLBOT_OC_CACHE`` or ``~/.cache/rollbot_oc``)."""
    return Path(os.environ.get("ROLLBOT_OC_CACHE") or Path.home() / ".cache" / "rollbot_oc")


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _load(name: str, target: Path) -> ca.Function | None:
    """The library at ``target`` if its checksum file matches and it loads, else None."""
    check = target.with_name(target.name + ".sha256")
    try:
        if not (target.is_file() and check.read_text().strip() == _digest(target)):
            return None
        return ca.external(name, str(target))
    except (OSError, RuntimeError):
        return None


@contextlib.contextmanager
def _locked(lock: Path):
    """Hold an exclusive lock on the file ``lock`` (created) while the block runs."""
    with open(lock, "a") as handle:
        if fcntl is not None:
            fcntl.flock(handle, fcntl.LOCK_EX)
        try:
            yield
        finally:
            if fcntl is not None:
                fcntl.flock(handle, fcntl.LOCK_UN)


def _build(cc: str, source: Path, target: Path, flags: tuple[str, ...]) -> str | None:
    """Compile ``source`` into ``target`` with its checksum file; returns the compiler's complaint, or None."""
    partial = source.with_suffix(".so")
    try:
        result = subprocess.run([cc, "-shared", "-fPIC", *flags, str(source), "-o", str(partial), "-lm"],
                                capture_output=True, text=True, timeout=COMPILE_TIMEOUT)
    except (OSError, subprocess.TimeoutExpired) as exc:
        return str(exc)
    if result.returncode != 0 or not partial.is_file():
        lines = (result.stderr or result.stdout).strip().splitlines()
        return f"{Path(cc).name} exited with status {result.returncode}" + (f": {lines[0]}" if lines else "")
    data = partial.read_bytes()
    atomic_write_bytes(target, data)  # the library, whole ...
    atomic_write_bytes(target.with_name(target.name + ".sha256"), hashlib.sha256(data).hexdigest().encode())
    return None  # ... then its checksum: a library without a matching checksum is never loaded


def _key(fun: ca.Function, flags: tuple[str, ...], jacobian: bool) -> str:
    """The library's name in the cache: a digest of the Function's serialised expression graph (the same graph
    generates the same C; serialising takes milliseconds where generating the C of a large Function and its
    Jacobian takes a second), the flags, whether the Jacobian is in, and the CasADi version."""
    text = f"{fun.serialize()} {' '.join(flags)} jacobian={jacobian} {ca.__version__}"
    return hashlib.sha1(text.encode()).hexdigest()[:16]


def compiled(fun: ca.Function, flags: tuple[str, ...] = ("-O1",), jacobian: bool = False) -> ca.Function:
    """``fun`` as a compiled C library (built once and cached), or ``fun`` itself if that cannot be done.

    Parameters
    ----------
    fun : casadi.Function
        An SX Function (or any Function CasADi can generate C for).
    flags : tuple of str
        Compiler flags.
    jacobian : bool
        Also compile ``fun``'s Jacobian (by AD), which CasADi then uses for
        every derivative of the loaded Function (for example inside an NLP).

    Returns
    -------
    casadi.Function
        The compiled Function, or ``fun`` unchanged (with a one-line
        ``CompiledCodeWarning``) when there is no compiler, it fails, or the
        cache folder cannot be created or written.
    """

    def source() -> str:
        with tempfile.TemporaryDirectory() as tmp:
            gen = ca.CodeGenerator(f"{fun.name()}.c", {"with_header": False})
            gen.add(fun)
            if jacobian:
                gen.add(fun.jacobian())
            gen.generate(tmp + os.sep)
            return (Path(tmp) / f"{fun.name()}.c").read_text()

    key = _key(fun, flags, jacobian)
    loaded = compiled_source(fun.name(), key, source, [fun.name()], flags)
    return loaded[fun.name()] if loaded is not None else fun


def compiled_source(name: str, key: str, source, functions, flags: tuple[str, ...] = ("-O1",)) -> dict | None:
    """The Functions ``functions`` of the C ``source`` (a callable giving the text: called only when the library
    is not cached) compiled into one library ``name_key``, built once and cached; None, with a one-line
    ``CompiledCodeWarning``, when there is no compiler, it fails, or the cache folder cannot be used.

    Parameters
    ----------
    name : str
        The library's name.
    key : str
        What identifies the source (a digest of what it was generated from and the flags).
    source : callable
        ``() -> str``, the C source.
    functions : sequence of str
        The Functions of the library to load (``casadi.external``).
    flags : tuple of str
        Compiler flags.
    """
    cc = compiler()
    if cc is None:
        return None
    folder = cache_dir()
    try:
        folder.mkdir(parents=True, exist_ok=True)
        target = folder / f"{name}_{key}.so"
        loaded = _load_all(functions, target)  # the common case: built before, no lock and no code generated
        if loaded is not None:
            return loaded
        with _locked(folder / f"{name}_{key}.lock"), tempfile.TemporaryDirectory() as tmp:
            loaded = _load_all(functions, target)  # another process may have built it while we waited
            if loaded is not None:
                return loaded
            path = Path(tmp) / f"{name}.c"
            path.write_text(source())
            problem = _build(cc, path, target, flags)
            loaded = None if problem else _load_all(functions, target)
            if loaded is not None:
                return loaded
            problem = problem or "the compiled library does not load"
    except (FileExistsError, NotADirectoryError):
        problem = f"cache folder {folder}: a file is in the way"
    except OSError as exc:
        problem = f"cache folder {folder}: {exc.strerror or exc}"
    warnings.warn(f"compiled code for {name} unavailable ({problem}); using the slower uncompiled Function",
                  CompiledCodeWarning, stacklevel=3)
    return None


def _load_all(functions, target: Path) -> dict | None:
    loaded = {}
    for function in functions:
        loaded[function] = _load(function, target)
        if loaded[function] is None:
            return None
    return loaded
