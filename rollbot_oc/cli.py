"""The ``rollbot-oc`` command line.

Every subcommand that computes takes ``--params FILE`` (TOML, see
``rollbot_oc.params``).  ``--json`` prints machine-readable JSON on stdout
(SI units, radians).  A user mistake (bad argument, bad file, value out of
range) prints one line ``rollbot-oc: error: ...`` on stderr and exits with
status 2; a computation that fails (a solver that does not converge) exits
with status 1.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
from pathlib import Path

from rollbot_oc.control.ocp import SolveFailed
from rollbot_oc.outputs import to_json, write_json
from rollbot_oc.params import load_params

__all__ = ["main", "build_parser"]


class UsageError(Exception):
    """A mistake in the command line or its files."""


class _Parser(argparse.ArgumentParser):
    def error(self, message):  # one line, not the whole usage block
        raise UsageError(f"{self.prog}: {message} (see --help)")


def _finite(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"{text!r} is not a finite number")
    return value


def _add_params(p):
    p.add_argument("--params", metavar="FILE", help="TOML parameter file (keys in the README); "
                   "default: the paper's prototype")


def _add_scenario(p):
    """The options every scenario-running subcommand shares."""
    p.add_argument("problem", metavar="PROBLEM.toml", help="scenario file (schema in the README)")
    _add_params(p)
    p.add_argument("--seed", type=int, default=0, metavar="N", help="seed of the sensor noise (default 0)")
    p.add_argument("--duration", type=_finite, metavar="T", help="override the problem's duration, s")


def _params_with_slope(args):
    params = load_params(args.params)
    if getattr(args, "slope_deg", None) is not None:
        params = params.replace(slope=math.radians(args.slope_deg))
    return params


def _cmd_openloop(args) -> int:
    from rollbot_oc.experiments import open_loop_run
    from rollbot_oc.plots import plot_top_view

    params = _params_with_slope(args)
    rows = []
    for omega0 in args.omega0:
        measured, result = open_loop_run(omega0, params, duration=args.duration, ramp_rate=args.ramp_rate)
        rows.append(measured.to_dict())
        if args.out:
            out = Path(args.out)
            plot_top_view(result, title=f"open loop, omega0 = {omega0:g} rad/s",
                          path=out / f"openloop_{omega0:g}.png")
    if args.out:
        write_json(Path(args.out) / "openloop.json", {"params": params.to_file_dict(), "runs": rows})
    if args.json:
        print(to_json(rows))
    else:
        print(f"{'omega0':>8} {'R0 (m)':>9} {'Omega':>9} {'xi (deg)':>9} {'settled':>8}")
        for r in rows:
            print(f"{r['omega0']:8.3f} {r['R0']:9.4f} {r['Omega']:9.4f} {math.degrees(r['xi']):9.3f} "
                  f"{str(r['settled']):>8}")
    return 0


def _paper_figures(params, out: Path) -> list[Path]:
    """Write the quasi-stable and eigenvalue figures for [0, max_speed] into ``out``."""
    import numpy as np

    from rollbot_oc.plots import plot_eigenvalues, plot_quasi_stable
    from rollbot_oc.quasi_stable import quasi_stable_curve
    from rollbot_oc.stability import stability_curve

    omegas = np.linspace(0.0, params.max_speed, 200)
    curves = {branch: quasi_stable_curve(omegas, params, branch) for branch in ("slow", "fast")}
    paths = [out / "quasi_stable.png", out / "eigenvalues.png"]
    plot_quasi_stable(curves, path=paths[0])
    plot_eigenvalues(stability_curve(omegas[1:], params), path=paths[1])
    return paths


def _report_rows(args, params, rows, header: str, line) -> None:
    """Write the paper's figures if asked (``--plot``), then print the rows as JSON or as a table."""
    if args.plot:
        _paper_figures(params, Path(args.plot))
    if args.json:
        print(to_json(rows))
        return
    print(header)
    for row in rows:
        print(line(row))


def _cmd_quasi(args) -> int:
    from rollbot_oc.quasi_stable import quasi_stable_curve

    params = load_params(args.params)
    states = quasi_stable_curve(args.omega0, params, args.branch)
    rows = [s.to_dict() for s in states]
    _report_rows(args, params, rows,
                 f"{'omega0':>8} {'Omega':>9} {'theta0(deg)':>11} {'xi(deg)':>8} {'R0 (m)':>9} {'branch':>6} converged",
                 lambda r: f"{r['omega0']:8.3f} {r['Omega']:9.4f} {math.degrees(r['theta0']):11.3f} "
                           f"{math.degrees(r['xi']):8.3f} {r['R0']:9.4f} {r['branch']:>6} {r['converged']}")
    failed = [r["omega0"] for r in rows if not r["converged"]]
    if failed:
        print(f"rollbot-oc: no quasi-stable state on the {args.branch} branch at omega0 = "
              f"{', '.join(f'{w:g}' for w in failed)} rad/s (see 'residual')", file=sys.stderr)
        return 1
    return 0


def _cmd_stability(args) -> int:
    from rollbot_oc.stability import stability_curve

    params = load_params(args.params)
    results = stability_curve(args.omega0, params, args.branch)
    rows = [r.to_dict() for r in results]
    _report_rows(args, params, rows, f"{'omega0':>8} {'Re(l2)':>9} {'Im(l2)':>9} {'tau (s)':>8} stable",
                 lambda r: f"{r['omega0']:8.3f} {r['lambda2'][0]:9.4f} {r['lambda2'][1]:9.4f} "
                           f"{'inf' if r['tau'] is None else format(r['tau'], '.3f'):>8} {r['stable']}")
    return 0


def _write_run(run, out: Path) -> None:
    """Trajectory (.npz), metrics (JSON) and the paper-style plots of a closed-loop run."""
    from rollbot_oc.plots import plot_time_series, plot_top_view

    stem = f"{run.problem.name}_{run.controller}"
    run.result.save(out / f"{stem}.npz")
    write_json(out / f"{stem}.json", run.metrics)
    targets = run.problem.mission.stops if run.problem.kind == "waypoints" else None
    circle = run.problem.mission if run.problem.kind == "circle" else None
    title = f"{run.problem.name}, {run.controller}"
    plot_top_view(run.result, centres=run.centres, targets=targets, circle=circle, title=title,
                  path=out / f"{stem}_top.png")
    plot_time_series(run.result, centres=run.centres, title=title, path=out / f"{stem}_time.png")


def _cmd_run(args) -> int:
    from rollbot_oc.problems import load_problem, run_open_loop, run_problem

    problem = load_problem(args.problem, base=load_params(args.params))
    if problem.kind == "open_loop":
        metrics = run_open_loop(problem)
        if args.out:
            write_json(Path(args.out) / f"{problem.name}.json", metrics)
    else:
        run = run_problem(problem, args.controller, seed=args.seed, duration=args.duration)
        metrics = run.metrics
        if args.out:
            _write_run(run, Path(args.out))
    if args.json:
        print(to_json(metrics))
    else:
        for key, value in metrics.items():
            if key != "runs":
                print(f"{key:>22}: {value}")
        for row in metrics.get("runs", []):
            print(f"omega0 {row['omega0']:5.2f} rad/s: R0 {row['R0']:.4f} m (theory {row['R0_theory']:.4f}, "
                  f"{100 * row['R0_error']:+.2f} %), settled {row['settled']}")
    return 0 if metrics.get("completed") else 1


def _cmd_compare(args) -> int:
    from rollbot_oc.plots import plot_comparison
    from rollbot_oc.problems import compare, comparison_row, comparison_table, load_problem

    problem = load_problem(args.problem, base=load_params(args.params))
    if problem.kind == "open_loop":
        raise ValueError(f"{args.problem}: an open-loop problem has no controller to compare")
    runs = compare(problem, seed=args.seed, duration=args.duration)
    table = comparison_table(runs)
    rows = [comparison_row(run) for run in runs]
    if args.out:
        out = Path(args.out)
        from rollbot_oc.outputs import atomic_write_text

        atomic_write_text(out / f"{problem.name}_comparison.md", f"# {problem.name}: PID against NMPC\n\n{table}\n")
        write_json(out / f"{problem.name}_comparison.json", {"problem": problem.name, "seed": args.seed,
                                                             "rows": rows, "metrics": [r.metrics for r in runs]})
        plot_comparison(runs, path=out / f"{problem.name}_comparison.png")
        for run in runs:
            _write_run(run, out)
    print(to_json(rows) if args.json else table)
    return 0 if all(r["completed"] for r in rows) else 1


def _cmd_demo(args) -> int:
    from rollbot_oc.report import make_report

    make_report(args.out, load_params(args.params), quick=args.quick)
    return 0


def _cmd_plot(args) -> int:
    from rollbot_oc.animate import animate_run
    from rollbot_oc.plots import plot_energy_and_contact, plot_time_series, plot_top_view
    from rollbot_oc.simulate import SimulationResult

    run = SimulationResult.load(args.run_file)
    out = Path(args.out)
    stem = Path(args.run_file).stem
    written = [plot_top_view(run, title=stem, path=out / f"{stem}_top.png") and out / f"{stem}_top.png",
               plot_time_series(run, title=stem, path=out / f"{stem}_time.png") and out / f"{stem}_time.png",
               plot_energy_and_contact(run, title=stem, path=out / f"{stem}_energy.png") and out / f"{stem}_energy.png"]
    if args.animate:
        written.append(animate_run(run, out / f"{stem}.gif", title=stem))
    for path in written:
        print(path)
    return 0


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of ``rollbot-oc`` (subcommands and their options)."""
    parser = _Parser(prog="rollbot-oc", description="Model, analyse and control Rollbot, the spherical robot "
                     "driven by a single motor. SI units and radians unless an option says otherwise.")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    sub.required = True

    p = sub.add_parser("openloop", help="the paper's open-loop experiment: constant driving speeds, "
                       "measured revolving radius, rate and tilt")
    p.add_argument("--omega0", type=_finite, nargs="+", required=True, metavar="W",
                   help="driving speeds, rad/s, in (0, max_speed]")
    _add_params(p)
    p.add_argument("--slope-deg", type=_finite, metavar="D", help="floor slope, degrees (overrides the file)")
    p.add_argument("--duration", type=_finite, metavar="T",
                   help="run length, s (default: ramp, 40 s settling, then at least two revolutions)")
    p.add_argument("--ramp-rate", type=_finite, default=0.5, metavar="A",
                   help="driving-speed ramp from rest, rad/s^2 (default 0.5)")
    p.add_argument("--out", metavar="DIR", help="write top-view plots (PNG) and openloop.json here")
    p.add_argument("--json", action="store_true", help="print a JSON list of measurements")
    p.set_defaults(run=_cmd_openloop)

    p = sub.add_parser("quasi", help="quasi-stable (steadily revolving) states at given driving speeds")
    p.add_argument("--omega0", type=_finite, nargs="+", required=True, metavar="W",
                   help="driving speeds, rad/s, in [0, max_speed]")
    _add_params(p)
    p.add_argument("--branch", choices=("slow", "fast"), default="slow",
                   help="slow: pendulum near the bottom (the experiments'); fast: pendulum near the top")
    p.add_argument("--plot", metavar="DIR", help="write quasi_stable.png and eigenvalues.png here")
    p.add_argument("--json", action="store_true", help="print a JSON list (SI units, radians)")
    p.set_defaults(run=_cmd_quasi)

    p = sub.add_parser("stability", help="linearised stability (eigenvalues, lambda2, recovery time) of "
                       "quasi-stable states")
    p.add_argument("--omega0", type=_finite, nargs="+", required=True, metavar="W",
                   help="driving speeds, rad/s, in [0, max_speed]")
    _add_params(p)
    p.add_argument("--branch", choices=("slow", "fast"), default="slow", help="branch of quasi-stable states")
    p.add_argument("--plot", metavar="DIR", help="write quasi_stable.png and eigenvalues.png here")
    p.add_argument("--json", action="store_true", help="print a JSON list (eigenvalues as [re, im], 1/s)")
    p.set_defaults(run=_cmd_stability)

    p = sub.add_parser("run", help="run a scenario file (problems/*.toml) under a controller and print its metrics")
    _add_scenario(p)
    p.add_argument("--controller", choices=("pid", "nmpc"), default="pid",
                   help="pid: the paper's quasi-stable baseline; nmpc: nonlinear MPC (default pid)")
    p.add_argument("--out", metavar="DIR", help="write the trajectory (.npz), metrics (.json) and plots (PNG) here")
    p.add_argument("--json", action="store_true", help="print the metrics as JSON (SI units)")
    p.set_defaults(run=_cmd_run)

    p = sub.add_parser("compare", help="run the PID baseline and the NMPC on one problem and compare them")
    _add_scenario(p)
    p.add_argument("--out", metavar="DIR", help="write the table (Markdown, JSON), an overlay plot and both runs here")
    p.add_argument("--json", action="store_true", help="print the table rows as JSON instead of Markdown")
    p.set_defaults(run=_cmd_compare)

    p = sub.add_parser("demo", help="the main job: quasi-stable figures, PID against NMPC on the N-shape, "
                       "an animation; writes a report folder")
    _add_params(p)
    p.add_argument("--out", metavar="DIR", default="out", help="report folder (default out/)")
    p.add_argument("--quick", action="store_true", help="fewer points and frames (about a minute less)")
    p.set_defaults(run=_cmd_demo)

    p = sub.add_parser("plot", help="figures (and an animation) of a saved run (.npz from run/compare --out)")
    p.add_argument("run_file", metavar="RUN.npz", help="a saved run")
    p.add_argument("--out", metavar="DIR", default=".", help="where to write the PNG files (default: here)")
    p.add_argument("--animate", action="store_true", help="also write an animated GIF")
    p.set_defaults(run=_cmd_plot)
    return parser


def main(argv=None) -> int:
    """Run ``rollbot-oc`` with ``argv``; returns the exit status."""
    os.environ.setdefault("MPLBACKEND", "Agg")  # the command line only writes figures to files
    try:
        args = build_parser().parse_args(argv)
        return args.run(args)
    except UsageError as exc:
        print(f"rollbot-oc: error: {exc}", file=sys.stderr)
        return 2
    except ValueError as exc:
        print(f"rollbot-oc: error: {exc}", file=sys.stderr)
        return 2
    except SolveFailed as exc:  # a computation that did not converge: reported, not a crash
        print(f"rollbot-oc: failed: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("rollbot-oc: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
