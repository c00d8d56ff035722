"""The NMPC's step on a Cortex-M7: instructions per solve on QEMU's instruction clock, RAM and flash.

Exports the N-shape with its firmware build (``rollbot-oc export-c --target cortex-m7``: the NMPC's own step with
``NMPCSettings.embedded()``, its run recorded), builds it and runs ``make qemu-check`` on the whole recorded run
(``PERIODS=0``; ``--periods N`` for the first N periods): the firmware on QEMU's ``mps2-an500`` board (Cortex-M7,
FPv5 double-precision FPU, ``-icount shift=0``) against the host build of the same program, then turns
instructions into time at 480 MHz (an STM32H7) under the stated assumptions (``CPI``): QEMU counts instructions,
not cycles.  The check's verdict is printed, not required: the figures are the benchmark's result either way.

Run: .venv/bin/python benchmarks/bench_firmware.py [--periods N] [--out DIR]
(``--out`` an existing export with its firmware build is reused as it is.)
"""

import sys
import tempfile
import time
from pathlib import Path

from rollbot_oc.export.firmware import missing_tools, parse_check, qemu_check
from rollbot_oc.export.project import export_c, read_export
from rollbot_oc.scenarios.bundled import load_bundled

CLOCK = 480e6  # Hz, an STM32H7's Cortex-M7
# Cycles per instruction for this code on a Cortex-M7 (assumptions, not measurements): 1 when the dual-issue
# pipeline hides the double-precision FPU's latencies and the code streams from flash through its cache as fast as
# it runs; 2 with the FP dependency chains, the flash wait states on straight-line code far larger than the 16 kB
# instruction cache, and data-cache misses on work arrays far larger than the 16 kB data cache (not in TCM).
CPI = (1.0, 2.0)


def main():
    missing = missing_tools()
    if missing:
        print(f"bench_firmware: skipped: no {', '.join(missing)} (docs/firmware.md says how to install them)")
        return
    args = sys.argv[1:]
    periods = int(args[args.index("--periods") + 1]) if "--periods" in args else 0
    folder = Path(args[args.index("--out") + 1]) if "--out" in args else Path(tempfile.mkdtemp()) / "rollbot_c"
    problem = load_bundled("n_shape")
    start = time.perf_counter()
    reused = (folder / "firmware.mk").is_file()
    if not reused:
        export_c(folder, problem, target="cortex-m7")
    exported = time.perf_counter() - start
    start = time.perf_counter()
    done = qemu_check(folder, periods)
    checked = time.perf_counter() - start
    if done.returncode and "qemu-check FAILED" not in done.stdout:
        raise SystemExit(done.stdout[-3000:] + done.stderr[-3000:])
    found = parse_check(done.stdout)
    h = read_export(folder)
    print(f"The NMPC's step on a Cortex-M7 (QEMU mps2-an500), N-shape (bundled), NMPCSettings.embedded(): "
          f"{found['periods']} of the recorded run's {h['periods']} periods of 10 ms replayed")
    built = "what was not built" if reused else "arm-none-eabi-gcc, the step at -O1, make -j2"
    print(f"  export {'reused' if reused else f'{exported:.1f} s'}, build ({built}) and qemu-check {checked:.1f} s on a "
          "2-core machine shared with other work")
    lines = [line for line in done.stdout[done.stdout.index("replayed "):].strip().splitlines()
             if not line.startswith("make")]
    print("  make qemu-check:\n    " + "\n    ".join(lines))
    print(f"\nInstructions into time at {CLOCK / 1e6:.0f} MHz, CPI {CPI[0]:g} to {CPI[1]:g} (module doc); the NMPC's "
          f"interval is 120 ms:")
    for what, key in (("per solve (rollbot_period_solve at a solve instant)", "per_solve"),
                      ("per interval (the step's calls from a solve instant to the next)", "per_interval"),
                      ("per period (measure, solve, commit: every period)", "per_period")):
        med, p95, top = found[key]
        row = ", ".join(f"{name} {v / 1e6:.2f} M = {1e3 * v * CPI[0] / CLOCK:.1f} to {1e3 * v * CPI[1] / CLOCK:.1f} ms"
                        for name, v in (("median", med), ("p95", p95), ("max", top)))
        print(f"  {what}: {row}")


if __name__ == "__main__":
    main()
