import os
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
sys.path.insert(0, str(Path(__file__).parent))
os.environ.setdefault("ROLLBOT_QUICK", "1")

# Property-based tests (hypothesis): "ci" (the default) keeps the suite fast and repeatable; "nightly" searches
# far more inputs: HYPOTHESIS_PROFILE=nightly python -m pytest tests/test_contract.py
from hypothesis import HealthCheck, settings  # noqa: E402

settings.register_profile("ci", max_examples=25, deadline=None, derandomize=True, database=None,
                          suppress_health_check=[HealthCheck.too_slow])
settings.register_profile("nightly", max_examples=1000, deadline=None,
                          suppress_health_check=[HealthCheck.too_slow])
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci"))


# runs several tests share, computed once per session (tests/shared.py)
from shared import c_export, n_shape_pid_run, n_shape_runs, pid_circle_run  # noqa: E402,F401


# The modules of long closed loops, notebooks and C builds run first: pytest-xdist's work stealing then fills the
# end of the run with short tests on both workers, instead of one worker finishing a long test alone.  test_nmpc
# leads: its first test asks for the shared N-shape runs (tests/shared.py), so they are computed at once, and
# test_export, which makes the shared export, comes early too.
FIRST = ("test_nmpc.py", "test_notebooks.py", "test_export.py", "test_gates.py", "test_ocp.py")
# The other readers of those shared runs and of the export come last: the second worker starts in the middle of
# the list, and would otherwise wait there for what the first worker is computing.
LAST = ("test_firmware.py", "test_mcap_log.py", "test_report.py")


def pytest_collection_modifyitems(items):
    rank = {name: i for i, name in enumerate(FIRST)} | {name: len(FIRST) + 1 + i for i, name in enumerate(LAST)}
    items.sort(key=lambda item: rank.get(item.path.name, len(FIRST)))  # stable: the order within a module stays
