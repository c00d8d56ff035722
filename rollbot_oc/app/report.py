"""The main job: a report folder with the paper's figures, the PID-against-NMPC comparison and an animation.

``make_report`` is what ``rollbot-oc demo`` (and ``make demo``) runs.  Steps:

1. quasi-stable states (both branches) and their stability over the driving
   speeds: ``quasi_stable.png``, ``eigenvalues.png``;
2. the open-loop experiment against the theory: ``openloop.json``;
3. the PID baseline and the NMPC on the N-shape problem: ``comparison.md``,
   ``comparison.json``, ``comparison.png`` and each run's plots and ``.npz``;
4. an animation of the NMPC run: ``n_shape_nmpc.gif``;
5. ``report.md`` (an index with the key numbers) and ``report.json``.
"""

from __future__ import annotations

import time
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np

from rollbot_oc.core.outputs import OutputFolder, atomic_write_text, write_json
from rollbot_oc.model.params import RollbotParams

__all__ = ["make_report"]


def _seconds(value) -> str:
    """A time for the report's text, s; a run that did not finish says so."""
    return "did not finish" if value is None else f"{value:.1f} s"


def make_report(out: str | Path = "out", params: RollbotParams | None = None, quick: bool = False,
                show_progress: bool | None = None, robot: str = "prototype") -> dict:
    """Compute, simulate and write the report folder (see module doc).

    Parameters
    ----------
    out : str or Path
        Report folder (checked and created before anything is computed).
    params : RollbotParams, optional
        The robot; the paper's prototype by default.
    quick : bool
        Fewer curve points, fewer open-loop speeds and a shorter animation (for tests).
    show_progress : bool or None
        The steps and the runs' progress on stderr: True shows them, False
        hides them, None only on a terminal (``progress``).
    robot : str
        What the robot is called in the figures' titles.

    Returns
    -------
    dict
        The key numbers (also in ``report.json``).

    Raises
    ------
    ConfigError
        If ``out`` cannot be used as a folder (checked first).
    """
    from rollbot_oc.view.animate import animate_run
    from rollbot_oc.analysis.experiments import check_open_loop, open_loop_run
    from rollbot_oc.view.plots import plot_comparison, plot_eigenvalues, plot_quasi_stable, save_run_figures
    from rollbot_oc.scenarios.problem import compare, comparison_row, comparison_table
    from rollbot_oc.core.progress import progress_bar
    from rollbot_oc.analysis.quasi_stable import quasi_stable_curve
    from rollbot_oc.scenarios.bundled import load_bundled
    from rollbot_oc.analysis.stability import stability_curve
    from rollbot_oc.view.text import run_title

    out = OutputFolder(out, "out")
    params = params or RollbotParams()
    problem = load_bundled("n_shape", base=params)  # the scenario is read before anything is computed
    speeds = [w for w in (1.0, 3.0, 6.0) if w <= params.max_speed] or [params.max_speed / 2]
    for speed in speeds:
        check_open_loop(speed, params)
    summary: dict = {"quick": quick}
    start = time.perf_counter()
    steps = progress_bar(show=show_progress, total=5, desc="demo", unit="step",
                         bar_format="{desc}: step {n_fmt}/{total_fmt} [{elapsed}]")

    done = iter(range(6))

    def step(what: str):  # the bar counts the steps done and names the one under way
        steps.n = next(done)
        steps.set_description_str(f"demo: {what}")

    step("quasi-stable states and their stability")
    omegas = np.linspace(0.0, params.max_speed, 60 if quick else 200)
    curves = {branch: quasi_stable_curve(omegas, params, branch) for branch in ("slow", "fast")}
    plot_quasi_stable(curves, path=out / "quasi_stable.png", robot=robot)
    stability = stability_curve(omegas[1:], params)
    plot_eigenvalues(stability, path=out / "eigenvalues.png", robot=robot)
    slow = curves["slow"]
    summary["quasi_stable"] = {"R0_at_rest": slow[0].R0, "R0_at_max_speed": slow[-1].R0,
                               "Re_lambda2_range": [min(r.lambda2.real for r in stability),
                                                    max(r.lambda2.real for r in stability)],
                               "tau_range": [min(r.tau for r in stability), max(r.tau for r in stability)]}

    plt.close("all")

    step("open-loop experiment against the theory")
    rows = []
    for speed, theory in zip(speeds, quasi_stable_curve(speeds, params)):
        measured, _ = open_loop_run(speed, params)
        rows.append({**measured.to_dict(), "R0_theory": theory.R0, "R0_error": measured.R0 / theory.R0 - 1})
    write_json(out / "openloop.json", {"runs": rows})
    summary["open_loop_max_R0_error"] = max(abs(r["R0_error"]) for r in rows)

    step("PID baseline and NMPC on the N-shape")
    runs = compare(problem, show_progress=show_progress)
    table = comparison_table(runs)
    atomic_write_text(out / "comparison.md", f"# N-shape: PID baseline against NMPC\n\n{table}\n")
    write_json(out / "comparison.json", {"rows": [comparison_row(r) for r in runs],
                                         "metrics": [r.metrics for r in runs]})
    plot_comparison(runs, path=out / "comparison.png")
    for run in runs:
        run.result.save(out / f"n_shape_{run.controller}.npz")
        save_run_figures(run, out)
    pid, nmpc = (r.metrics for r in runs)
    summary["n_shape"] = {"pid_time": pid["completion_time"], "nmpc_time": nmpc["completion_time"],
                          "speed_up": pid["completion_time"] / nmpc["completion_time"]
                          if pid["completion_time"] and nmpc["completion_time"] else None,
                          "pid_stop_errors": pid["stop_errors"], "nmpc_stop_errors": nmpc["stop_errors"],
                          "nmpc_solve_time_median": nmpc["solve_time_median"],
                          "nmpc_solve_time_p95": nmpc["solve_time_p95"]}

    plt.close("all")

    step("animation of the NMPC run")
    nmpc_run = runs[1]
    animate_run(nmpc_run.result, out / "n_shape_nmpc.gif", centres=nmpc_run.centres, targets=problem.mission.stops,
                title=run_title(nmpc_run), frames=20 if quick else 120)

    step("report")
    q = summary["quasi_stable"]
    n = summary["n_shape"]
    lines = [
        "# Rollbot report",
        "",
        f"Quasi-stable slow branch: R0 from {q['R0_at_rest']:.3f} m at rest to {q['R0_at_max_speed']:.3f} m at "
        f"{params.max_speed:.2f} rad/s; Re(lambda2) in [{q['Re_lambda2_range'][0]:.3f}, {q['Re_lambda2_range'][1]:.3f}]"
        f" 1/s, recovery time {q['tau_range'][0]:.1f} to {q['tau_range'][1]:.1f} s.",
        "",
        f"Open loop: the simulated R0 differs from the theory by at most {summary['open_loop_max_R0_error']:.1e} "
        f"(relative) at {', '.join(f'{w:g}' for w in speeds)} rad/s.",
        "",
        f"N-shape: the PID baseline needs {_seconds(n['pid_time'])}, the NMPC {_seconds(n['nmpc_time'])}"
        + (f" ({n['speed_up']:.1f} times faster)" if n["speed_up"] else "") + ".",
        "",
        table,
        "",
        "## Figures",
        "",
        "![quasi-stable states](quasi_stable.png)",
        "",
        "![eigenvalues and recovery time](eigenvalues.png)",
        "",
        "![PID against NMPC on the N-shape](comparison.png)",
        "",
        *(f"![{run.controller}: {what}](n_shape_{run.controller}_{suffix}.png)\n" for run in runs
          for suffix, what in (("top", "top view"), ("time", "time series"), ("energy", "energy and contact"))),
        "![animation of the NMPC run](n_shape_nmpc.gif)",
        "",
        "Data: [openloop.json](openloop.json), [comparison.md](comparison.md), [comparison.json](comparison.json), "
        + ", ".join(f"[n_shape_{run.controller}.npz](n_shape_{run.controller}.npz)" for run in runs)
        + " (`rollbot-oc plot RUN.npz` draws a saved run again).",
    ]
    atomic_write_text(out / "report.md", "\n".join(lines) + "\n")
    summary["wall_time"] = time.perf_counter() - start
    write_json(out / "report.json", summary)
    step("done")
    steps.close()
    return summary
