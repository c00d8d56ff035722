"""The controller on the robot: the exported C project builds without warnings, replays the whole N-shape
log within 1e-9 of the Python controller, and drives the simulator through ctypes to the same run."""

import hashlib
import re
import shutil
import subprocess
from dataclasses import replace

import casadi as ca
import numpy as np
import pytest

from rollbot_oc.app.cli import EXIT_USAGE, main
from rollbot_oc.model.codegen import compiler
from rollbot_oc.control.nmpc.tracking import tracking_problem
from rollbot_oc.model.params import RollbotParams
from rollbot_oc.scenarios.problem import run_problem
from rollbot_oc.scenarios.bundled import load_bundled
from shared import nmpc_metrics, step_settings

def test_structured_linearisation_as_a_graph_is_the_numeric_one():
    """``StructuredLinearisation.symbolic`` (what the C export generates) gives the numeric call's values."""
    route = tracking_problem(4, 0.1).solver("rti", qp_solver="qrqp", compiled=False)
    tr, lin = route.transcription, route.linearisation
    w, par = ca.MX.sym("w", tr.w.numel()), ca.MX.sym("par", tr.par.numel())
    graph = ca.Function("lin", [w, par], list(lin.symbolic(w, par)))
    rng = np.random.default_rng(1)
    w0 = tr.default_guess() + 0.01 * rng.standard_normal(tr.w.numel())
    par0 = rng.uniform(0.1, 1.0, tr.par.numel())
    par0[tr.layout.parameters["p"]] = RollbotParams().vector()
    for numeric, symbolic in zip(lin(w0, par0), graph(w0, par0)):
        numeric = np.array(ca.DM(numeric).full()) if not np.isscalar(numeric) else np.array([[numeric]])
        assert np.all(np.isfinite(symbolic.full()))
        assert np.allclose(numeric.reshape(symbolic.shape), symbolic.full(), rtol=1e-12, atol=1e-12)


def test_the_exported_filter_is_the_numeric_one(n_shape_runs):
    """The step's symbolic tilt filter (``export.step._estimator_update``) against ``TiltEstimator.update`` on the
    measured attitude (``attitude_gain`` 1), over a recorded stretch of the N-shape (its first 3 s under the NMPC,
    from the session's shared run): the same tilt and covariance to 1e-12."""
    from rollbot_oc.control.nmpc.estimation import TiltEstimator
    from rollbot_oc.model.dynamics import to_reduced
    from rollbot_oc.export.step import EMBEDDED_SETTINGS as s, _estimator_update, control_step

    params = RollbotParams()
    _, (_, run) = n_shape_runs
    assert run.controller == "nmpc" and run.result.dt == 0.01
    x, u = run.result.x[:, :301], run.result.command[:300]
    numeric = TiltEstimator(params, 0.01, s.filter.process_noise, s.filter.gyro_sigma, s.filter.model_error,
                            attitude_gain=s.filter.attitude_gain)
    symbolic = _estimator_update(numeric)
    tilt, P = numeric.tilt.copy(), numeric.P.copy()
    prior = P.copy()
    for k in range(u.size):  # the plant's own states: the 1 deg floor is in the residuals
        z_prev, z_now = to_reduced(x[:, k]), to_reduced(x[:, k + 1])
        numeric.update(z_prev, float(u[k]), z_now)
        tilt, P = symbolic(tilt, P, z_prev, float(u[k]), z_now)
        tilt, P = np.asarray(tilt).ravel(), np.asarray(P)
        assert np.allclose(tilt, numeric.tilt, atol=1e-12, rtol=0) and np.allclose(P, numeric.P, atol=1e-12, rtol=0)
    assert np.linalg.norm(tilt) > 0 and np.trace(P) < 0.5 * np.trace(prior)  # it did learn something
    with pytest.raises(ValueError, match="attitude_gain = 0.05"):
        control_step(params, s.replace(filter={"attitude_gain": 0.05}))


@pytest.mark.slow
def test_export_builds_replays_a_whole_run_and_closes_the_loop_through_c(c_export, tmp_path):
    """One test (on the session's one export and host build, ``c_export``, shared with test_firmware): the project
    is written whole, builds with -std=c99 -O2 -Wall -Werror, ``make check`` replays every period of a whole run
    (the N-shape's first two legs: a leg ahead planned, a stop left) within 1e-9 (and fails on a log the controller
    did not give), and the simulator driving the C library gives the same run.  ``benchmarks/bench_export_c.py``
    runs the whole N-shape."""
    from rollbot_oc.export.library import CController
    from rollbot_oc.export.project import build

    problem, result, built = c_export
    folder = result.folder
    for name in ("rollbot_period.c", "rollbot_period.h", "rollbot_config.h", "rollbot_data.c", "rollbot_controller.h",
                 "rollbot_controller.c", "main.c", "Makefile", "README.md", "replay_log.txt", "export.json"):
        assert (folder / name).is_file(), name
    source = (folder / "rollbot_period.c").read_text()
    assert "malloc" not in source and "calloc" not in source  # no heap in the step
    assert source.count("its factors stand") == 1  # qrqp keeps unchanged factors (the replay checks the outputs)
    assert result.metrics["completed"] and len(result.metrics["stop_errors"]) == 2
    assert result.log.shape[1] == 14 and result.log.shape[0] == int(round(result.metrics["duration"] / 0.01))
    assert result.sizes["work_bytes"] > 0 and result.sizes["memory_bytes"] == 8 * result.step.memory.size
    if built is None:
        pytest.skip("no C compiler or make: the exported project cannot be built here")

    returncode, stderr = built
    assert returncode == 0, stderr[-2000:]
    assert "warning" not in stderr.lower()  # -Wall -Werror: a warning would have failed the build
    check = build(folder, "check")
    assert check.returncode == 0, check.stdout[-2000:] + check.stderr[-2000:]
    found = re.search(r"max \|diff\| = (\S+)", check.stdout)
    assert found and float(found.group(1)) <= 1e-9
    assert f"replayed {result.log.shape[0]} periods" in check.stdout  # the whole run's log

    # closed loop: the simulator drives the C library (ctypes): the same commands (to 1e-9), the same metrics
    c = CController(folder, result.step, result.reference, record=True)
    run = run_problem(problem, c, show_progress=False)
    assert c.context_bytes >= result.sizes["work_bytes"]
    assert run.metrics["library_sha256"] == hashlib.sha256((folder / "librollbot_controller.so").read_bytes()).hexdigest()
    commands = np.array(c.commands)
    assert commands.shape == result.log[:, 12].shape
    assert np.max(np.abs(commands - result.log[:, 12])) <= 1e-9
    assert run.metrics["completed"]
    assert run.metrics["completion_time"] == pytest.approx(result.metrics["completion_time"], abs=1e-9)
    assert np.allclose(run.metrics["stop_errors"], result.metrics["stop_errors"], rtol=0, atol=1e-9)

    # a log the controller did not give fails the check (a copy: the shared folder stays as exported)
    log = tmp_path / "replay_log.txt"
    lines = (folder / "replay_log.txt").read_text().splitlines()[:200]
    fields = lines[-1].split()
    fields[12] = repr(float(fields[12]) + 1e-6)  # a command 1e-6 rad/s^2 off
    log.write_text("\n".join(lines[:-1] + [" ".join(fields)]) + "\n")
    check = subprocess.run([str(folder / "replay"), str(log)], capture_output=True, text=True)
    assert check.returncode != 0 and "check FAILED" in check.stdout


def test_the_step_weighs_the_arrival_only_past_the_legs_end():
    """The step honours the arrival weights (``TrackingWeights.arrival_speed``, ``arrival_omega``) as the NMPC does:
    its commands are those without them as long as the horizon ends within the first leg, and not once it reaches
    past the leg's end."""
    from rollbot_oc.export.project import embedded_controller
    from rollbot_oc.export.step import EMBEDDED_SETTINGS as s

    assert s.weights.legs.arrival_speed > 0 and s.weights.legs.arrival_omega > 0
    n_shape = load_bundled("n_shape")
    problem = replace(n_shape, mission=n_shape.mission.first(1), duration=3.0)  # one leg planned
    still = s.replace(weights={"legs": replace(s.weights.legs, arrival_speed=0.0, arrival_omega=0.0)})
    commands = []
    for settings in (still, s):
        controller, step, reference = embedded_controller(problem, settings=settings, record=True)
        run_problem(problem, controller, show_progress=False)
        commands.append(np.array(controller.commands))
    within = int(round((reference.durations[0] - s.horizon.N * s.horizon.h) / problem.dt))  # the horizon within the first leg
    assert 0 < within < commands[0].size
    assert np.array_equal(commands[0][:within], commands[1][:within])
    assert not np.allclose(commands[0], commands[1])
    # the weights the step blends in are the NMPC's own diagonal with those nodes ended
    from rollbot_oc.export.step import _RTI

    rti = _RTI(problem.params.replace(slope=0.0), s)
    ended = np.arange(s.horizon.N + 1) >= 10
    for name, (track, arrival, _hold) in rti.weights.items():
        expected = rti.solver._parameters(np.zeros(10), np.zeros((10, s.horizon.N + 1)), np.zeros(s.horizon.N), rti.p_nominal, None,
                                          s.weights.legs.diagonal(s.horizon.N, ended))[name]
        assert np.array_equal(np.asarray(track) + (np.asarray(arrival) - np.asarray(track)) * ended, expected), name


def test_export_c_refuses_what_it_cannot_export(tmp_path, capsys):
    """Open-loop problems and a firmware of anything but a course of stops are refused in one line."""
    assert main(["export-c", "--out", str(tmp_path / "c"), "--problem", "open_loop"]) == EXIT_USAGE
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "open-loop" in err[0] and "Traceback" not in err[0]
    assert main(["export-c", "--out", str(tmp_path / "c"), "--problem", "circle_R035", "--target", "cortex-m7"]) \
        == EXIT_USAGE
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "course of stops" in err[0]
    afile = tmp_path / "afile"
    afile.write_text("")
    assert main(["export-c", "--out", str(afile)]) == EXIT_USAGE
    assert "not a folder" in capsys.readouterr().err
    assert main(["run", "n_shape", "--controller", "c"]) == EXIT_USAGE
    assert "--c-project" in capsys.readouterr().err


def test_generated_code_edits_refuse_an_unexpected_source():
    """The edits of the generated step find exactly the code they expect, or stop the export (another CasADi)."""
    from rollbot_oc.control.nmpc.source import _keep_unchanged_factors, _qp_failure_not_an_error

    for edit in (_keep_unchanged_factors, _qp_failure_not_an_error):
        with pytest.raises(RuntimeError, match="CasADi version"):
            edit("int main(void) { return 0; }\n")


@pytest.mark.skipif(compiler() is None or shutil.which("make") is None,
                    reason="no C compiler or make: the exported step cannot be built here")
def test_the_exported_step_is_the_nmpcs_step(tmp_path, capsys):
    """The step of a circle's NMPC written as C (``export-c``'s ``write_step``) and built: the NMPC with that
    library as its step (``run --controller c``) gives the run of the NMPC itself, key for key (the library's hash
    added), and a perturbed library (the filtered position moved 1 um) gives another run; a library exported for
    other settings is refused.  (A short horizon, to build quickly.)"""
    from rollbot_oc.control.nmpc.source import FLAGS, LIBRARY, MANIFEST
    from rollbot_oc.core.errors import ConfigError
    from rollbot_oc.scenarios.problem import make_controller

    from rollbot_oc.export.step_library import write_step

    folder = tmp_path / "step"
    folder.mkdir()
    problem = load_bundled("circle_R065").with_duration(1.5)
    small = step_settings()  # a 10-interval horizon, quick to build (the step test_c_controller compiles too)
    manifest = write_step(folder, problem, settings=small)
    (folder / "Makefile").write_text("CC ?= cc\n-include step.mk\n")
    assert (folder / LIBRARY).is_file()  # the NMPC's own build of this source; make rebuilds it (below)
    for name in ("rollbot_step.c", "rollbot_step.h", MANIFEST, "step.mk", LIBRARY):
        assert (folder / name).is_file(), name
    assert manifest["N"] == 10 and manifest["problem"] == "circle_R065"

    def metrics(**options):
        return nmpc_metrics(problem, settings=small, **options)

    nmpc, c = metrics(), metrics(step_library=folder)
    assert c.pop("library_sha256") == hashlib.sha256((folder / LIBRARY).read_bytes()).hexdigest()
    assert c == nmpc and nmpc["solves"] > 0 and nmpc["failed_solves"] == 0

    source = (folder / "rollbot_step.c").read_text()
    call = re.search(r"int rollbot_measure\(.*?\{\n  return (casadi_f\d+)\(arg, res, iw, w, mem\);", source, re.S)
    perturbed = tmp_path / "perturbed"
    perturbed.mkdir()
    (perturbed / MANIFEST).write_text((folder / MANIFEST).read_text())
    (perturbed / "rollbot_step.c").write_text(source.replace(
        call.group(0), call.group(0).replace(f"return {call.group(1)}(arg, res, iw, w, mem);",
                                             f"int r = {call.group(1)}(arg, res, iw, w, mem); "
                                             "if (res[0]) res[0][0] += 1e-6; return r;")))
    flags = [f for f in FLAGS if not f.startswith("-O")] + ["-O0"]  # quicker to build; the same arithmetic on x86-64
    subprocess.run([compiler(), "-shared", "-fPIC", *flags, str(perturbed / "rollbot_step.c"), "-o",
                    str(perturbed / LIBRARY), "-lm"], check=True, capture_output=True, timeout=600)
    changed = metrics(step_library=perturbed)
    changed.pop("library_sha256")
    assert changed != nmpc  # the run it drove is another

    with pytest.raises(ConfigError, match="exported for another step"):
        make_controller("nmpc", problem, step_library=folder, settings=small.replace(recovery={"max_failures": 5}))
