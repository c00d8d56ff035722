"""The host side of ``make qemu-check``: the firmware's commands against the host's, its instructions, its memory.

Written by ``rollbot-oc export-c --target cortex-m7`` (the Python standard library only).  Reads the replay
(``replay_log.bin``, format in ``rollbot_replay.h``), the firmware's output under QEMU and the host build's output
of the same program (format in ``firmware_main.c``) and the linker map, and prints::

    max |diff| = ...                       the firmware's commands against the host build's (rad/s^2)
    instructions per solve: median N, p95 N, max N    rollbot_period_solve at the solve instants
    instructions per interval: ...                    the step's calls from a solve instant to the next
    instructions per period: ...                      the step's calls (measure, solve, commit) every period
    RAM: ... flash: ...                                from the linker map

Exit 0 if the commands agree within the tolerance and every event and mode is the host's, 1 if not, 2 if a file
cannot be read.
"""

import argparse
import math
import re
import struct
import subprocess
import sys

STM32H7_BANK = 512 * 1024  # bytes: an STM32H7's largest RAM bank (AXI SRAM)
ALLOCATORS = {"malloc", "calloc", "realloc", "free", "_malloc_r", "_calloc_r", "_realloc_r", "_free_r", "_sbrk",
              "_sbrk_r"}


def read_replay(path):
    """The Python NMPC's step's outputs ``(accel, speed, by_speed, event, mode)`` per period of the replay file."""
    with open(path, "rb") as f:
        data = f.read()
    if data[:8] != b"RBREPLAY":
        raise ValueError(f"{path}: not a replay file")
    version, periods, _memory, window = struct.unpack_from("<4I", data, 8)
    if version != 2:
        raise ValueError(f"{path}: replay file version {version}, not 2")
    at, rows = 24, []

    def take(n):
        nonlocal at
        values = struct.unpack_from(f"<{n}d", data, at)
        at += 8 * n
        return values

    for _ in range(periods):
        take(1 + 12)
        for _edits in range(2):
            take(2 * int(take(1)[0]))
        if take(1)[0]:
            take(window)
        rows.append(take(9)[4:])
    return rows


def read_output(path):
    """``(header, rows)`` of a replay program's output: rows of (accel, speed, by_speed, event, mode, solving,
    the period's instructions, its solve's instructions)."""
    with open(path, "rb") as f:
        data = f.read()
    if data[:8] != b"RBFWOUT2":
        raise ValueError(f"{path}: not an output of the firmware's replay")
    version, periods, context, stack, per_tick = struct.unpack_from("<4Id", data, 8)
    rows = [struct.unpack_from("<ddiiiIQQ", data, 32 + 48 * i) for i in range(periods)]
    return {"periods": periods, "context": context, "stack": stack, "per_tick": per_tick}, rows


def differ(a, b, tolerance):
    """``(|diff|, status differs)`` of two commands (accel, speed, by_speed, event, mode, ...)."""
    d = abs(a[0] - b[0])
    if not (math.isnan(a[1]) and math.isnan(b[1])):
        d = max(d, abs(a[1] - b[1]))
    if math.isnan(d):
        d = math.inf
    return d, any(int(x) != int(y) for x, y in zip(a[2:5], b[2:5]))


def percentiles(values):
    """Median, p95 (nearest rank below) and max of a list of numbers."""
    v = sorted(values)
    return v[len(v) // 2], v[int(0.95 * (len(v) - 1))], v[-1]


def map_sections(path):
    """``[(output section, input section, address, size, file)]`` of a GNU ld map's memory map."""
    with open(path) as f:
        text = f.read()
    start = text.find("Linker script and memory map")
    if start < 0:
        raise ValueError(f"{path}: not a GNU ld map file")
    found, output, pending = [], None, None
    for line in text[start:].splitlines():
        top = re.match(r"^(\.[\w.]+)\s+0x([0-9a-f]+)\s+0x([0-9a-f]+)", line)
        if top or re.match(r"^\.[\w.]+\s*$", line):
            output, pending = line.split()[0], None
            continue
        entry = re.match(r"^ (\.[\w.$]+|COMMON)(?:\s+0x([0-9a-f]+)\s+0x([0-9a-f]+)\s+(\S.*))?$", line)
        if entry:
            if entry.group(2):
                found.append((output, entry.group(1), int(entry.group(2), 16), int(entry.group(3), 16),
                              entry.group(4).strip()))
                pending = None
            else:
                pending = entry.group(1)
            continue
        rest = re.match(r"^\s+0x([0-9a-f]+)\s+0x([0-9a-f]+)\s+(\S.*)$", line)
        if rest and pending:
            found.append((output, pending, int(rest.group(1), 16), int(rest.group(2), 16), rest.group(3).strip()))
            pending = None
    return found


def memory(path, step_objects):
    """Bytes of flash and RAM from the linker map: the whole image, and the step's (its objects, the libm they
    call, the context)."""
    sections = map_sections(path)
    flash_out = {".text", ".ARM.extab", ".ARM.exidx", ".preinit_array", ".init_array", ".fini_array", ".data"}
    ram_out = {".data", ".bss"}
    names = {o.split("/")[-1] for o in step_objects}

    def is_step(file):
        base = file.split("/")[-1]
        return base in names or "libm.a(" in file

    total = {"flash": 0, "ram": 0, "heap": 0, "stack": 0}
    step = {"code": 0, "constants": 0, "data": 0, "bss": 0, "context": 0}
    for output, section, _addr, size, file in sections:
        if output in flash_out:
            total["flash"] += size
        if output in ram_out:
            total["ram"] += size
        if section.startswith(".bss.rollbot_context_storage") or section == ".bss.ctx":
            step["context"] += size
        elif is_step(file):
            if section.startswith(".text"):
                step["code"] += size
            elif section.startswith(".rodata"):
                step["constants"] += size
            elif section.startswith(".data"):
                step["data"] += size
            elif section.startswith(".bss") or section == "COMMON":
                step["bss"] += size
    with open(path) as f:
        text = f.read()
    for name, key in (("HEAP_SIZE", "heap"), ("STACK_SIZE", "stack")):
        m = re.search(rf"0x([0-9a-f]+)\s+{name} = ", text)
        total[key] = int(m.group(1), 16) if m else 0
    return total, step


def allocators(nm, objects):
    """The allocator symbols the step's objects call (``nm -u``)."""
    out = subprocess.run([nm, "-u", *objects], capture_output=True, text=True, check=True).stdout
    return sorted({line.split()[-1] for line in out.splitlines() if line.split() and line.split()[-1] in ALLOCATORS})


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("replay")
    parser.add_argument("firmware")
    parser.add_argument("host")
    parser.add_argument("objects", nargs="*", help="the step's object files (ARM)")
    parser.add_argument("--map", required=True)
    parser.add_argument("--nm", default="arm-none-eabi-nm")
    parser.add_argument("--tolerance", type=float, default=1e-9)
    args = parser.parse_args(argv)
    try:
        python = read_replay(args.replay)
        fw_head, fw = read_output(args.firmware)
        host_head, host = read_output(args.host)
    except (OSError, ValueError, struct.error) as exc:
        print(f"firmware_check: {exc}", file=sys.stderr)
        return 2
    n = fw_head["periods"]
    if n != host_head["periods"] or n == 0:
        print(f"firmware_check: the firmware replayed {n} periods, the host {host_head['periods']}", file=sys.stderr)
        return 2
    host_diffs = [differ(a, b, args.tolerance) for a, b in zip(fw, host)]
    python_diffs = [differ(a, b, args.tolerance) for a, b in zip(fw, python)]
    diff, statuses = max(d for d, _ in host_diffs), sum(s for _, s in host_diffs)
    diff_python, statuses_python = max(d for d, _ in python_diffs), sum(s for _, s in python_diffs)
    solves = [r[7] for r in fw if r[5]]
    steps = [r[6] for r in fw]
    print(f"replayed {n} periods of {0.01 * n:.2f} s on the Cortex-M7 (QEMU mps2-an500, -icount shift=0), "
          f"{len(solves)} solve instants")
    print(f"max |diff| = {diff:.3e} (commands, rad/s^2, firmware against the host build), {statuses} statuses differ (event, mode)")
    print(f"  against the Python controller's recorded commands: {diff_python:.3e}, {statuses_python} statuses differ")
    beyond = [i for i, (d, st) in enumerate(host_diffs) if not d <= args.tolerance or st]
    if beyond:
        i = beyond[0]
        print(f"  first difference beyond the tolerance: period {i}" + (f" (a solve instant: {fw[i][7]} instructions)"
                                                                         if fw[i][5] else ""))
    print(f"  QEMU's instruction clock: {fw_head['per_tick']:.3f} instructions per SysTick tick (calibrated)")
    if solves:
        med, p95, top = percentiles(solves)
        print(f"instructions per solve: median {med}, p95 {p95}, max {top}")
    else:
        print("instructions per solve: none (no solve instant replayed)")
    instants = [i for i, r in enumerate(fw) if r[5]]
    intervals = [sum(steps[a:b]) for a, b in zip(instants[:-1], instants[1:])]
    if intervals:
        med, p95, top = percentiles(intervals)
        print(f"instructions per interval: median {med}, p95 {p95}, max {top} (the step's calls, every period from a "
              f"solve instant to the next, {len(intervals)} intervals)")
    else:
        print("instructions per interval: none (fewer than two solve instants replayed)")
    med, p95, top = percentiles(steps)
    print(f"instructions per period: median {med}, p95 {p95}, max {top}, mean {sum(steps) / n:.0f} (the step's calls: "
          "measure, solve at a solve instant, commit)")
    try:
        total, step = memory(args.map, args.objects)
    except (OSError, ValueError) as exc:
        print(f"firmware_check: {exc}", file=sys.stderr)
        return 2
    context = step["context"] or fw_head["context"]
    ram = context + step["data"] + step["bss"] + fw_head["stack"]
    flash = step["code"] + step["constants"] + step["data"]
    print(f"RAM: step {ram} bytes = {100 * ram / STM32H7_BANK:.0f} % of an STM32H7's 512 kB bank "
          f"({'fits' if ram <= STM32H7_BANK else 'does not fit'}): context {context} (rollbot_context), "
          f"the step's own data {step['data'] + step['bss']}, stack peak {fw_head['stack']}; whole image "
          f"{total['ram']} bytes of .data and .bss, with {total['heap']} of heap and {total['stack']} of stack "
          "reserved")
    print(f"flash: step {flash} bytes: code {step['code']}, constants {step['constants']} (the generated step, its "
          f"API, the initial memory and the libm it calls), initial data {step['data']}; whole image {total['flash']} bytes")
    if args.objects:
        try:
            found = allocators(args.nm, args.objects)
        except (OSError, subprocess.CalledProcessError) as exc:
            print(f"firmware_check: {args.nm}: {exc}", file=sys.stderr)
            return 2
        print("heap: the step's objects call " + (", ".join(found) if found else "no allocator") + " (nm -u)")
    else:
        found = []
    ok = diff <= args.tolerance and statuses == 0 and not found
    print(f"qemu-check {'passed' if ok else 'FAILED'}: tolerance {args.tolerance:.1e}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
