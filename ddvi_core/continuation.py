"""Value iteration with a linearly implicit step (pseudo-transient continuation), and the
Newton estimate of the gain's error that the relative stopping rule reads.

Value iteration follows the Riccati flow dP/dtau = F(P) = H(P) + Q - K(P)^T R K(P) from a
small P0 (H(P) = A^T P + P A and K(P) = R^-1 B^T P, from the model or from the data's
regression).  Its derivative at P is the Lyapunov operator of the current closed loop,
DF_P[X] = H(X) - K(X)^T R K - K^T R K(X), K = K(P); on symmetric X it is a t x t matrix M
(t = n(n+1)/2) assembled from the maps' images of a basis, once per iteration.

The implicit step (Kelley and Keyes' pseudo-transient continuation) is

    (I / eps - M) X = F(P),   P <- P + X.

For a small eps it is forward Euler, value iteration's own step; as eps grows it tends to the
Newton step M X = -F(P), which is Kleinman's policy iteration.  The step needs no stabilising
gain: while the current gain leaves an unstable mode mu (Re mu > 0) in M, eps stays below
1 / (2 Re mu), so I / eps - M keeps its eigenvalues in the right half-plane and the step moves
P along the flow (the unstable mode grows, as it does under the flow, until the gain
stabilises it); the flow from P0 >= 0 needs no stabilising gain either.  eps grows by at most
GROWTH per step, aiming at a change of P of STRIDE times its size (so it shrinks, by at most
SHRINK, after a longer change), and without bound as the steps vanish near the fixed point.  The
safeguard: a step that leaves the positive semidefinite cone is not taken and eps shrinks by
SHRINK (the exact flow never leaves the cone, and a short implicit step is close to it); a
step that leaves the bound B_r resets P to P0 with r + 1, as value iteration does.

The relative stopping rule's measure is the gain's error estimated by the Newton correction
X_N = -M^-1 F(P): |K(X_N)| / |K(P)| is |K - K*| / |K| to first order in |P - P*| (K* the
fixed point of the maps: the Riccati gain for a model, the data's for a regression).  It is
infinite while M has an eigenvalue with Re >= 0 (the gain does not stabilise).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from ddvi_core.convergence import (
    TRUST,
    euler_limit_of_modes,
    meets_tolerance,
    met_message,
    unconverged_message,
)

if TYPE_CHECKING:  # the settings' module imports this one
    from ddvi_core.value_iteration import IterationSettings

__all__ = [
    "GROWTH",
    "SHRINK",
    "STRIDE",
    "basis_images",
    "continuation_loop",
    "gain_error",
    "linearisation",
    "riccati_flow",
]

GROWTH = 10.0
"""The step grows at most this much from one iteration to the next."""

STRIDE = 1.0
"""The step aims at changing P by this fraction of itself (a longer change is allowed once: the
next step is shorter)."""

SHRINK = 0.25
"""A step that leaves the cone is retried this much shorter."""

RiccatiMap = Callable[[NDArray], tuple[NDArray, NDArray]]
Images = tuple[NDArray, NDArray]
LoopResult = tuple[NDArray, NDArray, int, int, bool, float, NDArray, str]


def basis_images(riccati_map: RiccatiMap, n: int | None = None) -> Images:
    """(H(E_l) (t, n, n), K(E_l) (t, m, n)) for the basis E_l of symmetric matrices in vecs's
    upper-triangle order (t = n(n+1)/2; n defaults to ``riccati_map.n``): the maps once, so
    the derivative at any P is one contraction."""
    n = riccati_map.n if n is None else n
    Hs, Ks = [], []
    for i, j in zip(*np.triu_indices(n), strict=True):
        E = np.zeros((n, n))
        E[i, j] = E[j, i] = 1.0
        H, KE = riccati_map(E)
        Hs.append(H)
        Ks.append(KE)
    return np.array(Hs), np.array(Ks)


def riccati_flow(
    riccati_map: RiccatiMap, Q_s: NDArray, R_s: NDArray, P: NDArray
) -> tuple[NDArray, NDArray]:
    """(F(P) (n, n), K (m, n)) at P (n, n): the flow H(P) + Q - K^T R K, symmetrised against
    round-off, and the gain K = K(P), from the maps."""
    H, K = riccati_map(P)
    F = H + Q_s - K.T @ R_s @ K
    return (F + F.T) * 0.5, K


def linearisation(images: Images, R_s: NDArray, K: NDArray) -> NDArray:
    """M (t, t): the derivative of the Riccati map at a P whose gain is K (m, n), X ->
    H(X) - K(X)^T R K - K^T R K(X), on the coefficients of X in the basis of
    :func:`basis_images` (which are X's upper-triangle entries)."""
    H_b, K_b = images
    n = K.shape[1]
    rows, cols = np.triu_indices(n)
    cross = np.einsum("ik,ekj->eij", K.T @ R_s, K_b)
    return (H_b - cross - cross.transpose(0, 2, 1))[:, rows, cols].T


def _symmetric(p: NDArray, n: int) -> NDArray:
    rows, cols = np.triu_indices(n)
    X = np.zeros((n, n))
    X[rows, cols] = p
    return X + np.triu(X, 1).T


def gain_error(images: Images, M: NDArray, modes: NDArray, K: NDArray, F: NDArray) -> float:
    """The estimated |K - K*| / |K| from the Newton correction of the residual F (n, n) through
    M = :func:`linearisation` (its eigenvalues ``modes``); inf while a mode does not decay."""
    K_norm = float(np.linalg.norm(K))
    if not modes.size or float(np.max(modes.real)) >= 0 or K_norm == 0:
        return math.inf
    rows, cols = np.triu_indices(F.shape[0])
    try:
        p = np.linalg.solve(M, -F[rows, cols])
    except np.linalg.LinAlgError:
        return math.inf
    dK = np.einsum("l,lij->ij", p, images[1])
    error = float(np.linalg.norm(dK)) / K_norm
    return error if math.isfinite(error) else math.inf


def _first_step(modes: NDArray, gain: float, P_norm: float, residual: float) -> float:
    """``gain`` times forward Euler's stability limit on ``modes``, no longer than TRUST
    |P| / |F(P)|: the explicit step of value iteration, where the continuation starts."""
    eps = gain * euler_limit_of_modes(modes)
    if residual > 0:
        eps = min(eps, TRUST * max(P_norm, 1e-300) / residual)
    return eps if math.isfinite(eps) and eps > 0 else 1.0


def _cone_message(times: int, eps: float) -> str:
    return (
        f"P left the positive semidefinite cone {times} times in a row with steps down to "
        f"{eps:.3g}, shorter than value iteration's explicit step, which the exact Riccati flow "
        "never does: the data do not determine the map well enough (collect more, or richer, "
        "data)"
    )


@dataclass(frozen=True)
class _Continuation:
    """Where the implicit steps stand: the iterate P (n, n), the bound B_r's index r, the step
    eps (None until the first after a start from P0 is chosen) and that ``first`` step, the
    steps the safeguard rejected, and its cone rejections in a row at the first step's length
    or shorter (``cone_streak``)."""

    P: NDArray
    r: int = 0
    eps: float | None = None
    first: float = math.inf
    rejected: int = 0
    cone_streak: int = 0


def _with_step(
    state: _Continuation, modes: NDArray, gain: float, P_norm: float, residual: float
) -> _Continuation:
    """``state`` with this iteration's step: on a start from P0 :func:`_first_step` of M's
    ``modes`` (t,), and while a mode mu grows no longer than 1 / (2 Re mu), so that I / eps - M
    keeps its eigenvalues in the right half-plane."""
    if state.eps is None:
        first = _first_step(modes, gain, P_norm, residual)
        state = replace(state, eps=first, first=first)
    growing = float(np.max(modes.real)) if modes.size else 0.0
    if growing > 0:
        return replace(state, eps=min(state.eps, 0.5 / growing))
    return state


def _implicit_step(M: NDArray, F: NDArray, eps: float) -> NDArray:
    """X (n, n) solving (I / eps - M) X = F on the coefficients of symmetric matrices (M (t, t)
    from :func:`linearisation`, F (n, n) the flow); NaN when that system is singular."""
    n = F.shape[0]
    rows, cols = np.triu_indices(n)
    try:
        return _symmetric(np.linalg.solve(np.eye(rows.size) / eps - M, F[rows, cols]), n)
    except np.linalg.LinAlgError:
        return np.full((n, n), np.nan)


def _outside(P: NDArray, radius: float, psd_tol: float) -> str:
    """ "bound" when P (n, n) is finite and |P|_F > radius, "cone" when it is not finite or has
    an eigenvalue below -psd_tol |P|, else ""."""
    size = float(np.linalg.norm(P))
    if math.isfinite(size) and size > radius:
        return "bound"
    if not math.isfinite(size) or np.linalg.eigvalsh(P)[0] < -psd_tol * size:
        return "cone"
    return ""


def _restarted_from(state: _Continuation, P0_s: NDArray) -> _Continuation:
    """``state`` started again from P0_s (n, n) in the next bound, its first step to choose."""
    return replace(state, P=P0_s.copy(), r=state.r + 1, eps=None, cone_streak=0)


def _shortened(state: _Continuation) -> _Continuation:
    """``state`` after the safeguard rejected its step for leaving the cone: SHRINK times the
    step, and the streak grows while the step is no longer than the first."""
    streak = state.cone_streak + 1 if state.eps <= state.first else 0
    return replace(state, eps=state.eps * SHRINK, rejected=state.rejected + 1, cone_streak=streak)


def _advanced(state: _Continuation, P_new: NDArray, change: float, P_norm: float) -> _Continuation:
    """``state`` moved to P_new (n, n), a change of norm ``change`` from an iterate of norm
    ``P_norm``: the next step aims at a change of STRIDE |P|, growing by at most GROWTH and
    shrinking by at most SHRINK."""
    ratio = STRIDE * max(P_norm, 1e-300) / change if change > 0 else GROWTH
    eps = state.eps * min(GROWTH, max(ratio, SHRINK))
    return replace(state, P=P_new, eps=eps, cone_streak=0)


def continuation_loop(
    riccati_map: RiccatiMap,
    Q_s: NDArray,
    R_s: NDArray,
    P0_s: NDArray,
    settings: IterationSettings,
) -> LoopResult:
    """Value iteration by implicit steps (module docstring) from P0_s (n, n), in scaled units.

    ``settings`` (:class:`ddvi_core.value_iteration.IterationSettings`): the step's ``gain`` is
    the first step after each start from P0, as a fraction of forward Euler's stability limit;
    ``rule`` "relative" stops when :func:`gain_error` <= tol, "residual" when |F(P)| <
    tol max(1, |P|); ``psd_tol`` and ``max_psd_resets`` as in value iteration.  A rejected step
    counts as an iteration.  Returns the tuple of
    :func:`ddvi_core.value_iteration.value_iteration_loop`; ``history`` holds |P_k+1 - P_k|.
    """
    n = Q_s.shape[0]
    images = basis_images(riccati_map, n)
    state = _Continuation(P0_s.copy())
    K = np.zeros((R_s.shape[0], n))
    history: list[float] = []
    errors: list[float] = []
    residual = math.inf
    for k in range(settings.max_iterations):
        F, K = riccati_flow(riccati_map, Q_s, R_s, state.P)
        residual = float(np.linalg.norm(F))
        if not math.isfinite(residual):
            why = "the residual is not finite"
            return state.P, K, k + 1, state.r, False, residual, np.array(history), why
        P_norm = float(np.linalg.norm(state.P))
        M = linearisation(images, R_s, K)
        modes = np.linalg.eigvals(M)
        error = gain_error(images, M, modes, K, F) if settings.rule == "relative" else residual
        errors.append(error)
        if meets_tolerance(settings.rule, error, settings.tol, P_norm):
            met = met_message(settings.rule, error, settings.tol)
            why = f"{met}; implicit steps, {state.rejected} rejected by the safeguard"
            return state.P, K, k + 1, state.r, True, residual, np.array(history), why
        state = _with_step(state, modes, settings.steps.gain, P_norm, residual)
        X = _implicit_step(M, F, state.eps)
        P_new = state.P + X
        leaves = _outside(P_new, settings.bounds(state.r), settings.psd_tol)
        if leaves == "bound":
            state = _restarted_from(state, P0_s)
            history.append(0.0)
        elif leaves == "cone":
            shorter = _shortened(state)
            if shorter.cone_streak >= settings.max_psd_resets:
                why = _cone_message(shorter.cone_streak, state.eps)
                return state.P, K, k + 1, state.r, False, residual, np.array(history), why
            state = shorter
            history.append(0.0)
        else:
            change = float(np.linalg.norm(X))
            history.append(change)
            state = _advanced(state, P_new, change, P_norm)
    why = unconverged_message(settings.rule, np.array(errors), residual, settings.tol)
    return state.P, K, settings.max_iterations, state.r, False, residual, np.array(history), why
