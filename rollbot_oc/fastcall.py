"""Calling a CasADi Function many times from Python with little overhead.

``casadi.Function.__call__`` converts every argument to a DM and every result
back, about 20 to 40 us per call; for a 100 Hz loop over minutes of simulated
time that is most of the cost.  ``FastFunction`` binds preallocated numpy
buffers to the Function once (``Function.buffer``) and then only copies
numbers in and out.
"""

from __future__ import annotations

import casadi as ca
import numpy as np

__all__ = ["FastFunction"]


class FastFunction:
    """A CasADi Function evaluated through preallocated numpy buffers.

    Parameters
    ----------
    fun : casadi.Function
        A Function with dense inputs and outputs.

    Notes
    -----
    The arrays returned by a call are the Function's output buffers: they are
    overwritten by the next call, so copy what must be kept.
    """

    def __init__(self, fun: ca.Function):
        self.fun = fun
        self._inputs = [np.zeros(fun.nnz_in(i)) for i in range(fun.n_in())]
        self._outputs = [np.zeros(fun.nnz_out(i)) for i in range(fun.n_out())]
        self._buffer, self._evaluate = fun.buffer()
        for i, arr in enumerate(self._inputs):
            self._buffer.set_arg(i, memoryview(arr))
        for i, arr in enumerate(self._outputs):
            self._buffer.set_res(i, memoryview(arr))

    def __call__(self, *args) -> tuple[np.ndarray, ...]:
        """Evaluate with ``args`` (numbers or arrays in column-major order of each input)."""
        for buf, arg in zip(self._inputs, args):
            buf[:] = np.ravel(arg, order="F") if np.ndim(arg) > 1 else arg
        self._evaluate()
        return tuple(self._outputs)
