"""The toolkit's errors: user mistakes, numerical failures and interruptions.

Three families, each with its exit status in the ``rollbot-oc`` command
(see ``rollbot_oc.app.cli``):

* ``ConfigError`` (a ``ValueError``): a mistake of the user's, in an argument,
  a file or a value.  Its message names the file or option, the value and the
  valid range.  Exit status 2, raised before any long computation.
* ``NumericalFailure`` (a ``RuntimeError``) and its ``NotConverged``: a
  computation that ran but did not produce a usable result (a solver that did
  not converge, carrying its status).  Exit status 1.
* ``Interrupted`` (a ``KeyboardInterrupt``): Ctrl-C noticed by code that caught
  it, such as IPOPT inside CasADi.  Exit status 130.

Any other exception, a plain ``ValueError`` from deep inside numerical code
included, is an internal error (a bug): exit status 3.
"""

from __future__ import annotations

import signal
import threading
from contextlib import contextmanager

__all__ = ["ConfigError", "NumericalFailure", "NotConverged", "Interrupted", "interruptible", "check_interrupted"]


class ConfigError(ValueError):
    """A user mistake: a bad argument, file or value.

    The message names where the value came from (file and key, or option),
    the value and the valid range, in one line.
    """


class NumericalFailure(RuntimeError):
    """A computation that did not produce a usable result.

    Parameters
    ----------
    message : str
        What failed, in one line.
    status : str
        The solver's or the computation's status (for example IPOPT's
        ``return_status``).
    result : object, optional
        The partial result, for inspection.
    """

    def __init__(self, message: str, status: str = "failed", result=None):
        super().__init__(message)
        self.status = status
        self.result = result


class NotConverged(NumericalFailure):
    """A solver that did not converge; ``status`` is its return status.

    Parameters
    ----------
    what : str
        What was being solved (for example ``"rest-to-rest plan to [0, 1.2]"``).
    status : str
        The solver's return status.
    result : object, optional
        The failed solution (a ``Plan`` for the optimal-control problems).
    """

    def __init__(self, what: str, status: str, result=None):
        super().__init__(f"{what}: the solver did not converge (status {status})", status, result)


class Interrupted(KeyboardInterrupt):
    """Ctrl-C during a computation that caught it (IPOPT reports it as a failed solve)."""


_caught: list[list[int]] = []  # one record per active ``interruptible`` block (innermost last)


@contextmanager
def interruptible(what: str = "computation"):
    """Turn a Ctrl-C that a solver swallows into ``Interrupted``.

    CasADi checks for Ctrl-C itself while it computes and then either returns
    a failed status (IPOPT: ``NonIpopt_Exception_Thrown``) or raises a
    ``RuntimeError``, so the interrupt looks like a numerical failure.  Inside
    this block a Ctrl-C is recorded (and still stops the solver, or plain
    Python code at once).  When the block ends, by any exception or normally,
    a recorded Ctrl-C raises ``Interrupted``.  Code that catches solver errors
    and carries on calls ``check_interrupted()`` right after each solver call,
    so that it stops at once.  Outside the main thread (where signal handlers
    cannot be set) the block does nothing.

    Examples
    --------
    >>> with interruptible("rest-to-rest plan"):        # doctest: +SKIP
    ...     solution = solver(x0=guess, lbg=lbg, ubg=ubg)
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    caught: list[int] = []

    def handler(signum, frame):
        caught.append(signum)
        raise KeyboardInterrupt  # stops plain Python code at once; a CasADi solver catches it and stops

    previous = signal.signal(signal.SIGINT, handler)
    _caught.append(caught)
    try:
        yield
    except KeyboardInterrupt:
        raise
    except Exception as exc:
        if caught:  # the solver turned the Ctrl-C into an error
            raise Interrupted(f"{what} interrupted") from exc
        raise
    finally:
        _caught.remove(caught)
        signal.signal(signal.SIGINT, signal.default_int_handler if previous is None else previous)
    if caught:
        raise Interrupted(f"{what} interrupted")


def check_interrupted(what: str = "computation") -> None:
    """Raise ``Interrupted`` if Ctrl-C was pressed inside the active ``interruptible`` blocks.

    Call it right after a solver call whose failure is caught and tolerated
    (a failed solve that falls back), so that a Ctrl-C the solver swallowed
    stops the computation at once instead of counting as a failed solve.
    """
    if any(_caught):
        raise Interrupted(f"{what} interrupted")
