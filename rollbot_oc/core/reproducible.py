"""Small linear algebra that gives the same bits on every CPU.

numpy hands ``a @ b``, ``numpy.dot``, ``numpy.linalg.norm`` without ``axis`` and ``numpy.linalg.solve`` to
OpenBLAS, whose wheels choose their kernels when they load, by CPU: an AVX-512 machine, an AVX2 one and an old
SSE3 one round the same product differently in the last bit (fused multiply-adds, other summation orders). In a
closed loop such bits grow into different runs (another plan, another time to the last stop). The simulation,
the controllers and their metrics therefore use these helpers instead, built only from elementwise IEEE
operations, Python's ``math.fsum`` and ``math.hypot``, and CasADi's own QR (no BLAS). They are for the small
vectors and matrices of one control period (a few to a few tens of entries); offline analysis (eigenvalues, fits
to recorded data) keeps LAPACK. CasADi's IPOPT and HPIPM bring their own BLAS, built for one fixed kernel.

``tests/test_nmpc.py`` runs a closed loop under two OpenBLAS kernels and compares the JSON.
"""

from __future__ import annotations

import math

import casadi as ca
import numpy as np

__all__ = ["dot", "norm", "matmul", "solve", "unit"]


def dot(a, b) -> float:
    """Inner product of two vectors of one length: the rounded products summed exactly, then rounded once
    (``math.fsum``)."""
    return math.fsum(np.multiply(np.asarray(a, float).ravel(), np.asarray(b, float).ravel()).tolist())


def norm(v) -> float:
    """Euclidean norm of a vector (``math.hypot``: exact to within one rounding, the same on every CPU)."""
    return math.hypot(*np.asarray(v, float).ravel().tolist())


def unit(v) -> np.ndarray:
    """``v`` divided by its ``norm`` (a new float array)."""
    v = np.array(v, dtype=float)
    return v / norm(v)


def matmul(a, b) -> np.ndarray:
    """Matrix product ``a @ b`` of 2-D arrays, or of a 2-D array and a vector, summed in a fixed order
    (elementwise products reduced over the inner axis, no BLAS)."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    if a.ndim != 2 or b.ndim not in (1, 2) or a.shape[1] != b.shape[0]:
        raise ValueError(f"matmul: shapes {a.shape} and {b.shape} do not align")
    if b.ndim == 1:
        return matmul(a, b[:, None])[:, 0]
    return (a[:, :, None] * b[None, :, :]).sum(axis=1)


def solve(a, b) -> np.ndarray:
    """``x`` with ``a @ x = b`` for a small square nonsingular ``a`` (CasADi's dense QR, no LAPACK); ``b`` a
    vector or a matrix, and ``x`` of its shape."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    x = np.array(ca.solve(ca.DM(a), ca.DM(b.reshape(len(b), -1))), dtype=float)
    return x.reshape(b.shape)
