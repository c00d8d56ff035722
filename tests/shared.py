"""Closed-loop runs that more than one test measures, computed once per test session and shared (read-only).

Under pytest-xdist the first worker to ask computes a run and leaves it pickled in the session's temporary folder,
behind a lock; the others wait for it and load it, so it is computed once whichever workers run those tests.
The fixtures are made available to every test module by ``conftest.py``.
"""

import contextlib
import os
import pickle
from dataclasses import replace

import pytest

try:
    import fcntl
except ImportError:  # not POSIX: each worker computes its own
    fcntl = None


def _shared(tmp_path_factory, name: str, compute):
    """``compute()``, or what another worker of this session computed under ``name``."""
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
    """The same ``Problem`` wherever it was read from (its ``source`` aside)."""
    return pickle.dumps(replace(a, source="")) == pickle.dumps(replace(b, source=""))


@pytest.fixture(scope="session")
def n_shape_runs(tmp_path_factory):
    """The bundled N-shape under the PID and the NMPC, seed 0, as ``compare`` runs it (and ``rollbot-oc demo``):
    ``(problem, [pid, nmpc])``.  Used by test_nmpc, test_pid and test_report."""
    from rollbot_oc.problems import compare
    from rollbot_oc.scenarios import load_bundled

    problem = load_bundled("n_shape")
    return problem, _shared(tmp_path_factory, "n_shape_runs",
                            lambda: compare(problem, show_progress=False))
