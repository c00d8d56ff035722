"""Where a campaign's cases run: in this process, on a local Dask cluster, or on an existing one.

* ``workers=1`` (and no scheduler): in this process, one case after the
  other, no Dask at all (for debugging: breakpoints and tracebacks work);
* ``workers=N`` or by default: a ``dask.distributed.LocalCluster`` of ``N``
  worker processes (default: this machine's cores), one thread each (CasADi
  holds the GIL), started here and closed at the end, on error and on
  Ctrl-C;
* ``scheduler="tcp://HOST:8786"``, or the environment variable
  ``DASK_SCHEDULER_ADDRESS`` when no number of workers is given: an existing cluster, whose workers must run the
  same ``rollbot_oc`` code as this process (checked: ``code_fingerprint``).

``execute`` runs one case wherever it is sent and returns its row; an
exception in the case becomes an ``error`` row.  A case the cluster loses (a
worker that died, a connection that broke) becomes an ``error`` row starting
with ``WORKER_FAILURE``, which a campaign started again runs again.
"""

from __future__ import annotations

import functools
import hashlib
import os
import socket
import time
from contextlib import contextmanager
from pathlib import Path

from rollbot_oc.campaign.case import Outcome, describe
from rollbot_oc.campaign.function import plain
from rollbot_oc.campaign.store import CASE_COLUMNS, OUTCOME_COLUMNS, RUN_COLUMNS, WORKER_FAILURE
from rollbot_oc.core.errors import ConfigError
import logging
import uuid

__all__ = ["execute", "executor", "check_workers", "code_fingerprint", "default_workers", "SCHEDULER_VARIABLE",
           "MAX_WORKERS"]

SCHEDULER_VARIABLE = "DASK_SCHEDULER_ADDRESS"
MAX_WORKERS = 1024


@functools.lru_cache(maxsize=1)
def code_fingerprint() -> str:
    """A hash (12 hex digits) of the source of the ``rollbot_oc`` package this process imports."""
    root = Path(__file__).resolve().parents[1]
    digest = hashlib.sha256()
    for path in sorted(root.rglob("*.py")):
        digest.update(str(path.relative_to(root)).encode() + b"\0" + path.read_bytes() + b"\0")
    return digest.hexdigest()[:12]


def execute(kind, case) -> dict:
    """Run one case of ``kind`` and return its table row (inputs, metrics, status, error, provenance)."""
    start = time.perf_counter()
    try:
        outcome = kind.run(dict(case.inputs), case.seed)
    except Exception as exc:  # a case's failure is its row, never lost (Ctrl-C and exits pass through)
        outcome = Outcome(error=describe(exc))
    row = {"case": case.index, "case_id": case.id, "seed": case.seed, **case.inputs}
    try:
        for source in (outcome.inputs, outcome.metrics):
            for key, value in source.items():
                if key in row or key in OUTCOME_COLUMNS + RUN_COLUMNS:
                    raise ValueError(f"the case's value {key!r} has the name of another column")
                row[key] = plain(value, key)
    except (TypeError, ValueError) as exc:
        row = {key: row[key] for key in CASE_COLUMNS + tuple(case.inputs)}
        outcome = Outcome(error=describe(exc))
    row.update(status=outcome.status, error=outcome.error or outcome.cause, code=code_fingerprint(),
               wall_time=time.perf_counter() - start, worker=f"{socket.gethostname()}:{os.getpid()}")
    return row


def lost_row(case, exc: BaseException) -> dict:
    """The row of a case the cluster lost (run again when the campaign starts again)."""
    return {"case": case.index, "case_id": case.id, "seed": case.seed, **case.inputs, "status": "error",
            "error": WORKER_FAILURE + describe(exc), "code": None, "wall_time": None, "worker": None}


def default_workers() -> int:
    """This machine's usable cores."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1


def check_workers(workers, scheduler) -> tuple[int | None, str | None]:
    """The number of local workers and the scheduler address, checked (``ConfigError`` naming the option).

    Returns ``(workers, None)`` for local work (``workers`` defaulting to
    this machine's cores) or ``(None, address)`` for an existing scheduler.
    """
    if workers is not None:
        if isinstance(workers, bool) or not isinstance(workers, int) or not 1 <= workers <= MAX_WORKERS:
            raise ConfigError(f"--workers {workers!r} is out of range: valid is a whole number in [1, {MAX_WORKERS}]")
        if scheduler:
            raise ConfigError(f"--workers {workers} and --scheduler {scheduler}: give one (the scheduler's cluster "
                              "has its own workers)")
    else:  # an explicit --workers runs locally whatever the environment says
        scheduler = scheduler or os.environ.get(SCHEDULER_VARIABLE) or None
    if scheduler is not None and not (isinstance(scheduler, str) and ":" in scheduler):
        raise ConfigError(f"--scheduler {scheduler!r} must be an address such as tcp://HOST:8786")
    return (None if scheduler else workers or default_workers()), scheduler


class _InProcess:
    """Cases one after the other in this process."""

    where = "in-process"
    workers = 1

    def __init__(self, kind):
        self.kind = kind

    def run(self, cases):
        for case in cases:
            yield execute(self.kind, case)


class _Dask:
    """Cases as Dask tasks on a client's cluster, rows as they finish."""

    def __init__(self, client, kind, where: str):
        self.client, self.kind, self.where = client, kind, where
        self.workers = len(client.nthreads())
        self._check_code()

    def _check_code(self):
        mine = code_fingerprint()
        theirs = self.client.run(code_fingerprint)
        different = {worker: code for worker, code in theirs.items() if code != mine}
        if different:
            worker, code = next(iter(different.items()))
            raise ConfigError(f"{self.where}: worker {worker} runs other rollbot_oc code (fingerprint {code}, here "
                              f"{mine}); install the same version on every worker (or set PYTHONPATH to the same "
                              "source tree)")

    def run(self, cases):

        from distributed import as_completed  # optional extra [scale]: only a run on Dask needs it

        kind = self.client.scatter(self.kind, broadcast=True, hash=False)
        token = uuid.uuid4().hex[:8]
        futures = {self.client.submit(execute, kind, case, key=f"case-{case.id}-{token}", pure=False): case
                   for case in cases}
        try:
            for future in as_completed(futures):
                try:
                    yield future.result()
                except Exception as exc:  # the cluster lost it (KilledWorker, a broken connection)
                    yield lost_row(futures[future], exc)
                future.release()
        finally:
            self.client.cancel(list(futures))


@contextmanager
def executor(kind, workers: int | None = None, scheduler: str | None = None):
    """The place the cases of ``kind`` run (see the module doc), closed when the block ends.

    Yields an object with ``run(cases)`` (an iterator over the rows as the
    cases finish), ``workers`` and ``where`` (a description).

    Raises
    ------
    ConfigError
        For a bad number of workers, both workers and a scheduler, a scheduler
        that cannot be reached, or workers that run other code.
    """
    workers, scheduler = check_workers(workers, scheduler)
    if workers == 1:
        yield _InProcess(kind)
        return
    try:
        from distributed import Client, LocalCluster  # optional extra [scale], as above
    except ImportError:
        raise ConfigError("running on Dask needs the extra 'scale': pip install 'rollbot_oc[scale]' "
                          "(or --workers 1 to run in this process)") from None

    if scheduler:
        try:
            client = Client(scheduler, timeout="20s")
        except (OSError, TimeoutError) as exc:
            raise ConfigError(f"--scheduler {scheduler}: cannot connect ({exc})") from None
        with client:
            yield _Dask(client, kind, f"Dask scheduler {scheduler}")
        return
    # the scheduler always serves HTTP (health, metrics; the dashboard with bokeh): on a free port of this host
    with LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address="127.0.0.1:0",
                      silence_logs=logging.ERROR) as cluster, Client(cluster) as client:
        yield _Dask(client, kind, f"local Dask cluster of {workers} worker processes")
