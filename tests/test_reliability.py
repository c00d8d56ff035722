"""Issue 9: every bad input gets one clear line, every contract is honest, nothing escapes the output folder.

One test (or a few) per finding of the issue, numbered as there.
"""

import json
import math
import os
import signal
import stat
import subprocess
import sys
import textwrap
import threading
import tomllib
import warnings
from pathlib import Path

import casadi as ca
import numpy as np
import pytest

from rollbot_oc.app import cli
from rollbot_oc.app.cli import main
from rollbot_oc.model.dynamics import rest_state
from rollbot_oc.core.errors import ConfigError, Interrupted, NotConverged, NumericalFailure, interruptible
from rollbot_oc.core.outputs import OutputFolder, atomic_write_text, file_mode, to_json, write_json
from rollbot_oc.model.params import RollbotParams, load_params
from rollbot_oc.scenarios.problem import check_duration, load_problem, problem_from_dict
from rollbot_oc.scenarios.bundled import bundled_names, load_scenario
from rollbot_oc.simulation.plant import SimulationResult, simulate

ROOT = Path(__file__).resolve().parent.parent
CIRCLE = {"name": "c", "kind": "circle", "duration": 10.0, "circle": {"radius": 0.35}}


def cli_run(argv, capsys):
    status = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return status, out, err


def one_error_line(err: str) -> str:
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("rollbot-oc: error: "), err
    return lines[0]


def strict_json(text: str):
    def refuse(name):
        raise AssertionError(f"{name} in JSON")

    return json.loads(text, parse_constant=refuse)


def write(path: Path, text: str) -> Path:
    path.write_text(textwrap.dedent(text))
    return path


def circle_file(tmp_path, **changes) -> Path:
    lines = [f"name = {changes.get('name', 'c')!r}".replace("'", '"'), 'kind = "circle"',
             f"duration = {changes.get('duration', 10.0)}", "[circle]", f"radius = {changes.get('radius', 0.35)}"]
    return write(tmp_path / "c.toml", "\n".join(lines) + "\n" + changes.get("extra", ""))


@pytest.fixture
def no_computing(monkeypatch):
    """Make every long computation fail loudly: an error must be found before any of them starts."""
    import rollbot_oc.analysis.experiments
    import rollbot_oc.view.plots
    import rollbot_oc.scenarios.problem
    import rollbot_oc.analysis.quasi_stable

    def computed(*args, **kwargs):
        raise AssertionError("computed before checking the output folder")

    for module, name in [(rollbot_oc.scenarios.problem, "run_problem"), (rollbot_oc.scenarios.problem, "run_open_loop"),
                         (rollbot_oc.scenarios.problem, "compare"), (rollbot_oc.analysis.experiments, "open_loop_run"),
                         (rollbot_oc.analysis.quasi_stable, "quasi_stable_curve"), (rollbot_oc.view.plots, "plot_top_view")]:
        monkeypatch.setattr(module, name, computed)


# 1 -------------------------------------------------------------------------------------------------------------
def saved_run(tmp_path) -> Path:
    return simulate(rest_state(), 1.0, speed=1.0).save(tmp_path / "ramp.npz")


@pytest.mark.parametrize("command", ["run", "openloop", "plot", "quasi", "demo"])
@pytest.mark.parametrize("case", ["file", "parent_file", "uncreatable"])
def test_1_bad_output_folder_is_refused_before_computing(command, case, tmp_path, capsys, no_computing):
    blocker = tmp_path / "blocker"
    blocker.write_text("a file")
    out = {"file": blocker, "parent_file": blocker / "sub", "uncreatable": Path("/proc/rollbot_oc_out")}[case]
    option = "--plot" if command == "quasi" else "--out"
    argv = {"run": ["run", circle_file(tmp_path)], "openloop": ["openloop", "--omega0", "1"],
            "plot": ["plot", saved_run(tmp_path)], "quasi": ["quasi", "--omega0", "1"], "demo": ["demo"]}[command]
    status, out_text, err = cli_run(argv + [option, out], capsys)
    assert status == 2, err
    line = one_error_line(err)
    assert option in line and str(out) in line


def test_1_unwritable_output_folder(tmp_path, monkeypatch):
    monkeypatch.setattr(os, "access", lambda path, mode: False)  # as a user without write permission sees it
    with pytest.raises(ConfigError, match="--out .*not writable"):
        OutputFolder(tmp_path / "out")


def test_1_output_folder_is_created_with_its_parents(tmp_path):
    folder = OutputFolder(tmp_path / "a" / "b")
    assert folder.path.is_dir() and folder.file("x.json") == tmp_path / "a" / "b" / "x.json"


# 2 -------------------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("loader", [load_params, load_problem])
def test_2_bad_paths_name_the_file(loader, tmp_path):
    folder = tmp_path / "folder.toml"
    folder.mkdir()
    latin = tmp_path / "latin.toml"
    latin.write_bytes('name = "Zürich"\n'.encode("latin-1"))
    for path, message in [(folder, "is a folder"), ("", "empty"), (latin, "not UTF-8"),
                          (tmp_path / "missing.toml", "does not exist"), ("a\0b", "NUL")]:
        with pytest.raises(ConfigError, match=message) as info:
            loader(path)
        assert str(path).strip("\0") in str(info.value) or message in ("empty", "NUL")


@pytest.mark.skipif(os.geteuid() == 0, reason="root reads any file")
def test_2_unreadable_file(tmp_path):
    path = tmp_path / "secret.toml"
    path.write_text("R = 0.12\n")
    path.chmod(0)
    with pytest.raises(ConfigError, match="cannot be read"):
        load_params(path)


def test_2_a_byte_order_mark_is_fine(tmp_path):
    path = tmp_path / "bom.toml"
    path.write_bytes(b"\xef\xbb\xbfR = 0.13\n")
    assert load_params(path).R == 0.13


def test_2_cli_bad_parameter_paths(tmp_path, capsys):
    for params in ["", tmp_path, tmp_path / "nope.toml"]:
        status, _, err = cli_run(["quasi", "--omega0", "1", "--params", params], capsys)
        assert status == 2
        one_error_line(err)


# 3 -------------------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("value", ["1e9", "0", "1e5", "-3", "0.5"])
def test_3_duration_option_has_the_file_range(value, tmp_path, capsys, no_computing):
    status, _, err = cli_run(["run", circle_file(tmp_path), "--duration", value], capsys)
    assert status == 2 and "[1, 3600]" in one_error_line(err) and "--duration" in err


def test_3_one_range_for_file_and_option(tmp_path):
    with pytest.raises(ConfigError, match=r"duration.*\[1, 3600\]"):
        load_problem(circle_file(tmp_path, duration=1e5))
    problem = load_problem(circle_file(tmp_path))
    for bad in (0.0, 1e9, float("nan")):
        with pytest.raises(ConfigError, match="duration"):
            problem.with_duration(bad)
    assert check_duration(3600, "x") == 3600.0 and problem.with_duration(1).duration == 1.0


def test_3_zero_duration_is_not_the_file_duration():
    from rollbot_oc.scenarios.problem import run_problem

    problem = problem_from_dict(CIRCLE)
    with pytest.raises(ConfigError, match="duration"):
        run_problem(problem, "pid", duration=0)


def test_3_openloop_duration(capsys, no_computing):
    status, _, err = cli_run(["openloop", "--omega0", "1", "--duration", "1e9"], capsys)
    assert status == 2 and "--duration" in one_error_line(err)


# 4 -------------------------------------------------------------------------------------------------------------
def test_4_truncated_or_odd_saved_runs(tmp_path, capsys):
    good = saved_run(tmp_path)
    data = good.read_bytes()
    cases = {"truncated.npz": data[: len(data) // 2], "empty.npz": b"", "text.npz": b"hello",
             "head.npz": data[:100]}
    np.savez(tmp_path / "other.npz", t=np.arange(3.0))
    crafted = {"shapes.npz": ("x", lambda x: x[:, :2]), "huge.npz": ("x", lambda x: 1e300 * x),
               "backwards.npz": ("t", lambda t: t[::-1].copy()), "events.npz": ("event_kinds", lambda k: ["slide"]),
               "params.npz": ("params_file", lambda p: np.array('{"R": -1}'))}
    for name, (key, change) in crafted.items():
        arrays = dict(np.load(good))
        arrays[key] = change(arrays[key])
        np.savez(tmp_path / name, **arrays)
    for name, content in cases.items():
        (tmp_path / name).write_bytes(content)
    for name in list(cases) + list(crafted) + ["other.npz"]:
        with pytest.raises(ConfigError, match="saved run" if name != "params.npz" else "parameter R"):
            SimulationResult.load(tmp_path / name)
        status, _, err = cli_run(["plot", tmp_path / name, "--out", tmp_path / "figs"], capsys)
        assert status == 2 and name in one_error_line(err)


# 5 -------------------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("table", ["params", "floor", "start", "sensor", "circle"])
def test_5_a_table_that_is_not_a_table(table):
    with pytest.raises(ConfigError, match=f"'{table}' = 5 must be a table"):
        problem_from_dict({**CIRCLE, table: 5}, "p.toml")


# 6 -------------------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("radius", [0.05, 5.0])
def test_6_circle_radius_outside_the_quasi_stable_range(radius):
    with pytest.raises(ConfigError, match=r"radius.*valid for this robot is \[0\.1200, 1\.2750\] m"):
        problem_from_dict({**CIRCLE, "circle": {"radius": radius}}, "p.toml")


def test_6_the_range_is_that_robots():
    bigger = {**CIRCLE, "circle": {"radius": 0.13}, "params": {"R": 0.2, "r0": 0.15}}
    with pytest.raises(ConfigError, match=r"valid for this robot is \[0\.2000, "):
        problem_from_dict(bigger)
    assert problem_from_dict({**bigger, "circle": {"radius": 0.25}}).mission.radius == 0.25


# 7 -------------------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("name", ["../../escape", "/tmp/escape", "a/b", "..", "", "-x", "a b", "x" * 65, 5, "é"])
def test_7_problem_names_are_plain_identifiers(name):
    with pytest.raises(ConfigError, match="'name'"):
        problem_from_dict({**CIRCLE, "name": name}, "p.toml")


def test_7_names_that_are_fine():
    for name in ("circle_R035", "n-shape", "A1", "_x"):
        assert problem_from_dict({**CIRCLE, "name": name}).name == name


def test_7_nothing_is_written_outside_the_folder(tmp_path):
    folder = OutputFolder(tmp_path / "out")
    for name in ("../x.json", "/tmp/x.json", "..", "", "a/b.png"):
        with pytest.raises(ConfigError, match="plain file name"):
            folder / name
    assert not (tmp_path / "x.json").exists()


def test_7_cli_refuses_an_escaping_name(tmp_path, capsys, no_computing):
    work = tmp_path / "a" / "b"
    work.mkdir(parents=True)
    problem = circle_file(work, name="../../escape")
    status, _, err = cli_run(["run", problem, "--out", work / "out"], capsys)
    assert status == 2 and "'name'" in one_error_line(err)
    assert sorted(p.name for p in tmp_path.rglob("*")) == ["a", "b", "c.toml"]


# 8 -------------------------------------------------------------------------------------------------------------
def test_8_the_error_families():
    assert issubclass(ConfigError, ValueError) and issubclass(NotConverged, NumericalFailure)
    assert issubclass(NumericalFailure, RuntimeError) and issubclass(Interrupted, KeyboardInterrupt)
    exc = NotConverged("plan", "Maximum_Iterations_Exceeded", result=3)
    assert exc.status == "Maximum_Iterations_Exceeded" and exc.result == 3 and "did not converge" in str(exc)


def test_8_stability_non_convergence_exits_1_like_quasi(tmp_path, capsys):
    params = write(tmp_path / "damped.toml", "k0 = 0.02534\n")  # the slow branch folds near 8 rad/s
    for command in ("quasi", "stability"):
        status, out, err = cli_run([command, "--omega0", "2", "9", "--json", "--params", params], capsys)
        assert status == 1 and "no quasi-stable state" in err and "error" not in err
        rows = strict_json(out)
        assert rows[0]["converged"] and not rows[1]["converged"]
    assert rows[1]["eigenvalues"] is None and rows[1]["tau"] is None


def test_8_stability_curve_raises_a_numerical_failure():
    from rollbot_oc.analysis.stability import stability_curve

    with pytest.raises(NumericalFailure, match="no quasi-stable state"):
        stability_curve([2.0, 9.0], RollbotParams(k0=0.02534))


@pytest.mark.parametrize("exc, status, prefix", [
    (ValueError("deep numerical invariant"), 3, "rollbot-oc: internal error: ValueError: deep numerical invariant"),
    (np.linalg.LinAlgError("Singular matrix"), 3, "rollbot-oc: internal error: LinAlgError"),
    (NotConverged("plan", "Infeasible_Problem_Detected"), 1, "rollbot-oc: failed: plan: the solver did not converge"),
    (ConfigError("bad value"), 2, "rollbot-oc: error: bad value"),
    (KeyboardInterrupt(), 130, "rollbot-oc: interrupted"),
    (Interrupted("plan interrupted"), 130, "rollbot-oc: interrupted"),
    (OSError(28, "No space left on device", "out/x.json"), 2, "rollbot-oc: error: out/x.json: No space left"),
])
def test_8_exit_codes_of_the_taxonomy(exc, status, prefix, monkeypatch, capsys):
    def fail(args):
        raise exc

    monkeypatch.setattr(cli, "_cmd_problems", fail)
    code, out, err = cli_run(["problems", "--json"], capsys)
    assert code == status and err.startswith(prefix) and err.count("\n") == 1 and "Traceback" not in err
    if status == 1:  # --json: the JSON contract holds on failure too
        assert strict_json(out) == {"completed": False, "error": str(exc), "status": "Infeasible_Problem_Detected"}


def test_8_debug_shows_the_traceback_of_an_internal_error(monkeypatch, capsys):
    def fail(args):
        raise ValueError("deep numerical invariant")

    monkeypatch.setattr(cli, "_cmd_problems", fail)
    for argv in (["--debug", "problems"], ["problems", "--debug"]):
        code, _, err = cli_run(argv, capsys)
        assert code == 3 and "Traceback" in err and "deep numerical invariant" in err.strip().splitlines()[-1]


def test_8_user_value_errors_are_config_errors():
    from rollbot_oc.analysis.quasi_stable import RadiusMap, quasi_stable_curve

    with pytest.raises(ConfigError, match="omega0"):
        quasi_stable_curve([-1.0])
    with pytest.raises(ConfigError, match="branch"):
        quasi_stable_curve([1.0], branch="odd")
    with pytest.raises(ConfigError, match="radius"):
        RadiusMap().omega(5.0)


# 9 -------------------------------------------------------------------------------------------------------------
def test_9_strict_json():
    obj = {"a": math.nan, "b": np.array([1.0, np.inf, -np.inf]), "c": np.float64("nan"), "d": [np.int64(3), (1.5,)],
           "e": {"f": np.bool_(True), "g": Path("x")}}
    assert strict_json(to_json(obj)) == {"a": None, "b": [1.0, None, None], "c": None, "d": [3, [1.5]],
                                         "e": {"f": True, "g": "x"}}


def test_9_json_files_are_strict(tmp_path):
    path = write_json(tmp_path / "x.json", {"v": float("nan")})
    assert strict_json(path.read_text())["v"] is None


def test_9_quasi_failure_prints_null_not_nan(tmp_path, capsys):
    params = write(tmp_path / "tiny.toml", "g = 1e-300\n")
    status, out, _ = cli_run(["quasi", "--omega0", "1", "--json", "--params", params], capsys)
    assert status == 1 and "NaN" not in out
    strict_json(out)


# 10 ------------------------------------------------------------------------------------------------------------
CODEGEN_SCRIPT = """
import sys, warnings
import casadi as ca
from rollbot_oc.model.codegen import compiled
warnings.simplefilter("always")
x = ca.SX.sym("x", 3)
f = compiled(ca.Function("reliability_test", [x], [2 * ca.sin(x)]))
print(f.class_name(), float(f([1, 2, 3])[0]))
"""


def run_codegen(cache, env=None):
    env = {**os.environ, "ROLLBOT_OC_CACHE": str(cache), "PYTHONPATH": str(ROOT), **(env or {})}
    return subprocess.run([sys.executable, "-c", CODEGEN_SCRIPT], capture_output=True, text=True, env=env,
                          timeout=120)


needs_compiler = pytest.mark.skipif(not any(map(__import__("shutil").which, ("gcc", "clang", "cc"))),
                                    reason="no C compiler")


@needs_compiler
def test_10_broken_libraries_are_rebuilt(tmp_path):
    cache = tmp_path / "cache"
    first = run_codegen(cache)
    assert first.returncode == 0 and first.stdout.startswith("External"), first.stderr
    library = next(cache.glob("*.so"))
    for garbage in (b"", b"\x7fELF garbage"):
        library.write_bytes(garbage)
        if garbage:  # a matching checksum does not make garbage loadable
            Path(f"{library}.sha256").write_text(__import__("hashlib").sha256(garbage).hexdigest())
        again = run_codegen(cache)
        assert again.returncode == 0 and again.stdout.startswith("External"), again.stderr
        assert library.stat().st_size > 1000


def test_10_no_cache_or_no_compiler_falls_back_with_one_warning(tmp_path):
    blocker = tmp_path / "blocker"
    blocker.write_text("x")
    for cache, env in [(blocker, {}), (blocker / "sub", {}), ("/proc/rollbot_cache", {}),
                       (tmp_path / "cache", {"CC": "false"})]:
        result = run_codegen(cache, env)
        assert result.returncode == 0, result.stderr
        assert result.stdout.split()[0] == "SXFunction" and float(result.stdout.split()[1]) == pytest.approx(
            2 * math.sin(1))
        assert "CompiledCodeWarning" in result.stderr and "uncompiled" in result.stderr


@needs_compiler
def test_10_two_processes_compile_once(tmp_path):
    log = tmp_path / "compiles.log"
    wrapper = tmp_path / "cc"
    wrapper.write_text(f"#!/bin/sh\necho x >> {log}\nsleep 1\nexec gcc \"$@\"\n")
    wrapper.chmod(0o755)
    env = {**os.environ, "ROLLBOT_OC_CACHE": str(tmp_path / "cache"), "PYTHONPATH": str(ROOT), "CC": str(wrapper)}
    procs = [subprocess.Popen([sys.executable, "-c", CODEGEN_SCRIPT], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                              text=True, env=env) for _ in range(2)]
    outputs = [p.communicate(timeout=120) for p in procs]
    assert all(p.returncode == 0 and out.startswith("External") for p, (out, _) in zip(procs, outputs)), outputs
    assert log.read_text().count("x") == 1


def test_10_compiler_search_includes_clang(monkeypatch):
    import shutil

    from rollbot_oc.model import codegen

    monkeypatch.delenv("CC", raising=False)
    monkeypatch.setattr(shutil, "which", lambda name: "/usr/bin/clang" if name == "clang" else None)
    assert codegen.compiler() == "/usr/bin/clang"


# 11 ------------------------------------------------------------------------------------------------------------
def slow_ipopt():
    n = 2000
    x = ca.SX.sym("x", n)
    f = ca.sum1(100 * (x[1:] - x[:-1] ** 2) ** 2 + (1 - x[:-1]) ** 2)
    solver = ca.nlpsol("s", "ipopt", {"x": x, "f": f}, {
        "ipopt.print_level": 0, "print_time": 0, "ipopt.max_iter": 100000, "ipopt.tol": 1e-30,
        "ipopt.hessian_approximation": "limited-memory"})
    return lambda: solver(x0=[0.5] * n)


def test_11_ctrl_c_inside_ipopt_is_an_interruption():
    solve = slow_ipopt()
    # the handler before the block is restored after it (here Python's own: a process started in the background by
    # a shell without job control inherits SIGINT ignored, and keeps it so)
    inherited = signal.signal(signal.SIGINT, signal.default_int_handler)
    timer = threading.Timer(0.5, os.kill, (os.getpid(), signal.SIGINT))
    timer.start()
    try:
        with pytest.raises(Interrupted):
            with interruptible("rosenbrock"):
                solve()  # IPOPT swallows the Ctrl-C and returns NonIpopt_Exception_Thrown
        assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
    finally:
        timer.cancel()
        signal.signal(signal.SIGINT, inherited)


def test_11_cli_reports_a_swallowed_ctrl_c_as_interrupted(monkeypatch, capsys):
    solve = slow_ipopt()

    def command(args):
        threading.Timer(0.5, os.kill, (os.getpid(), signal.SIGINT)).start()
        solve()
        raise NotConverged("plan", "NonIpopt_Exception_Thrown")  # what the OCP makes of it

    monkeypatch.setattr(cli, "_cmd_problems", command)
    status, _, err = cli_run(["problems"], capsys)
    assert status == 130 and err.strip().splitlines()[-1] == "rollbot-oc: interrupted"  # after CasADi's own note


# 12 ------------------------------------------------------------------------------------------------------------
def test_12_bundled_scenarios(capsys):
    names = bundled_names()
    assert names == sorted(p.stem for p in (ROOT / "problems").glob("*.toml"))
    status, out, _ = cli_run(["problems", "--json"], capsys)
    rows = strict_json(out)
    assert status == 0 and [r["name"] for r in rows] == names
    assert {r["kind"] for r in rows} == {"circle", "waypoints", "open_loop", "gates"} and all(r["description"] for r in rows)
    status, out, _ = cli_run(["problems"], capsys)
    assert status == 0 and out.splitlines()[1 + names.index("n_shape")].split()[:2] == ["n_shape", "waypoints"]


def test_12_run_takes_a_bundled_name(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # not the source folder
    for text in ("n_shape", "n_shape.toml", "problems/n_shape.toml"):
        problem = load_scenario(text)
        assert problem.name == "n_shape" and len(problem.mission.stops) == 4
    (tmp_path / "n_shape.toml").write_text('name = "local"\nkind = "circle"\nduration = 5\n[circle]\nradius = 0.3\n')
    assert load_scenario("n_shape.toml").name == "local"  # an existing file wins
    with pytest.raises(ConfigError, match="bundled are approach, circle_R020"):
        load_scenario("m_shape")


def test_12_demo_reads_its_scenario_through_importlib_resources():
    source = (ROOT / "rollbot_oc" / "app" / "report.py").read_text()
    assert "problems/" not in source and 'load_bundled("n_shape"' in source
    assert "importlib.resources.files" in (ROOT / "rollbot_oc" / "scenarios" / "bundled.py").read_text()


# 13 ------------------------------------------------------------------------------------------------------------
def test_13_files_respect_the_umask(tmp_path):
    old = os.umask(0o002)
    try:
        assert file_mode() == 0o664
        path = atomic_write_text(tmp_path / "shared.txt", "x")
        assert stat.S_IMODE(path.stat().st_mode) == 0o664
    finally:
        os.umask(old)
    path = atomic_write_text(tmp_path / "default.txt", "x")
    assert stat.S_IMODE(path.stat().st_mode) == 0o666 & ~old


def test_13_cli_files_are_shareable(tmp_path, capsys):
    status, _, _ = cli_run(["plot", saved_run(tmp_path), "--out", tmp_path / "figs"], capsys)
    assert status == 0
    for path in (tmp_path / "figs").iterdir():
        assert stat.S_IMODE(path.stat().st_mode) == file_mode(), path


# 14 ------------------------------------------------------------------------------------------------------------
def test_14_derived_defaults_follow_in_problem_files_as_in_parameter_files(tmp_path):
    changes = "r0 = 0.08\nm = 0.4\nR = 0.13\nM_s = 1.0\n"
    from_params = load_params(write(tmp_path / "p.toml", changes))
    problem = load_problem(circle_file(tmp_path, extra="[params]\n" + changes))
    for params in (from_params, problem.params):
        assert params.max_torque == pytest.approx(0.08 * 0.4 * 9.81)
        assert params.k0 == pytest.approx(0.4 * (1.0 + 0.04) * 0.13**2)
    assert problem.params == from_params


def test_14_set_values_stay_set():
    explicit = RollbotParams(k0=0.01, max_torque=0.2)
    problem = problem_from_dict({**CIRCLE, "params": {"m": 0.4}}, base=explicit)
    assert problem.params.k0 == 0.01 and problem.params.max_torque == 0.2
    derived = problem_from_dict({**CIRCLE, "params": {"m": 0.4}}, base=RollbotParams(R=0.13))
    assert derived.params.max_torque == pytest.approx(0.093 * 0.4 * 9.81)
    assert derived.params.k0 == pytest.approx(0.4 * 0.88 * 0.13**2)
    # a change that leaves a derived default where it was keeps it derived
    assert RollbotParams().replace(slope=0.01).derived == {"k0", "max_torque"}
    assert RollbotParams().replace(m=0.4).max_torque == RollbotParams().max_torque  # replace keeps values
    assert RollbotParams().with_changes(m=0.4).max_torque == RollbotParams(m=0.4).max_torque  # the file rule


# 15 ------------------------------------------------------------------------------------------------------------
def test_15_zero_damping(tmp_path, capsys):
    params = RollbotParams(k0=0.0)
    assert simulate(rest_state(params), 2.0, params=params, speed=1.0).completed  # the physics allows it
    status, _, err = cli_run(["quasi", "--omega0", "1", "--params", write(tmp_path / "k.toml", "k0 = 0\n")],
                             capsys)
    assert status == 2 and "k0 > 0" in one_error_line(err)
    with pytest.raises(ConfigError, match=r"k0 = 0.0 N m s: scenarios need damping k0 > 0"):
        problem_from_dict({**CIRCLE, "params": {"k0": 0}}, "p.toml")


# 16 ------------------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("argv, words", [
    (["run", "n_shape", "--seed", "-1"], ["--seed", "'-1'", "[0, 4294967295]"]),
    (["run", "n_shape", "--seed", "x"], ["--seed", "'x'", "whole number"]),
    (["nonsense"], ["invalid choice: 'nonsense'"]),
    (["openloop", "--omega0", "1", "--ramp-rate", "0"], ["--ramp-rate", "> 0"]),
    (["openloop", "--omega0", "1", "--slope-deg", "45"], ["--slope-deg", "[0, 30]"]),
])
def test_16_argument_errors_name_the_option_once(argv, words, capsys, no_computing):
    status, _, err = cli_run(argv, capsys)
    line = one_error_line(err)
    assert status == 2 and line.count("rollbot-oc:") == 1 and all(w in line for w in words), line


# 17 ------------------------------------------------------------------------------------------------------------
def test_17_license_is_an_spdx_string():
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())
    assert project["project"]["license"] == "MIT"
    assert any(r.startswith("setuptools>=77") for r in project["build-system"]["requires"])


# Found on the way ----------------------------------------------------------------------------------------------
def test_help_and_version_return_0(capsys):
    assert main(["--version"]) == 0 and "rollbot-oc" in capsys.readouterr().out
    assert main(["run", "--help"]) == 0 and "bundled scenario" in capsys.readouterr().out


def test_warnings_are_one_line(monkeypatch, capsys):
    def warn(args):
        warnings.warn("something\nodd", UserWarning)
        return 0

    monkeypatch.setattr(cli, "_cmd_problems", warn)
    assert main(["problems"]) == 0
    assert capsys.readouterr().err == "rollbot-oc: warning: something odd\n"


def test_open_loop_duration_is_not_silently_ignored(capsys, no_computing):
    status, _, err = cli_run(["run", "open_loop", "--duration", "100"], capsys)
    assert status == 2 and "does not apply" in one_error_line(err)


def test_controller_that_cannot_be_built_is_a_user_error(tmp_path, capsys):
    problem = write(tmp_path / "odd_dt.toml", """\
        name = "odd_dt"
        kind = "waypoints"
        duration = 2
        dt = 0.003
        [waypoints]
        stops = [[0.0, 0.3]]
        """)
    status, _, err = cli_run(["run", problem, "--controller", "nmpc"], capsys)
    assert status == 2 and "nmpc controller cannot be built" in one_error_line(err)


def test_params_reject_junk_values(tmp_path):
    for text, message in [("R = nan\n", "finite"), ("R = inf\n", "finite"), ("R = 1e300\nM_s = 1e300\n", "k0"),
                          ("params = 3\n", "unknown key"), ("R = [1]\n", "finite number")]:
        with pytest.raises(ConfigError, match=message):
            load_params(write(tmp_path / "p.toml", text))


def test_open_loop_failure_is_a_row_of_nulls(monkeypatch, capsys):
    import rollbot_oc.analysis.experiments as experiments

    def slips(omega0, params, **kwargs):
        raise NumericalFailure(f"open loop at omega0 = {omega0} rad/s: the robot left the no-slip model", "slide")

    monkeypatch.setattr(experiments, "open_loop_run", slips)
    status, out, err = cli_run(["openloop", "--omega0", "1", "--json"], capsys)
    assert status == 1 and err.startswith("rollbot-oc: failed: open loop at omega0 = 1.0")
    row = strict_json(out)[0]
    assert row["omega0"] == 1.0 and row["R0"] is None and row["settled"] is False
