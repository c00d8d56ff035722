"""The ``rollbot-oc`` command line.

Every subcommand that computes takes ``--params FILE`` (TOML, see
``rollbot_oc.model.params``).  ``--json`` prints strict JSON on stdout (SI units,
radians, ``null`` for what is missing).  Exit status:

* 0: success;
* 1: a computation that did not converge or a run that did not complete
  (``rollbot-oc: failed: ...`` on stderr; the JSON, when asked for, is still
  printed);
* 2: a user error (argument, file, value), one line ``rollbot-oc: error: ...``
  naming the option or file, the value and the valid range, found before any
  long computation;
* 130: interrupted (Ctrl-C);
* 3: an internal error (a bug), one line ``rollbot-oc: internal error: ...``;
  ``--debug`` shows its traceback.

Every file a command writes is inside its output folder (``--out``,
``--plot``), which is checked and created before anything is computed.

Without ``--json`` a command prints a summary for people
(``rollbot_oc.view.text``) whose first line says whether it worked and how
well; ``--quiet`` prints nothing but errors.  Long work shows its progress on
stderr (``rollbot_oc.core.progress``), only where stderr is a terminal unless
``--progress`` asks for it.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import traceback
import warnings
from contextlib import contextmanager

from rollbot_oc import __version__
from rollbot_oc.core.errors import ConfigError, NumericalFailure, interruptible
from rollbot_oc.core.outputs import output_folder, to_json, user_path, write_json
from rollbot_oc.export.firmware import TARGETS as FIRMWARE_TARGETS
from rollbot_oc.model.params import load_params

__all__ = ["main", "build_parser", "EXIT_OK", "EXIT_FAILED", "EXIT_USAGE", "EXIT_INTERNAL", "EXIT_INTERRUPTED"]

EXIT_OK, EXIT_FAILED, EXIT_USAGE, EXIT_INTERNAL, EXIT_INTERRUPTED = 0, 1, 2, 3, 130
PROG = "rollbot-oc"
MAX_SEED = 2**32 - 1


class UsageError(ConfigError):
    """A mistake in the command line itself (argparse's complaints)."""


class _Parser(argparse.ArgumentParser):
    def error(self, message):  # one line, not the whole usage block
        raise UsageError(f"{message} (see '{self.prog} --help')")


def _finite(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"{text!r} is not a finite number")
    return value


def _positive(text: str) -> float:
    value = _finite(text)
    if value <= 0:
        raise argparse.ArgumentTypeError(f"{text!r} is out of range: valid is > 0")
    return value


def _seed(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a whole number") from None
    if not 0 <= value <= MAX_SEED:
        raise argparse.ArgumentTypeError(f"{text!r} is out of range: valid is [0, {MAX_SEED}]")
    return value


def _add_params(p):
    p.add_argument("--params", metavar="FILE", help="TOML parameter file (keys in the README); "
                   "default: the paper's prototype")


def _add_scenario(p):
    """The options every scenario-running subcommand shares."""
    p.add_argument("problem", metavar="PROBLEM", help="scenario file (schema in the README) or the name of a "
                   "bundled scenario (rollbot-oc problems)")
    _add_params(p)
    p.add_argument("--seed", type=_seed, default=0, metavar="N", help=f"seed of the sensor noise, in [0, {MAX_SEED}] "
                   "(default 0)")
    p.add_argument("--duration", type=_finite, metavar="T", help="override the problem's duration, s, in [1, 3600]")
    p.add_argument("--realtime", action="store_true", help="NMPC: judge late solves by the wall clock (hardware in "
                   "the loop); by default by a modelled compute time, so the same seed gives the same run on any "
                   "machine")


def _params_with_slope(args):
    params = load_params(args.params)
    if getattr(args, "slope_deg", None) is not None:
        try:
            params = params.replace(slope=math.radians(args.slope_deg))
        except ConfigError:
            raise ConfigError(f"--slope-deg {args.slope_deg:g} is out of range: valid is [0, 30]") from None
    return params


def _load_scenario(args):
    """The problem of a scenario subcommand, with ``--duration`` applied and checked."""
    from rollbot_oc.scenarios.problem import check_duration
    from rollbot_oc.scenarios.bundled import load_scenario

    problem = load_scenario(args.problem, base=load_params(args.params))
    if args.duration is not None:
        problem = problem.with_duration(check_duration(args.duration, "--duration"))
    return problem


def _failed(message: str) -> int:
    print(f"{PROG}: failed: {message}", file=sys.stderr)
    return EXIT_FAILED


def _show_progress(args) -> bool | None:
    """``show_progress`` of the long computations: forced by --progress, off with --quiet, else on a terminal."""
    return True if args.progress else False if args.quiet else None


def _robot(args) -> str:
    """What the robot is called in titles and summaries."""
    return f"robot {args.params}" if getattr(args, "params", None) else "prototype"


def _emit(args, data, text) -> None:
    """Print ``data`` as JSON with --json, else ``text()`` (the human summary) unless --quiet."""
    if getattr(args, "json", False):
        print(to_json(data))
    elif not args.quiet:
        print(text())


def _cmd_openloop(args) -> int:
    from rollbot_oc.analysis.experiments import OpenLoopMeasurement, check_open_loop, open_loop_run
    from rollbot_oc.view.plots import plot_top_view
    from rollbot_oc.scenarios.problem import check_duration
    from rollbot_oc.core.progress import progress_bar
    from rollbot_oc.view.text import open_loop_text

    params = _params_with_slope(args)
    if args.duration is not None:
        check_duration(args.duration, "--duration")
    for omega0 in args.omega0:  # every setting checked before the first run
        check_open_loop(omega0, params, ramp_rate=args.ramp_rate, duration=args.duration)
    out = output_folder(args.out)
    rows, failures = [], []
    for omega0 in progress_bar(args.omega0, _show_progress(args), desc="open-loop runs", unit="speed"):
        try:
            measured, result = open_loop_run(omega0, params, duration=args.duration, ramp_rate=args.ramp_rate)
        except NumericalFailure as exc:  # the robot left the no-slip model: a row of nulls, exit status 1
            rows.append(OpenLoopMeasurement.failed_dict(omega0, str(exc)))
            failures.append(str(exc))
            continue
        rows.append(measured.to_dict())
        if out:
            plot_top_view(result, title=f"{_robot(args)}, open loop at omega0 = {omega0:g} rad/s\nR0 = "
                          f"{measured.R0:.4f} m, Omega = {measured.Omega:.3f} rad/s, settled: {measured.settled}",
                          path=out / f"openloop_{omega0:g}.png")
    if out:
        write_json(out / "openloop.json", {"params": params.to_file_dict(), "runs": rows})
    _emit(args, rows, lambda: open_loop_text(rows))
    return _failed("; ".join(failures)) if failures else EXIT_OK


def _paper_figures(params, out, robot: str) -> list:
    """Write the quasi-stable and eigenvalue figures for [0, max_speed] into the folder ``out``."""
    import numpy as np

    from rollbot_oc.view.plots import plot_eigenvalues, plot_quasi_stable
    from rollbot_oc.analysis.quasi_stable import quasi_stable_curve
    from rollbot_oc.analysis.stability import stability_of_states

    omegas = np.linspace(0.0, params.max_speed, 200)
    curves = {branch: quasi_stable_curve(omegas, params, branch) for branch in ("slow", "fast")}
    paths = [out / "quasi_stable.png", out / "eigenvalues.png"]
    plot_quasi_stable(curves, path=paths[0], robot=robot)
    results = [r for r in stability_of_states(curves["slow"][1:]) if r is not None]
    plot_eigenvalues(results, path=paths[1], robot=robot)
    return paths


def _report_rows(args, params, plot, rows, text) -> int:
    """Write the paper's figures into ``plot`` if given, print the rows (JSON or ``text``); status 1 if one failed."""
    if plot:
        _paper_figures(params, plot, _robot(args))
    _emit(args, rows, lambda: text(rows, args.branch))
    failed = [r["omega0"] for r in rows if not r["converged"]]
    if failed:
        return _failed(f"no quasi-stable state on the {args.branch} branch at omega0 = "
                       f"{', '.join(f'{w:g}' for w in failed)} rad/s (see 'residual')")
    return EXIT_OK


def _cmd_quasi(args) -> int:
    from rollbot_oc.analysis.quasi_stable import quasi_stable_curve
    from rollbot_oc.view.text import quasi_text

    params = load_params(args.params)
    plot = output_folder(args.plot, "--plot")
    states = quasi_stable_curve(args.omega0, params, args.branch)
    return _report_rows(args, params, plot, [s.to_dict() for s in states], quasi_text)


def _cmd_stability(args) -> int:
    from rollbot_oc.analysis.quasi_stable import quasi_stable_curve
    from rollbot_oc.analysis.stability import stability_of_states, stability_record
    from rollbot_oc.view.text import stability_text

    params = load_params(args.params)
    plot = output_folder(args.plot, "--plot")
    states = quasi_stable_curve(args.omega0, params, args.branch)
    rows = [stability_record(s, r) for s, r in zip(states, stability_of_states(states))]
    return _report_rows(args, params, plot, rows, stability_text)


def _write_run(run, out) -> None:
    """Trajectory (.npz), metrics (JSON), log (MCAP) and the plots of a closed-loop run, in the folder ``out``."""
    from rollbot_oc.robot import log as mcap_log
    from rollbot_oc.view.plots import save_run_figures

    stem = f"{run.problem.name}_{run.controller}"
    run.result.save(out / f"{stem}.npz")
    write_json(out / f"{stem}.json", run.metrics)
    if mcap_log.available():
        mcap_log.write_run_log(run, out / f"{stem}.mcap")
    else:
        warnings.warn(f"{stem}.mcap not written: the run's log needs the mcap package ({mcap_log.INSTALL})")
    save_run_figures(run, out)


SETTINGS_PRESETS = ("embedded", "nmpc")  # export-c --settings: NMPCSettings.preset (control.nmpc.settings.PRESETS)


def _nmpc_options(args, preset: str = "nmpc") -> dict:
    """The NMPC's settings from the command line (``--realtime``) over a preset (``SETTINGS_PRESETS``)."""
    if not args.realtime and preset == "nmpc":
        return {}
    from rollbot_oc.control.nmpc import NMPCSettings

    settings = NMPCSettings.preset(preset)
    return {"settings": settings.replace(timing={"realtime": True}) if args.realtime else settings}


def _cmd_run(args) -> int:
    from rollbot_oc.scenarios.problem import make_controller, run_open_loop, run_problem
    from rollbot_oc.view.text import open_loop_text, run_text

    problem = _load_scenario(args)
    out = output_folder(args.out)
    if not problem.mission.closed_loop:
        if args.duration is not None:
            raise ConfigError(f"--duration does not apply to the open-loop problem {problem.name}: each speed runs "
                              "until two revolutions are measured")
        metrics = run_open_loop(problem, show_progress=_show_progress(args))
        if out:
            write_json(out / f"{problem.name}.json", metrics)
        _emit(args, metrics, lambda: open_loop_text(metrics["runs"], problem.name))
    else:
        controller = args.controller
        if controller == "c":  # the NMPC, its control step the exported C library (with the export's settings)
            folder, preset = _c_project(args, problem)
            controller = make_controller("nmpc", problem, **_nmpc_options(args, preset), step_library=folder)
        run = run_problem(problem, controller, seed=args.seed, show_progress=_show_progress(args),
                          label=args.controller, **(_nmpc_options(args) if args.controller == "nmpc" else {}))
        metrics = run.metrics
        if out:
            _write_run(run, out)
        _emit(args, metrics, lambda: run_text(run))
    return EXIT_OK if metrics.get("completed") else _failed(f"{problem.name}: the run did not complete")


def _cmd_export_c(args) -> int:
    from rollbot_oc.control.nmpc.source import LIBRARY
    from rollbot_oc.export.project import build, export_c
    from rollbot_oc.scenarios.bundled import load_scenario

    out = output_folder(args.out)
    problem = load_scenario(args.problem, base=load_params(args.params))
    from rollbot_oc.control.nmpc import NMPCSettings

    result = export_c(out.path, problem, settings=NMPCSettings.preset(args.settings), seed=args.seed, show_progress=_show_progress(args),
                      target=args.target, preset=args.settings)
    done = None if (out.path / LIBRARY).is_file() else build(out.path, LIBRARY)
    if done is not None and done.returncode != 0:
        lines = (done.stderr or done.stdout).strip().splitlines()
        raise ConfigError(f"export-c {out.path}: make {LIBRARY} failed" + (f": {lines[-1]}" if lines else ""))
    m = result.metrics
    cut = m["duration"] < problem.duration - 1e-9  # recorded for RECORD_SECONDS only
    data = {"folder": str(out.path), "problem": problem.name, "target": args.target, "settings": args.settings,
            "step": {k: result.step[k] for k in ("key", "memory", "window", "N")}, "periods": len(result.log),
            "solves": result.solves, "sizes": result.sizes, "completed": m["completed"],
            "completion_time": m.get("completion_time"), "stop_errors": m.get("stop_errors")}

    def text() -> str:
        worst = f", worst stop error {100 * max(m['stop_errors']):.1f} cm" if m.get("stop_errors") else ""
        run = f"completed in {m['completion_time']:.1f} s" if m["completed"] else \
            f"its first {m['duration']:.0f} s" if cut else "did not complete"
        lines = [f"{problem.name}: exported the NMPC's control step to {out.path} ({LIBRARY}: "
                 f"rollbot-oc run {problem.name} --controller c --c-project {out.path})",
                 f"  recorded run of the NMPC: {run}{worst}; {len(result.log)} periods, {result.solves} solves "
                 "(replay_log.bin)",
                 f"  memory: {result.sizes['memory_bytes']} bytes, work arrays: {result.sizes['work_bytes']} bytes",
                 f"  build and check: make -C {out.path} check"]
        if args.target == "cortex-m7":
            lines.append(f"  firmware (Cortex-M7 on QEMU): make -C {out.path} qemu-check")
        return "\n".join(lines)

    _emit(args, data, text)
    # a recording cut short of the problem's duration (a circle's run never ends) is a prefix, not a failure
    return EXIT_OK if m["completed"] or cut else _failed(f"{problem.name}: the recorded run did not complete")


def _c_project(args, problem):
    """``(folder, preset)`` of ``--c-project`` for ``run --controller c``: the NMPC's step library built there
    (export-c builds it; ``make`` again if it is missing) and the settings preset it was exported with."""
    from rollbot_oc.control.nmpc.source import LIBRARY
    from rollbot_oc.export.project import build

    if not args.c_project:
        raise ConfigError("--controller c needs --c-project DIR (a folder written by rollbot-oc export-c)")
    folder = user_path(args.c_project, "--c-project")
    if not folder.is_dir():
        raise ConfigError(f"--c-project {folder}: not a folder written by rollbot-oc export-c")
    if not (folder / LIBRARY).is_file():
        done = build(folder, LIBRARY)
        if done.returncode != 0:
            lines = (done.stderr or done.stdout).strip().splitlines()
            raise ConfigError(f"--c-project {folder}: make failed" + (f": {lines[-1]}" if lines else ""))
    import json

    try:
        preset = json.loads((folder / "step.json").read_text()).get("settings") or "nmpc"
    except (OSError, ValueError, AttributeError):
        preset = "nmpc"  # the library's own check says what is wrong with the folder
    return folder, preset if preset in SETTINGS_PRESETS else "nmpc"


def _cmd_compare(args) -> int:
    from rollbot_oc.core.outputs import atomic_write_text
    from rollbot_oc.view.plots import plot_comparison
    from rollbot_oc.scenarios.problem import compare
    from rollbot_oc.view.text import compare_text, comparison_row, comparison_table

    problem = _load_scenario(args)
    if not problem.mission.closed_loop:
        raise ConfigError(f"{args.problem}: an open-loop problem has no controller to compare")
    out = output_folder(args.out)
    runs = compare(problem, seed=args.seed, show_progress=_show_progress(args), nmpc_options=_nmpc_options(args))
    rows = [comparison_row(run) for run in runs]
    if out:
        atomic_write_text(out / f"{problem.name}_comparison.md",
                          f"# {problem.name}: PID against NMPC\n\n{comparison_table(runs)}\n")
        write_json(out / f"{problem.name}_comparison.json", {"problem": problem.name, "seed": args.seed,
                                                             "rows": rows, "metrics": [r.metrics for r in runs]})
        plot_comparison(runs, path=out / f"{problem.name}_comparison.png")
        for run in runs:
            _write_run(run, out)
    _emit(args, rows, lambda: compare_text(runs))
    incomplete = [r["controller"] for r in rows if not r["completed"]]
    return _failed(f"{problem.name}: not completed by {', '.join(incomplete)}") if incomplete else EXIT_OK


def _cmd_problems(args) -> int:
    from rollbot_oc.scenarios.bundled import list_bundled
    from rollbot_oc.view.text import problems_text

    rows = list_bundled()
    _emit(args, rows, lambda: problems_text(rows))
    return EXIT_OK


def _cmd_params(args) -> int:
    from rollbot_oc.analysis.design import robot_record
    from rollbot_oc.model.params import RollbotParams, read_params_table
    from rollbot_oc.view.text import params_text

    table = read_params_table(args.params) if args.params else {}
    params = RollbotParams.from_file_dict(table, source=f"parameter file {args.params}")
    record = robot_record(params, given=set(table), robot=_robot(args))
    _emit(args, record, lambda: params_text(record))
    return EXIT_OK


def _cmd_demo(args) -> int:
    from rollbot_oc.app.report import make_report
    from rollbot_oc.view.text import demo_text

    params = load_params(args.params)
    out = output_folder(args.out).path
    summary = make_report(out, params, quick=args.quick, show_progress=_show_progress(args), robot=_robot(args))
    _emit(args, summary, lambda: demo_text(summary, out / "report.md"))
    return EXIT_OK


def _cmd_plot(args) -> int:
    from pathlib import Path

    from rollbot_oc.view.animate import animate_run
    from rollbot_oc.view.plots import plot_energy_and_contact, plot_time_series, plot_top_view
    from rollbot_oc.simulation.plant import SimulationResult
    from rollbot_oc.view.text import saved_run_verdict

    if str(args.run_file).endswith(".mcap"):
        from rollbot_oc.robot.log import read_log

        run = read_log(user_path(args.run_file, "RUN")).result
    else:
        run = SimulationResult.load(args.run_file)
    out = output_folder(args.out)
    stem = Path(args.run_file).stem or "run"
    title = f"{stem}\n{saved_run_verdict(run)}"
    written = [out / f"{stem}_top.png", out / f"{stem}_time.png", out / f"{stem}_energy.png"]
    for plot, path in zip((plot_top_view, plot_time_series, plot_energy_and_contact), written):
        plot(run, title=title, path=path)
    if args.animate:
        written.append(animate_run(run, out / f"{stem}.gif", title=stem))
    _emit(args, None, lambda: "\n".join([f"{stem}: {saved_run_verdict(run)}; {len(written)} files written:",
                                          *(f"  {path}" for path in written)]))
    return EXIT_OK


def _cmd_campaign(args) -> int:
    from rollbot_oc.campaign import load_campaign_spec, run_campaign
    from rollbot_oc.campaign.summary import summary_markdown

    campaign = load_campaign_spec(args.spec)
    result = run_campaign(campaign, args.out or f"out/{campaign.name}", workers=args.workers, scheduler=args.scheduler)
    summary = result.summary
    print(to_json(summary) if args.json else summary_markdown(summary), end="\n" if args.json else "")
    return _failed(f"{summary['failed']} of {summary['cases']} cases did not succeed (causes in "
                   f"{result.folder / 'summary.md'})") if summary["failed"] else EXIT_OK


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of ``rollbot-oc`` (subcommands and their options)."""
    parser = _Parser(prog=PROG, description="Model, analyse and control Rollbot, the spherical robot "
                     "driven by a single motor. SI units and radians unless an option says otherwise. Exit status: "
                     "0 success, 1 did not converge or complete, 2 bad argument or file, 3 internal error, "
                     "130 interrupted.")
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    common = {"--quiet": "print nothing but errors (for scripts: the exit status says how it went); "
                         "not with --json",
              "--progress": "show progress on stderr even when it is not a terminal (default: only on a terminal)"}
    parser.add_argument("--debug", action="store_true", help="show the traceback of an internal error")
    for option, text in common.items():
        parser.add_argument(option, action="store_true", help=text)
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    sub.required = True
    shared = _Parser(add_help=False)  # the global options are also taken after the subcommand
    shared.add_argument("--debug", action="store_true", default=argparse.SUPPRESS, help=argparse.SUPPRESS)
    for option, text in common.items():
        shared.add_argument(option, action="store_true", default=argparse.SUPPRESS, help=text)

    def command(name: str, **kwargs) -> argparse.ArgumentParser:
        return sub.add_parser(name, parents=[shared], **kwargs)

    p = command("openloop", help="the paper's open-loop experiment: constant driving speeds, "
                       "measured revolving radius, rate and tilt")
    p.add_argument("--omega0", type=_finite, nargs="+", required=True, metavar="W",
                   help="driving speeds, rad/s, in (0, max_speed]")
    _add_params(p)
    p.add_argument("--slope-deg", type=_finite, metavar="D", help="floor slope, degrees, in [0, 30] "
                   "(overrides the file)")
    p.add_argument("--duration", type=_finite, metavar="T",
                   help="run length, s, in [1, 3600] and beyond the ramp and 45 s of settling "
                        "(default: ramp, 40 s settling, then at least two revolutions)")
    p.add_argument("--ramp-rate", type=_positive, default=0.5, metavar="A",
                   help="driving-speed ramp from rest, rad/s^2, > 0 (default 0.5)")
    p.add_argument("--out", metavar="DIR", help="write top-view plots (PNG) and openloop.json here")
    p.add_argument("--json", action="store_true", help="print a JSON list of measurements")
    p.set_defaults(run=_cmd_openloop)

    p = command("quasi", help="quasi-stable (steadily revolving) states at given driving speeds")
    p.add_argument("--omega0", type=_finite, nargs="+", required=True, metavar="W",
                   help="driving speeds, rad/s, in [0, max_speed]")
    _add_params(p)
    p.add_argument("--branch", choices=("slow", "fast"), default="slow",
                   help="slow: pendulum near the bottom (the experiments'); fast: pendulum near the top")
    p.add_argument("--plot", metavar="DIR", help="write quasi_stable.png and eigenvalues.png here")
    p.add_argument("--json", action="store_true", help="print a JSON list (SI units, radians)")
    p.set_defaults(run=_cmd_quasi)

    p = command("stability", help="linearised stability (eigenvalues, lambda2, recovery time) of "
                       "quasi-stable states")
    p.add_argument("--omega0", type=_finite, nargs="+", required=True, metavar="W",
                   help="driving speeds, rad/s, in [0, max_speed]")
    _add_params(p)
    p.add_argument("--branch", choices=("slow", "fast"), default="slow", help="branch of quasi-stable states")
    p.add_argument("--plot", metavar="DIR", help="write quasi_stable.png and eigenvalues.png here")
    p.add_argument("--json", action="store_true", help="print a JSON list (eigenvalues as [re, im], 1/s)")
    p.set_defaults(run=_cmd_stability)

    p = command("run", help="run a scenario (file or bundled name) under a controller and print its metrics")
    _add_scenario(p)
    p.add_argument("--controller", choices=("pid", "nmpc", "c"), default="pid",
                   help="pid: the paper's quasi-stable baseline; nmpc: nonlinear MPC; c: the NMPC with its control "
                   "step the C library of --c-project (default pid)")
    p.add_argument("--c-project", metavar="DIR", help="--controller c: a folder written by rollbot-oc export-c for "
                   "this problem (its step library built with make if missing)")
    p.add_argument("--out", metavar="DIR", help="write the trajectory (.npz), metrics (.json), the run's log (.mcap, "
                   "for Foxglove) and plots (PNG) here")
    p.add_argument("--json", action="store_true", help="print the metrics as JSON (SI units)")
    p.set_defaults(run=_cmd_run)

    p = command("export-c", help="the controller on the robot: export the NMPC's control step (filter, delay "
                "compensation, RTI, fallbacks) as C99 with its library (run --controller c) and the replay of a "
                "recorded run of the NMPC (make, make check)")
    p.add_argument("--out", metavar="DIR", required=True, help="the C project's folder (created)")
    p.add_argument("--problem", metavar="FILE", default="n_shape", help="scenario file or bundled name of a "
                   "closed-loop problem (default n_shape); the NMPC's run on it (to its end, at most 60 s) is recorded "
                   "for make check")
    _add_params(p)
    p.add_argument("--seed", type=_seed, default=0, metavar="N", help=f"seed of the recorded run's sensor noise, in "
                   f"[0, {MAX_SEED}] (default 0)")
    p.add_argument("--target", choices=FIRMWARE_TARGETS, default="host", help="host: the C99 project (default); "
                   "cortex-m7: also the firmware for QEMU's mps2-an500 board and make qemu-check (arm-none-eabi-gcc, "
                   "qemu-system-arm; docs/firmware.md)")
    p.add_argument("--settings", choices=SETTINGS_PRESETS, default="embedded", help="the NMPC's settings: embedded "
                   "(NMPCSettings.embedded(): 25 intervals of 0.12 s, for a robot's processor; default) or nmpc (those of "
                   "run --controller nmpc); run --controller c takes the export's")
    p.add_argument("--json", action="store_true", help="print what was exported as JSON (sizes in bytes)")
    p.set_defaults(run=_cmd_export_c)

    p = command("compare", help="run the PID baseline and the NMPC on one problem and compare them")
    _add_scenario(p)
    p.add_argument("--out", metavar="DIR", help="write the table (Markdown, JSON), an overlay plot and both runs here")
    p.add_argument("--json", action="store_true", help="print the table rows as JSON instead of Markdown")
    p.set_defaults(run=_cmd_compare)

    p = command("problems", help="list the bundled scenarios (name, kind, description)")
    p.add_argument("--json", action="store_true", help="print a JSON list of {name, kind, description}")
    p.set_defaults(run=_cmd_problems)

    p = command("params", help="the robot's parameters with units and sources (default, file, derived), and what "
                "follows from them: masses, range of revolving radius, worst recovery time")
    _add_params(p)
    p.add_argument("--json", action="store_true", help="print a JSON object {robot, params, derived}")
    p.set_defaults(run=_cmd_params)

    p = command("demo", help="the main job: quasi-stable figures, PID against NMPC on the N-shape, "
                       "an animation; writes a report folder")
    _add_params(p)
    p.add_argument("--out", metavar="DIR", default="out", help="report folder (default out/)")
    p.add_argument("--quick", action="store_true", help="fewer points and frames (about a minute less)")
    p.set_defaults(run=_cmd_demo)

    p = command("campaign", help="run a campaign of independent cases (random courses, design points, a function) "
                "on Dask; resumes an interrupted one")
    p.add_argument("spec", metavar="SPEC", help="campaign spec (TOML, schema in the README) or a bundled spec's name "
                   "(robustness, design, design_r0_k0)")
    p.add_argument("--workers", type=int, metavar="N", help="local worker processes, in [1, 1024]; 1 runs in this "
                   "process (default: this machine's cores)")
    p.add_argument("--scheduler", metavar="ADDR", help="an existing Dask scheduler, tcp://HOST:8786 (default: "
                   "$DASK_SCHEDULER_ADDRESS, else a local cluster)")
    p.add_argument("--out", metavar="DIR", help="results.parquet, summary.json/.md, figures and the resumable part "
                   "files (default out/NAME)")
    p.add_argument("--json", action="store_true", help="print summary.json (cases, succeeded, failed, success_rate, "
                   "wall_time, cases_per_second, ...)")
    p.set_defaults(run=_cmd_campaign)

    p = command("plot", help="figures (and an animation) of a saved run (.npz or .mcap from run/compare --out)")
    p.add_argument("run_file", metavar="RUN", help="a saved run (.npz) or a run's log (.mcap)")
    p.add_argument("--out", metavar="DIR", default=".", help="where to write the PNG files (default: here)")
    p.add_argument("--animate", action="store_true", help="also write an animated GIF")
    p.set_defaults(run=_cmd_plot)
    return parser


@contextmanager
def _one_line_warnings():
    """Show warnings (as filtered by Python: each once per place) as ``rollbot-oc: warning: ...`` lines on stderr."""
    def show(message, category, filename, lineno, file=None, line=None):
        text = " ".join(str(message).split())
        print(f"{PROG}: warning: {text}", file=sys.stderr)

    with warnings.catch_warnings():
        warnings.showwarning = show
        from rollbot_oc.simulation.floor import RollbotDeprecationWarning

        warnings.simplefilter("default", RollbotDeprecationWarning)  # the user's settings that have moved
        yield


def _one_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split()) or type(exc).__name__
    return text if len(text) <= 2000 else text[:2000] + " ..."


def main(argv=None) -> int:
    """Run ``rollbot-oc`` with ``argv`` (default ``sys.argv[1:]``); returns the exit status (see module doc)."""
    os.environ.setdefault("MPLBACKEND", "Agg")  # the command line only writes figures to files
    for stream in (sys.stdout, sys.stderr):  # a path that is not UTF-8 is printed escaped, never a crash
        if hasattr(stream, "reconfigure"):
            stream.reconfigure(errors="backslashreplace")
    argv = list(sys.argv[1:] if argv is None else argv)
    debug = "--debug" in argv[:argv.index("--")] if "--" in argv else "--debug" in argv
    args = None
    with _one_line_warnings():
        try:
            args = build_parser().parse_args(argv)
            if args.quiet and getattr(args, "json", False):
                raise UsageError(f"--quiet and --json exclude each other (see '{PROG} {args.command} --help')")
            with interruptible(f"{PROG} {args.command}"):  # a Ctrl-C a solver swallows still interrupts
                return args.run(args)
        except SystemExit as exc:  # --help and --version
            return exc.code if isinstance(exc.code, int) else EXIT_OK
        except KeyboardInterrupt:
            print(f"{PROG}: interrupted", file=sys.stderr)
            return EXIT_INTERRUPTED
        except ConfigError as exc:
            print(f"{PROG}: error: {_one_line(exc)}", file=sys.stderr)
            return EXIT_USAGE
        except OSError as exc:  # a file that cannot be read or written while working (disk full, removed folder)
            where = f"{exc.filename}: " if exc.filename else ""
            print(f"{PROG}: error: {where}{exc.strerror or _one_line(exc)}", file=sys.stderr)
            return EXIT_USAGE
        except Exception as exc:  # noqa: BLE001 - the last line of defence: no traceback unless --debug
            if not isinstance(exc, NumericalFailure):
                if debug:
                    traceback.print_exc()
                print(f"{PROG}: internal error: {type(exc).__name__}: {_one_line(exc)}"
                      + ("" if debug else " (run with --debug for the traceback)"), file=sys.stderr)
                return EXIT_INTERNAL
            if args is not None and getattr(args, "json", False):  # the JSON contract holds on failure too
                print(to_json({"completed": False, "error": _one_line(exc), "status": getattr(exc, "status", None)}))
            return _failed(_one_line(exc))


if __name__ == "__main__":
    sys.exit(main())
