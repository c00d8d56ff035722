"""What a user sees: output that leads with "did it work, and how well", units everywhere, --quiet, the params
command, and progress on a terminal and nowhere else."""

import fcntl
import json
import os
import pty
import re
import struct
import subprocess
import sys
import termios
from pathlib import Path
from types import SimpleNamespace

import pytest

from rollbot_oc.app.cli import main
from rollbot_oc.missions import Waypoints
from rollbot_oc.model.params import RollbotParams
from rollbot_oc.scenarios.problem import run_problem
from rollbot_oc.scenarios.bundled import load_bundled
from rollbot_oc.simulation.plant import simulate
from rollbot_oc.view.text import compare_headline, run_verdict, text_table

ROOT = Path(__file__).parent.parent
LONG_NUMBER = re.compile(r"\d\.\d{6,}")  # raw floats: 0.01009703228701816


def output(argv, capsys, status=0):
    assert main(argv) == status
    return capsys.readouterr()


def short_circle(tmp_path) -> Path:
    """circle_R035 cut to 40 s, deviations measured from 20 s on: a run of a second or two that completes."""
    problem = tmp_path / "short.toml"
    problem.write_text((ROOT / "problems" / "circle_R035.toml").read_text()
                       .replace("duration = 300.0", "duration = 40.0").replace("settle_time = 120.0",
                                                                               "settle_time = 20.0"))
    return problem


def test_run_leads_with_the_verdict_in_units(capsys, tmp_path):
    out = output(["run", str(short_circle(tmp_path))], capsys).out
    lines = out.splitlines()
    assert re.fullmatch(r"circle_R035, pid \(seed 0\): on the circle after \d+\.\d s, "
                        r"deviation \d\.\d\d cm average, \d\.\d\d cm largest", lines[0]), lines[0]
    details = dict(re.split(r"\s{2,}", line.strip(), maxsplit=1) for line in lines[1:])
    assert re.fullmatch(r"\d\.\d\d cm", details["largest deviation"])
    assert re.fullmatch(r"\d+\.\d s", details["completion time"])
    assert re.fullmatch(r"\d\.\d\d ms", details["solve time median"])
    assert re.fullmatch(r"\d\.\d{3} N m", details["largest motor torque"])
    assert details["simulated"] == "40.0 s" and details["contact events"] == "none"
    assert not LONG_NUMBER.search(out)


def test_a_run_that_did_not_complete_says_so_first(capsys):
    result = output(["run", "n_shape", "--duration", "5"], capsys, status=1)
    assert result.out.startswith("n_shape, pid (seed 0): NOT completed: 0 of 4 stops in 5.0 s\n")
    assert "stops reached          0 of 4" in result.out
    assert result.err == "rollbot-oc: failed: n_shape: the run did not complete\n"


def test_analysis_output_leads_with_what_was_found(capsys):
    lines = output(["quasi", "--omega0", "1", "3"], capsys).out.splitlines()
    assert lines[0] == "2 of 2 quasi-stable states found (slow branch): R0 from 0.129 to 0.219 m"
    assert "omega0 (rad/s)" in lines[1] and "R0 (m)" in lines[1] and "xi (deg)" in lines[1]
    assert lines[3].split()[:2] == ["3.000", "0.2186"]
    lines = output(["stability", "--omega0", "1", "3"], capsys).out.splitlines()
    assert lines[0] == "stable at 2 of 2 driving speeds (slow branch): recovery time 7.2 to 7.6 s"
    assert "recovery time (s)" in lines[1] and lines[3].split()[-2:] == ["7.56", "yes"]
    out = output(["problems"], capsys).out
    from rollbot_oc.scenarios.bundled import bundled_names

    assert out.startswith(f"{len(bundled_names())} bundled scenarios") and "n_shape" in out


def test_open_loop_output(capsys):
    lines = output(["openloop", "--omega0", "3", "--duration", "60"], capsys).out.splitlines()
    assert lines[0] == "1 of 1 driving speeds settled on a circle, R0 from 0.219 to 0.219 m"
    assert lines[1].split() == ["omega0", "(rad/s)", "R0", "(m)", "Omega", "(rad/s)", "xi", "(deg)", "drift",
                                "(mm/s)", "settled"]


def test_quiet_prints_nothing_but_errors(capsys, tmp_path):
    assert output(["quasi", "--omega0", "1", "--quiet"], capsys) == ("", "")
    assert output(["--quiet", "params"], capsys) == ("", "")
    damped = tmp_path / "damped.toml"
    damped.write_text("k0 = 0.02534\n")
    quiet = output(["quasi", "--omega0", "9", "--params", str(damped), "--quiet"], capsys, status=1)
    assert quiet.out == "" and quiet.err.startswith("rollbot-oc: failed: no quasi-stable state")
    both = output(["quasi", "--omega0", "1", "--quiet", "--json"], capsys, status=2)
    assert both.out == "" and both.err.count("\n") == 1 and "--quiet and --json" in both.err


def test_params_shows_values_units_and_sources(capsys, tmp_path):
    robot = tmp_path / "robot.toml"
    robot.write_text("[params]\nr0 = 0.08\nk0 = 0.006\n")
    record = json.loads(output(["params", "--params", str(robot), "--json"], capsys).out)
    params = {p["key"]: p for p in record["params"]}
    assert params["r0"]["source"] == "file" and params["k0"]["source"] == "file"
    assert params["R"]["source"] == "default" and params["phi_deg"] == {
        "key": "phi_deg", "value": 45.0, "unit": "deg", "meaning": "motor axis to pendulum arm", "source": "default"}
    assert params["max_torque"]["source"] == "derived"  # r0 m g with the file's r0
    assert params["max_torque"]["value"] == pytest.approx(0.08 * 0.306 * 9.81)
    derived = {d["key"]: d for d in record["derived"]}
    assert derived["R0_min"]["value"] == pytest.approx(0.12, abs=1e-6) and derived["R0_min"]["unit"] == "m"
    assert derived["tau_max"]["unit"] == "s" and derived["tau_max"]["value"] > 0 and derived["stable"]["value"]
    lines = output(["params", "--params", str(robot)], capsys).out.splitlines()
    assert re.fullmatch(rf"robot {re.escape(str(robot))}: revolves on circles of 0\.120 m to \d\.\d{{3}} m, "
                        r"worst recovery time \d+\.\d s, stable at every driving speed", lines[0]), lines[0]
    assert lines[1].split() == ["parameter", "value", "unit", "source", "meaning"]
    table = {line.split()[0]: line.split() for line in lines[2:] if line.strip()}
    assert table["r0"][1:4] == ["0.08", "m", "file"] and table["max_torque"][2:5] == ["N", "m", "derived"]
    assert table["tau_max"][2:4] == ["s", "derived"]
    # the prototype: the derived defaults are derived, everything else a default
    prototype = json.loads(output(["params", "--json"], capsys).out)
    assert {p["key"] for p in prototype["params"] if p["source"] == "derived"} == {"k0", "max_torque"}
    assert {p["source"] for p in prototype["params"]} == {"default", "derived"}


def test_params_without_damping_still_describes_the_robot(capsys, tmp_path):
    robot = tmp_path / "undamped.toml"
    robot.write_text("k0 = 0\n")
    out = output(["params", "--params", str(robot)], capsys).out
    assert "no quasi-stable analysis" in out.splitlines()[0] and "k0" in out


def test_described_follows_the_derived_default_rule():
    changed = RollbotParams().with_changes(M_s=1.0)
    sources = {d["key"]: d["source"] for d in changed.described(given={"M_s"})}
    assert sources["M_s"] == "file" and sources["k0"] == "derived" and sources["R"] == "default"
    fixed = RollbotParams(k0=0.01).with_changes(M_s=1.0)
    assert {d["key"]: d["source"] for d in fixed.described()}["k0"] == "default"  # given in code: not derived


# -- the summary line on its own ------------------------------------------------------------------------------
def fake_run(controller, completed, time, errors, **extra):
    metrics = {"completed": completed, "completion_time": time, "stop_errors": errors, "duration": 60.0,
               "events": [], "avg_deviation": None, "max_deviation": None, **extra}
    problem = SimpleNamespace(name="n_shape", kind="waypoints", mission=Waypoints(((0, 0),) * 4))
    return SimpleNamespace(problem=problem, controller=controller, seed=0, metrics=metrics)


def test_verdicts_name_what_went_wrong():
    pid = fake_run("pid", True, 190.44, [0.01, 0.016, 0.012, 0.008])
    nmpc = fake_run("nmpc", True, 27.3, [0.03] * 4, fallback_shifted=2, fallback_pid=1)
    assert run_verdict(pid) == "completed in 190.4 s, worst stop error 1.6 cm"
    assert run_verdict(nmpc) == "completed in 27.3 s, worst stop error 3.0 cm, fallbacks: 2 shifted plan, 1 PID"
    braked = fake_run("nmpc", True, 27.3, [0.03] * 4, fallback_shifted=0, fallback_brake=2, fallback_pid=0)
    assert run_verdict(braked) == "completed in 27.3 s, worst stop error 3.0 cm, fallbacks: 2 brake"
    assert compare_headline([pid, nmpc]) == "n_shape: nmpc 7.0x as fast as pid (27.3 s against 190.4 s)"
    stuck = fake_run("nmpc", False, None, [0.02], fallback_shifted=0, fallback_pid=0,
                     events=[{"kind": "slide", "time": 12.34, "margin": -0.1}], torque_limit_violation=True)
    assert run_verdict(stuck) == ("NOT completed: 1 of 4 stops in 60.0 s, worst stop error 2.0 cm, slid at 12.3 s, "
                                  "torque limit exceeded, no fallbacks")
    assert compare_headline([pid, stuck]) == "n_shape: completed by pid of pid, nmpc"


def test_text_table_aligns_numbers_right_and_text_left():
    table = text_table(["name", "value (m)", "ok"], [["a", "1.5", "yes"], ["long name", "-", "no"]])
    assert table.splitlines() == ["name       value (m)   ok", "a                1.5  yes", "long name          -   no"]


# -- progress -------------------------------------------------------------------------------------------------
def test_simulate_reports_progress_every_half_second():
    from rollbot_oc.control.pid import QuasiStablePID

    problem = load_bundled("n_shape")
    calls = []
    controller = QuasiStablePID(problem.mission, problem.params.replace(slope=0.0))
    simulate(problem.initial_state(), 3.0, params=problem.params, controller=controller,
             progress=lambda t, info: calls.append((t, info)))
    assert [t for t, _ in calls] == pytest.approx([0.5, 1.0, 1.5, 2.0, 2.5, 3.0])
    assert all(info["stops"] == [] for _, info in calls)


def test_run_progress_shows_on_a_terminal_and_nowhere_else(capsys, monkeypatch):
    problem = load_bundled("n_shape").with_duration(2.0)
    run_problem(problem, "pid")  # pytest's stderr is not a terminal: silent
    assert capsys.readouterr() == ("", "")
    run_problem(problem, "pid", show_progress=False)
    assert capsys.readouterr() == ("", "")
    monkeypatch.setattr(sys.stderr, "isatty", lambda: True)
    run_problem(problem, "pid")
    out, err = capsys.readouterr()
    assert out == "" and "n_shape pid" in err and "2.0/2.0 s simulated" in err and "stops 0/4" in err


def test_progress_on_a_real_terminal_only(tmp_path):
    """The command on a pseudo-terminal shows its progress on stderr; piped, stderr stays empty; stdout is JSON."""
    argv = [sys.executable, "-m", "rollbot_oc.app.cli", "run", str(short_circle(tmp_path)), "--duration", "15", "--json"]
    env = {**os.environ, "PYTHONPATH": str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    piped = subprocess.run(argv, capture_output=True, text=True, env=env)
    assert piped.stderr == "rollbot-oc: failed: circle_R035: the run did not complete\n"
    master, terminal = pty.openpty()
    fcntl.ioctl(terminal, termios.TIOCSWINSZ, struct.pack("HHHH", 24, 120, 0, 0))  # 24 x 120 characters
    with subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=terminal, env=env) as process:
        os.close(terminal)
        shown = b""
        while True:
            try:
                chunk = os.read(master, 4096)
            except OSError:  # the terminal closed with the process
                break
            if not chunk:
                break
            shown += chunk
        stdout = process.stdout.read()
    os.close(master)
    assert json.loads(stdout)["duration"] == pytest.approx(15.0) == json.loads(piped.stdout)["duration"]
    assert b"circle_R035 pid" in shown and b"s simulated" in shown and b"rollbot-oc: failed" in shown
