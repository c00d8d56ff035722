"""Calling a CasADi Function many times from Python with little overhead.

``casadi.Function.__call__`` converts every argument to a DM and every result
back, about 20 to 40 us per call; for a 100 Hz loop over minutes of simulated
time that is most of the cost.  ``FastFunction`` binds preallocated numpy
buffers to the Function once (``Function.buffer``) and then only copies
numbers in and out.
"""

from __future__ import annotations

import functools
import threading

import casadi as ca
import numpy as np

__all__ = ["FastFunction", "fast_map"]


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


def fast_map(fun: ca.Function, n: int, shared: tuple[int, ...] = ()) -> FastFunction:
    """``fun`` mapped over ``n`` columns (``Function.map``, serial) as a ``FastFunction``, built once and cached.

    Parameters
    ----------
    fun : casadi.Function
        The Function of one column (a long-lived object: the cache keys on it).
    n : int
        Number of columns.
    shared : tuple of int
        Inputs given once for all columns (not repeated), e.g. the parameters.

    Notes
    -----
    Inputs and outputs are the mapped Function's: input ``i`` of ``fun`` with
    shape ``(r, c)`` takes ``n`` blocks, so an ``(n, r)`` C-ordered array of
    column vectors can be passed as it is (raveled); output ``j`` of shape
    ``(r, c)`` comes back flat and ``reshape(n, c, r)`` gives the blocks
    transposed (structural zeros included).  Each thread gets its own buffers.
    """
    return _fast_map(fun, n, tuple(shared), threading.get_ident())


@functools.lru_cache(maxsize=256)
def _fast_map(fun: ca.Function, n: int, shared: tuple[int, ...], thread: int) -> FastFunction:
    inputs = fun.sx_in() if fun.is_a("SXFunction") else fun.mx_in()
    dense = ca.Function(fun.name(), inputs, [ca.densify(out) for out in fun.call(inputs)])  # buffers are dense
    return FastFunction(dense.map(f"{fun.name()}_map{n}", "serial", n, list(shared), []))
