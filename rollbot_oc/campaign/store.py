"""A campaign's results on disk: part files written as cases finish, one table at the end.

Layout of the output folder::

    parts/part-000000.parquet ...   rows of finished cases, a few at a time (each file written whole)
    parts/.lock                     held while a campaign runs in this folder
    results.parquet                 the table: one row per case of the campaign, in case order

* Rows are buffered and written as a part file (temporary file, then
  rename) every ``flush_rows`` rows or ``flush_seconds`` seconds, and when
  the run ends, is interrupted or fails: at most the cases still running are
  lost on a crash, never a finished one that was written.
* ``finished()`` reads every part: a campaign started again in the same
  folder skips the cases whose id has a row (whatever their status), except
  rows of cases the infrastructure lost (a worker that died:
  ``WORKER_FAILURE``), which run again.  Parts of cases that are no longer
  in the campaign (another spec written to the same folder) are kept but left
  out of the table.
* ``table()`` builds the table from the rows of the campaign's cases, in
  case order, the columns in a fixed order (``columns``), so the same rows
  give the same table however they were batched into parts.
* Only one campaign runs in a folder at a time (an advisory lock on
  ``parts/.lock``; a second run is refused with a ``ConfigError``).
"""

from __future__ import annotations

import io
import json
import time
from pathlib import Path

from rollbot_oc.core.errors import ConfigError
from rollbot_oc.core.outputs import atomic_write_bytes

__all__ = ["ResultStore", "columns", "RUN_COLUMNS", "WORKER_FAILURE", "CASE_COLUMNS", "OUTCOME_COLUMNS"]

CASE_COLUMNS = ("case", "case_id", "seed")
OUTCOME_COLUMNS = ("status", "error")
# provenance of the computation, not its result: they differ between runs of the same campaign
RUN_COLUMNS = ("code", "wall_time", "worker")
WORKER_FAILURE = "worker failure: "  # the start of the error of a case the infrastructure lost (run again)

try:
    import fcntl
except ImportError:  # not POSIX: no lock
    fcntl = None


def columns(kind, rows: list[dict]) -> list[str]:
    """The table's columns: case, inputs, metrics (declared, then any others in order of appearance), outcome, run."""
    fixed = list(CASE_COLUMNS) + list(kind.input_columns) + list(kind.metric_columns)
    extra = dict.fromkeys(key for row in rows for key in row
                          if key not in fixed and key not in OUTCOME_COLUMNS + RUN_COLUMNS)
    return fixed + list(extra) + list(OUTCOME_COLUMNS) + list(RUN_COLUMNS)


class ResultStore:
    """The part files and the table of a campaign in an output folder (see the module doc).

    Parameters
    ----------
    folder : OutputFolder
        The campaign's output folder (checked and created).
    flush_rows : int
        Write a part file once this many rows are waiting.
    flush_seconds : float
        ... or once the oldest waiting row is this old, s.

    Raises
    ------
    ConfigError
        If another campaign is running in the folder.
    """

    def __init__(self, folder, flush_rows: int = 64, flush_seconds: float = 2.0):
        self.folder = folder
        self.parts = Path(folder.path) / "parts"
        self.parts.mkdir(exist_ok=True)
        self.flush_rows, self.flush_seconds = flush_rows, flush_seconds
        self._waiting: list[dict] = []
        self._since = None
        self._lock = open(self.parts / ".lock", "a")
        if fcntl is not None:
            try:
                fcntl.flock(self._lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError:
                self._lock.close()
                raise ConfigError(f"--out {folder.path}: another campaign is running in this folder") from None
        self._next = 1 + max((int(p.stem.split("-")[1]) for p in self._part_files()), default=-1)

    def _part_files(self) -> list[Path]:
        return sorted(p for p in self.parts.glob("part-*.parquet") if p.stem.split("-")[1].isdigit())

    def rows(self) -> dict[str, dict]:
        """Rows on disk by case id (the last written wins), the cases the infrastructure lost included."""
        import pyarrow.parquet as pq  # optional extra [scale]: only the tables need it

        rows = {}
        for path in self._part_files():
            for row in pq.read_table(path).to_pylist():
                rows[row["case_id"]] = row
        return rows

    def finished(self) -> dict[str, dict]:
        """Rows on disk by case id (the last written wins), without the cases the infrastructure lost."""
        return {key: row for key, row in self.rows().items()
                if not str(row.get("error") or "").startswith(WORKER_FAILURE)}

    def add(self, row: dict) -> None:
        """Keep a finished case's row; write a part file if enough are waiting or the oldest is old enough."""
        self._waiting.append(row)
        self._since = self._since or time.monotonic()
        if len(self._waiting) >= self.flush_rows or time.monotonic() - self._since >= self.flush_seconds:
            self.flush()

    def flush(self) -> None:
        """Write the waiting rows as one part file (whole: temporary file, then rename)."""
        if not self._waiting:
            return
        atomic_write_bytes(self.parts / f"part-{self._next:06d}.parquet", _parquet(self._waiting))
        self._next += 1
        self._waiting, self._since = [], None

    def close(self) -> None:
        """Write what is waiting and release the folder."""
        try:
            self.flush()
        finally:
            if not self._lock.closed:
                self._lock.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def table(self, kind, cases):
        """The table of ``cases`` (every one must have a row), as a ``pandas.DataFrame`` in case order.

        The case index is the campaign's (a row written under another spec takes its new position).  A case the
        infrastructure lost is an ``error`` row starting with ``WORKER_FAILURE`` (run again on the next start).
        """
        import pandas as pd  # optional extra [scale], as above

        found = self.rows()
        rows = []
        for case in cases:
            row = dict(found[case.id])
            row["case"] = case.index
            rows.append(row)
        return pd.DataFrame.from_records(rows, columns=columns(kind, rows))

    def write_table(self, table) -> Path:
        """Write the table as ``results.parquet`` (whole)."""
        return atomic_write_bytes(self.folder / "results.parquet",
                                  _parquet(table.to_dict("records"), list(table.columns)))


def _parquet(rows: list[dict], names: list[str] | None = None) -> bytes:
    """Parquet bytes of plain rows; a column whose values have no common type is stored as JSON text."""
    import pyarrow as pa  # optional extra [scale], as above
    import pyarrow.parquet as pq  # optional extra [scale], as above

    names = names or list(dict.fromkeys(key for row in rows for key in row))
    arrays = {}
    for name in names:
        values = [_none_for_nan(row.get(name)) for row in rows]
        try:
            arrays[name] = pa.array(values)
        except (pa.ArrowInvalid, pa.ArrowTypeError):
            arrays[name] = pa.array([None if v is None else json.dumps(v) for v in values], pa.string())
    buffer = io.BytesIO()
    pq.write_table(pa.table(arrays), buffer)
    return buffer.getvalue()


def _none_for_nan(value):
    """pandas' missing values (NaN in a column of objects) as None; lists and plain values as they are."""
    if isinstance(value, float) and value != value:
        return None
    if hasattr(value, "tolist"):  # numpy values from a DataFrame
        return value.tolist()
    return value

