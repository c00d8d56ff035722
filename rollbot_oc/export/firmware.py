"""The controller on a Cortex-M7: the firmware build an export adds for ``--target cortex-m7``.

``write_firmware(folder)`` writes, beside the C project of ``export.project`` (which holds the recorded run,
``replay_log.bin``: ``export.replay``):

* ``firmware_main.c``: the replay program, built for the Cortex-M7 (``app.elf``) and for the host
  (``firmware_host``): each period of the recorded run through the step as the board runs it (the host's
  edits of the memory, ``measure``, ``solve`` on the host's window at a solve instant, ``commit``: the
  project's ``rollbot_replay.c``), the commands written back, the instructions of every period and of every
  solve counted on QEMU's instruction clock;
* ``firmware_startup.c``, ``firmware_mps2_an500.ld``: the vector table, reset and memory of QEMU's
  ``mps2-an500`` board (Cortex-M7; code in flash, data copied to RAM at reset, static context, no heap in
  the step);
* ``firmware.mk`` (included by the ``Makefile``): ``make firmware`` with ``arm-none-eabi-gcc -mcpu=cortex-m7
  -mfpu=fpv5-d16 -mfloat-abi=hard -ffp-contract=off`` and newlib's semihosting (``--specs=rdimon.specs``),
  ``make qemu-check`` runs both builds on the first ``PERIODS`` periods and compares them; the step is compiled
  with the NMPC's own flags (``STEP_FLAGS``, ``step.mk``), the rest with ``-O2``
  (``firmware_check.py``);
* ``firmware_check.py``: the comparison (standard library only): ``max |diff| = ...`` against the host build,
  ``instructions per solve: median N, p95 N, max N``, RAM and flash from the linker map.

``qemu_check(folder)`` runs ``make qemu-check`` and ``parse_check`` reads what it printed.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
from importlib import resources
from pathlib import Path

from rollbot_oc.core.errors import ConfigError
from rollbot_oc.core.outputs import atomic_write_text

__all__ = ["TARGETS", "FIRMWARE_FILES", "TOOLS", "write_firmware", "remove_firmware", "missing_tools", "qemu_check",
           "parse_check"]

TARGETS = ("host", "cortex-m7")  # what ``export-c --target`` builds for: the host project, and the firmware too
FIRMWARE_FILES = ("firmware_main.c", "firmware_startup.c", "firmware_mps2_an500.ld", "firmware.mk",
                  "firmware_check.py")
TOOLS = ("arm-none-eabi-gcc", "qemu-system-arm", "make", "python3")
CHECK_TIMEOUT = 3600.0  # s, for make qemu-check (the build of the generated step takes about half a minute)


def write_firmware(folder):
    """Write the firmware's files into an exported folder (module doc)."""
    folder = Path(folder)
    templates = resources.files("rollbot_oc.export") / "c"
    for name in FIRMWARE_FILES:
        atomic_write_text(folder / name, (templates / name).read_text())


def remove_firmware(folder):
    """Remove the firmware's files from an exported folder (a host export over a Cortex-M7 one)."""
    for name in FIRMWARE_FILES:
        (Path(folder) / name).unlink(missing_ok=True)


def missing_tools() -> list[str]:
    """The tools ``make qemu-check`` needs that are not on the PATH (module doc; a C compiler for the host too)."""
    from rollbot_oc.model.codegen import compiler

    missing = [tool for tool in TOOLS if shutil.which(tool) is None]
    return missing + ([] if compiler() is not None else ["cc"])


def qemu_check(folder, periods: int | None = None, jobs: int = 2,
               timeout: float = CHECK_TIMEOUT) -> subprocess.CompletedProcess:
    """Run ``make qemu-check`` in a folder exported with ``--target cortex-m7`` (the completed process).

    ``periods``: the periods replayed (``firmware.mk``'s ``PERIODS`` by default, the first 170; 0 for the whole
    recorded run).

    Raises
    ------
    ConfigError
        If a tool is missing (``missing_tools``) or the folder has no firmware build.
    """
    from rollbot_oc.model.codegen import compiler

    missing = missing_tools()
    if missing:
        raise ConfigError(f"make qemu-check needs {', '.join(missing)} (Debian: apt-get install gcc-arm-none-eabi "
                          "libnewlib-arm-none-eabi qemu-system-arm)")
    if not (Path(folder) / "firmware.mk").is_file():
        raise ConfigError(f"{folder}: no firmware build (export with --target cortex-m7)")
    env = dict(os.environ)
    env.setdefault("CC", compiler())
    command = ["make", "-C", str(folder), f"-j{jobs}", "qemu-check"]
    if periods is not None:
        command.append(f"PERIODS={int(periods)}")
    return subprocess.run(command, capture_output=True, text=True, timeout=timeout, env=env)


def parse_check(text: str) -> dict:
    """The figures ``make qemu-check`` printed: ``diff``, ``statuses_differ``, ``diff_python``, ``periods``,
    ``solves``, ``per_solve``, ``per_interval`` and ``per_period`` (median, p95, max instructions), ``ram``, ``ram_context``,
    ``stack``, ``flash``, ``flash_code``, ``flash_constants``, ``image_ram``, ``image_flash``, ``passed``.

    Raises
    ------
    ValueError
        If a line is missing.
    """
    patterns = {
        "periods_solves": r"replayed (\d+) periods .*?, (\d+) solve instants",
        "diff": r"max \|diff\| = (\S+) .*?, (\d+) statuses differ",
        "diff_python": r"against the Python controller's recorded commands: (\S+),",
        "per_solve": r"instructions per solve: median (\d+), p95 (\d+), max (\d+)",
        "per_interval": r"instructions per interval: median (\d+), p95 (\d+), max (\d+)",
        "per_period": r"instructions per period: median (\d+), p95 (\d+), max (\d+)",
        "ram": r"RAM: step (\d+) bytes .*?: context (\d+) .*?stack peak (\d+); whole image (\d+) bytes",
        "flash": r"flash: step (\d+) bytes: code (\d+), constants (\d+) .*?; whole image (\d+) bytes",
        "passed": r"qemu-check (passed|FAILED)",
    }
    found = {}
    for key, pattern in patterns.items():
        m = re.search(pattern, text)
        if m is None:
            raise ValueError(f"make qemu-check printed no line matching {pattern!r}")
        found[key] = m.groups()
    return {"periods": int(found["periods_solves"][0]), "solves": int(found["periods_solves"][1]),
            "diff": float(found["diff"][0]), "statuses_differ": int(found["diff"][1]),
            "diff_python": float(found["diff_python"][0]),
            "per_solve": tuple(int(v) for v in found["per_solve"]),
            "per_interval": tuple(int(v) for v in found["per_interval"]),
            "per_period": tuple(int(v) for v in found["per_period"]),
            "ram": int(found["ram"][0]), "ram_context": int(found["ram"][1]), "stack": int(found["ram"][2]),
            "image_ram": int(found["ram"][3]), "flash": int(found["flash"][0]), "flash_code": int(found["flash"][1]),
            "flash_constants": int(found["flash"][2]), "image_flash": int(found["flash"][3]),
            "passed": found["passed"][0] == "passed"}
