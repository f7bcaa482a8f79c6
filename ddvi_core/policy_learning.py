"""Data-driven policy iteration and the hybrid of value and policy iteration, on the same
regression as the paper's Algorithm 2.

The regression of :mod:`ddvi_core.regression` gives, from data alone, two linear maps of P:
H(P) = A^T P + P A and K(P) = R^-1 B^T P.  Kleinman's policy iteration on data (Jiang and
Jiang, Automatica 2012) evaluates a gain K_k by solving, for P_k,

    H(P) - K_k^T R K(P) - K(P)^T R K_k + Q + K_k^T R K_k = 0

(the Lyapunov equation of A - B K_k, here a linear system of n(n+1)/2 equations in vecs(P)
assembled from the maps), then improves it: K_{k+1} = K(P_k).  It converges quadratically
from a stabilising K0, and the evaluation says whether a gain stabilises: its P is positive
definite then (Q > 0, or (A, Q^1/2) observable), indefinite or undefined otherwise.

The hybrid needs no stabilising K0: it starts with policy iteration when K0 stabilises the
closed loop the data imply (its eigenvalues, and its evaluation positive definite); otherwise
it runs value iteration until the gain's estimated relative error
(:func:`ddvi_core.continuation.gain_error`) is at most HYBRID_SWITCH, where Newton's method
converges, and then policy iteration.  A positive definite evaluation alone does not tell a
stabilising gain on data: on a plant with a pole at zero (a motor's shaft angle) the data's
map puts it a hair to the right (+1.7e-8 on the DC motor's), whose Lyapunov equation is near
singular, and its solution came out positive definite, with |P| ~ 1e11 and a first policy
gain 1e7 too large, which policy iteration then only halves per step.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
from numpy.typing import NDArray

from ddvi_core.continuation import basis_images
from ddvi_core.regression import RiccatiMap, implied_plant
from ddvi_core.value_iteration import (
    LEARNING_METHODS,
    ClosedLoop,
    IterationSettings,
    value_iteration_loop,
)

__all__ = [
    "LEARNING_METHODS",
    "IterationSettings",
    "basis_images",
    "is_positive_definite",
    "iterate",
    "policy_evaluation",
    "policy_iteration_loop",
]

HYBRID_SWITCH = 0.1
"""The hybrid's value iteration hands over to policy iteration at this estimated relative
error of the gain."""

LoopResult = tuple[NDArray, NDArray, int, int, bool, float, NDArray, str]


def policy_evaluation(
    images: tuple[NDArray, NDArray], Q_s: NDArray, R_s: NDArray, K: NDArray
) -> NDArray | None:
    """P (n, n) solving the data's Lyapunov equation of the gain K (m, n) (module docstring)
    from the maps' ``images`` (:func:`basis_images`), or None when that equation is singular
    (a closed-loop eigenvalue pair sums to zero)."""
    n = Q_s.shape[0]
    rows, cols = np.triu_indices(n)
    H_b, K_b = images
    cross = np.einsum("ik,ekj->eij", K.T @ R_s, K_b)
    M = (H_b - cross - cross.transpose(0, 2, 1))[:, rows, cols].T
    rhs = -(Q_s + K.T @ R_s @ K)[rows, cols]
    with np.errstate(all="ignore"):
        try:
            p = np.linalg.solve(M, rhs)
        except np.linalg.LinAlgError:
            return None
    if not np.all(np.isfinite(p)):
        return None
    P = np.zeros((n, n))
    P[rows, cols] = p
    return P + np.triu(P, 1).T


def is_positive_definite(P: NDArray | None) -> bool:
    return P is not None and bool(np.linalg.eigvalsh(P)[0] > 0)


def policy_iteration_loop(
    riccati_map: RiccatiMap,
    Q_s: NDArray,
    R_s: NDArray,
    K0_s: NDArray,
    tol: float,
    max_iterations: int,
    images: tuple[NDArray, NDArray] | None = None,
    advice: str = "give a stabilising learning.K0 or use the hybrid method",
) -> LoopResult:
    """Kleinman's iteration on the data's maps from the gain K0_s (m, n), stopping when
    |P_k - P_{k-1}| <= tol |P_k|; ``advice`` ends the message when a gain does not
    stabilise.  Returns the tuple of
    :func:`ddvi_core.value_iteration.value_iteration_loop`; history holds |P_k - P_{k-1}|."""
    images = basis_images(riccati_map) if images is None else images
    K, P_prev = K0_s, None
    history = []
    for k in range(1, max_iterations + 1):
        P = policy_evaluation(images, Q_s, R_s, K)
        if not is_positive_definite(P):
            why = (
                "the gain does not stabilise the closed loop the data imply (its policy "
                f"evaluation's P is not positive definite) at policy iteration {k}: {advice}"
            )
            return (
                P_prev if P_prev is not None else Q_s,
                K,
                k,
                0,
                False,
                math.inf,
                np.array(history),
                why,
            )
        K = riccati_map(P)[1]
        if P_prev is not None:
            history.append(float(np.linalg.norm(P - P_prev)))
            if history[-1] <= tol * float(np.linalg.norm(P)):
                return P, K, k, 0, True, history[-1], np.array(history), ""
        P_prev = P
    why = f"|P_k - P_k-1| / |P_k| = {history[-1] / np.linalg.norm(P_prev):.3g} > tol {tol:g}"
    return P_prev, K, max_iterations, 0, False, history[-1], np.array(history), why


def _stabilises(
    images: tuple[NDArray, NDArray], Q_s: NDArray, R_s: NDArray, K: NDArray, closed_loop: ClosedLoop
) -> bool:
    """K stabilises the closed loop the data imply, and its evaluation is positive definite."""
    return bool(np.max(closed_loop(K).real) < 0) and is_positive_definite(
        policy_evaluation(images, Q_s, R_s, K)
    )


def _hybrid(
    riccati_map: RiccatiMap,
    Q_s: NDArray,
    R_s: NDArray,
    P0_s: NDArray,
    K0_s: NDArray,
    settings: IterationSettings,
    closed_loop: ClosedLoop,
) -> LoopResult:
    """Value iteration until the gain's estimated relative error is at most HYBRID_SWITCH,
    then policy iteration from that gain (from K0_s at once if it stabilises)."""
    images = basis_images(riccati_map)
    K, vi_iterations, resets = K0_s, 0, 0
    if not _stabilises(images, Q_s, R_s, K0_s, closed_loop):
        near_settings = replace(
            settings, method="vi", tol=max(settings.tol, HYBRID_SWITCH), rule="relative", memory=0
        )
        P, K, vi_iterations, resets, near, _, _, why = value_iteration_loop(
            riccati_map, Q_s, R_s, P0_s, near_settings, closed_loop
        )
        if not near:
            why = f"value iteration did not bring the gain near enough for policy iteration: {why}"
            return P, K, vi_iterations, resets, False, math.inf, np.zeros(0), why
        K = riccati_map(P)[1]
    advice = "the data's map is not the Lyapunov map of a plant; use value iteration (ddvi)"
    budget = max(1, settings.max_iterations - vi_iterations)
    out = policy_iteration_loop(riccati_map, Q_s, R_s, K, settings.tol, budget, images, advice)
    return (*out[:2], out[2] + vi_iterations, resets, *out[4:])


def iterate(
    riccati_map: RiccatiMap,
    Q_s: NDArray,
    R_s: NDArray,
    P0_s: NDArray,
    K0_s: NDArray,
    settings: IterationSettings,
) -> LoopResult:
    """The learner's iteration as ``settings`` say, in scaled units: value iteration from
    P0_s (n, n), policy iteration from K0_s (m, n), or the hybrid.  The step and stopping
    rules read the closed loop's eigenvalues off the matrices the data's map implies
    (:func:`ddvi_core.regression.implied_plant`), never A or B.
    """
    method = settings.method
    A_d, B_d = implied_plant(riccati_map, R_s)

    def closed_loop(K_s: NDArray) -> NDArray:
        return np.linalg.eigvals(A_d - B_d @ K_s)

    if method == "vi":
        return value_iteration_loop(riccati_map, Q_s, R_s, P0_s, settings, closed_loop)
    if method == "pi":
        return policy_iteration_loop(
            riccati_map, Q_s, R_s, K0_s, settings.tol, settings.max_iterations
        )
    if method == "hybrid":
        return _hybrid(riccati_map, Q_s, R_s, P0_s, K0_s, settings, closed_loop)
    raise ValueError(f"method must be one of {', '.join(LEARNING_METHODS)}, got {method!r}")
