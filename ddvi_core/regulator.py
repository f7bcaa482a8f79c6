"""The regulator equations (the paper's Problem 1) and the feedforward gain.

    X E = A X + B U + D,   0 = C X + F,   minimising Tr(X^T Qbar X + U^T Rbar U).

Solved exactly as an equality-constrained least-squares problem in the vectorised unknowns,
which covers both the unique case (m = p) and the under-determined one (m > p).
"""

from __future__ import annotations

import numpy as np
import scipy.linalg
from numpy.typing import ArrayLike, NDArray

from ddvi_core.vec import unvec, vec

__all__ = [
    "InfeasibleError",
    "feedforward_gain",
    "solve_equality_constrained_lstsq",
    "solve_regulator_equations",
]


class InfeasibleError(ValueError):
    """The regulator equations have no solution (the rank condition fails)."""


def _sqrt_psd(M: NDArray) -> NDArray:
    w, V = np.linalg.eigh((M + M.T) / 2)
    return (V * np.sqrt(np.clip(w, 0.0, None))) @ V.T


def solve_equality_constrained_lstsq(
    M: NDArray, c: NDArray, G: NDArray, g: NDArray, rtol: float = 1e-9
) -> tuple[NDArray, float]:
    """Minimise |M z - c| subject to G z = g.

    M : (k, N), c : (k,), G : (r, N), g : (r,).  Returns (z (N,), relative constraint
    residual).  Raises InfeasibleError when G z = g has no solution.  Among several minimisers
    the one of least norm is returned.
    """
    z_p, *_ = np.linalg.lstsq(G, g, rcond=None)
    scale = max(float(np.linalg.norm(g)), float(np.linalg.norm(G, 2)) * float(np.linalg.norm(z_p)))
    residual = float(np.linalg.norm(G @ z_p - g)) / (scale if scale > 0 else 1.0)
    if residual > rtol:
        raise InfeasibleError(f"constraints are inconsistent (relative residual {residual:.2e})")
    Z = scipy.linalg.null_space(G, rcond=rtol)
    if Z.shape[1] == 0:
        return z_p, residual
    w, *_ = np.linalg.lstsq(M @ Z, c - M @ z_p, rcond=None)
    return z_p + Z @ w, residual


def solve_regulator_equations(
    A: ArrayLike,
    B: ArrayLike,
    C: ArrayLike,
    D: ArrayLike,
    E: ArrayLike,
    F: ArrayLike,
    Qbar: ArrayLike | None = None,
    Rbar: ArrayLike | None = None,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Minimum-trace solution (X*, U*) of the regulator equations.

    A (n,n), B (n,m), C (p,n), D (n,q), E (q,q), F (p,q); Qbar (n,n) and Rbar (m,m) positive
    definite, identity by default.  Returns X* (n,q) and U* (m,q).  Raises InfeasibleError,
    naming the offending eigenvalue of E, when no solution exists.
    """
    A, B, C, D, E, F = (np.asarray(M, dtype=float) for M in (A, B, C, D, E, F))
    n, m, p, q = A.shape[0], B.shape[1], C.shape[0], E.shape[0]
    Qbar = np.eye(n) if Qbar is None else np.asarray(Qbar, dtype=float)
    Rbar = np.eye(m) if Rbar is None else np.asarray(Rbar, dtype=float)
    In, Iq = np.eye(n), np.eye(q)
    # vec(X E) - vec(A X) - vec(B U) = vec(D);  vec(C X) = -vec(F)
    G = np.block(
        [
            [np.kron(E.T, In) - np.kron(Iq, A), -np.kron(Iq, B)],
            [np.kron(Iq, C), np.zeros((p * q, m * q))],
        ]
    )
    g = np.concatenate([vec(D), -vec(F)])
    M = scipy.linalg.block_diag(np.kron(Iq, _sqrt_psd(Qbar)), np.kron(Iq, _sqrt_psd(Rbar)))
    # balance the two blocks of equations so that units do not decide feasibility
    row_scale = np.linalg.norm(G, axis=1)
    row_scale[row_scale == 0] = 1.0
    try:
        z, _ = solve_equality_constrained_lstsq(
            M, np.zeros(M.shape[0]), G / row_scale[:, None], g / row_scale
        )
    except InfeasibleError:
        raise InfeasibleError(_explain_infeasible(A, B, C, E)) from None
    return unvec(z[: n * q], (n, q)), unvec(z[n * q :], (m, q))


def _explain_infeasible(A: NDArray, B: NDArray, C: NDArray, E: NDArray) -> str:
    n, m, p = A.shape[0], B.shape[1], C.shape[0]
    from ddvi_core.problem import numerical_rank

    parts = []
    for lam in np.unique(np.round(np.linalg.eigvals(E), 12)):
        Mr = np.block([[A - lam * np.eye(n), B], [C, np.zeros((p, m))]])
        r = numerical_rank(Mr)
        if r < n + p:
            parts.append(f"eigenvalue {lam:.6g} of E gives rank {r}, needed n + p = {n + p}")
    why = "; ".join(parts) or "the equations are inconsistent"
    return f"regulator equations X E = A X + B U + D, C X + F = 0 have no solution: {why}"


def feedforward_gain(K: ArrayLike, X: ArrayLike, U: ArrayLike) -> NDArray[np.float64]:
    """L = U + K X, the feedforward gain of u = -K x + L v.  K (m,n), X (n,q), U (m,q)."""
    return np.asarray(U, dtype=float) + np.asarray(K, dtype=float) @ np.asarray(X, dtype=float)
