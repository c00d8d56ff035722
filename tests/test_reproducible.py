"""The BLAS-free helpers against numpy's BLAS and against exact arithmetic (the closed loop's bit-for-bit check
across BLAS kernels is ``test_nmpc.test_the_same_seed_gives_the_same_json_under_every_blas_kernel``)."""

import math
from fractions import Fraction

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from rollbot_oc.core.reproducible import dot, matmul, norm, solve, unit

finite = st.floats(-1e3, 1e3, allow_nan=False, allow_infinity=False)


@given(st.integers(1, 12).flatmap(lambda n: st.tuples(arrays(float, n, elements=finite),
                                                      arrays(float, n, elements=finite))))
def test_dot_sums_the_rounded_products_exactly_once_rounded(pair):
    a, b = pair
    exact = sum(Fraction(x * y) for x, y in zip(a.tolist(), b.tolist()))  # each product rounded, the sum exact
    assert dot(a, b) == float(exact)
    assert dot(a, b) == pytest.approx(float(a @ b), rel=1e-12, abs=1e-9)


@given(arrays(float, st.integers(1, 12), elements=finite.filter(lambda x: x == 0 or abs(x) > 1e-100)),
       st.integers(-600, 600))
def test_norm_agrees_with_numpy_and_unit_has_norm_one(v, power):
    """(numpy's norm squares its entries, and loses tiny ones; ``norm`` is exact under scaling by powers of 2.)"""
    assert norm(v * 2.0**power) == norm(v) * 2.0**power
    assert norm(v) == pytest.approx(float(np.linalg.norm(v)), rel=1e-15, abs=0.0)
    if norm(v) > 1e-6:
        assert norm(unit(v)) == pytest.approx(1.0, abs=4e-16)
        assert np.allclose(unit(v) * norm(v), v, rtol=1e-15, atol=1e-12)


@given(st.integers(1, 5), st.integers(1, 5), st.integers(1, 5), st.data())
def test_matmul_agrees_with_numpy(n, k, m, data):
    a = data.draw(arrays(float, (n, k), elements=finite))
    b = data.draw(arrays(float, (k, m), elements=finite))
    scale = np.abs(a) @ np.abs(b)  # the rounding error of a sum is relative to the sum of the magnitudes
    assert np.all(np.abs(matmul(a, b) - a @ b) <= 1e-14 * scale + 1e-300)
    assert np.all(np.abs(matmul(a, b[:, 0]) - a @ b[:, 0]) <= 1e-14 * scale[:, 0] + 1e-300)


def test_matmul_refuses_shapes_that_do_not_align():
    with pytest.raises(ValueError, match=r"shapes \(2, 3\) and \(2,\)"):
        matmul(np.ones((2, 3)), np.ones(2))


@given(st.integers(1, 5), st.data())
def test_solve_inverts_a_well_conditioned_matrix(n, data):
    """``a`` symmetric positive definite with its eigenvalues in [1, 10], as the filters' innovation matrices."""
    q, _ = np.linalg.qr(data.draw(arrays(float, (n, n), elements=st.floats(-1, 1))) + 3 * np.eye(n))
    a = q @ np.diag(data.draw(arrays(float, n, elements=st.floats(1, 10)))) @ q.T
    b = data.draw(arrays(float, (n, 2), elements=finite))
    x = solve(a, b)
    assert x.shape == b.shape and solve(a, b[:, 0]).shape == (n,)
    assert np.allclose(a @ x, b, rtol=0, atol=1e-12 * (1 + np.abs(b).max()))
    assert np.allclose(x, np.linalg.solve(a, b), rtol=1e-11, atol=1e-11 * (1 + np.abs(b).max()))


def test_the_helpers_return_plain_floats_where_numpy_returns_scalars():
    assert type(dot([1.0, 2.0], [3.0, 4.0])) is float and dot([1.0, 2.0], [3.0, 4.0]) == 11.0
    assert type(norm([3.0, 4.0])) is float and norm([3.0, 4.0]) == 5.0
    assert norm([1e200, 1e200]) == pytest.approx(math.sqrt(2) * 1e200)  # no overflow of the squares
