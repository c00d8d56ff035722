"""Closed-loop runs that more than one test measures, computed once per test session and shared (read-only).

Under pytest-xdist the first worker to ask computes a run and leaves it pickled in the session's temporary folder,
behind a lock; the others wait for it and load it, so it is computed once whichever workers run those tests.
The fixtures are made available to every test module by ``conftest.py``.
"""

import contextlib
import os
import pickle
from dataclasses import fields, is_dataclass, replace

import numpy as np
import pytest

try:
    import fcntl
except ImportError:  # not POSIX: each worker computes its own
    fcntl = None


_computed: dict = {}  # this process's


def _shared(tmp_path_factory, name: str, compute):
    """``compute()``, or what this process or another worker of this session computed under ``name``."""
    if name not in _computed:
        _computed[name] = _compute_once(tmp_path_factory, name, compute)
    return _computed[name]


def _compute_once(tmp_path_factory, name: str, compute):
    if not os.environ.get("PYTEST_XDIST_WORKER") or fcntl is None:
        return compute()
    root = tmp_path_factory.getbasetemp().parent  # the folder the workers' own temporary folders share
    path = root / f"shared_{name}.pkl"
    with open(root / f"shared_{name}.lock", "w") as lock, contextlib.ExitStack() as unlock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        unlock.callback(fcntl.flock, lock, fcntl.LOCK_UN)
        if path.is_file():
            return pickle.loads(path.read_bytes())
        value = compute()
        path.write_bytes(pickle.dumps(value))
        return value


def same_problem(a, b) -> bool:
    """The same ``Problem`` wherever it was read from (its ``source`` aside), field by field."""
    return _equal(replace(a, source=""), replace(b, source=""))


def _equal(a, b) -> bool:
    if type(a) is not type(b):
        return False
    if is_dataclass(a):
        return all(_equal(getattr(a, f.name), getattr(b, f.name)) for f in fields(a))
    if isinstance(a, np.ndarray):
        return a.shape == b.shape and bool(np.array_equal(a, b))
    if isinstance(a, dict):
        return a.keys() == b.keys() and all(_equal(a[k], b[k]) for k in a)
    if isinstance(a, (list, tuple)):
        return len(a) == len(b) and all(_equal(x, y) for x, y in zip(a, b))
    return bool(a == b)


WALL_CLOCK = ("wall_time", "solve_time", "plan_time", "plan_solve_time", "step_time")  # metrics the wall clock decides


def step_settings():
    """The NMPC settings of the tests that run its step as an exported C library: the bundled step's 3 s horizon
    in 10 intervals (each mission kind's step quick to build); plans quick to build and solve: one start per leg
    on a 20-interval grid, no leg planned ahead, a circle's entry on a 0.5 s grid, the plan through gates on a
    limited-memory Hessian.  One object for every such test, so that each kind's step library is compiled once
    (the planner is not part of the step)."""
    from rollbot_oc.control.nmpc import NMPCSettings
    from rollbot_oc.control.nmpc.settings import PlannerSettings

    planner = PlannerSettings()
    return NMPCSettings(horizon={"N": 10, "h": 0.3}, entry={"interval": 0.5},
                        planner={"starts": 1, "resumes": 0, "legs_ahead": 0, "fresh": 0,
                                 "legs": replace(planner.legs, N=20),
                                 "gates": replace(planner.gates, hessian="limited-memory")})


def nmpc_metrics(problem, params=None, seed: int = 0, **options) -> dict:
    """The metrics of the NMPC's run of ``problem`` (``make_controller("nmpc", problem, params, **options)``,
    sensor noise ``seed``) without what the wall clock decides (``WALL_CLOCK`` keys, each plan's
    ``solve_time``): what two runs of the same controller must give bit for bit."""
    from rollbot_oc.scenarios.problem import make_controller, run_problem

    controller = make_controller("nmpc", problem, params, **options)
    return comparable(run_problem(problem, controller, seed=seed, show_progress=False).metrics)


def comparable(metrics: dict) -> dict:
    """A run's metrics (or its ``--json``) without what the wall clock decides (``nmpc_metrics``)."""
    out = {k: v for k, v in metrics.items() if not k.startswith(WALL_CLOCK)}
    if out.get("plans"):
        out["plans"] = [{k: v for k, v in plan.items() if k != "solve_time"} for plan in out["plans"]]
    return out


@pytest.fixture(scope="session")
def n_shape_runs(tmp_path_factory):
    """The bundled N-shape under the PID and the NMPC, seed 0, each run as ``compare`` (and ``rollbot-oc demo``)
    runs it: ``(problem, [pid, nmpc])``.  Used by test_nmpc, test_export and test_report."""
    return n_shape_problem(), [n_shape_run(tmp_path_factory, name) for name in ("pid", "nmpc")]


@pytest.fixture(scope="session")
def n_shape_pid_run(tmp_path_factory):
    """The PID's of ``n_shape_runs`` alone (the NMPC's not computed for it).  Used by test_pid."""
    return n_shape_problem(), n_shape_run(tmp_path_factory, "pid")


def n_shape_problem():
    from rollbot_oc.scenarios.bundled import load_bundled

    return load_bundled("n_shape")


def n_shape_run(tmp_path_factory, controller: str):
    from rollbot_oc.scenarios.problem import run_problem

    # compare(problem, seed=0) is [run_problem(problem, name, seed=0, params=None, duration=None) for pid, nmpc]
    return _shared(tmp_path_factory, f"n_shape_{controller}", lambda: run_problem(
        n_shape_problem(), controller, seed=0, params=None, duration=None, show_progress=False))


@pytest.fixture(scope="session")
def pid_circle_run(tmp_path_factory):
    """``pid_circle_run(name)``: the bundled circle ``name`` under the PID, seed 0, its whole duration (each run
    once per session when first asked).  Used by test_pid and test_nmpc."""
    from rollbot_oc.scenarios.problem import run_problem
    from rollbot_oc.scenarios.bundled import load_bundled

    def run(name: str):
        return _shared(tmp_path_factory, f"pid_{name}",
                       lambda: run_problem(load_bundled(name), "pid", show_progress=False))

    return run


@pytest.fixture(scope="session")
def c_export(tmp_path_factory):
    """The N-shape's first two legs (40 s at most) exported as C with the firmware build (``export_c``: the NMPC's
    step with ``NMPCSettings.embedded()``, its recorded run; target ``cortex-m7``) and built for the host (``make all
    firmware_host``, -j2: the hand-written C linked to the step's library), once per session in a folder the
    workers share: ``(problem, result, built)``, ``built`` the build's ``(returncode, stderr)`` or None where there
    is no C compiler or make.  Tests read the folder and build further targets in it, but change none of its
    files.  Used by test_export and test_firmware."""
    import shutil

    from rollbot_oc.model.codegen import compiler

    root = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER") and fcntl is not None:
        root = root.parent  # the folder the workers' own temporary folders share
    folder = root / "shared_c_export"
    n_shape = n_shape_problem()
    problem = replace(n_shape, mission=n_shape.mission.first(2), duration=40.0)

    def compute():
        from rollbot_oc.export.project import build, export_c

        if folder.exists():
            shutil.rmtree(folder)  # a worker that failed half-way left it
        result = replace(export_c(folder, problem, target="cortex-m7"), functions=None)  # (CasADi's: not pickled)
        if compiler() is None or shutil.which("make") is None:
            return result, None
        done = build(folder, "all firmware_host", jobs=2)
        return result, (done.returncode, done.stderr)

    from rollbot_oc.control.nmpc import NMPCSettings
    from rollbot_oc.scenarios.problem import make_controller

    result, built = _shared(tmp_path_factory, "c_export", compute)
    # the step's Functions, built again in this worker as export_c built them (the same key: test_export checks)
    functions = make_controller("nmpc", problem, settings=NMPCSettings.embedded()).step.functions
    return problem, replace(result, functions=functions), built
