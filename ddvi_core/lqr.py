"""Model-based optimal state feedback: the algebraic Riccati equation and Kleinman's policy
iteration.  Both return K (m,n) and P (n,n) for u = -K x minimising the integral of
x^T Q x + u^T R u."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import scipy.linalg
from numpy.typing import ArrayLike, NDArray

__all__ = [
    "LQRResult",
    "NotStabilisingError",
    "policy_iteration",
    "relative_gain_error",
    "solve_lqr",
]


class NotStabilisingError(ValueError):
    """A gain leaves an eigenvalue of A - B K outside the open left half-plane."""


@dataclass(frozen=True)
class LQRResult:
    K: NDArray[np.float64]
    P: NDArray[np.float64]
    closed_loop_eigenvalues: NDArray[np.complex128]
    iterations: int = 0
    history: list[float] = field(default_factory=list)  # |P_k - P_{k-1}| per iteration


def _closed_loop_check(A: NDArray, B: NDArray, K: NDArray, what: str) -> NDArray:
    eig = np.linalg.eigvals(A - B @ K)
    worst = eig[np.argmax(eig.real)]
    if worst.real >= 0.0:
        raise NotStabilisingError(
            f"{what}: closed loop A - B K has eigenvalue {worst:.6g} with non-negative real "
            "part; (A, B) is probably not stabilisable or (A, sqrt(Q)) not detectable "
            "(run `ddvi check` on the system)"
        )
    return eig


def relative_gain_error(K: ArrayLike, K_ref: ArrayLike) -> float:
    """|K - K_ref| / |K_ref| in Frobenius norms: how far a gain is from a reference gain.

    K and K_ref (m,n) of one shape, finite.  A zero K_ref gives inf (0.0 when K is zero too):
    no gain is relatively close to nothing.  Raises ValueError on shapes that differ or a
    non-finite entry.
    """
    K, K_ref = np.asarray(K, dtype=float), np.asarray(K_ref, dtype=float)
    if K.shape != K_ref.shape:
        raise ValueError(f"relative_gain_error: K is {K.shape}, K_ref {K_ref.shape}")
    if not (np.all(np.isfinite(K)) and np.all(np.isfinite(K_ref))):
        raise ValueError("relative_gain_error: a gain has a non-finite entry")
    diff, ref = float(np.linalg.norm(K - K_ref)), float(np.linalg.norm(K_ref))
    if ref == 0.0:
        return 0.0 if diff == 0.0 else math.inf
    return diff / ref


def solve_lqr(A: ArrayLike, B: ArrayLike, Q: ArrayLike, R: ArrayLike) -> LQRResult:
    """Stabilising solution of A^T P + P A + Q - P B R^-1 B^T P = 0 and K = R^-1 B^T P.

    A (n,n), B (n,m), Q (n,n), R (m,m).  scipy's solver can return a non-stabilising P
    without complaint, so the closed loop is checked and NotStabilisingError raised.
    """
    A, B, Q, R = (np.asarray(M, dtype=float) for M in (A, B, Q, R))
    try:
        P = scipy.linalg.solve_continuous_are(A, B, Q, R)
    except (np.linalg.LinAlgError, ValueError) as exc:
        raise NotStabilisingError(f"Riccati equation has no stabilising solution: {exc}") from None
    P = (P + P.T) / 2
    K = np.linalg.solve(R, B.T @ P)
    eig = _closed_loop_check(A, B, K, "Riccati solution")
    return LQRResult(K=K, P=P, closed_loop_eigenvalues=eig)


def policy_iteration(
    A: ArrayLike,
    B: ArrayLike,
    Q: ArrayLike,
    R: ArrayLike,
    K0: ArrayLike | None = None,
    tol: float = 1e-10,
    max_iterations: int = 100,
) -> LQRResult:
    """Kleinman's policy iteration from a stabilising K0 (zero by default, which requires A
    Hurwitz).  Each step solves the Lyapunov equation
    (A - B K)^T P + P (A - B K) + Q + K^T R K = 0 and sets K = R^-1 B^T P.
    Stops when |P_k - P_{k-1}| <= tol |P_k|.
    """
    A, B, Q, R = (np.asarray(M, dtype=float) for M in (A, B, Q, R))
    K = np.zeros((B.shape[1], A.shape[0])) if K0 is None else np.asarray(K0, dtype=float)
    _closed_loop_check(A, B, K, "policy iteration needs a stabilising initial gain K0, but K0")
    P_prev = None
    history: list[float] = []
    for k in range(1, max_iterations + 1):
        Ak = A - B @ K
        P = scipy.linalg.solve_continuous_lyapunov(Ak.T, -(Q + K.T @ R @ K))
        P = (P + P.T) / 2
        K = np.linalg.solve(R, B.T @ P)
        if P_prev is not None:
            history.append(float(np.linalg.norm(P - P_prev)))
            if history[-1] <= tol * np.linalg.norm(P):
                eig = _closed_loop_check(A, B, K, "policy iteration")
                return LQRResult(K, P, eig, iterations=k, history=history)
        P_prev = P
    eig = _closed_loop_check(A, B, K, "policy iteration")
    return LQRResult(K, P, eig, iterations=max_iterations, history=history)
