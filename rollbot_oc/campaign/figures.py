"""Figures of a campaign's table, in the toolkit's style (``rollbot_oc.view.plots``), each written whole.

* ``plot_success_rates``: success rate against each input that varies
  (its values, or six bins of equal count), one line per group (controller);
* ``plot_closed_loop_histograms``: the stop errors and the completion times
  over each course's minimum-time bound (or the completion times when there
  is no bound), one histogram per controller;
* ``plot_pareto``: radius range against worst recovery time (colour: the
  N-shape bound where computed), the Pareto front and the reference design
  marked;
* ``plot_design_map``: each metric over a two-dimensional grid.

Every function writes its figure to ``path`` and returns the path, or,
given ``path=None``, returns the figure (for a notebook).
"""

from __future__ import annotations

import matplotlib.pyplot as plt
import numpy as np

from rollbot_oc.view.plots import TARGET, save_figure

__all__ = ["plot_success_rates", "plot_closed_loop_histograms", "plot_pareto", "plot_design_map"]

LABELS = {"radius_range": "radius range R0max - R0min (m)", "radius_ratio": "R0max / R0min",
          "tau_max": "worst recovery time (s)", "n_shape_bound": "minimum-time N-shape bound (s)"}
BINS = 6


def _finish(fig, path):
    """Write the figure to ``path`` and close it (returns the path), or, without a path, return the figure."""
    if path is None:
        return fig
    save_figure(fig, path)
    plt.close(fig)
    return path


def _legend(ax) -> None:
    """A legend, if anything drawn has a label."""
    if ax.get_legend_handles_labels()[0]:
        ax.legend(fontsize=8)


def _varied(table, inputs) -> list[str]:
    """The numeric inputs with more than one value."""
    out = []
    for name in inputs:
        if name in table and table[name].dtype.kind in "fiu" and table[name].nunique() > 1:
            out.append(name)
    return out


def _rate_by(rows, name):
    """Success rate of ``rows`` by value of ``name`` (by equal-count bins if it has many values)."""
    x = rows[name].astype(float)
    ok = (rows["status"] == "succeeded").astype(float)
    if x.nunique() <= BINS:
        rate = ok.groupby(x).mean()
        return rate.index.to_numpy(float), rate.to_numpy(), ok.groupby(x).size().to_numpy()
    edges = np.unique(np.quantile(x, np.linspace(0, 1, BINS + 1)))
    which = np.clip(np.searchsorted(edges, x, side="right") - 1, 0, len(edges) - 2)
    centres = [x[which == i].mean() for i in range(len(edges) - 1)]
    rates = [ok[which == i].mean() for i in range(len(edges) - 1)]
    counts = [int((which == i).sum()) for i in range(len(edges) - 1)]
    return np.array(centres), np.array(rates), np.array(counts)


def plot_success_rates(table, inputs, group, path):
    """Success rate against each varied input (see the module doc); a note if none varies."""
    names = _varied(table, inputs)
    columns = min(4, max(1, len(names)))
    rows = max(1, -(-len(names) // columns))
    fig, axes = plt.subplots(rows, columns, figsize=(3.6 * columns, 2.8 * rows), squeeze=False)
    groups = sorted(table[group].unique()) if group else [None]
    for ax, name in zip(axes.flat, names):
        for value in groups:
            subset = table if value is None else table[table[group] == value]
            if len(subset):
                x, rate, _ = _rate_by(subset, name)
                ax.plot(x, 100 * rate, "o-", ms=4, label=value)
        ax.set_xlabel(name)
        ax.set_ylim(-5, 105)
        ax.grid(alpha=0.3)
    for ax in axes.flat[len(names):]:
        ax.axis("off")
    if not names:
        axes.flat[0].text(0.5, 0.5, "no input varies", ha="center", va="center")
    axes[0, 0].set_ylabel("success rate (%)")
    if group and names:
        _legend(axes.flat[0])
    fig.suptitle(f"success rate against each varied input ({len(table)} cases)")
    fig.tight_layout()
    return _finish(fig, path)


def plot_closed_loop_histograms(stop_errors: dict, times: dict, tolerance: float, ratio: bool, path):
    """Histograms of stop errors and of times, one per controller (see the module doc).

    Parameters
    ----------
    stop_errors : dict
        Controller -> every stop error of its runs, m.
    times : dict
        Controller -> the completion time over the bound of each successful run (``ratio``), or its
        completion time, s.
    tolerance : float
        The stop tolerance, m (a line).
    ratio : bool
        Whether ``times`` are ratios.
    path : Path
    """
    fig, (left, right) = plt.subplots(1, 2, figsize=(10, 3.8))
    for controller, errors in stop_errors.items():
        if errors:
            left.hist(100 * np.asarray(errors), bins=30, alpha=0.6, label=f"{controller} ({len(errors)} stops)")
    for controller, values in times.items():
        if values:
            right.hist(values, bins=30, alpha=0.6, label=f"{controller} ({len(values)} runs)")
    left.axvline(100 * tolerance, color=TARGET, ls="--", lw=1, label="tolerance")
    left.set_xlabel("stop error (cm)")
    right.set_xlabel("completion time / minimum-time bound" if ratio else "completion time (s)")
    for ax in (left, right):
        ax.set_ylabel("count")
        ax.grid(alpha=0.3)
        _legend(ax)
    right.set_title("successful runs", fontsize=9)
    fig.tight_layout()
    return _finish(fig, path)


def plot_pareto(table, front, path):
    """Radius range against worst recovery time, the front and the reference marked (see the module doc)."""
    fig, ax = plt.subplots(figsize=(6.5, 4.8))
    ok = table[table["status"] == "succeeded"]
    colour = ok["n_shape_bound"].astype(float) if ok["n_shape_bound"].notna().any() else None
    style = {"c": colour, "cmap": "viridis"} if colour is not None else {"color": "tab:gray"}
    points = ax.scatter(ok["radius_range"], ok["tau_max"], s=22, label="designs", **style)
    if colour is not None:
        fig.colorbar(points, ax=ax, label=LABELS["n_shape_bound"])
    if len(front):
        ax.plot(front["radius_range"], front["tau_max"], "o", mfc="none", mec="tab:red", ms=9, label="Pareto front")
    reference = table[(table["reference"] == True) & (table["status"] == "succeeded")]  # noqa: E712
    if len(reference):
        ax.plot(reference["radius_range"], reference["tau_max"], "*", color="black", ms=14, label="reference")
    failed = table[table["status"] != "succeeded"]
    if len(failed):
        ax.set_title(f"{len(failed)} designs failed (not shown)", fontsize=9)
    ax.set_xlabel(LABELS["radius_range"])
    ax.set_ylabel(LABELS["tau_max"])
    ax.grid(alpha=0.3)
    _legend(ax)
    fig.tight_layout()
    return _finish(fig, path)


def plot_design_map(table, axes, metrics, path):
    """Each metric with values over the grid of the two ``axes`` (the reference marked)."""
    grid = table[table["reference"] == False]  # noqa: E712
    shown = [m for m in metrics if grid[m].notna().any()]
    x_name, y_name = axes
    xs, ys = np.unique(grid[x_name].astype(float)), np.unique(grid[y_name].astype(float))
    fig, panels = plt.subplots(1, len(shown), figsize=(4.6 * len(shown), 3.9), squeeze=False)
    reference = table[table["reference"] == True]  # noqa: E712
    for ax, metric in zip(panels.flat, shown):
        values = np.full((len(ys), len(xs)), np.nan)
        for _, row in grid.iterrows():
            values[np.searchsorted(ys, float(row[y_name])), np.searchsorted(xs, float(row[x_name]))] = row[metric]
        mesh = ax.pcolormesh(xs, ys, values, shading="nearest", cmap="viridis")
        fig.colorbar(mesh, ax=ax, label=LABELS.get(metric, metric))
        if len(reference):
            ax.plot(reference[x_name], reference[y_name], "*", color="white", mec="black", ms=14)
        ax.set_xlabel(x_name)
        ax.set_ylabel(y_name)
    fig.tight_layout()
    return _finish(fig, path)
