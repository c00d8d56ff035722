"""The command-line contracts (JSON keys, exit codes, one-line errors)."""

import json
from pathlib import Path

import pytest

from rollbot_oc.app.cli import main


def run_json(argv, capsys, status=0):
    assert main(argv) == status
    return json.loads(capsys.readouterr().out)


def test_quasi_json_contract(capsys, tmp_path):
    rows = run_json(["quasi", "--omega0", "0", "3", "9.42", "--json", "--plot", str(tmp_path)], capsys)
    for row in rows:
        assert {"omega0", "Omega", "theta0", "xi", "R0", "branch", "converged", "residual"} <= set(row)
        assert row["branch"] == "slow" and row["converged"]
    assert rows[0]["R0"] == pytest.approx(0.12, abs=1e-3) and rows[2]["R0"] == pytest.approx(1.28, rel=0.02)
    assert (tmp_path / "quasi_stable.png").stat().st_size > 10_000
    assert (tmp_path / "eigenvalues.png").stat().st_size > 10_000
    fast = run_json(["quasi", "--omega0", "3", "--branch", "fast", "--json"], capsys)
    assert fast[0]["branch"] == "fast" and fast[0]["Omega"] < 0


def test_stability_json_contract(capsys):
    rows = run_json(["stability", "--omega0", "1", "6", "--json"], capsys)
    for row in rows:
        assert {"omega0", "eigenvalues", "lambda2", "tau", "stable"} <= set(row)
        assert len(row["eigenvalues"]) == 5 and all(len(e) == 2 for e in row["eigenvalues"])
        assert -0.2 <= row["lambda2"][0] <= -0.1 and row["tau"] == pytest.approx(-1 / row["lambda2"][0])
        assert row["stable"] is True
    unstable = run_json(["stability", "--omega0", "6", "--branch", "fast", "--json"], capsys)
    assert unstable[0]["stable"] is False and unstable[0]["tau"] is None


def test_quasi_reports_a_failed_solve_with_status_1(capsys, tmp_path):
    params = tmp_path / "damped.toml"
    params.write_text("k0 = 0.02534\n")  # 5x the prototype's damping: the slow branch folds near 8 rad/s
    assert main(["quasi", "--omega0", "2", "9", "--json", "--params", str(params)]) == 1
    out = capsys.readouterr()
    rows = json.loads(out.out)
    assert rows[0]["converged"] and not rows[1]["converged"]
    assert "no quasi-stable state" in out.err


@pytest.mark.parametrize("argv, message", [
    (["quasi", "--omega0", "-2"], "out of range"),
    (["quasi", "--omega0", "1", "--branch", "odd"], "invalid choice"),
    (["stability"], "required"),
    (["nonsense"], "invalid choice"),
])
def test_bad_arguments(argv, message, capsys):
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1


def test_run_json_contract(capsys, tmp_path):
    problem = tmp_path / "short.toml"
    problem.write_text((Path(__file__).parent.parent / "problems" / "circle_R035.toml").read_text()
                       .replace("duration = 300.0", "duration = 40.0").replace("settle_time = 120.0",
                                                                               "settle_time = 20.0"))
    status = main(["run", str(problem), "--controller", "pid", "--seed", "2", "--json", "--out", str(tmp_path)])
    metrics = json.loads(capsys.readouterr().out)
    keys = {"completed", "completion_time", "avg_speed", "stop_errors", "avg_deviation", "max_deviation",
            "max_motor_torque", "max_driving_speed", "min_normal_force", "min_slide_margin", "step_time_median"}
    assert keys <= set(metrics) and status in (0, 1) and (status == 0) == metrics["completed"]
    assert metrics["seed"] == 2 and metrics["step_time_median"] > 0
    for suffix in (".npz", ".json", "_top.png", "_time.png"):
        assert (tmp_path / f"circle_R035_pid{suffix}").exists()
    assert json.loads((tmp_path / "circle_R035_pid.json").read_text())["versions"]["numpy"]


def test_run_rejects_a_bad_problem_in_one_line(capsys, tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text('name = "x"\nkind = "circle"\nduration = 10\n[circle]\nradius = 0.3\nwobble = 1\n')
    assert main(["run", str(bad)]) == 2
    err = capsys.readouterr().err
    assert "unknown key(s) wobble" in err and err.count("\n") == 1
