"""The control step's C: the three Functions of ``control.nmpc.period`` generated as one self-contained C99 file.

``step_source`` generates ``rollbot_step.c`` and its header (no CasADi headers, no heap: the work arrays come
from the caller) with two edits: a failed QP returns normally, as in CasADi's virtual machine, and ``qrqp``
keeps its factors when its KKT matrix has not changed (``_keep_unchanged_factors``: the same outputs, one
factorisation fewer per converged QP).  The NMPC compiles exactly this source (``compiled_step``, through the
cache of ``rollbot_oc.model.codegen``) and ``export-c`` writes it into the C project, so the Python NMPC and the C
controller run the same code, built with the same flags (``FLAGS``).
"""

from __future__ import annotations

import hashlib
import json
import os
import tempfile
from dataclasses import dataclass
from pathlib import Path

import casadi as ca

from rollbot_oc.core.errors import ConfigError
from rollbot_oc.model.codegen import cache_dir, compiled_source

__all__ = ["StepSource", "step_source", "compiled_step", "load_library", "step_key", "patched", "cached_library", "FLAGS", "NAMES", "LIBRARY",
           "MANIFEST"]

FLAGS = ("-O1", "-ffp-contract=off")  # no fused multiply-adds, on any target: the last bits agree
NAMES = ("rollbot_measure", "rollbot_solve", "rollbot_commit")
LIBRARY = "librollbot_step.so"  # the step's library in a folder written by export-c (``make`` builds it)
MANIFEST = "step.json"  # beside it: the key of the step it was generated from


@dataclass(frozen=True)
class StepSource:
    """The step's generated C.

    Attributes
    ----------
    source, header : str
        ``rollbot_step.c`` and ``rollbot_step.h``.
    key : str
        A digest of the Functions the source was generated from (serialised) and of ``FLAGS``.
    """

    source: str
    header: str
    key: str


def step_key(functions) -> str:
    """What identifies the step's C: a digest of its Functions (``StepFunctions``) and of ``FLAGS``."""
    return _key([functions.measure, functions.solve, functions.commit])


def _key(functions) -> str:
    text = " ".join(f.serialize() for f in functions) + " ".join(FLAGS) + ca.__version__
    return hashlib.sha1(text.encode()).hexdigest()[:16]


def step_source(functions) -> StepSource:
    """The C of the step's Functions (``StepFunctions``: its ``measure``, ``solve`` and ``commit``)."""
    funs = [functions.measure, functions.solve, functions.commit]
    with tempfile.TemporaryDirectory() as tmp:
        gen = ca.CodeGenerator("rollbot_step.c", {"with_header": True})
        for fun in funs:
            gen.add(fun)
        gen.generate(tmp + os.sep)
        source = patched((Path(tmp) / "rollbot_step.c").read_text())
        header = (Path(tmp) / "rollbot_step.h").read_text()
    return StepSource(source, header, step_key(functions))


def cached_library(functions) -> Path | None:
    """The compiled step library in the codegen cache (built if need be: ``compiled_step``), or None."""
    if compiled_step(functions) is None:
        return None
    path = cache_dir() / f"rollbot_step_{step_key(functions)}.so"
    return path if path.is_file() else None


def compiled_step(functions) -> dict | None:
    """``{name: Function}`` of the step's compiled C (``step_source``, built once and cached), or None where it
    cannot be compiled (a one-line warning)."""
    funs = [functions.measure, functions.solve, functions.commit]
    return compiled_source("rollbot_step", _key(funs), lambda: step_source(functions).source, NAMES, FLAGS)


def patched(source: str) -> str:
    """Generated C with a QP step and ``qrqp`` in it, edited for the step (module doc): a failed QP returns
    normally (``_qp_failure_not_an_error``) and unchanged KKT factors are kept (``_keep_unchanged_factors``).

    Raises
    ------
    RuntimeError
        If the generated code is not the one expected, or allocates memory on the heap.
    """
    source = _keep_unchanged_factors(_qp_failure_not_an_error(source))
    if "malloc" in source or "calloc" in source:
        raise RuntimeError("the generated step allocates memory on the heap")
    return source


_QP_STATUS_RETURN = """  if (d.status == QP_SUCCESS) {;
    return 0;
  } else if (d.status == QP_NO_SEARCH_DIR) {
    return 4;
  } else {
    return -1;
  }
"""


def _qp_failure_not_an_error(source: str) -> str:
    """The generated QP solvers returning normally when their QP fails, as they do in CasADi's virtual
    machine (``error_on_fail`` off): the step judges a QP by the violation of its step
    (``SQPRoute.to_function``), and a generated call that returns an error would end the whole step."""
    if source.count(_QP_STATUS_RETURN) < 1:
        raise RuntimeError("the generated QP solver's status return is not the one expected (CasADi version?)")
    return source.replace(_QP_STATUS_RETURN, "  /* a failed QP is judged by the step's violation */\n")


_QRQP_FACTORISE = """  if (d->has_search_dir) {
    d->sing = 1;
    return;
  }
  casadi_qrqp_kkt(d);
"""
_QRQP_KEEP_FACTORS = """  if (d->has_search_dir) {
    d->sing = 1;
    return;
  }
  /* rollbot_oc: no active-set change since this solve's last regular factorisation: its factors stand */
  if (d->iter > 0 && d->index == -1 && !d->sing) return;
  casadi_qrqp_kkt(d);
"""


def _keep_unchanged_factors(source: str) -> str:
    """The generated ``qrqp`` not factorising its KKT matrix again when it has not changed.

    ``qrqp`` forms and factorises its KKT matrix at every iteration (``casadi_qrqp_prepare``), including
    the last, whose only use is the convergence test.  That matrix depends on the QP's data, fixed during a
    solve, and on which multipliers are zero (``casadi_qrqp_kkt``); only ``casadi_qrqp_flip`` changes that
    pattern, and when it does ``index`` is left at the flipped constraint (``calc_dependent`` and
    ``take_step`` keep zeros zero and non-zeros non-zero).  The factors are overwritten elsewhere only by
    ``casadi_qrqp_singular_step``, which runs only after a singular factorisation.  So after this solve's
    first factorisation (``iter > 0``), with no flip (``index == -1``) and the factors in place regular
    (``sing == 0``), factorising again gives the same factors bit for bit: keeping them changes no output
    and halves the factorisations of a typical warm-started solve (one step, then the test).
    """
    if source.count(_QRQP_FACTORISE) < 1:
        raise RuntimeError("the generated qrqp factorisation is not the one expected (CasADi version?)")
    return source.replace(_QRQP_FACTORISE, _QRQP_KEEP_FACTORS)


def load_library(folder, functions) -> tuple[dict, str]:
    """``({name: Function}, sha256)`` of the step library of a folder written by ``export-c`` and built
    (``LIBRARY``), checked against the step the controller would build (``MANIFEST``'s key).

    Raises
    ------
    ConfigError
        If the folder holds no manifest or library, was exported for another step (another problem
        kind or settings), or the library does not load.
    """
    folder = Path(folder)
    try:
        key = json.loads((folder / MANIFEST).read_text())["key"]
    except (OSError, ValueError, KeyError, TypeError):
        raise ConfigError(f"{folder}: not a folder written by rollbot-oc export-c (no readable {MANIFEST})") from None
    expected = step_key(functions)
    if key != expected:
        raise ConfigError(f"{folder}: exported for another step (key {key}, this controller's is {expected}: "
                          "another problem kind or settings; the robot is the memory's, set by the host)")
    path = folder / LIBRARY
    try:
        loaded = {name: ca.external(name, str(path.resolve())) for name in NAMES}
    except RuntimeError as exc:
        raise ConfigError(f"{path}: the step's library does not load ({str(exc).splitlines()[-1][:80]}); "
                          f"build it with make -C {folder} {LIBRARY}") from None
    return loaded, hashlib.sha256(path.read_bytes()).hexdigest()
