"""Value iteration for the continuous-time Riccati equation (the paper's Algorithm 1), with the
time/state/cost scaling that makes it converge on orbital problems.

Value iteration is forward Euler on dP/dtau = A^T P + P A + Q - P B R^-1 B^T P with steps
eps_k.  Its speed is set by the slowest closed-loop rate measured in the iteration's time unit,
so the problem is first rescaled (:mod:`ddvi_core.scaling`; docs/design.md, "The paper's errata"
and "Expected figures"):

    tau = w0 t,   x = S x_s,   u = s_u u_s,   cost multiplied by c
    A_s = S^-1 A S / w0,  B_s = S^-1 B s_u / w0,  Q_s = c S Q S / w0,  R_s = c s_u R s_u / w0
    P = S^-1 P_s S^-1 / c,  K = s_u K_s S^-1

The same loop serves the model-based iteration here and the data-driven one in
:mod:`ddvi_core.learning`; only the map P -> (A^T P + P A, R^-1 B^T P) differs.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ddvi_core.anderson import DEFAULT_MEMORY, AndersonHistory
from ddvi_core.continuation import (
    LoopResult,
    basis_images,
    continuation_loop,
    gain_error,
    linearisation,
    riccati_flow,
)
from ddvi_core.convergence import adaptive_step, meets_tolerance, met_message, unconverged_message
from ddvi_core.scaling import Scaling, balanced_scaling

__all__ = [
    "LEARNING_METHODS",
    "BoundSchedule",
    "IterationSettings",
    "StepSequence",
    "VIResult",
    "value_iteration",
    "value_iteration_loop",
]


STEP_KINDS = ("harmonic", "constant", "adaptive", "implicit")
STOPPING_RULES = ("residual", "relative")


@dataclass(frozen=True)
class StepSequence:
    """eps_k for k = 0, 1, ...: ``harmonic`` eps_k = gain / (k + 1) (the paper's 1/k),
    ``constant`` eps_k = gain (forward Euler with a fixed step: pick it below the Euler
    stability limit of the slowest lightly damped closed-loop mode), or ``adaptive``: ``gain``
    (below 1) times the Euler stability limit of the current iterate's closed loop, no longer
    than :data:`ddvi_core.convergence.TRUST` |P| / |F(P)| (the loop computes it; see
    :func:`ddvi_core.convergence.adaptive_step`), or ``implicit``: linearly implicit steps
    that start at ``gain`` (below 1) times that limit and grow towards Newton's
    (:mod:`ddvi_core.continuation`)."""

    kind: str = "harmonic"
    gain: float = 1.0

    def __post_init__(self) -> None:
        if self.kind not in STEP_KINDS:
            raise ValueError(f"step kind must be one of {', '.join(STEP_KINDS)}, got {self.kind!r}")
        if not (self.gain > 0 and math.isfinite(self.gain)):
            raise ValueError(f"step gain must be positive and finite, got {self.gain}")
        if self.kind in ("adaptive", "implicit") and not self.gain < 1:
            raise ValueError(f"an {self.kind} step's gain is a fraction below 1, got {self.gain}")

    def __call__(self, k: int) -> float:
        return self.gain / (k + 1) if self.kind == "harmonic" else self.gain


@dataclass(frozen=True)
class BoundSchedule:
    """Radii of the bounded sets B_r: ``linear`` base (r + 1) (the paper's 10 (r + 1)) or
    ``geometric`` base 2^r (which reaches a large |P*| in few resets)."""

    kind: str = "linear"
    base: float = 10.0

    def __post_init__(self) -> None:
        if self.kind not in ("linear", "geometric"):
            raise ValueError(f"bound kind must be 'linear' or 'geometric', got {self.kind!r}")
        if not self.base > 0:
            raise ValueError(f"bound base must be positive, got {self.base}")

    def __call__(self, r: int) -> float:
        return self.base * (r + 1) if self.kind == "linear" else self.base * 2.0 ** min(r, 1000)


LEARNING_METHODS = ("vi", "pi", "hybrid")


@dataclass(frozen=True)
class IterationSettings:
    """How the learner iterates on its data, and how value iteration's loops run.

    method : one of :data:`LEARNING_METHODS`: "vi" (value iteration, the paper's Algorithm
        2), "pi" (policy iteration from a stabilising gain) or "hybrid" (value iteration
        until the gain is near the fixed point, then policy iteration).
    steps, bounds : value iteration's step sequence and its bounded sets' radii.
    tol, max_iterations : the stopping rule's tolerance, and the iterations allowed.
    rule : the stopping rule, "residual" (|F(P)| < tol max(1, |P|)) or "relative" (the
        scale-free estimate of |K - K*| / |K| at most tol, :mod:`ddvi_core.continuation`).
    memory : value iteration's Anderson acceleration over that many past steps (0: plain;
        :mod:`ddvi_core.anderson`).
    psd_tol : P leaves the cone when an eigenvalue is below -psd_tol |P| (a strict test would
        reset on round-off).
    max_psd_resets : value iteration gives up after that many restarts in a row for leaving
        the cone with no shorter step (:func:`value_iteration_loop`).
    """

    method: str = "vi"
    steps: StepSequence = field(default_factory=StepSequence)
    bounds: BoundSchedule = field(default_factory=BoundSchedule)
    tol: float = 1e-6
    max_iterations: int = 200_000
    rule: str = "residual"
    memory: int = DEFAULT_MEMORY
    psd_tol: float = 1e-6
    max_psd_resets: int = 3

    def __post_init__(self) -> None:
        if self.method not in LEARNING_METHODS:
            raise ValueError(
                f"method must be one of {', '.join(LEARNING_METHODS)}, got {self.method!r}"
            )


@dataclass(frozen=True)
class VIResult:
    """Outcome of value iteration, gains in the problem's units.

    K (m,n), P (n,n); ``residual`` is the last |P~_k - P_{k-1}| / eps_{k-1} (scaled units);
    ``history`` holds |P_k - P_{k-1}| per iteration.
    """

    K: NDArray[np.float64]
    P: NDArray[np.float64]
    iterations: int
    resets: int
    converged: bool
    residual: float
    scaling: Scaling
    history: NDArray[np.float64] = field(repr=False)
    message: str = ""


# P_s -> (A_s^T P_s + P_s A_s, K_s) in scaled units
RiccatiMap = Callable[[NDArray], tuple[NDArray, NDArray]]


ClosedLoop = Callable[[NDArray], NDArray]
"""K_s (m, n) -> the eigenvalues (n,) of the closed loop A_s - B_s K_s (scaled units)."""


def _step(
    steps: StepSequence,
    k: int,
    K: NDArray,
    P_norm: float,
    residual: float,
    closed_loop: ClosedLoop | None,
) -> float:
    """eps_k: the sequence's, or the adaptive step from the current closed loop."""
    if steps.kind == "adaptive":
        return adaptive_step(closed_loop(K), steps.gain, P_norm, residual)
    return steps(k)


def _frobenius(X: NDArray) -> float:
    """|X|_F of X (n, n)."""
    return float(np.sqrt(np.sum(X * X)))


def _leaves(P: NDArray, radius: float, psd_tol: float) -> str:
    """ "bound" when |P|_F > radius, "cone" when an eigenvalue is below -psd_tol |P|, else ""."""
    norm = _frobenius(P)
    if norm > radius:
        return "bound"
    return "cone" if np.linalg.eigvalsh(P)[0] < -psd_tol * norm else ""


def _cone_resets_message(times: int, eps: float) -> str:
    return (
        f"P left the positive semidefinite cone {times} times from P0 with a "
        f"step of {eps:.3g}, which the exact Riccati flow never does: the data do "
        f"not determine the map well enough (collect more, or richer, data)"
    )


def _gain_error_of(
    riccati_map: RiccatiMap, R_s: NDArray, n: int
) -> Callable[[NDArray, NDArray], float]:
    """(K, F(P)) -> the estimated |K - K*| / |K| (:func:`ddvi_core.continuation.gain_error`)."""
    images = basis_images(riccati_map, n)

    def error(K: NDArray, F: NDArray) -> float:
        M = linearisation(images, R_s, K)
        return gain_error(images, M, np.linalg.eigvals(M), K, F)

    return error


@dataclass
class _Acceleration:
    """The loop's Anderson state: the history, the plain step to fall back on, counters."""

    history: AndersonHistory | None
    fallback: NDArray | None = None  # the plain step from the iterate the last one came from
    error_from: float = math.inf  # that iterate's stopping measure
    accepted: int = 0
    rejected: int = 0

    @staticmethod
    def of(settings: IterationSettings) -> _Acceleration:
        """Anderson's history over ``settings.memory`` steps with the relative rule, none
        otherwise.  The residual alone does not judge an extrapolation: measured on the default
        mission's constant step, the residual-guarded extrapolation stalled at a residual of 31
        in 200,000 iterations."""
        accelerate = settings.memory > 0 and settings.rule == "relative"
        return _Acceleration(AndersonHistory(settings.memory) if accelerate else None)

    def restart(self) -> None:
        self.fallback = None
        if self.history is not None:
            self.history.restart()

    def take_back(self, error: float) -> NDArray | None:
        """The safeguard: the plain step to take instead when the last extrapolated iterate
        raised the stopping rule's measure to ``error`` (a rejection), else None."""
        if self.fallback is None or error <= self.error_from:
            return None
        plain = self.fallback
        self.fallback = None
        self.rejected += 1
        return plain

    def extrapolate(
        self, P: NDArray, F: NDArray, eps: float, error: float, radius: float, psd_tol: float
    ) -> NDArray | None:
        """Anderson's extrapolation of the step eps from P (n, n) along F (n, n) when it stays
        in the cone and in the bound ``radius``, else None (one that leaves is a rejection).
        Only once the gain stabilises (``error`` finite): there the iteration contracts and
        the estimate judges an extrapolation."""
        self.fallback = None
        if self.history is None or not math.isfinite(error):
            return None
        extrapolated = self.history.propose(P, F, eps)
        if extrapolated is None:
            return None
        if _leaves(extrapolated, radius, psd_tol):
            self.rejected += 1
            self.restart()
            return None
        self.accepted += 1
        return extrapolated


@dataclass(frozen=True)
class _Restarts:
    """The restarts from P0 (n, n): r of them (B_r the bound in force), and of those for leaving
    the cone, how many in a row with no shorter step (``cone_streak``) and the last one's step
    (``cone_eps``)."""

    P0: NDArray
    r: int = 0
    cone_streak: int = 0
    cone_eps: float = math.inf


def _restarted(restarts: _Restarts, leaves: str, eps: float) -> _Restarts:
    """``restarts`` after one more, because the step of ``eps`` left the bound ("bound") or the
    cone ("cone").  With an unchanged step every restart retraces the same path, so the
    streak grows while the step has not shrunk and starts again at 1 when it has."""
    if leaves != "cone":
        return replace(restarts, r=restarts.r + 1)
    streak = restarts.cone_streak + 1 if eps >= restarts.cone_eps else 1
    return _Restarts(restarts.P0, restarts.r + 1, streak, eps)


def _next_iterate(
    P: NDArray,
    F: NDArray,
    eps: float,
    error: float,
    acc: _Acceleration,
    restarts: _Restarts,
    settings: IterationSettings,
) -> tuple[NDArray, _Restarts, str]:
    """The iterate after P (n, n), whose flow is F (n, n), step eps and stopping measure
    ``error``: Anderson's extrapolation when ``acc`` takes one (``acc`` then keeps the plain
    step P + eps F to fall back on), else that plain step while it stays in the bound and the
    cone, else P0 with the restart counted and ``acc`` restarted.  Also which of them the plain
    step left ("bound", "cone", or "" when the iteration goes on)."""
    P_new = P + eps * F
    radius = settings.bounds(restarts.r)
    extrapolated = acc.extrapolate(P, F, eps, error, radius, settings.psd_tol)
    if extrapolated is not None:
        acc.fallback = P_new
        acc.error_from = error
        return extrapolated, restarts, ""
    leaves = _leaves(P_new, radius, settings.psd_tol)
    if not leaves:
        return P_new, restarts, ""
    acc.restart()
    return restarts.P0.copy(), _restarted(restarts, leaves, eps), leaves


def value_iteration_loop(
    riccati_map: RiccatiMap,
    Q_s: NDArray,
    R_s: NDArray,
    P0_s: NDArray,
    settings: IterationSettings,
    closed_loop: ClosedLoop | None = None,
) -> LoopResult:
    """The iteration shared by Algorithms 1 and 2, in scaled units, from P0_s (n, n) as
    ``settings`` say (its ``method`` is not read).

    P~_{k+1} = P_k + eps_k (H_k + Q - K_{k+1}^T R K_{k+1});  reset to P0 (r += 1) when P~ leaves
    B_r (|P~|_F > radius, or an eigenvalue below -psd_tol |P~|: a strict PSD test would reset on
    round-off).  Stopping ``rule``: ``residual`` stops when |P~_{k+1} - P_k| / eps_k <
    tol max(1, |P_k|); ``relative`` (scale-free) when the estimated |K_k - K*| / |K_k|
    (the Newton correction's, :func:`ddvi_core.continuation.gain_error`) is at most tol.
    ``closed_loop`` (needed by the ``adaptive`` step) gives the eigenvalues of the current
    closed loop.  Norms are Frobenius.  The ``implicit`` step runs
    :func:`ddvi_core.continuation.continuation_loop` instead (no Anderson acceleration).

    ``memory`` > 0 accelerates the ``relative`` rule's iteration by Anderson's method over
    that many past steps (:mod:`ddvi_core.anderson`) once the gain stabilises: an
    extrapolated iterate is taken only while it stays in the cone and the bound and does not
    raise the estimated error; otherwise the plain step is taken from where it came (an
    iteration is spent on the rejected one).  The ``residual`` rule iterates plainly.

    The exact Riccati flow never leaves the PSD cone from P0 >= 0 (at its boundary, where
    P z = 0, z^T dP z = z^T Q z >= 0): a step that does is too long, and the resets last until
    eps_k has shrunk.  A map estimated from data can leave it at any step: then it leaves from
    every restart alike, and the loop would reset until ``max_iterations`` (measured: 11,764
    resets in 200,000 iterations, 12 s, on a 6-orbit window where converging windows reset 0
    times that way).  With an unchanged step every restart retraces the same path, so after
    ``max_psd_resets`` such resets in a row with no shorter step it gives up.
    Returns (P, K, iterations, resets, converged, residual, history, why): ``why`` says why
    it stopped unconverged, or what was met when converged; ``history`` holds eps_k |F(P_k)|.
    """
    if settings.steps.kind == "implicit":
        return continuation_loop(riccati_map, Q_s, R_s, P0_s, settings)
    if settings.steps.kind == "adaptive" and closed_loop is None:
        raise ValueError("the adaptive step needs closed_loop")
    relative = settings.rule == "relative"
    gain_error_of = _gain_error_of(riccati_map, R_s, P0_s.shape[0]) if relative else None
    P = P0_s.copy()
    K = np.zeros((R_s.shape[0], P.shape[0]))
    residual = math.inf
    history = np.empty(settings.max_iterations)
    errors = np.empty(settings.max_iterations)
    restarts = _Restarts(P0_s)
    acc = _Acceleration.of(settings)
    for k in range(settings.max_iterations):
        F, K = riccati_flow(riccati_map, Q_s, R_s, P)
        residual = _frobenius(F)
        if not math.isfinite(residual) and acc.fallback is None:
            why = "the residual is not finite"
            return P, K, k + 1, restarts.r, False, residual, history[:k], why
        P_norm = _frobenius(P)
        eps = _step(settings.steps, k, K, P_norm, residual, closed_loop)
        # the stopping rule's measure: the estimated |K - K*| / |K|, or the residual
        errors[k] = gain_error_of(K, F) if relative else residual
        plain = acc.take_back(errors[k])
        if plain is not None:  # take the plain step from where the extrapolation came from
            P = plain
            errors[k] = math.inf
            history[k] = history[k - 1] if k else 0.0
            continue
        history[k] = eps * residual
        if meets_tolerance(settings.rule, errors[k], settings.tol, P_norm):
            done = (
                f"{met_message(settings.rule, errors[k], settings.tol)}; {acc.accepted} "
                f"accelerated steps, {acc.rejected} rejected by the safeguard"
            )
            return P + eps * F, K, k + 1, restarts.r, True, residual, history[: k + 1], done
        P, restarts, leaves = _next_iterate(P, F, eps, errors[k], acc, restarts, settings)
        if leaves == "cone" and restarts.cone_streak >= settings.max_psd_resets:
            why = _cone_resets_message(restarts.cone_streak, eps)
            return P, K, k + 1, restarts.r, False, residual, history[: k + 1], why
    why = unconverged_message(settings.rule, errors, residual, settings.tol)
    return P, K, settings.max_iterations, restarts.r, False, residual, history, why


def value_iteration(
    A: ArrayLike,
    B: ArrayLike,
    Q: ArrayLike,
    R: ArrayLike,
    *,
    P0: ArrayLike | None = None,
    steps: StepSequence | None = None,
    bounds: BoundSchedule | None = None,
    tol: float = 1e-6,
    max_iterations: int = 200_000,
    scaling: Scaling | bool = True,
    rule: str = "residual",
    memory: int = DEFAULT_MEMORY,
) -> VIResult:
    """Model-based value iteration (Algorithm 1) for K*, P*.

    A (n,n), B (n,m), Q (n,n), R (m,m).  ``scaling``: True (default) for
    :func:`balanced_scaling`, False for the problem's own units, or a :class:`Scaling`.
    P0 is given in scaled units (default 1e-3 I, small against P* as docs/design.md,
    "Expected figures", advises).  ``tol`` bounds the scaled Riccati residual relative to |P_k|
    at the stop (``rule`` "residual"), or the estimated |K - K*| / |K| (``rule`` "relative",
    scale-free: see :mod:`ddvi_core.continuation`).  ``memory``: Anderson acceleration of
    the explicit steps over that many past steps (0: plain value iteration;
    :mod:`ddvi_core.anderson`).
    """
    A, B, Q, R = (np.asarray(M, dtype=float) for M in (A, B, Q, R))
    n, m = B.shape
    if scaling is True:
        sc = balanced_scaling(A, B, Q, R)
    elif scaling is False:
        sc = Scaling.identity(n, m)
    else:
        sc = scaling
    A_s, B_s = sc.dynamics(A, B)
    Q_s, R_s = sc.weights(Q, R)
    RinvBt = np.linalg.solve(R_s, B_s.T)

    def riccati_map(P: NDArray) -> tuple[NDArray, NDArray]:
        AtP = A_s.T @ P
        return AtP + AtP.T, RinvBt @ P

    def closed_loop(K_s: NDArray) -> NDArray:
        return np.linalg.eigvals(A_s - B_s @ K_s)

    P0_s = 1e-3 * np.eye(n) if P0 is None else np.asarray(P0, dtype=float)
    settings = IterationSettings(
        "vi", steps or StepSequence(), bounds or BoundSchedule(), tol, max_iterations, rule, memory
    )
    P_s, K_s, k, resets, converged, residual, history, why = value_iteration_loop(
        riccati_map, Q_s, R_s, P0_s, settings, closed_loop
    )
    K_s = RinvBt @ P_s
    message = (
        f"converged in {k} iterations ({resets} resets): {why}"
        if converged
        else f"not converged after {k} iterations: {why}"
    )
    return VIResult(
        K=sc.unscale_K(K_s),
        P=sc.unscale_P(P_s),
        iterations=k,
        resets=resets,
        converged=converged,
        residual=residual,
        scaling=sc,
        history=history,
        message=message,
    )
