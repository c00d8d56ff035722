"""Animation of a run: the top view of the path and a view of the shell with its motor axis and pendulum.

Written with matplotlib's animation module: GIF through Pillow (always
available with matplotlib), MP4 through ffmpeg where it is installed.  The
file is written whole (temporary file, then rename).
"""

from __future__ import annotations

from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
from matplotlib import animation

from rollbot_oc.model.dynamics import QUAT, THETA
from rollbot_oc.core.errors import ConfigError
from rollbot_oc.core.outputs import atomic_path
from rollbot_oc.view.plots import CENTRE, ROBOT, SPEED, TARGET
from rollbot_oc.model.rotations import quat_to_matrix_np

__all__ = ["animate_run", "shell_geometry"]


def shell_geometry(x, params, meridians: int = 6, parallels: int = 4, points: int = 40):
    """Lines that draw the shell (in its own rotating frame), its motor axis and the pendulum, floor frame, m.

    Returns
    -------
    (wires, axis, mass)
        ``wires``: list of (3, points) arrays (meridians about the motor axis and parallels),
        ``axis``: (3, 2) end points of the motor axis through the shell,
        ``mass``: (3,) position of the pendulum mass; all relative to the shell centre.
    """
    T = quat_to_matrix_np(x[QUAT])
    R = params.R
    a = np.linspace(0.0, 2 * np.pi, points)
    wires = []
    for k in range(meridians):
        b = np.pi * k / meridians
        wires.append(T @ (R * np.array([np.cos(a) * np.cos(b), np.cos(a) * np.sin(b), np.sin(a)])))
    for lat in np.linspace(-np.pi / 3, np.pi / 3, parallels):
        ring = np.array([np.cos(lat) * np.cos(a), np.cos(lat) * np.sin(a), np.full_like(a, np.sin(lat))])
        wires.append(T @ (R * ring))
    axis = T @ np.array([[0.0, 0.0], [0.0, 0.0], [-1.2 * R, 1.2 * R]])
    theta = x[THETA]
    body = params.r0 * np.array([np.sin(params.phi) * np.cos(theta), np.sin(params.phi) * np.sin(theta),
                                 -np.cos(params.phi)])
    return wires, axis, T @ body


def animate_run(result, path, centres=None, targets=None, circle=None, title: str | None = None, fps: int = 12,
                frames: int = 120, speedup: float | None = None):
    """Write an animation of ``result`` to ``path`` (``.gif``, or ``.mp4`` where ffmpeg exists).

    Parameters
    ----------
    result : SimulationResult
    path : str or Path
        Output file; its suffix picks the format.
    centres : numpy.ndarray (2, K+1), optional
        Centre of curvature along the run, m (drawn blue).
    targets : sequence of (x, y), optional
        Waypoints, m (red crosses).
    circle : Circle, optional
        Target circle (red, dashed).
    title : str, optional
    fps : int
        Frames per second of the file.
    frames : int
        Number of frames (spread evenly over the run).
    speedup : float, optional
        Ignored unless given: then ``frames`` follows from the run length, ``fps`` and this speed-up.

    Returns
    -------
    pathlib.Path
    """
    path = Path(path)
    if path.suffix not in (".gif", ".mp4"):
        raise ConfigError(f"animation path {path}: use a .gif or .mp4 file")
    if path.suffix == ".mp4" and not animation.writers.is_available("ffmpeg"):
        raise ConfigError("MP4 needs ffmpeg, which is not installed here; write a .gif instead")
    t, s, params = result.t, result.position, result.params
    if speedup:
        frames = max(2, int(t[-1] / speedup * fps))
    index = np.unique(np.linspace(0, len(t) - 1, frames).astype(int))

    fig = plt.figure(figsize=(10, 4.8))
    ax = fig.add_subplot(1, 2, 1)
    ax3 = fig.add_subplot(1, 2, 2, projection="3d")
    pad = 2 * params.R
    ax.set_xlim(s[0].min() - pad, s[0].max() + pad)
    ax.set_ylim(s[1].min() - pad, s[1].max() + pad)
    ax.set_aspect("equal", adjustable="box")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.grid(alpha=0.3)
    ax.plot(s[0], s[1], color=ROBOT, alpha=0.15, lw=0.8)
    if circle is not None:
        a = np.linspace(0, 2 * np.pi, 200)
        ax.plot(circle.centre[0] + circle.radius * np.cos(a), circle.centre[1] + circle.radius * np.sin(a),
                color=TARGET, ls="--", lw=1.0)
    if targets is not None and len(targets):
        tx, ty = np.asarray(targets, float).T
        ax.plot(tx, ty, "x", color=TARGET, ms=9, mew=2)
    trail, = ax.plot([], [], color=ROBOT, lw=1.2, label="shell centre")
    ctrail, = ax.plot([], [], color=CENTRE, lw=1.0, label="centre of curvature")
    body = plt.Circle((s[0, 0], s[1, 0]), params.R, color=ROBOT, alpha=0.35)
    ax.add_patch(body)
    heading, = ax.plot([], [], color="k", lw=1.5)
    clock = ax.text(0.02, 0.95, "", transform=ax.transAxes, fontsize=9)
    ax.legend(loc="lower right", fontsize=7)
    if title:
        ax.set_title(title, fontsize=10)

    lim = 1.3 * params.R
    ax3.set_xlim(-lim, lim)
    ax3.set_ylim(-lim, lim)
    ax3.set_zlim(-params.R, 1.6 * lim - params.R)
    ax3.set_box_aspect((1, 1, 1))
    ax3.set_xlabel("x (m)", fontsize=8)
    ax3.set_ylabel("y (m)", fontsize=8)
    ax3.set_zlabel("z (m)", fontsize=8)
    ax3.set_title("shell, motor axis (black), pendulum (green)", fontsize=9)
    floor = np.linspace(-lim, lim, 2)
    fx, fy = np.meshgrid(floor, floor)
    ax3.plot_surface(fx, fy, np.full_like(fx, -params.R), color="0.85", alpha=0.4)
    wires, axis, mass = shell_geometry(result.x[:, 0], params)
    wire_lines = [ax3.plot(*w, color=ROBOT, lw=0.7, alpha=0.7)[0] for w in wires]
    axis_line, = ax3.plot(*axis, color="k", lw=2.0)
    mass_dot, = ax3.plot(*mass[:, None], "o", color=SPEED, ms=8)
    arm, = ax3.plot([0, mass[0]], [0, mass[1]], [0, mass[2]], color=SPEED, lw=1.5)

    def draw(k):
        trail.set_data(s[0, :k + 1], s[1, :k + 1])
        if centres is not None:
            ctrail.set_data(centres[0, :k + 1], centres[1, :k + 1])
        body.center = (s[0, k], s[1, k])
        axis_dir = quat_to_matrix_np(result.x[QUAT, k])[:, 2]
        tip = s[:, k] + 2 * params.R * axis_dir[:2]
        heading.set_data([s[0, k], tip[0]], [s[1, k], tip[1]])
        clock.set_text(f"t = {t[k]:.1f} s, driving speed {result.driving_speed[k]:+.1f} rad/s")
        wires, axis, mass = shell_geometry(result.x[:, k], params)
        for line, w in zip(wire_lines, wires):
            line.set_data_3d(*w)
        axis_line.set_data_3d(*axis)
        mass_dot.set_data_3d(*mass[:, None])
        arm.set_data_3d([0, mass[0]], [0, mass[1]], [0, mass[2]])
        return [trail, ctrail, body, heading, clock, axis_line, mass_dot, arm, *wire_lines]

    anim = animation.FuncAnimation(fig, draw, frames=index, blit=False)
    writer = animation.PillowWriter(fps=fps) if path.suffix == ".gif" else animation.FFMpegWriter(fps=fps)
    fig.set_dpi(80)
    try:
        with atomic_path(path, mode=None) as tmp:
            anim.save(tmp, writer=writer)
    finally:
        plt.close(fig)
    return path
