import json

import numpy as np
import pytest

from rollbot_oc.app.cli import main
from rollbot_oc.analysis.experiments import fit_circle, open_loop_run
from rollbot_oc.model.params import RollbotParams


def test_fit_circle_recovers_a_circle():
    a = np.linspace(0.3, 2.0, 50)
    fit = fit_circle(np.array([1.5 + 0.4 * np.cos(a), -0.2 + 0.4 * np.sin(a)]))
    assert np.allclose(fit.centre, [1.5, -0.2], atol=1e-12) and fit.radius == pytest.approx(0.4, rel=1e-12)
    assert fit.rms < 1e-12
    with pytest.raises(ValueError, match="3 points"):
        fit_circle(np.zeros((2, 2)))


def test_openloop_cli_prints_settled_circles(capsys, tmp_path):
    assert main(["openloop", "--omega0", "1", "3", "6", "--json", "--out", str(tmp_path)]) == 0
    rows = json.loads(capsys.readouterr().out)
    assert [r["omega0"] for r in rows] == [1.0, 3.0, 6.0]
    assert all(r["settled"] for r in rows)
    radii = [r["R0"] for r in rows]
    assert RollbotParams().R < radii[0] < radii[1] < radii[2] < 1.28  # R0 grows with omega0 from R tan(phi)
    assert all(np.pi / 4 < r["xi"] < np.pi / 2 for r in rows)
    assert (tmp_path / "openloop_3.png").stat().st_size > 1000
    assert json.loads((tmp_path / "openloop.json").read_text())["versions"]["casadi"]


def test_slope_makes_the_open_loop_circle_drift():
    level, _ = open_loop_run(3.0, RollbotParams(), duration=70.0)
    sloped, _ = open_loop_run(3.0, RollbotParams(slope=np.radians(1.0)), duration=70.0)
    assert level.settled and level.drift < 1e-5
    assert not sloped.settled and sloped.drift > 1e-3  # m/s: the circle walks across the floor


@pytest.mark.parametrize("argv, message", [
    (["openloop", "--omega0", "-1"], "omega0 = -1.0"),
    (["openloop", "--omega0", "20"], "out of range"),
    (["openloop", "--omega0", "abc"], "not a number"),
    (["openloop"], "required"),
    (["openloop", "--omega0", "1", "--params", "/nonexistent.toml"], "does not exist"),
    (["openloop", "--omega0", "1", "--slope-deg", "45"], "slope"),
])
def test_cli_bad_input_is_one_line(argv, message, capsys):
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1 and "Traceback" not in err
