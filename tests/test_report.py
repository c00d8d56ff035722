"""The main job (rollbot-oc demo), the plot command and the animation."""

import copy
import json

import numpy as np
from PIL import Image

from rollbot_oc.scenarios import problem as problems
from rollbot_oc.view.animate import animate_run
from rollbot_oc.app.cli import main
from rollbot_oc.model.dynamics import rest_state
from rollbot_oc.simulation.plant import SimulationResult, simulate

from shared import same_problem

FIGURES = ["quasi_stable.png", "eigenvalues.png", "comparison.png", "n_shape_pid_top.png", "n_shape_nmpc_top.png",
           "n_shape_pid_time.png", "n_shape_nmpc_time.png", "n_shape_pid_energy.png", "n_shape_nmpc_energy.png"]


def test_demo_writes_the_report_folder(tmp_path, capsys, monkeypatch, n_shape_runs):
    """The demo's N-shape comparison is the session's shared ``n_shape_runs`` (the same ``compare`` call on the
    same problem, computed once for this test and test_nmpc's); everything else the demo computes itself."""
    problem, runs = n_shape_runs
    asked = []

    def shared_compare(demo_problem, seed=0, params=None, duration=None, show_progress=None, nmpc_options=None):
        asked.append(demo_problem)
        assert same_problem(demo_problem, problem) and (seed, params, duration, nmpc_options) == (0, None, None, None)
        return copy.deepcopy(runs)

    monkeypatch.setattr(problems, "compare", shared_compare)
    out = tmp_path / "report"
    assert main(["demo", "--quick", "--out", str(out)]) == 0
    assert len(asked) == 1
    for name in FIGURES + ["comparison.md", "comparison.json", "report.md", "report.json", "openloop.json",
                           "n_shape_pid.npz", "n_shape_nmpc.npz", "n_shape_nmpc.gif"]:
        assert (out / name).stat().st_size > 0, name
    summary = json.loads((out / "report.json").read_text())
    assert summary["n_shape"]["speed_up"] >= 4 and summary["versions"]["casadi"]
    assert summary["quasi_stable"]["R0_at_max_speed"] > 1.2
    table = (out / "comparison.md").read_text()
    assert "| completion time (s) |" in table and "nmpc" in table
    with Image.open(out / "n_shape_nmpc.gif") as gif:
        assert gif.n_frames >= 20
    lines = capsys.readouterr().out.splitlines()  # the summary leads; the steps' progress is on a terminal only
    assert lines[0].startswith(f"report written: {out / 'report.md'}") and lines[1].startswith("  N-shape: PID ")
    report = (out / "report.md").read_text()
    for name in FIGURES + ["n_shape_nmpc.gif"]:
        assert f"]({name})" in report, name  # every figure linked


def test_plot_command_and_saved_runs(tmp_path, capsys):
    run = simulate(rest_state(), 5.0, speed=lambda t: min(3.0, t))
    path = run.save(tmp_path / "ramp.npz")
    again = SimulationResult.load(path)
    assert np.array_equal(again.x, run.x) and again.params == run.params
    assert main(["plot", str(path), "--out", str(tmp_path)]) == 0
    for suffix in ("_top.png", "_time.png", "_energy.png"):
        assert (tmp_path / f"ramp{suffix}").stat().st_size > 10_000
    assert main(["plot", str(tmp_path / "missing.npz")]) == 2
    assert "cannot read a saved run" in capsys.readouterr().err


def test_animation_frames(tmp_path):
    run = simulate(rest_state(), 3.0, speed=lambda t: min(3.0, 2 * t))
    gif = animate_run(run, tmp_path / "roll.gif", frames=8)
    with Image.open(gif) as image:
        assert image.n_frames == 8
    try:
        animate_run(run, tmp_path / "roll.avi")
    except ValueError as exc:
        assert ".gif or .mp4" in str(exc)
    else:
        raise AssertionError("an unknown format must be refused")
