"""A minimal text progress bar for long loops (sweeps, the demo), in terminals and notebooks alike."""

from __future__ import annotations

import sys
import time

__all__ = ["progress"]


def progress(items, label: str = "", enabled: bool = True, stream=None, width: int = 30):
    """Yield from ``items`` while drawing ``[#####     ] k/n label (elapsed s)`` on ``stream`` (stderr).

    Parameters
    ----------
    items : iterable with a length
    label : str
        What is being done.
    enabled : bool
        False yields silently.
    stream : file, optional
        Where to draw (default ``sys.stderr``).
    width : int
        Characters in the bar.
    """
    items = list(items)
    stream = stream or sys.stderr
    total, start = len(items), time.perf_counter()
    for k, item in enumerate(items):
        if enabled:
            done = int(width * k / max(total, 1))
            stream.write(f"\r[{'#' * done}{' ' * (width - done)}] {k}/{total} {label} "
                         f"({time.perf_counter() - start:.0f} s)")
            stream.flush()
        yield item
    if enabled:
        stream.write(f"\r[{'#' * width}] {total}/{total} {label} ({time.perf_counter() - start:.0f} s)\n")
        stream.flush()
