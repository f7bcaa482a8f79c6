"""Vectorisation operators: vec/unvec, vecs/unvecs, vecv (paper's Notation section)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ddvi_core.vec import triangle_size, unvec, unvecs, vec, vecs, vecv


def _sym(rng: np.random.Generator, n: int) -> np.ndarray:
    M = rng.standard_normal((n, n))
    return M + M.T


def test_vec_is_column_stacking() -> None:
    A = np.array([[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]])
    np.testing.assert_array_equal(vec(A), [1.0, 4.0, 2.0, 5.0, 3.0, 6.0])
    np.testing.assert_array_equal(unvec(vec(A), (2, 3)), A)


@settings(max_examples=40, deadline=None)
@given(st.integers(1, 5), st.integers(1, 5), st.integers(1, 5), st.integers(0, 2**31 - 1))
def test_vec_kronecker_identity(n: int, k: int, m: int, seed: int) -> None:
    rng = np.random.default_rng(seed)
    A = rng.standard_normal((n, k))
    X = rng.standard_normal((k, m))
    B = rng.standard_normal((m, 3))
    np.testing.assert_allclose(vec(A @ X @ B), np.kron(B.T, A) @ vec(X), rtol=1e-12, atol=1e-12)
    np.testing.assert_array_equal(unvec(vec(X), X.shape), X)


def test_vecs_layout_and_round_trip() -> None:
    P = np.array([[1.0, 2.0, 3.0], [2.0, 4.0, 5.0], [3.0, 5.0, 6.0]])
    np.testing.assert_array_equal(vecs(P), [1.0, 4.0, 6.0, 4.0, 10.0, 6.0])
    np.testing.assert_array_equal(unvecs(vecs(P)), P)
    np.testing.assert_array_equal(unvecs(vecs(P), 3), P)


@settings(max_examples=50, deadline=None)
@given(st.integers(1, 7), st.integers(0, 2**31 - 1))
def test_vecv_vecs_quadratic_form(n: int, seed: int) -> None:
    rng = np.random.default_rng(seed)
    P = _sym(rng, n)
    x = rng.standard_normal(n)
    assert vecs(P).shape == (triangle_size(n),)
    assert vecv(x) @ vecs(P) == pytest.approx(x @ P @ x, rel=1e-12, abs=1e-12)
    np.testing.assert_allclose(unvecs(vecs(P)), P, rtol=0, atol=1e-14)


def test_vecv_batch_matches_rows() -> None:
    rng = np.random.default_rng(3)
    Xb = rng.standard_normal((9, 4))
    V = vecv(Xb)
    assert V.shape == (9, triangle_size(4))
    for i in range(9):
        np.testing.assert_array_equal(V[i], vecv(Xb[i]))
    P = _sym(rng, 4)
    np.testing.assert_allclose(V @ vecs(P), np.einsum("ni,ij,nj->n", Xb, P, Xb), rtol=1e-12)


def test_vecv_entries() -> None:
    np.testing.assert_array_equal(vecv([2.0, 3.0, 5.0]), [4.0, 6.0, 10.0, 9.0, 15.0, 25.0])


def test_triangle_size() -> None:
    assert [triangle_size(n) for n in range(5)] == [0, 1, 3, 6, 10]
    with pytest.raises(ValueError):
        triangle_size(-1)


@pytest.mark.parametrize(
    ("fn", "arg"),
    [
        (vec, np.zeros(3)),
        (vec, np.zeros((2, 2, 2))),
        (vecs, np.zeros((2, 3))),
        (vecs, np.zeros(4)),
        (vecs, np.array([[1.0, 2.0], [0.0, 1.0]])),  # not symmetric
        (unvecs, np.zeros((2, 3))),
        (unvecs, np.zeros(4)),  # 4 is not a triangle number
        (vecv, np.zeros((2, 2, 2))),
        (vecv, np.float64(1.0)),
    ],
)
def test_bad_shapes_raise(fn, arg) -> None:
    with pytest.raises(ValueError):
        fn(arg)


def test_unvec_bad_size_and_unvecs_wrong_n() -> None:
    with pytest.raises(ValueError):
        unvec(np.zeros(5), (2, 3))
    with pytest.raises(ValueError):
        unvec(np.zeros((2, 3)), (2, 3))
    with pytest.raises(ValueError):
        unvecs(np.zeros(6), 4)
