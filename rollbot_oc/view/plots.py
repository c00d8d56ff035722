"""Figures, in one style: labelled axes with units and the paper's colours.

Colour convention (the paper's figures): robot (shell centre) orange, centre
of curvature blue, driving speed green; targets red, theory lines blue.
Every function returns a matplotlib Figure and, given ``path``, also writes it
as PNG (atomically).
"""

from __future__ import annotations

import io
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np

from rollbot_oc.core.outputs import atomic_write_bytes
from rollbot_oc.model.dynamics import RollbotModel
from rollbot_oc.view.text import compare_headline, run_verdict
from rollbot_oc.view.text import run_title

__all__ = [
    "ROBOT", "CENTRE", "SPEED", "TARGET", "THEORY", "MEASURED", "save_figure", "plot_top_view", "plot_time_series",
    "plot_quasi_stable", "plot_eigenvalues", "plot_comparison", "plot_energy_and_contact", "save_run_figures",
]

ROBOT = "tab:orange"
CENTRE = "tab:blue"
SPEED = "tab:green"
TARGET = "tab:red"
THEORY = "tab:blue"
MEASURED = "tab:purple"


def save_figure(fig, path: str | Path | None, dpi: int = 120):
    """Write ``fig`` as PNG to ``path`` atomically (if a path is given) and return the figure."""
    if path is not None:
        buffer = io.BytesIO()
        fig.savefig(buffer, format="png", dpi=dpi, bbox_inches="tight")
        atomic_write_bytes(path, buffer.getvalue())
    return fig


def plot_top_view(result, centres=None, targets=None, circle=None, title: str | None = None, path=None, ax=None):
    """Top view of the shell-centre path (orange) and, if given, of the centre of curvature (blue).

    Parameters
    ----------
    result : SimulationResult
        The run.
    centres : numpy.ndarray (2, K+1), optional
        Centre of curvature along the run, m.
    targets : sequence of (x, y), optional
        Target points, m, drawn as red crosses.
    circle : Circle, optional
        Target circle, drawn in red.
    title : str, optional
    path : str or Path, optional
        Where to write the PNG.
    ax : matplotlib Axes, optional
        Draw into this axes instead of a new figure.
    """
    fig, ax = (plt.subplots(figsize=(5.5, 5.5)) if ax is None else (ax.figure, ax))
    s = result.position
    ax.plot(s[0], s[1], color=ROBOT, lw=1.2, label="shell centre s")
    ax.plot(s[0, 0], s[1, 0], "o", color=ROBOT, ms=5)
    if centres is not None:
        ax.plot(centres[0], centres[1], color=CENTRE, lw=1.0, label="centre of curvature o")
    if circle is not None:
        a = np.linspace(0.0, 2 * np.pi, 200)
        ax.plot(circle.centre[0] + circle.radius * np.cos(a), circle.centre[1] + circle.radius * np.sin(a),
                color=TARGET, lw=1.0, ls="--", label="target circle")
    if targets is not None and len(targets):
        tx, ty = np.asarray(targets, float).T
        ax.plot(tx, ty, "x", color=TARGET, ms=9, mew=2, label="targets")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(alpha=0.3)
    ax.legend(loc="best", fontsize=8)
    if title:
        ax.set_title(title)
    return save_figure(fig, path)


def plot_modes(ax, timelines: dict, t_end: float) -> None:
    """The controller's modes over time on ``ax``: one row per machine of ``timelines`` (its name ->
    ``[{"mode", "t", "reason"}, ...]``, as a run's ``modes`` and ``step_modes``), each mode a coloured span
    labelled with its name, from its start to the next change (or ``t_end``, s)."""
    names = sorted({change["mode"] for timeline in timelines.values() for change in timeline})
    colours = {name: plt.get_cmap("tab10")(i % 10) for i, name in enumerate(names)}
    for row, (machine, timeline) in enumerate(timelines.items()):
        ends = [change["t"] for change in timeline[1:]] + [t_end]
        for change, end in zip(timeline, ends):
            if end <= change["t"]:
                continue
            ax.broken_barh([(change["t"], end - change["t"])], (row - 0.4, 0.8), color=colours[change["mode"]],
                           alpha=0.75)
            if end - change["t"] >= 0.04 * t_end:
                ax.text(0.5 * (change["t"] + end), row, change["mode"], ha="center", va="center", fontsize=7)
    ax.set_yticks(range(len(timelines)), list(timelines))
    ax.set_ylim(-0.5, len(timelines) - 0.5)
    ax.set_xlim(0.0, t_end)
    ax.set_xlabel("time (s)")


def _timelines(metrics: dict) -> dict:
    """A run's mode timelines (``modes`` of its supervisor, ``step_modes`` of its step), if it has any."""
    return {label: metrics[key] for key, label in (("modes", "supervisor"), ("step_modes", "step"))
            if metrics.get(key)}


def plot_time_series(result, centres=None, title: str | None = None, path=None, modes: dict | None = None):
    """Position, centre of curvature and driving speed over time (the paper's time panels); under them the
    controller's modes (``modes``: a run's metrics with ``modes`` and ``step_modes``), if it has any."""
    timelines = _timelines(modes or {})
    rows = 4 if timelines else 3
    fig, axes = plt.subplots(rows, 1, figsize=(7, 6.5 + 1.2 * (rows - 3)), sharex=True,
                             height_ratios=[3, 3, 3, 1.4][:rows])
    t, s = result.t, result.position
    for i, (ax, label) in enumerate(zip(axes[:2], ("x (m)", "y (m)"))):
        ax.plot(t, s[i], color=ROBOT, label="shell centre")
        if centres is not None:
            ax.plot(t, centres[i], color=CENTRE, label="centre of curvature")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    axes[0].legend(loc="best", fontsize=8)
    axes[2].plot(t, result.driving_speed, color=SPEED)
    axes[2].set_ylabel("driving speed (rad/s)")
    axes[2].grid(alpha=0.3)
    if timelines:
        plot_modes(axes[3], timelines, float(t[-1]))
    else:
        axes[2].set_xlabel("time (s)")
    if title:
        axes[0].set_title(title)
    fig.tight_layout()
    return save_figure(fig, path)


def plot_quasi_stable(curves, path=None, title: str | None = None, robot: str = "prototype"):
    """The paper's 'key parameters of quasi-stable state' figure: R0, Omega, xi, theta0 against omega0.

    Parameters
    ----------
    curves : dict of str -> list of QuasiStableState
        One curve per branch name (for example ``{"slow": [...], "fast": [...]}``).
    path : str or Path, optional
        Where to write the PNG.
    title : str, optional
        Default: the robot and the range of revolving radius on the slow branch.
    robot : str
        What the robot is called in the default title.
    """
    fig, axes = plt.subplots(2, 2, figsize=(9, 6.5), sharex=True)
    panels = [("R0", "revolving radius R0 (m)", 1.0), ("Omega", "revolving rate Omega (rad/s)", 1.0),
              ("xi", "tilt of motor axis xi (deg)", 180 / np.pi),
              ("theta0", "pendulum angle theta0 (deg)", 180 / np.pi)]
    styles = {"slow": dict(color=THEORY, ls="-"), "fast": dict(color="tab:gray", ls="--")}
    for ax, (key, label, scale) in zip(axes.ravel(), panels):
        for branch, states in curves.items():
            ok = [s for s in states if s.converged]
            ax.plot([s.omega0 for s in ok], [getattr(s, key) * scale for s in ok], label=f"{branch} branch",
                    **styles.get(branch, {}))
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    for ax in axes[1]:
        ax.set_xlabel("driving speed omega0 (rad/s)")
    axes[0, 0].legend(fontsize=8)
    slow = [s.R0 for s in curves.get("slow", []) if s.converged]
    radii = f": slow-branch R0 from {min(slow):.3f} to {max(slow):.3f} m" if slow else ""
    fig.suptitle(title or f"Quasi-stable states of the {robot}{radii}")
    fig.tight_layout()
    return save_figure(fig, path)


def plot_eigenvalues(results, path=None, title: str | None = None, robot: str = "prototype"):
    """The paper's eigenvalue figure: eigenvalue trajectories over omega0, and the recovery time.

    Parameters
    ----------
    results : list of Stability
        Along increasing driving speed.
    path : str or Path, optional
        Where to write the PNG.
    title : str, optional
        Default: the robot, whether every state is stable and the range of recovery time.
    robot : str
        What the robot is called in the default title.
    """
    fig, (ax, ax2) = plt.subplots(1, 2, figsize=(11, 4.5), gridspec_kw=dict(width_ratios=[1.3, 1]))
    omegas = np.array([r.state.omega0 for r in results])
    eig = np.array([r.eigenvalues for r in results])
    points = ax.scatter(eig.real.ravel(), eig.imag.ravel(), c=np.repeat(omegas, eig.shape[1]), s=6, cmap="viridis")
    ax.plot([r.symmetry_eigenvalue for r in results], np.zeros(len(results)), "x", color=TARGET, ms=4,
            label="symmetry mode (removed)")
    ax.axvline(0.0, color="k", lw=0.6)
    fig.colorbar(points, ax=ax, label="driving speed omega0 (rad/s)")
    ax.set_xlabel("Re(lambda) (1/s)")
    ax.set_ylabel("Im(lambda) (1/s)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="lower left")
    ax2.plot(omegas, [r.lambda2.real for r in results], color=THEORY, label="Re(lambda2)")
    ax2.set_xlabel("driving speed omega0 (rad/s)")
    ax2.set_ylabel("Re(lambda2) (1/s)")
    ax2.grid(alpha=0.3)
    ax3 = ax2.twinx()
    ax3.plot(omegas, [r.tau for r in results], color=ROBOT, label="recovery time tau")
    ax3.set_ylabel("recovery time tau (s)")
    ax2.legend(loc="upper left", fontsize=8)
    ax3.legend(loc="upper right", fontsize=8)
    taus = [r.tau for r in results if np.isfinite(r.tau)]
    verdict = ("stable at every speed" if all(r.stable for r in results) else "NOT stable at every speed") + (
        f", recovery time {min(taus):.1f} to {max(taus):.1f} s" if taus else "")
    fig.suptitle(title or f"Linearised stability of the {robot}'s quasi-stable states: {verdict}")
    fig.tight_layout()
    return save_figure(fig, path)


def _mark_progress(ax, run) -> None:
    """Mark on a time axis where ``run`` reached each stop, or reached its circle and started being measured."""
    m = run.metrics
    for i, t in enumerate(m.get("stop_times", []), 1):
        ax.axvline(t, color=TARGET, ls="--", lw=0.9)
        ax.annotate(f"stop {i}", (t, 1.0), xycoords=("data", "axes fraction"), xytext=(-3, -3),
                    textcoords="offset points", ha="right", va="top", fontsize=8, color=TARGET, rotation=90)
    if m.get("reach_time") is not None:
        ax.axvline(m["reach_time"], color=TARGET, ls="--", lw=0.9)
        ax.annotate("on the circle", (m["reach_time"], 1.0), xycoords=("data", "axes fraction"), xytext=(3, -3),
                    textcoords="offset points", va="top", fontsize=8, color=TARGET)
        if m.get("avg_deviation") is not None:
            ax.axvspan(m["settle_time"], run.result.t[-1], color=TARGET, alpha=0.07, label="deviation measured")


def plot_comparison(runs, path=None, title: str | None = None):
    """Several controllers on one problem: top view overlaid, and each run's driving speed on its own time axis.

    Each time panel spans its own run (a 27 s and a 190 s run both fill their
    width), with the same speed axis, the stops reached (or the arrival on
    the circle) marked, and the run's verdict as its title.

    Parameters
    ----------
    runs : list of RunResult
        Runs of the same problem (for example ``scenarios.problem.compare``).
    path : str or Path, optional
        Where to write the PNG.
    title : str, optional
        Default: which controller did better (``view.text.compare_headline``).
    """

    fig = plt.figure(figsize=(13, 2.2 + 3.0 * len(runs)), layout="constrained")
    grid = fig.add_gridspec(2 * len(runs), 2, width_ratios=[1, 1.5], height_ratios=[3, 1] * len(runs))
    ax = fig.add_subplot(grid[:, 0])
    colours = {"pid": ROBOT, "nmpc": "tab:brown"}
    problem = runs[0].problem
    time_axes = []
    for i, run in enumerate(runs):
        colour = colours.get(run.controller, None)
        s = run.result.position
        ax.plot(s[0], s[1], color=colour, lw=1.1, label=run.controller)
        axt = fig.add_subplot(grid[2 * i, 1], sharey=time_axes[0] if time_axes else None)
        axt.plot(run.result.t, run.result.driving_speed, color=colour, lw=1.0)
        _mark_progress(axt, run)
        axt.set_xlim(0.0, run.result.t[-1])
        axt.set_ylabel(f"{run.controller}\ndriving speed (rad/s)")
        axt.set_title(f"{run.controller}: {run_verdict(run)}", fontsize=9, loc="left")
        axt.grid(alpha=0.3)
        time_axes.append(axt)
        axm = fig.add_subplot(grid[2 * i + 1, 1], sharex=axt)
        timelines = _timelines(run.metrics)
        if timelines:
            plot_modes(axm, timelines, float(run.result.t[-1]))
        else:
            axm.set_yticks([])
            axm.text(0.5, 0.5, f"{run.controller}: no modes", transform=axm.transAxes, ha="center", va="center",
                     fontsize=8)
            axm.set_xlabel("time (s)")
    mission = problem.mission
    if mission.targets:
        tx, ty = np.asarray(mission.targets).T
        ax.plot(tx, ty, "x", color=TARGET, ms=10, mew=2, label="stops" if mission.stops else "gates")
        for i, (x, y) in enumerate(mission.targets, 1):
            ax.annotate(str(i), (x, y), xytext=(6, 4), textcoords="offset points", color=TARGET, fontsize=9)
    if mission.orbit is not None:
        a, orbit = np.linspace(0.0, 2 * np.pi, 200), mission.orbit
        ax.plot(orbit.centre[0] + orbit.radius * np.cos(a), orbit.centre[1] + orbit.radius * np.sin(a),
                color=TARGET, ls="--", lw=1.0, label="target circle")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title("top view", fontsize=9, loc="left")
    fig.suptitle(title or compare_headline(runs))
    return save_figure(fig, path)


def save_run_figures(run, folder) -> list[Path]:
    """Top view, time series and energy/contact plots of a closed-loop run, titled with its verdict.

    Parameters
    ----------
    run : RunResult
        The run (``scenarios.problem.run_problem``).
    folder : Path or OutputFolder
        Where to write ``<problem>_<controller>_top.png``, ``_time.png`` and ``_energy.png``.

    Returns
    -------
    list of Path
        The files written.
    """

    stem = f"{run.problem.name}_{run.controller}"
    targets = run.problem.mission.targets or None
    circle = run.problem.mission.orbit
    title = run_title(run)
    paths = [folder / f"{stem}_top.png", folder / f"{stem}_time.png", folder / f"{stem}_energy.png"]
    figures = [plot_top_view(run.result, centres=run.centres, targets=targets, circle=circle, title=title,
                             path=paths[0]),
               plot_time_series(run.result, centres=run.centres, title=title, path=paths[1], modes=run.metrics),
               plot_energy_and_contact(run.result, title=title, path=paths[2])]
    for figure in figures:
        plt.close(figure)
    return paths


def plot_energy_and_contact(result, path=None, title: str | None = None):
    """Energy, motor and damping power, ground reaction and contact margins along a run.

    The energy panel also draws ``E(0) +`` the integrated motor and damping power: the two
    curves lie on each other when the simulation conserves energy as it should.
    """

    model = RollbotModel(result.params)
    t = result.t
    energy = model.energy(result.x)
    power = model.power(result.x[:, :-1], result.applied_accel)
    power_end = model.power(result.x[:, 1:], result.applied_accel)  # acceleration held over each period
    work = np.concatenate([[0.0], np.cumsum(0.5 * (power[:2] + power_end[:2]).sum(axis=0) * result.dt)])
    fig, axes = plt.subplots(3, 1, figsize=(7, 7.5), sharex=True)
    axes[0].plot(t, energy, color=ROBOT, label="mechanical energy E")
    axes[0].plot(t, energy[0] + work, color="k", ls=":", label="E(0) + work of motor and damping")
    axes[0].set_ylabel("energy (J)")
    axes[1].plot(t[:-1], power[0], color=SPEED, label="motor power")
    axes[1].plot(t[:-1], power[1], color=CENTRE, label="damping power")
    axes[1].set_ylabel("power (W)")
    axes[2].plot(t[:-1], result.normal_force, color="k", label="normal force (no-jump margin)")
    axes[2].plot(t[:-1], result.slide_margin, color=TARGET, label="no-slide margin mu N_z - |N_t|")
    axes[2].axhline(0.0, color="0.5", lw=0.8)
    axes[2].set_ylabel("force (N)")
    axes[2].set_xlabel("time (s)")
    for ax in axes:
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8, loc="best")
    if title:
        axes[0].set_title(title)
    fig.tight_layout()
    return save_figure(fig, path)
