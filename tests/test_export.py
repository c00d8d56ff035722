"""The controller on the robot: the exported C project (the NMPC's own step) builds without warnings, replays a
recorded run of the NMPC within 1e-9 (and fails on a perturbed log or library), and the NMPC with the exported
library as its step runs as the NMPC."""

import hashlib
import os
import re
import shutil
import struct
import subprocess

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


SHIM = r"""
#define _GNU_SOURCE
#include <dlfcn.h>
/* rollbot_commit interposed: the step's acceleration moved 1e-6 rad/s^2 */
typedef int commit(const double** arg, double** res, long long* iw, double* w, int mem);
int rollbot_commit(const double** arg, double** res, long long* iw, double* w, int mem) {
    static commit* real;
    int r;
    if (!real) real = (commit*)dlsym(RTLD_NEXT, "rollbot_commit");
    r = real(arg, res, iw, w, mem);
    if (res[0]) res[0][0] += 1e-6;
    return r;
}
"""


@pytest.mark.slow
def test_export_builds_and_replays_the_nmpcs_run(c_export, tmp_path):
    """One test (on the session's one export and host build, ``c_export``, shared with test_firmware): the project
    is written whole, around the NMPC's own step (the source and library the NMPC compiled), builds with -std=c99
    -O2 -Wall -Werror, and ``make check`` replays every period of the NMPC's recorded run (the N-shape's first two
    legs: a plan taking over, a stop left) within 1e-9, every event and mode the same; a log the step did not give,
    or a library whose commit is perturbed, fails it."""
    from rollbot_oc.control.nmpc.source import LIBRARY, cached_library, step_source
    from rollbot_oc.export.project import build, read_export
    from rollbot_oc.export.replay import read_replay

    problem, result, built = c_export
    folder = result.folder
    for name in ("rollbot_step.c", "rollbot_step.h", "step.json", "step.mk", "rollbot_config.h", "rollbot_data.c",
                 "rollbot_controller.h", "rollbot_controller.c", "rollbot_replay.h", "rollbot_replay.c", "main.c",
                 "Makefile", "README.md", "replay_log.bin", "export.json"):
        assert (folder / name).is_file(), name
    source = (folder / "rollbot_step.c").read_text()
    assert source == step_source(result.functions).source  # the NMPC's own step, as it compiles it
    assert "malloc" not in source and "calloc" not in source  # no heap in the step
    assert source.count("its factors stand") == 1  # qrqp keeps unchanged factors (the replay checks the outputs)
    assert result.metrics["completed"] and len(result.metrics["stop_errors"]) == 2
    assert len(result.log) == int(round(result.metrics["duration"] / 0.01))
    assert [p.k for p in result.log] == list(range(len(result.log)))
    edited = {int(i) for p in result.log for i, _ in p.after}
    f = result.functions
    assert {f.memory["warm"].start, f.memory["current"].start} <= edited  # a plan taking over, a leg left
    assert result.solves == result.metrics["solves"] > 10
    header, periods = read_replay((folder / "replay_log.bin").read_bytes())
    assert header == {"periods": len(result.log), "memory": f.memory.size, "window": f.window.size}
    assert all(np.array_equal(a.values(), b.values(), equal_nan=True) for a, b in zip(periods, result.log))
    assert read_export(folder)["step"]["key"] == result.step["key"]
    assert result.sizes["work_bytes"] > 0 and result.sizes["memory_bytes"] == 8 * f.memory.size
    if built is None:
        pytest.skip("no C compiler or make: the exported project cannot be built here")
    cached = cached_library(f)
    assert cached is not None and (folder / LIBRARY).read_bytes() == cached.read_bytes()  # not compiled again

    returncode, stderr = built
    assert returncode == 0, stderr[-2000:]
    assert "warning" not in stderr.lower()  # -Wall -Werror: a warning would have failed the build
    check = build(folder, "check")
    assert check.returncode == 0, check.stdout[-2000:] + check.stderr[-2000:]
    found = re.search(r"max \|diff\| = (\S+) .*?, (\d+) events or modes differ", check.stdout)
    assert found and float(found.group(1)) <= 1e-9 and found.group(2) == "0"
    assert f"replayed {len(result.log)} periods, {result.solves} solve instants" in check.stdout

    # a log the step did not give fails the check (a copy: the shared folder stays as exported)
    log = tmp_path / "replay_log.bin"
    data = bytearray((folder / "replay_log.bin").read_bytes())
    accel_at = len(data) - 5 * 8  # the last period's recorded acceleration
    data[accel_at:accel_at + 8] = struct.pack("<d", struct.unpack_from("<d", data, accel_at)[0] + 1e-6)
    log.write_bytes(bytes(data))
    check = subprocess.run([str(folder / "replay"), str(log)], capture_output=True, text=True)
    assert check.returncode == 1 and "check FAILED" in check.stdout
    # and so does a library whose commit gives another acceleration (interposed: the same step otherwise)
    shim = tmp_path / "shim.so"
    (tmp_path / "shim.c").write_text(SHIM)
    subprocess.run([compiler(), "-shared", "-fPIC", str(tmp_path / "shim.c"), "-o", str(shim), "-ldl"], check=True,
                   capture_output=True, timeout=120)
    check = subprocess.run([str(folder / "replay"), str(folder / "replay_log.bin")], capture_output=True, text=True,
                           env={**os.environ, "LD_PRELOAD": str(shim)})
    assert check.returncode == 1 and "check FAILED" in check.stdout
    assert 9e-7 < float(re.search(r"max \|diff\| = (\S+)", check.stdout).group(1)) < 1.1e-6


def test_the_replay_file_holds_the_periods_as_recorded():
    """``replay_bytes`` and ``read_replay`` agree on every field; too many edits or a window of another size are
    refused, and a cut file is reported."""
    from rollbot_oc.export.replay import MAX_EDITS, Period, read_replay, replay_bytes

    rng = np.random.default_rng(0)
    periods = [Period(0, rng.standard_normal(12), np.array([[3.0, 0.5]]), np.zeros((0, 2)), None,
                      (0.0, 0.0, 1.0, np.nan), (0.25, np.nan, 0.0, 0.0, 0.0)),
               Period(1, rng.standard_normal(12), np.zeros((0, 2)), np.array([[1.0, 0.0], [2.0, 0.0]]),
                      rng.standard_normal(7), (1.0, 0.0, 0.0, 2.5), (-0.5, 2.5, 1.0, 4.0, 3.0))]
    data = replay_bytes(periods, 10, 7)
    header, back = read_replay(data)
    assert header == {"periods": 2, "memory": 10, "window": 7}
    for a, b in zip(periods, back):
        assert np.array_equal(a.values(), b.values(), equal_nan=True)
    with pytest.raises(ValueError, match="7 doubles, not 8"):
        replay_bytes(periods, 10, 8)
    many = [Period(0, np.zeros(12), np.zeros((MAX_EDITS + 1, 2)))]
    with pytest.raises(ValueError, match="edits of the memory at once"):
        replay_bytes(many, 10, 7)
    with pytest.raises(ValueError, match="ends within period 1"):
        read_replay(data[:-8])


def test_export_c_refuses_what_it_cannot_export(tmp_path, capsys):
    """Open-loop problems and a step solved by IPOPT (no C) are refused in one line, before anything runs."""
    from rollbot_oc.control.nmpc import NMPCSettings
    from rollbot_oc.core.errors import ConfigError
    from rollbot_oc.export.project import export_c

    assert main(["export-c", "--out", str(tmp_path / "c"), "--problem", "open_loop"]) == EXIT_USAGE
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "open-loop" in err[0] and "Traceback" not in err[0]
    with pytest.raises(ConfigError, match="valid is 'rti'"):
        export_c(tmp_path / "ipopt", load_bundled("n_shape"), settings=NMPCSettings(horizon={"solver": "ipopt"}))
    assert not (tmp_path / "ipopt").exists()
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
