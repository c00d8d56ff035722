"""The standalone C project of the NMPC's control step (``rollbot-oc export-c``).

``export_c(out, problem)`` builds the NMPC of ``problem`` (``NMPCSettings.embedded()`` by default), runs it in
closed loop on the problem with a recorder on its step (``export.replay.StepRecorder``: per period what the
board's step received from the host's supervisor and what it gave), and writes into the folder ``out``:

* ``rollbot_step.c``, ``rollbot_step.h``, ``step.json``, ``step.mk``: the step's three Functions generated as
  one C file, the source the Python NMPC compiles and runs (``export.step_library``), and its library
  ``librollbot_step.so`` (the NMPC's own build, copied from the codegen cache where there is a compiler);
* ``rollbot_config.h``, ``rollbot_data.c``: sizes and memory offsets, and the initial memory (generated);
* ``rollbot_controller.h``, ``rollbot_controller.c``: the documented API around the step (``rollbot_init``,
  ``rollbot_set_memory``, ``rollbot_period_measure``, ``rollbot_period_solve``, ``rollbot_period_commit``),
  and ``rollbot_replay.h``, ``rollbot_replay.c``, ``main.c``: the replay (written by hand, in
  ``rollbot_oc/export/c``);
* ``replay_log.bin``: the recorded run (``export.replay``);
* ``README.md``; ``Makefile``: ``make`` builds ``replay`` and ``librollbot_controller.so`` (the API linked to
  ``librollbot_step.so``: the step is not compiled again), ``make check`` replays the log and fails if a command
  differs by more than 1e-9 rad/s^2 or an event or mode differs;
* ``export.json``: what was exported (sizes in bytes, the recorded run's metrics, the target);
* with ``target="cortex-m7"``, the firmware build too (``export.firmware``: ``make qemu-check`` replays the
  recorded run on QEMU's Cortex-M7 board).

The supervisor (modes, plans, reference windows) stays on the host, as on a robot with a link: the replay gives
the step the windows the host computed.  Every file is written whole (``outputs.atomic_write_text``).
``build(out)`` runs ``make`` there.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

from rollbot_oc.control.nmpc.settings import NMPCSettings
from rollbot_oc.core.errors import ConfigError
from rollbot_oc.core.outputs import OutputFolder, atomic_write_bytes, atomic_write_text, to_json
from rollbot_oc.export.firmware import TARGETS, remove_firmware, write_firmware
from rollbot_oc.export.replay import StepRecorder, replay_bytes
from rollbot_oc.export.step_library import write_functions
from rollbot_oc.model.codegen import compiler
from rollbot_oc.scenarios.problem import make_controller, run_problem

__all__ = ["export_c", "ExportResult", "build", "read_export", "HAND_WRITTEN", "LOG_NAME", "BUILD_TIMEOUT",
           "RECORD_SECONDS"]

HAND_WRITTEN = ("rollbot_controller.h", "rollbot_controller.c", "rollbot_replay.h", "rollbot_replay.c", "main.c",
                "Makefile", "README.md")
LOG_NAME = "replay_log.bin"
BUILD_TIMEOUT = 900.0  # s, for make
RECORD_SECONDS = 60.0  # the recorded run's longest, s: a circle's run never ends (a log of about 60 kB a second)


@dataclass
class ExportResult:
    """What ``export_c`` wrote and recorded.

    Attributes
    ----------
    folder : Path
    functions : StepFunctions
        The step's Functions (``control.nmpc.period``).
    metrics : dict
        The recorded closed-loop run of the NMPC (``scenarios.problem.compute_metrics``).
    log : list of export.replay.Period
        Every period of that run as the step saw it.
    sizes : dict
        Bytes of the step's memory, of a reference window and of the generated code's work arrays.
    step : dict
        What ``step.json`` holds (the step's key, sizes).
    """

    folder: Path
    functions: object
    metrics: dict
    log: list
    sizes: dict
    step: dict

    @property
    def solves(self) -> int:
        """Solve instants of the recorded run."""
        return sum(p.window is not None for p in self.log)


def _work(header: str) -> dict:
    """The largest work sizes (``SZ_ARG`` ...) of the three generated functions, from their header."""
    found = {}
    for line in header.splitlines():
        parts = line.split()
        if len(parts) == 3 and parts[0] == "#define" and "_SZ_" in parts[1]:
            key = parts[1].split("_SZ_")[1]
            found[key] = max(found.get(key, 0), int(parts[2]))
    return found


def _sizes(f, work: dict) -> dict:
    """Bytes of the memory, a window and the work arrays (``casadi_int`` is ``long long``; 8-byte pointers on the
    64-bit host, 4-byte on a 32-bit MCU)."""
    return {"memory_bytes": 8 * f.memory.size, "window_bytes": 8 * f.window.size,
            **{f"sz_{k.lower()}": v for k, v in work.items()},
            "work_bytes": 8 * (work["ARG"] + work["RES"] + work["IW"] + work["W"])}


def _config_header(f, work: dict, settings: NMPCSettings) -> str:
    L, tr = f.memory, f.solver.route.transcription
    lines = ["/* rollbot_config.h - generated by rollbot-oc export-c: sizes and offsets of the exported step. */",
             "#ifndef ROLLBOT_CONFIG_H", "#define ROLLBOT_CONFIG_H", "",
             f"#define ROLLBOT_N {settings.horizon.N}  /* intervals of the horizon */",
             f"#define ROLLBOT_EVERY {f.every}  /* control periods per interval (solve instants) */",
             f"#define ROLLBOT_DT {f.dt!r}  /* control period, s */",
             f"#define ROLLBOT_H {settings.horizon.h!r}  /* interval of the horizon, s */",
             f"#define ROLLBOT_MEM_SIZE {L.size}  /* doubles of the step's memory */",
             f"#define ROLLBOT_WINDOW_SIZE {f.window.size}  /* doubles of a reference window */",
             f"#define ROLLBOT_NW {tr.w.numel()}  /* decision variables of the tracking problem */",
             f"#define ROLLBOT_NG {tr.g.numel()}  /* its constraints */"]
    for key in ("ARG", "RES", "IW", "W"):
        lines.append(f"#define ROLLBOT_SZ_{key} {max(work[key], 1)}  /* work array of the generated functions */")
    for name, sl in L.slices.items():
        macro = {"p": "PARAMS", "P": "COVARIANCE"}.get(name, name.upper())  # distinct in C's upper case
        lines.append(f"#define ROLLBOT_MEM_{macro} {sl.start}  /* offset of '{name}' ({sl.stop - sl.start})"
                     " in the memory */")
    lines += ["", f"extern const double rollbot_initial_memory[{L.size}];", "", "#endif", ""]
    return "\n".join(lines)


def _data_source(f) -> str:
    values = [repr(float(v)) for v in f.initial_memory]
    rows = [", ".join(values[i:i + 4]) for i in range(0, len(values), 4)]
    return "\n".join(["/* rollbot_data.c - generated by rollbot-oc export-c: the step's initial memory. */",
                      '#include "rollbot_config.h"', "",
                      f"const double rollbot_initial_memory[{len(values)}] = {{", "    " + ",\n    ".join(rows),
                      "};", ""])


def export_c(out, problem, params=None, settings: NMPCSettings | None = None, seed: int = 0,
             show_progress: bool | None = False, target: str = "host", duration: float | None = None,
             preset: str | None = None) -> ExportResult:
    """Export the NMPC's control step for ``problem`` as a C project in the folder ``out`` (module doc).

    Parameters
    ----------
    out : str or Path
        Output folder (created; ``outputs.OutputFolder``).
    problem : Problem
        A closed-loop problem (stops, a circle, gates); the recorded run is the NMPC's on it.
    params : RollbotParams, optional
        The robot the controller believes in (the problem's on a level floor by default).
    settings : NMPCSettings, optional
        The NMPC's settings (``NMPCSettings.embedded()`` by default); its solver must be ``rti``.
    seed : int
        Seed of the recorded run's sensor noise.
    show_progress : bool or None
        Progress of the recorded run on stderr (as for ``scenarios.problem.run_problem``).
    target : str
        One of ``firmware.TARGETS``: ``host`` (the C project alone) or ``cortex-m7`` (the firmware build too).
    duration : float, optional
        The recorded run's duration, s (the problem's, at most ``RECORD_SECONDS``, by default; a course of stops
        ends when it is done).
    preset : str, optional
        The name of the settings' preset, kept in ``step.json`` (``settings``) for ``run --controller c``
        (``embedded`` or ``nmpc`` when the settings are ``NMPCSettings.embedded()`` or the defaults, by default).

    Raises
    ------
    ConfigError
        If ``target`` is not one of ``firmware.TARGETS``, ``out`` cannot be a folder, the problem is open loop or
        the settings' solver is not ``rti`` (IPOPT has no C).
    """
    if target not in TARGETS:
        raise ConfigError(f"target {target!r} is not one of: {', '.join(TARGETS)}")
    if not problem.mission.closed_loop:
        raise ConfigError(f"export-c: {problem.name} is an open-loop problem; the controller is exported for "
                          "closed-loop problems")
    s = settings or NMPCSettings.embedded()
    if s.horizon.solver != "rti":
        raise ConfigError(f"export-c: horizon.solver = {s.horizon.solver!r}; the exported step is the real-time "
                          "iteration: valid is 'rti'")
    if preset is None:
        preset = s.preset_name()
    folder = OutputFolder(out)  # checked and created before anything is computed
    nmpc = make_controller("nmpc", problem, params, settings=s)
    f = nmpc.step.functions
    recorder = nmpc.step.recorder = StepRecorder(f.initial_memory, f.memory["mode"])
    run = run_problem(problem, nmpc, seed=seed, show_progress=show_progress,
                      duration=duration if duration is not None else min(problem.duration, RECORD_SECONDS))
    nmpc.step.recorder = None
    log = recorder.periods
    step = write_functions(folder.path, f, problem.name, s, preset)
    work = _work((folder / "rollbot_step.h").read_text())
    sizes = _sizes(f, work)
    atomic_write_text(folder / "rollbot_config.h", _config_header(f, work, s))
    atomic_write_text(folder / "rollbot_data.c", _data_source(f))
    templates = resources.files("rollbot_oc.export") / "c"
    for name in HAND_WRITTEN:
        atomic_write_text(folder / name, (templates / name).read_text())
    atomic_write_bytes(folder / LOG_NAME, replay_bytes(log, f.memory.size, f.window.size))
    if target == "host":
        remove_firmware(folder.path)
    else:
        write_firmware(folder.path)
    metrics = {k: v for k, v in run.metrics.items() if not k.startswith("step_time") and k != "wall_time"}
    atomic_write_text(folder / "export.json", to_json({
        "problem": problem.name, "target": target, "periods": len(log),
        "solves": sum(p.window is not None for p in log), "step": {k: step[k] for k in ("key", "memory", "window",
                                                                                          "N", "h", "dt")},
        "sizes": sizes, "metrics": metrics}) + "\n")
    return ExportResult(folder.path, f, run.metrics, log, sizes, step)


def build(folder, target: str | None = None, jobs: int = 1) -> subprocess.CompletedProcess:
    """Run ``make`` (or ``make target``, several targets separated by spaces) in an exported folder; the
    completed process (its output kept).

    Raises
    ------
    ConfigError
        If there is no ``make`` or no C compiler.
    """
    if shutil.which("make") is None or compiler() is None:
        raise ConfigError("building the exported controller needs make and a C compiler (cc, gcc or clang)")
    env = dict(os.environ)
    env.setdefault("CC", compiler())
    command = ["make", "-C", str(folder), f"-j{jobs}"] + (target.split() if target else [])
    return subprocess.run(command, capture_output=True, text=True, timeout=BUILD_TIMEOUT, env=env)


def read_export(folder) -> dict:
    """The ``export.json`` of an exported folder."""
    return json.loads((Path(folder) / "export.json").read_text())
