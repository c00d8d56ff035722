"""The NMPC with its step as an exported C library (``rollbot-oc run P --controller c``) gives the run of the NMPC
itself (``--controller nmpc``), key for key, on every bundled closed-loop problem the acceptance names and on the
random courses 0 to 4 (seed 0, each with its believed robot and noise seed, as the campaign runs them).

Each run is shortened (``DURATION`` s of simulated time, the gates problem to its first gate) and uses one small
settings object (``shared.step_settings``), so that each mission kind's step is compiled once;
``benchmarks/bench_c_controller.py`` runs the whole problems at the default settings.  That a perturbed library
gives another run is ``test_export.test_the_exported_step_is_the_nmpcs_step``'s.
"""

import hashlib
import json
import shutil
from dataclasses import replace

import pytest

from rollbot_oc.model.codegen import compiler
from shared import comparable, nmpc_metrics, step_settings

pytestmark = pytest.mark.skipif(compiler() is None or shutil.which("make") is None,
                                reason="no C compiler or make: the exported step cannot be built here")

DURATION = 3.0  # s of each run: ten solves at the small settings' 0.3 s interval, the first plans followed
BUNDLED = ("n_shape", "n_shape_imu", "n_shape_outages", "circle_R020", "circle_R065", "approach", "gates")
COURSES = range(5)


def _case(name: str):
    """``(problem, believed robot or None, noise seed)`` of a case, shortened."""
    from rollbot_oc.scenarios.bundled import load_bundled
    from rollbot_oc.scenarios.courses import random_course

    if name.startswith("course_"):
        course = random_course(0, int(name.removeprefix("course_")))
        return course.problem.with_duration(DURATION), course.believed, course.noise_seed
    problem = load_bundled(name).with_duration(DURATION)
    if problem.mission.gates:  # the plan through the gates is solved before the robot moves: one gate
        problem = replace(problem, mission=replace(problem.mission, points=problem.mission.points[:1]))
    return problem, None, 0


@pytest.fixture(scope="module")
def step_folders(tmp_path_factory):
    """``folder(problem, params, functions)``: a folder written by ``write_step`` for the step of ``functions``
    (one per step: mission kinds whose steps are the same share it, the robot being the memory's)."""
    from rollbot_oc.control.nmpc.source import step_key
    from rollbot_oc.export.step_library import write_step

    folders = {}

    def folder(problem, params, functions):
        key = step_key(functions)
        if key not in folders:
            path = tmp_path_factory.mktemp(f"step_{key}")
            assert write_step(path, problem, params, settings=step_settings())["key"] == key
            folders[key] = path
        return folders[key]

    return folder


@pytest.mark.parametrize("name", [*BUNDLED, *(f"course_{i}" for i in COURSES)])
def test_the_c_step_runs_the_nmpcs_run(name, step_folders):
    """The NMPC whose step is the library of a folder written by ``write_step`` gives the plain NMPC's metrics
    key for key (wall-clock keys aside; its ``library_sha256`` added), and the plain NMPC runs the same library:
    its step's Functions are the compiled C, and the file it loads from the codegen cache has the bytes of the
    folder's library."""
    from rollbot_oc.control.nmpc.source import LIBRARY, cached_library
    from rollbot_oc.scenarios.problem import make_controller, run_problem

    problem, params, seed = _case(name)
    settings = step_settings()
    plain = make_controller("nmpc", problem, params, settings=settings)
    assert all(f.fun.class_name() == "External" for f in (plain.step._measure, plain.step._solve, plain.step._commit))
    folder = step_folders(problem, params, plain.step.functions)
    sha = hashlib.sha256((folder / LIBRARY).read_bytes()).hexdigest()
    assert hashlib.sha256(cached_library(plain.step.functions).read_bytes()).hexdigest() == sha

    nmpc = comparable(run_problem(problem, plain, seed=seed, show_progress=False).metrics)
    c = nmpc_metrics(problem, params, seed, settings=settings, step_library=folder)
    assert c.pop("library_sha256") == sha and "library_sha256" not in nmpc
    assert c == nmpc
    assert nmpc["solves"] >= DURATION / settings.horizon.h - 1 and nmpc["duration"] == pytest.approx(DURATION)


def test_run_controller_c_prints_the_nmpcs_json(tmp_path, capsys):
    """Through the command line: ``export-c`` a circle (its step at the NMPC's settings, ``--settings nmpc``; its
    recorded run the first 60 s, a prefix of the circle's, which is not a failure), then ``run --json`` with
    ``--controller nmpc`` and with ``--controller c --c-project`` that folder: the same JSON (wall-clock keys
    aside), the second naming its controller ``c`` and the library it ran."""
    from rollbot_oc.app.cli import main
    from rollbot_oc.control.nmpc.source import LIBRARY

    folder = tmp_path / "c"
    assert main(["export-c", "--out", str(folder), "--problem", "circle_R065", "--settings", "nmpc", "--json"]) == 0
    exported = json.loads(capsys.readouterr().out)
    assert exported["step"]["N"] == 60 and (folder / LIBRARY).is_file()

    runs = []
    for options in (["--controller", "nmpc"], ["--controller", "c", "--c-project", str(folder)]):
        main(["run", "circle_R065", "--duration", "1", "--json", *options])
        runs.append(comparable(json.loads(capsys.readouterr().out)))
    nmpc, c = runs
    assert c.pop("library_sha256") == hashlib.sha256((folder / LIBRARY).read_bytes()).hexdigest()
    assert (nmpc.pop("controller"), c.pop("controller")) == ("nmpc", "c")  # each run named as asked
    assert c == nmpc and nmpc["solves"] >= 19
