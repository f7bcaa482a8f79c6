"""The regression of data-driven value iteration (the paper's Algorithm 2), step by step.

Pure functions on arrays, in the iteration's scaled units (see :mod:`ddvi_core.value_iteration`):
the interval integrals scaled, the X_j at which xbar_j = x - X_j v is taken, Theta_j and
delta_j with their columns equilibrated, the maps pinv(Theta_j) delta_j from vecs(P) to the
unknowns, and what the converged P implies: K, B, D, S(X_j) and the regulator (X*, U*).
:func:`ddvi_core.learning.learn_from_data` strings them together; with N = n + q and rho
intervals, the unknowns of Theta_j are [vecs(H) (n(n+1)/2); vec(K) (mn); vec((D - S(X_j))^T P)
(qn)].
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg
from numpy.typing import ArrayLike, NDArray

from ddvi_core.regulator import solve_equality_constrained_lstsq
from ddvi_core.vec import triangle_size, unvec, vec, vecs, vecv

__all__ = [
    "EquilibratedTheta",
    "RiccatiMap",
    "ScaledIntervals",
    "equilibrated_thetas",
    "exostate_offsets",
    "implied_matrices",
    "implied_plant",
    "rank_report",
    "regression_maps",
    "regression_solution",
    "scale_intervals",
    "solve_output_regulation",
    "theta",
]


@dataclass(frozen=True)
class ScaledIntervals:
    """Interval integrals in the iteration's units (tau = w0 t, x = S x_s).

    W (rho, N, N), G (rho, N, m), w_start (rho, N), w_end (rho, N); ``increments`` (rho, N, N)
    the matrices D_l whose contraction with T^T P T is the value increment of interval l (a
    windowed collector's, :class:`ddvi_core.learning.IntervalCollector`), or None: the
    increment is taken between the end points."""

    W: NDArray[np.float64]
    G: NDArray[np.float64]
    w_start: NDArray[np.float64]
    w_end: NDArray[np.float64]
    increments: NDArray[np.float64] | None = None


def scale_intervals(
    W: NDArray,
    G: NDArray,
    w_start: NDArray,
    w_end: NDArray,
    w0: float,
    S: NDArray,
    increments: NDArray | None = None,
) -> ScaledIntervals:
    """Scale the integrals W (rho, N, N), G (rho, N, m), end points (rho, N) and increments
    (rho, N, N, or None) to tau = w0 t and w = diag(S, I_q) w_s, for state scales S (n,):
    dt = dtau / w0, so integrals gain w0; an increment (a window's derivative times dt) does
    not."""
    q = W.shape[1] - S.size
    sw = np.concatenate([S, np.ones(q)])
    outer = np.outer(sw, sw)[None]
    D = None if increments is None else increments / outer
    return ScaledIntervals(w0 * W / outer, w0 * G / sw[None, :, None], w_start / sw, w_end / sw, D)


def exostate_offsets(
    C: ArrayLike | None, F: ArrayLike | None, S: NDArray, n: int, q: int
) -> list[NDArray]:
    """The X_j (n, q) of Algorithm 2 in scaled coordinates, for C (p, n), F (p, q) and state
    scales S (n,): X_0 = 0, X_1 = -pinv(C_s) F, then a basis of {X : C_s X = 0}.  With no
    exostate (q = 0), the single X_0 (n, 0)."""
    if not q:
        return [np.zeros((n, 0))]
    C_s = np.asarray(C, dtype=float) * S[None, :]
    F_s = np.asarray(F, dtype=float)
    X_list = [np.zeros((n, q)), -np.linalg.pinv(C_s) @ F_s]
    basis = scipy.linalg.null_space(np.kron(np.eye(q), C_s))
    return X_list + [unvec(b, (n, q)) for b in basis.T]


def theta(
    n: int, m: int, q: int, T: NDArray, R: NDArray, data: ScaledIntervals
) -> tuple[NDArray, NDArray]:
    """Theta_j (rho, n(n+1)/2 + (m+q)n) and delta_j (rho, n(n+1)/2) for xbar = T w, with
    T (n, N) and R (m, m)."""
    W, G, ws, we = data.W, data.G, data.w_start, data.w_end
    rows, cols = np.triu_indices(n)
    M = np.einsum("ia,lab,jb->lij", T, W, T)
    I_x = M[:, rows, cols]
    Gu = np.einsum("ia,lak->lik", T, G).reshape(len(W), n * m)
    Gv = np.einsum("ia,lak->lik", T, W[:, :, n:]).reshape(len(W), n * q)
    if data.increments is None:
        delta = vecv(we @ T.T) - vecv(ws @ T.T)
    else:  # tr(T D T^T P) = vecs(P) . (T D T^T)[rows, cols]
        delta = np.einsum("ia,lab,jb->lij", T, data.increments, T)[:, rows, cols]
    Theta = np.hstack([I_x, 2.0 * Gu @ np.kron(np.eye(n), R), 2.0 * Gv])
    return Theta, delta


@dataclass(frozen=True)
class EquilibratedTheta:
    """Theta_j (rho, cols), delta_j (rho, n(n+1)/2) and Theta_j's column norms (cols,), ones
    where a column is zero: Theta_j / norms is the equilibrated regression."""

    Theta: NDArray[np.float64]
    delta: NDArray[np.float64]
    norms: NDArray[np.float64]

    @property
    def scaled(self) -> NDArray[np.float64]:
        return self.Theta / self.norms


def equilibrated_thetas(
    n: int,
    m: int,
    q: int,
    X_list: list[NDArray],
    X_off: NDArray | float,
    R_s: NDArray,
    data: ScaledIntervals,
) -> list[EquilibratedTheta]:
    """Theta_j for each X_j (n, q) of ``X_list``, taken about X_j + X_off.

    The columns are equilibrated because the unknowns (H, K, (D - S)^T P) differ by many
    orders of magnitude, and an unequilibrated least-squares solve loses them to round-off."""
    out = []
    for X in X_list:
        Th, d = theta(n, m, q, np.hstack([np.eye(n), -(X + X_off)]), R_s, data)
        norms = np.linalg.norm(Th, axis=0)
        out.append(EquilibratedTheta(Th, d, np.where(norms > 0, norms, 1.0)))
    return out


def rank_report(
    Theta: NDArray, n: int, m: int, q: int, rank: int, needed: int, rho: int, rtol: float
) -> str:
    """What a rank-deficient Theta (rho, needed) lacks and what to do about it."""
    parts = [f"data rank {rank} of {needed} needed (n(n+1)/2 + (m+q)n with n={n}, m={m}, q={q})"]
    if rho < needed:
        parts.append(f"only {rho} intervals were collected; at least {needed} are needed")
    *_, Vt = np.linalg.svd(Theta, full_matrices=True)
    null = Vt[rank:]
    t = triangle_size(n)
    blocks = {
        "the state's quadratic terms (x excitation)": slice(0, t),
        "the input terms (u excitation: add exploration noise)": slice(t, t + m * n),
        "the exostate terms (v excitation: the exosystem signals or their product with x)": slice(
            t + m * n, t + (m + q) * n
        ),
    }
    missing = [
        name
        for name, sl in blocks.items()
        if null.size and float(np.max(np.linalg.norm(null[:, sl], axis=1))) > 0.3
    ]
    if missing:
        parts.append("not excited: " + "; ".join(missing))
    parts.append(
        "collect more intervals with richer exploration (at least 3 sinusoids of "
        "distinct frequencies) before learning"
    )
    return "; ".join(parts)


def regression_maps(thetas: list[EquilibratedTheta]) -> list[NDArray]:
    """pinv(Theta_j) delta_j (cols, n(n+1)/2) for each j, computed once (the paper's Remark):
    each maps vecs(P) to the unknowns, so an iteration is one matrix-vector product."""
    return [
        np.linalg.lstsq(th.scaled, th.delta, rcond=None)[0] / th.norms[:, None] for th in thetas
    ]


class RiccatiMap:
    """P (n, n) -> (H (n, n), K (m, n)) read from the regression map of X_0 (cols, n(n+1)/2):
    H estimates A^T P + P A and K estimates R^-1 B^T P, without A or B."""

    def __init__(self, map0: NDArray, n: int, m: int) -> None:
        t = triangle_size(n)
        self.n, self.m = n, m
        self.rows, self.cols = np.triu_indices(n)
        diagonal = self.rows == self.cols
        self.weights = np.where(diagonal, 1.0, 2.0)
        self.H_map = map0[:t] * np.where(diagonal, 1.0, 0.5)[:, None]
        self.K_map = map0[t : t + m * n]

    def __call__(self, P: NDArray) -> tuple[NDArray, NDArray]:
        n, rows, cols = self.n, self.rows, self.cols
        p = self.weights * P[rows, cols]  # vecs(P)
        H = np.zeros((n, n))
        H[rows, cols] = self.H_map @ p
        return H + np.triu(H, 1).T, (self.K_map @ p).reshape(n, self.m).T


def implied_plant(riccati_map: RiccatiMap, R_s: NDArray) -> tuple[NDArray, NDArray]:
    """(A_s (n, n), B_s (n, m)) that the data's map implies: H(e_i e_i^T) = a_i e_i^T +
    e_i a_i^T for a_i the i-th row of A (so its column i holds a_i, twice on the diagonal) and
    K(I) = R^-1 B^T.  Only the step rule and the stopping rule use them (the closed loop's
    eigenvalues), never the iteration itself."""
    n = riccati_map.n
    A = np.empty((n, n))
    for i in range(n):
        E = np.zeros((n, n))
        E[i, i] = 1.0
        col = riccati_map(E)[0][:, i].copy()
        col[i] *= 0.5
        A[i] = col
    B = (R_s @ riccati_map(np.eye(n))[1]).T
    return A, B


def regression_solution(
    map0: NDArray, th0: EquilibratedTheta, P_s: NDArray, n: int, m: int
) -> tuple[NDArray, float]:
    """K_s (m, n) at the converged P_s (n, n), and the relative least-squares residual of
    Theta_0's regression there."""
    t, mn = triangle_size(n), m * n
    p_star = vecs(P_s)
    theta0 = map0 @ p_star
    K_s = unvec(theta0[t : t + mn], (m, n))
    target = th0.delta @ p_star
    residual = float(
        np.linalg.norm(th0.Theta @ theta0 - target) / max(np.linalg.norm(target), 1e-300)
    )
    return K_s, residual


def implied_matrices(
    maps: list[NDArray], P_s: NDArray, K_s: NDArray, R_s: NDArray, n: int, m: int, q: int
) -> tuple[NDArray, NDArray, list[NDArray]]:
    """What the data imply at P_s (n, n): B_s (n, m) = P^-1 K^T R, D_s (n, q) and
    S(X_j) = D - P^-1 M_j^T (n, q) for each map, M_j = (D - S(X_j))^T P (q, n)."""
    t, mn = triangle_size(n), m * n
    Pinv = np.linalg.inv(P_s)
    B_s = Pinv @ K_s.T @ R_s
    if not q:
        return B_s, np.zeros((n, 0)), []
    p_star = vecs(P_s)
    Ms = [unvec((mp @ p_star)[t + mn :], (q, n)) for mp in maps]
    D_s = Pinv @ Ms[0].T
    S_X = [Pinv @ (Ms[0] - Mj).T for Mj in Ms]
    return B_s, D_s, S_X


def solve_output_regulation(
    X_list: list[NDArray],
    S_X: list[NDArray],
    B_s: NDArray,
    D_s: NDArray,
    S: NDArray,
    Qbar: ArrayLike | None,
    Rbar: ArrayLike | None,
) -> tuple[NDArray, NDArray]:
    """(X_s (n, q), U_s (m, q)) by the paper's Problem 1, from the data's S(X_j).

    X = X_1 + sum z_j X_j (j >= 2) subject to S(X) = B U + D, minimising
    |Qbar^1/2 X|^2 + |Rbar^1/2 U|^2 with X weighted in SI units (states scaled by S (n,))."""
    n, q = X_list[0].shape
    m = B_s.shape[1]
    Iq = np.eye(q)
    Qb = np.eye(n) if Qbar is None else np.asarray(Qbar, dtype=float)
    Rb = np.eye(m) if Rbar is None else np.asarray(Rbar, dtype=float)
    free = len(X_list) > 2
    Nx = np.column_stack([vec(X) for X in X_list[2:]]) if free else np.zeros((n * q, 0))
    Ns = np.column_stack([vec(Sx) for Sx in S_X[2:]]) if free else np.zeros((n * q, 0))
    h = Nx.shape[1]
    Gc = np.hstack([Ns, -np.kron(Iq, B_s)])
    gc = vec(D_s) - vec(S_X[1])
    Wx = np.kron(Iq, scipy.linalg.sqrtm(Qb).real * S[None, :])
    Mo = scipy.linalg.block_diag(Wx @ Nx, np.kron(Iq, scipy.linalg.sqrtm(Rb).real))
    co = np.concatenate([-Wx @ vec(X_list[1]), np.zeros(m * q)])
    z, _ = solve_equality_constrained_lstsq(Mo, co, Gc, gc, rtol=1e-6)
    X_s = X_list[1] + (unvec(Nx @ z[:h], (n, q)) if h else 0.0)
    return X_s, unvec(z[h:], (m, q))
