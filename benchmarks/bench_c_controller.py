"""The NMPC and the NMPC through its step as an exported C library, on whole problems at the default settings.

For each bundled closed-loop problem the acceptance names (``rollbot-oc run P --controller nmpc --json`` and
``rollbot-oc run P --controller c --c-project DIR --json``, DIR written by ``write_step``, the step part of
``export-c``) and for the random courses 0 to 4 of seed 0 (the same two runs through the Python API, each with
its believed robot and noise seed, as the campaign runs them): whether the two JSON documents are identical once
the wall-clock keys are removed (``tests/shared.py``: ``comparable``; the ``controller`` name and the C run's
``library_sha256`` set aside), the keys that differ if not, the completion time and the library's sha256.

Run: nice -n 10 .venv/bin/python benchmarks/bench_c_controller.py [NAME ...] [--out FILE]
(NAME: a bundled problem or ``course_I``; all by default.)  Rows are written to FILE as they are measured
(default ``benchmarks/bench_c_controller_result.md``).
"""

import argparse
import contextlib
import hashlib
import io
import json
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))
from shared import comparable  # noqa: E402  (the wall-clock keys, as the tests remove them)

from rollbot_oc.app.cli import main  # noqa: E402
from rollbot_oc.control.nmpc.source import LIBRARY  # noqa: E402
from rollbot_oc.export.step_library import write_step  # noqa: E402
from rollbot_oc.scenarios.bundled import load_bundled  # noqa: E402
from rollbot_oc.scenarios.courses import random_course  # noqa: E402
from rollbot_oc.scenarios.problem import make_controller, run_problem  # noqa: E402

BUNDLED = ("n_shape", "n_shape_imu", "n_shape_outages", "circle_R020", "circle_R065", "approach", "gates")
COURSES = tuple(f"course_{i}" for i in range(5))


def _cli_json(argv) -> dict:
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        main(argv)
    return json.loads(out.getvalue())


def compare(name: str, folder: Path) -> dict:
    """The two runs of ``name`` and how they compare."""
    start = time.perf_counter()
    if name.startswith("course_"):
        course = random_course(0, int(name.removeprefix("course_")))
        problem, params, seed = course.problem, course.believed, course.noise_seed
        write_step(folder, problem, params)
        runs = [run_problem(problem, controller, seed=seed, params=params, show_progress=False, label=label).metrics
                for controller, label in ((make_controller("nmpc", problem, params), "nmpc"),
                                          (make_controller("nmpc", problem, params, step_library=folder), "c"))]
    else:
        problem = load_bundled(name)
        write_step(folder, problem)
        runs = [_cli_json(["run", name, "--json", "--controller", "nmpc"]),
                _cli_json(["run", name, "--json", "--controller", "c", "--c-project", str(folder)])]
    nmpc, c = (comparable(m) for m in runs)
    sha = c.pop("library_sha256", None)
    names = (nmpc.pop("controller", None), c.pop("controller", None))
    differ = sorted(k for k in nmpc.keys() | c.keys() if nmpc.get(k) != c.get(k))
    return {"problem": name, "identical": not differ and names == ("nmpc", "c"), "differ": differ,
            "completed": nmpc.get("completed"), "completion_time": nmpc.get("completion_time"),
            "c_completion_time": c.get("completion_time"), "solves": nmpc.get("solves"),
            "failed_solves": nmpc.get("failed_solves"), "sha256": sha,
            "sha_ok": sha == hashlib.sha256((folder / LIBRARY).read_bytes()).hexdigest(),
            "seconds": time.perf_counter() - start}


def _row(r: dict) -> str:
    time_ = "-" if r["completion_time"] is None else f"{r['completion_time']:.2f}"
    return (f"| {r['problem']} | {'yes' if r['identical'] else 'NO: ' + ', '.join(r['differ'])} | {r['completed']} | "
            f"{time_} | {r['solves']} | {r['failed_solves']} | `{(r['sha256'] or '-')[:16]}` | {r['seconds']:.0f} |")


def main_(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("names", nargs="*", default=[*BUNDLED, *COURSES])
    parser.add_argument("--out", default=str(Path(__file__).with_name("bench_c_controller_result.md")))
    args = parser.parse_args(argv)
    out = Path(args.out)
    lines = ["# bench_c_controller: the NMPC (`--controller nmpc`) and the NMPC through its step's C library "
             "(`--controller c`), whole problems, default settings", "",
             "Command: `nice -n 10 .venv/bin/python benchmarks/bench_c_controller.py " + " ".join(argv or []) + "`",
             "", "| problem | same JSON | completed | completion s | solves | failed solves | library sha256 (16) "
             "| wall s (both runs) |", "|---|---|---|---|---|---|---|---|"]
    out.write_text("\n".join(lines) + "\n")
    rows = []
    for name in args.names:
        with tempfile.TemporaryDirectory() as tmp:
            r = compare(name, Path(tmp))
        assert r["sha_ok"], f"{name}: the run's library_sha256 is not the folder's library"
        rows.append(r)
        lines.append(_row(r))
        print(lines[-1], flush=True)
        out.write_text("\n".join(lines) + "\n")
    same = sum(r["identical"] for r in rows)
    lines += ["", f"identical JSON on {same} of {len(rows)} problems (wall-clock keys removed; the controller's "
                  "name, nmpc or c, and the C run's library_sha256 set aside)."]
    out.write_text("\n".join(lines) + "\n")
    print(lines[-1])
    return 0 if same == len(rows) else 1


if __name__ == "__main__":
    sys.exit(main_(sys.argv[1:]))
