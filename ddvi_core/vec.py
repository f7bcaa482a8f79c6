"""Vectorisation operators of the paper's Notation section.

``vec`` stacks columns; ``vecs`` takes the upper triangle of a symmetric matrix row by row with
the off-diagonal entries doubled; ``vecv`` takes the distinct products of a vector's entries in
the same order.  Together they satisfy ``vecv(x) @ vecs(P) == x @ P @ x``, the identity that
turns a quadratic value function into a linear regression.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["triangle_size", "unvec", "unvecs", "vec", "vecs", "vecv"]


def triangle_size(n: int) -> int:
    """Number of distinct entries of an n-by-n symmetric matrix, n(n+1)/2."""
    if n < 0:
        raise ValueError(f"n must be non-negative, got {n}")
    return n * (n + 1) // 2


def vec(A: ArrayLike) -> NDArray[np.float64]:
    """Column stacking of a matrix.

    A : (n, m) -> (n*m,), ``vec(A)[j*n + i] == A[i, j]``.
    """
    A = np.asarray(A, dtype=float)
    if A.ndim != 2:
        raise ValueError(f"vec expects a matrix, got an array of shape {A.shape}")
    return A.reshape(-1, order="F")


def unvec(a: ArrayLike, shape: tuple[int, int]) -> NDArray[np.float64]:
    """Inverse of :func:`vec`: (n*m,) -> (n, m)."""
    a = np.asarray(a, dtype=float)
    if a.ndim != 1 or a.size != shape[0] * shape[1]:
        raise ValueError(f"unvec: cannot reshape an array of shape {a.shape} to {shape}")
    return a.reshape(shape, order="F")


def _check_square_symmetric(P: NDArray[np.float64], name: str) -> None:
    if P.ndim != 2 or P.shape[0] != P.shape[1]:
        raise ValueError(f"{name} expects a square matrix, got shape {P.shape}")
    scale = max(1.0, float(np.max(np.abs(P)))) if P.size else 1.0
    if not np.allclose(P, P.T, rtol=0.0, atol=1e-10 * scale):
        raise ValueError(f"{name} expects a symmetric matrix")


def vecs(P: ArrayLike) -> NDArray[np.float64]:
    """Upper triangle of a symmetric matrix, row by row, off-diagonals doubled.

    P : (n, n) symmetric -> (n(n+1)/2,) ``[p11, 2p12, ..., 2p1n, p22, 2p23, ..., pnn]``.
    """
    P = np.asarray(P, dtype=float)
    _check_square_symmetric(P, "vecs")
    rows, cols = np.triu_indices(P.shape[0])
    weights = np.where(rows == cols, 1.0, 2.0)
    return weights * P[rows, cols]


def unvecs(p: ArrayLike, n: int | None = None) -> NDArray[np.float64]:
    """Inverse of :func:`vecs`: (n(n+1)/2,) -> (n, n) symmetric."""
    p = np.asarray(p, dtype=float)
    if p.ndim != 1:
        raise ValueError(f"unvecs expects a vector, got shape {p.shape}")
    if n is None:
        n = round(float((np.sqrt(8 * p.size + 1) - 1) / 2))
    if triangle_size(n) != p.size:
        raise ValueError(f"unvecs: length {p.size} is not n(n+1)/2 for n = {n}")
    rows, cols = np.triu_indices(n)
    P = np.zeros((n, n))
    P[rows, cols] = np.where(rows == cols, p, p / 2.0)
    return P + np.triu(P, 1).T


def vecv(x: ArrayLike) -> NDArray[np.float64]:
    """Distinct products of a vector's entries, ``[x1^2, x1 x2, ..., x1 xn, x2^2, ..., xn^2]``.

    x : (n,) -> (n(n+1)/2,); or a batch (N, n) -> (N, n(n+1)/2), one row per vector.
    """
    x = np.asarray(x, dtype=float)
    if x.ndim not in (1, 2):
        raise ValueError(f"vecv expects a vector or a batch of vectors, got shape {x.shape}")
    rows, cols = np.triu_indices(x.shape[-1])
    return x[..., rows] * x[..., cols]
