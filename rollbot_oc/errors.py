"""The toolkit's errors: user mistakes, numerical failures and interruptions.

Three families, each with its exit status in the ``rollbot-oc`` command
(see ``rollbot_oc.cli``):

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

__all__ = ["ConfigError", "NumericalFailure", "NotConverged", "Interrupted", "interruptible"]


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


@contextmanager
def interruptible(what: str = "computation"):
    """Turn a Ctrl-C that a solver swallows into ``Interrupted``.

    CasADi's solvers (IPOPT, the QP solvers) check for Ctrl-C themselves and
    then return a failed status (``NonIpopt_Exception_Thrown``) instead of
    raising.  Inside this block a Ctrl-C is recorded (and still stops the
    solver); when the block ends, ``Interrupted`` is raised, so the interrupt
    is never mistaken for a numerical failure.  Outside the main thread (where
    signal handlers cannot be set) the block does nothing.

    Examples
    --------
    >>> with interruptible("rest-to-rest plan"):        # doctest: +SKIP
    ...     solution = solver(x0=guess, lbg=lbg, ubg=ubg)
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    caught = []

    def handler(signum, frame):
        caught.append(signum)
        raise KeyboardInterrupt  # makes the solver stop (it catches this) or stops plain Python code

    previous = signal.signal(signal.SIGINT, handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, signal.default_int_handler if previous is None else previous)
    if caught:
        raise Interrupted(f"{what} interrupted")
