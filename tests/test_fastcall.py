"""Mapped low-overhead calls: the same numbers as CasADi's own map, dense blocks, one set of buffers per thread."""

import threading

import casadi as ca
import numpy as np

from rollbot_oc.core.fastcall import fast_map


def test_fast_map_matches_function_map():
    x, p = ca.SX.sym("x", 2), ca.SX.sym("p", 3)
    out = ca.SX.zeros(2, 2)  # a sparse output: the block comes back dense, zeros included
    out[0, 0], out[1, 0] = x[0] * p[0], ca.sin(x[1]) + p[2]
    fun = ca.Function("f", [x, p], [out, ca.dot(x, x)])
    X, P = np.random.default_rng(0).normal(size=(5, 2)), np.array([2.0, -1.0, 0.5])
    blocks, norms = fast_map(fun, 5, shared=(1,))(X.ravel(), P)
    reference = fun.map(5)(X.T, P)
    expected = np.stack(np.split(np.array(reference[0]), 5, axis=1))  # (5, 2, 2)
    assert np.array_equal(blocks.reshape(5, 2, 2).transpose(0, 2, 1), expected)
    assert expected[0, 0, 1] == 0 and expected[0, 0, 0] != 0
    assert np.array_equal(norms, np.array(reference[1]).ravel())
    assert fast_map(fun, 5, shared=(1,)) is fast_map(fun, 5, shared=(1,))  # built once
    other = []
    thread = threading.Thread(target=lambda: other.append(fast_map(fun, 5, shared=(1,))))
    thread.start()
    thread.join()
    assert other[0] is not fast_map(fun, 5, shared=(1,))  # buffers are never shared between threads
