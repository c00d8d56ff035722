"""The NMPC's control step as a C library in an exported folder: the source the Python NMPC compiles.

``write_step(folder, problem)`` builds the NMPC of ``problem`` (its mission kind, the robot the controller
believes in, its settings) and writes its step's generated C (``control.nmpc.source``): ``rollbot_step.c``,
``rollbot_step.h``, ``step.json`` (the key of the step, checked when the library is loaded) and
``step.mk``, the make rule of ``librollbot_step.so`` with the NMPC's own compiler flags; the library itself is
the one the NMPC compiled from the same source (copied from the codegen cache, where a compiler exists).  ``rollbot-oc run
PROBLEM --controller c --c-project FOLDER`` runs the NMPC with that library as its step: the same C as
``--controller nmpc``, so the two print the same metrics.
"""

from __future__ import annotations

from pathlib import Path

from rollbot_oc.control.nmpc.source import FLAGS, LIBRARY, MANIFEST, cached_library, step_source
from rollbot_oc.core.outputs import atomic_write_bytes, atomic_write_text, to_json
from rollbot_oc.scenarios.problem import make_controller

__all__ = ["write_step", "write_functions", "STEP_RULE"]

STEP_RULE = f"""# The NMPC's control step (rollbot_step.c: measure, solve, commit) as the library the Python NMPC loads
# with --controller c; built with the flags the NMPC compiles the same source with (STEP_FLAGS, on every target).
STEP_FLAGS = {' '.join(FLAGS)}
{LIBRARY}: rollbot_step.c rollbot_step.h
\t$(CC) -shared -fPIC $(STEP_FLAGS) rollbot_step.c -o $@ -lm
"""


def write_step(folder, problem, params=None, settings=None) -> dict:
    """Write the step of ``problem``'s NMPC into ``folder`` (module doc); returns what ``step.json`` holds.

    Parameters
    ----------
    folder : Path
        An output folder (created).
    problem : Problem
        Any closed-loop problem the NMPC takes (stops, a circle, gates).
    params : RollbotParams, optional
        The robot the controller believes in (the problem's on a level floor by default, as ``run``).
    settings : NMPCSettings, optional
    """
    nmpc = make_controller("nmpc", problem, params, **({"settings": settings} if settings else {}))
    return write_functions(folder, nmpc.step.functions, problem.name, nmpc.settings)


def write_functions(folder, f, problem_name: str, settings, preset: str | None = None) -> dict:
    """``write_step`` for the step Functions ``f`` (``StepFunctions``) of an NMPC with ``settings`` built for the
    problem ``problem_name`` (``preset``: the name of the settings' preset, if any); returns what ``step.json``
    holds."""
    source = step_source(f)
    folder = Path(folder)
    atomic_write_text(folder / "rollbot_step.c", source.source)
    atomic_write_text(folder / "rollbot_step.h", source.header)
    atomic_write_text(folder / "step.mk", STEP_RULE)
    manifest = {"key": source.key, "problem": problem_name, "library": LIBRARY, "memory": f.memory.size,
                "window": f.window.size, "settings": preset, "N": settings.horizon.N, "h": settings.horizon.h, "dt": f.dt,
                "functions": {name: {"inputs": fun.name_in(), "outputs": fun.name_out()}
                              for name, fun in zip(("measure", "solve", "commit"), (f.measure, f.solve, f.commit))}}
    atomic_write_text(folder / MANIFEST, to_json(manifest) + "\n")
    built = cached_library(f)  # the library the NMPC compiled from this source (``make`` rebuilds it)
    if built is not None:
        atomic_write_bytes(folder / LIBRARY, built.read_bytes())
    return manifest
