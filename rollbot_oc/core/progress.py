"""Progress displays of long work (tqdm, on stderr; a widget in notebooks).

Every long computation takes ``show_progress``: True shows its progress,
False hides it, None (the default) shows it only where stderr is a terminal
or in a notebook, so that scripts, pipes and ``--json`` output stay clean
(tqdm's ``disable=None``).

* ``progress_bar``: a tqdm bar under that rule (loops: sweeps, the demo's steps);
* ``working``: a line that says what one long call is doing and for how long
  (planning, where the work cannot report its own progress);
* ``RunProgress``: the ``progress`` callback of a closed-loop run
  (``simulate(progress=...)``): simulated time against the duration and the
  stops reached so far.
"""

from __future__ import annotations

import threading
from contextlib import contextmanager

from tqdm.auto import tqdm

__all__ = ["progress_bar", "working", "RunProgress"]


def progress_bar(iterable=None, show: bool | None = None, **options) -> tqdm:
    """A tqdm bar on stderr, shown as ``show`` says (None: only on a terminal or in a notebook).

    Parameters
    ----------
    iterable : iterable, optional
        What to loop over (as for ``tqdm``).
    show : bool or None
        True shows the bar, False hides it, None shows it only where stderr is
        a terminal or in a notebook.
    **options
        Passed to ``tqdm`` (``desc``, ``total``, ``unit``, ...).
    """
    return tqdm(iterable, disable=None if show is None else not show, **options)


@contextmanager
def working(desc: str, show: bool | None = None, tick: float = 0.5):
    """Show ``desc: <elapsed time>`` while the block runs, refreshed every ``tick`` seconds.

    For one long call that reports no progress of its own (planning).  The
    clock is refreshed by a daemon thread while the call lets it run, and
    stops with the block.
    """
    bar = progress_bar(show=show, desc=desc, total=None, bar_format="{desc}: {elapsed}", leave=None)
    if bar.disable:
        yield
        return
    done = threading.Event()

    def refresh():
        while not done.wait(tick):
            bar.refresh()

    clock = threading.Thread(target=refresh, daemon=True)
    clock.start()
    try:
        yield
    finally:
        done.set()
        clock.join()
        bar.close()


class RunProgress:
    """The progress of a closed-loop run: simulated time against its duration, and the stops reached.

    Pass the object as ``simulate(progress=...)``; ``finish`` shows where the
    run ended.  Usable as a context manager, which closes the bar.

    Parameters
    ----------
    duration : float
        Length of the run, s.
    desc : str
        What runs (``"n_shape pid"``).
    stops : int
        Stops of the mission (0 for a circle: no stop count is shown).
    show : bool or None
        As for ``progress_bar``.
    """

    FORMAT = "{desc}: {percentage:3.0f}%|{bar}| {n:.1f}/{total:.1f} s simulated [{elapsed}<{remaining}{postfix}]"

    def __init__(self, duration: float, desc: str, stops: int = 0, show: bool | None = None):
        self.stops = stops
        self.bar = progress_bar(show=show, desc=desc, total=float(duration), bar_format=self.FORMAT, leave=None,
                                postfix=f"stops 0/{stops}" if stops else None)

    @property
    def shown(self) -> bool:
        """Whether the bar is displayed (a hidden one need not be called)."""
        return not self.bar.disable

    def _postfix(self, reached: int):
        if self.stops:
            self.bar.set_postfix_str(f"stops {reached}/{self.stops}", refresh=False)

    def __call__(self, t: float, info: dict) -> None:
        """Record the simulated time ``t``, s, and the controller's report ``info`` (its ``stops``)."""
        self._postfix(len(info.get("stops", ())))
        self.bar.update(t - self.bar.n)

    def finish(self, t: float, info: dict) -> None:
        """The run ended at ``t``, s (early when the mission was done or the robot lost contact)."""
        self(t, info)
        self.bar.refresh()

    def close(self) -> None:
        self.bar.close()

    def __enter__(self) -> "RunProgress":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
