"""Step length, stopping rule and budget report of value iteration, from the current iterate.

Value iteration is forward Euler on the Riccati flow F(P) = A^T P + P A + Q - P B R^-1 B^T P.
Linearised at P_k, the flow is the Lyapunov operator of the current closed loop
A_k = A - B K_{k+1}, whose eigenvalues are mu = lambda_i + lambda_j for the eigenvalues lambda
of A_k.  Euler with step eps is stable on a mode mu with Re mu < 0 while
|1 + eps mu| < 1, that is eps < -2 Re mu / |mu|^2: :func:`euler_step_limit`.  The relative
stopping rule's estimate of the gain's error is :func:`ddvi_core.continuation.gain_error`.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

__all__ = [
    "TRUST",
    "adaptive_step",
    "budget_report",
    "euler_limit_of_modes",
    "euler_step_limit",
    "meets_tolerance",
    "unconverged_message",
]

TRUST = 0.5
"""The largest relative change of P in one step: far from the fixed point (P0 small, F(P) of
the size of Q) the linearisation says little, and the step grows P by at most half per step."""


def euler_step_limit(lam: NDArray) -> float:
    """The largest stable Euler step for the Lyapunov operator of a matrix with eigenvalues
    ``lam`` (n,): :func:`euler_limit_of_modes` of mu = lam_i + lam_j."""
    return euler_limit_of_modes((lam[:, None] + lam[None, :]).ravel())


def euler_limit_of_modes(mu: NDArray) -> float:
    """The largest stable Euler step on the modes ``mu``: min of -2 Re mu / |mu|^2 for
    decaying modes, and 1 / |mu| for modes that do not decay (Euler's growth |1 + eps mu|
    stays below 2 on them, while the flow itself moves P towards a stabilising gain).  inf
    when every mu is 0."""
    size = np.abs(mu)
    nonzero = size > 1e-12 * max(float(np.max(size)) if size.size else 0.0, 1e-300)
    if not np.any(nonzero):
        return math.inf
    mu, size = mu[nonzero], size[nonzero]
    decaying = mu.real < 0
    limits = np.where(decaying, -2.0 * mu.real / size**2, 1.0 / size)
    return float(np.min(limits))


def adaptive_step(lam: NDArray, fraction: float, P_norm: float, dP_norm: float) -> float:
    """eps_k: ``fraction`` (0 < fraction < 1) of the Euler stability limit of the closed loop
    with eigenvalues ``lam`` (n,), and no longer than TRUST |P| / |F(P)|."""
    eps = fraction * euler_step_limit(lam)
    if dP_norm > 0:
        eps = min(eps, TRUST * max(P_norm, 1e-300) / dP_norm)
    return eps if math.isfinite(eps) else 1.0


def budget_report(errors: NDArray, tol: float) -> str:
    """Why an iteration budget ran out, from the per-iteration error estimates ``errors``
    (k,): the last error against ``tol``, its trend over the last half of the budget, and, when
    it falls, about how many more iterations it needs at that rate."""
    k = errors.size
    finite = errors[np.isfinite(errors)]
    if not finite.size:
        return f"the iterate's gain never stabilised the closed loop in {k} iterations"
    last = float(finite[-1])
    half = finite[finite.size // 2 :]
    first = float(half[0])
    text = f"estimated relative error of K {last:.3g} > tol {tol:g}"
    if half.size < 2 or not (first > 0 and last > 0):
        return text
    ratio = last / first
    per_step = math.log(ratio) / (half.size - 1)
    trend = f"; over the last {half.size} iterations it went from {first:.3g} to {last:.3g}"
    if per_step < 0:
        more = math.log(tol / last) / per_step
        return text + trend + f" (about {more:.3g} more iterations at that rate)"
    return (
        text + trend + " (not falling: more iterations will not help; check the data or the step)"
    )


def meets_tolerance(rule: str, error: float, tol: float, P_norm: float) -> bool:
    """The stopping rule at an iterate of norm ``P_norm``: with ``rule`` "relative", the
    estimated |K - K*| / |K| ``error`` is at most tol; otherwise the residual ``error`` is below
    tol max(1, |P|)."""
    if rule == "relative":
        return error <= tol
    return error < tol * max(1.0, P_norm)


def met_message(rule: str, error: float, tol: float) -> str:
    """What the stopping rule (:func:`meets_tolerance`) met at the stop, for a converged
    message."""
    if rule == "relative":
        return f"estimated |K - K*|/|K| {error:.3g} <= tol {tol:g}"
    return f"residual {error:.3g} < tol {tol:g} max(1, |P|)"


def unconverged_message(rule: str, errors: NDArray, residual: float, tol: float) -> str:
    """Why the budget ran out unconverged: :func:`budget_report` of the per-iteration
    estimates ``errors`` (k,) with the "relative" ``rule``, else the last residual against
    tol."""
    if rule == "relative":
        return budget_report(errors, tol)
    return f"residual {residual:.3g} > tol {tol:g} max(1, |P|)"
