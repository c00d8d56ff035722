"""Figures, in one style: labelled axes with units and the paper's colours.

Colour convention (the paper's figures): robot (shell centre) orange, centre
of curvature blue, driving speed green; targets red, theory lines blue.
Every function returns a matplotlib Figure and, given ``path``, also writes it
as PNG (atomically).
"""

from __future__ import annotations

import io
from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # figures are written to files; no display needed
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from rollbot_oc.outputs import atomic_write_bytes  # noqa: E402

__all__ = ["ROBOT", "CENTRE", "SPEED", "TARGET", "THEORY", "save_figure", "plot_top_view", "plot_time_series"]

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


def plot_top_view(result, centres=None, targets=None, title: str | None = None, path=None, ax=None):
    """Top view of the shell-centre path (orange) and, if given, of the centre of curvature (blue).

    Parameters
    ----------
    result : SimulationResult
        The run.
    centres : numpy.ndarray (2, K+1), optional
        Centre of curvature along the run, m.
    targets : sequence of (x, y), optional
        Target points, m, drawn as red crosses.
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


def plot_time_series(result, centres=None, title: str | None = None, path=None):
    """Position, centre of curvature and driving speed over time (the paper's time panels)."""
    fig, axes = plt.subplots(3, 1, figsize=(7, 6.5), sharex=True)
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
    axes[2].set_xlabel("time (s)")
    axes[2].grid(alpha=0.3)
    if title:
        axes[0].set_title(title)
    fig.tight_layout()
    return save_figure(fig, path)
