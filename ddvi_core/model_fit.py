"""A data-driven learner by first-order model fitting: the robust alternative to the paper's
value iteration (:mod:`ddvi_core.learning`) when navigation is noisy or the model is wrong.

The learner never reads A, B or D.  Over any interval [a, b] of the data, integrating
x' = A x + B u + D v gives the first-order interval relation

    x(b) - x(a) = A int_a^b x dt + B int_a^b u dt + D int_a^b v dt,

linear in the unknowns (A, B, D).  Keeping the cumulative integrals of x, u and v at every
sample makes every interval a difference of two rows, so many overlapping intervals (say
600 s long, one starting every 10 s) cost no more memory than the samples of the window.
(A, B, D) is the least-squares fit over all of them, each regressor column scaled to unit
RMS; the Riccati equation (:func:`ddvi_core.lqr.solve_lqr`) and the regulator equations
(:func:`ddvi_core.regulator.solve_regulator_equations`) solved on the fitted model then give
K and L = U + K X.

Why it survives noise where the value regression does not: it fits n (n + m + q) numbers
with the structure of a linear system, not n(n+1)/2 + (m+q) n coefficients of a quadratic
form; white noise on an end point enters the left-hand side only (an unbiased error that
the many intervals average out), and in the integrals it is averaged over the interval.

:class:`IntegralHistory` is the streaming side (one call per navigation sample); the rest are
pure functions on arrays.
"""

from __future__ import annotations

import collections
import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ddvi_core.learning import (
    LearningError,
    RankDeficientError,
    check_dimensions,
    check_sample,
)
from ddvi_core.lqr import NotStabilisingError, solve_lqr
from ddvi_core.regulator import InfeasibleError, feedforward_gain, solve_regulator_equations

__all__ = [
    "FittedModel",
    "IntegralData",
    "IntegralHistory",
    "ModelFitError",
    "ModelFitResult",
    "fit_linear_model",
    "gains_from_model",
    "interval_regressors",
    "learn_by_model_fit",
    "prediction_residual",
]


class ModelFitError(LearningError):
    """A fitted model that gives no gains (not stabilisable, no regulator solution)."""


@dataclass(frozen=True)
class IntegralData:
    """Samples with their running integrals (K samples): t (K,), x (K, n), the cumulative
    integrals Ix (K, n), Iu (K, m), Iv (K, q) from the first sample, and segment (K,): samples
    of one segment have no gap between them, and no interval spans two segments."""

    t: NDArray[np.float64]
    x: NDArray[np.float64]
    Ix: NDArray[np.float64]
    Iu: NDArray[np.float64]
    Iv: NDArray[np.float64]
    segment: NDArray[np.int64]

    @property
    def samples(self) -> int:
        return self.t.size

    def since(self, t: float) -> IntegralData:
        """The samples at or after t (s): a learning window."""
        keep = self.t >= t - 1e-6
        return IntegralData(*(a[keep] for a in _columns(self)))

    def before(self, t: float) -> IntegralData:
        """The samples at or before t (s)."""
        keep = self.t <= t + 1e-6
        return IntegralData(*(a[keep] for a in _columns(self)))


class IntegralHistory:
    """Streaming running integrals, for an on-board learner.

    ``add(t, x, u, v)`` takes one navigation sample: time t (s), state x (n,), the input u (m,)
    applied from t until the next sample (a zero-order hold, integrated exactly), exostate v
    (q,); x and v are integrated by the trapezoidal rule.  ``interval`` and ``stride`` (s)
    are the intervals' length and spacing the learner will use.  A gap longer than ``max_gap``
    seconds (lost navigation) starts a new segment.  At most ``max_samples`` samples are kept
    (the oldest go first), so memory is bounded by the learning window."""

    def __init__(
        self,
        n: int,
        m: int,
        q: int,
        interval: float,
        stride: float,
        max_gap: float | None = None,
        max_samples: int = 100_000,
    ) -> None:
        check_dimensions(n, m, q)
        if not (interval > 0 and stride > 0 and math.isfinite(interval + stride)):
            raise ValueError(f"interval and stride must be positive s, got {interval}, {stride}")
        self.n, self.m, self.q = n, m, q
        self.interval, self.stride = float(interval), float(stride)
        self.max_gap = float(max_gap) if max_gap is not None else math.inf
        self._rows: collections.deque = collections.deque(maxlen=int(max_samples))
        self._last: tuple | None = None  # t, x, u, v, (Ix, Iu, Iv), segment of the last sample
        self.samples = 0

    def add(self, t: float, x: ArrayLike, u: ArrayLike, v: ArrayLike | None = None) -> None:
        if not math.isfinite(t):
            raise LearningError(f"sample time is not finite: {t}")
        x, u = check_sample("x", x, self.n), check_sample("u", u, self.m)
        v = check_sample("v", v, self.q)
        if self._last is None:
            sums, segment = (np.zeros(self.n), np.zeros(self.m), np.zeros(self.q)), 0
        else:
            t0, x0, u0, v0, (Ix, Iu, Iv), segment = self._last
            dt = t - t0
            if dt <= 0:
                raise LearningError(f"sample time {t} does not increase (last was {t0})")
            if dt > self.max_gap:
                segment += 1
                dt = 0.0  # integrals carry over unchanged: the gap is in no interval
            sums = (Ix + 0.5 * dt * (x0 + x), Iu + dt * u0, Iv + 0.5 * dt * (v0 + v))
        self._last = (t, x, u, v, sums, segment)
        self._rows.append((t, x, *sums, segment))
        self.samples += 1

    @property
    def intervals(self) -> int:
        """About how many intervals the kept samples hold (gaps aside): for status reports."""
        if not self._rows:
            return 0
        span = self._rows[-1][0] - self._rows[0][0] - self.interval
        return max(0, math.floor(span / self.stride + 1e-9) + 1) if span >= 0 else 0

    def data(self) -> IntegralData:
        if not self._rows:
            empty = (np.zeros((0, k)) for k in (self.n, self.n, self.m, self.q))
            return IntegralData(np.zeros(0), *empty, np.zeros(0, dtype=np.int64))
        cols = list(zip(*self._rows, strict=True))
        return IntegralData(
            np.array(cols[0]), *(np.array(c) for c in cols[1:5]), np.array(cols[5], dtype=np.int64)
        )


def interval_pairs(
    t: NDArray, segment: NDArray, length: float, stride: float, smoothing: float = 0.0
) -> NDArray[np.int64]:
    """Sample indices (rho, 4) of the intervals [a, b] and their shifts by ``smoothing`` w:
    one interval starts at the first sample of every ``stride`` seconds; columns are a, a + w,
    b = a + length, b + w (each the first sample at or after that time).  Kept where all four
    lie in one segment and, with w > 0, the shifted pair spans exactly what the first does;
    with w = 0, b no later than a + length + stride."""
    if t.size == 0:
        return np.zeros((0, 4), dtype=np.int64)
    grid = np.arange(t[0], t[-1] - length - smoothing + 1e-6, stride)
    a = np.unique(np.searchsorted(t, grid - 1e-6))
    a_w, b = (np.searchsorted(t, t[a] + off - 1e-6) for off in (smoothing, length))
    ok = (a_w < t.size) & (b < t.size)
    a, a_w, b = a[ok], a_w[ok], b[ok]
    b_w = np.searchsorted(t, t[b] + smoothing - 1e-6)
    ok = b_w < t.size
    idx = np.stack([a[ok], a_w[ok], b[ok], b_w[ok]], axis=1)
    ti, seg = t[idx], segment[idx]
    ok = np.all(seg == seg[:, :1], axis=1) & (ti[:, 2] - ti[:, 0] <= length + stride + 1e-6)
    if smoothing > 0:
        width = ti[:, 1] - ti[:, 0]
        ok &= (np.abs(width - (ti[:, 3] - ti[:, 2])) < 1e-3) & (width > 0)
    return idx[ok]


def _cumulative(t: NDArray, y: NDArray) -> NDArray:
    """The running trapezoidal integral of y (K, k) over t (K,), zero at the first sample."""
    import scipy.integrate  # when a fit needs it: it costs a service's start-up a second

    return scipy.integrate.cumulative_trapezoid(y, t, axis=0, initial=0.0) if t.size else y


def interval_regressors(
    data: IntegralData, length: float, stride: float, smoothing: float = 0.0
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The interval relation's rows: y (rho, n) and phi (rho, n + m + q).

    With ``smoothing`` w = 0: y = x(b) - x(a), phi = [int x, int u, int v] over [a, b].  With
    w > 0, the same relation averaged over the shifts s in [0, w] of the interval (times w):
    y = int_b^{b+w} x - int_a^{a+w} x and phi the matching differences of the double
    integrals, exact for the linear system, and the end points' white noise averaged over w
    (the end points are what noise hurts most)."""
    if not (length > 0 and stride > 0 and smoothing >= 0 and math.isfinite(length + stride)):
        raise LearningError(
            f"interval length and stride must be positive s and smoothing >= 0, got "
            f"{length}, {stride}, {smoothing}"
        )
    k = interval_pairs(data.t, data.segment, length, stride, smoothing)
    cols = (data.Ix, data.Iu, data.Iv)
    if smoothing > 0:
        y = data.Ix
        cols = tuple(_cumulative(data.t, c) for c in cols)
    else:
        y = data.x

    def span(z: NDArray) -> NDArray:
        if smoothing > 0:
            return (z[k[:, 3]] - z[k[:, 2]]) - (z[k[:, 1]] - z[k[:, 0]])
        return z[k[:, 2]] - z[k[:, 0]]

    return span(y), np.hstack([span(c) for c in cols])


@dataclass(frozen=True)
class FittedModel:
    """x' = A x + B u + D v fitted on rho intervals: A (n, n), B (n, m), D (n, q); ``rank``
    and ``needed`` of the scaled regressor, its ``condition`` number, ``residual`` the RMS of
    the fit's residual over the RMS of dx."""

    A: NDArray[np.float64]
    B: NDArray[np.float64]
    D: NDArray[np.float64]
    intervals: int
    rank: int
    needed: int
    condition: float
    residual: float


def _fit_report(rank: int, needed: int, rho: int, weakest: NDArray, names: list[str]) -> str:
    parts = [f"interval-fit regressor rank {rank} of {needed} needed"]
    if rho < needed:
        parts.append(f"only {rho} intervals; at least {needed} are needed")
    top = np.argsort(-np.abs(weakest))[:3]
    parts.append("weakest direction mostly " + ", ".join(names[k] for k in top))
    parts.append("explore longer or with richer exploration before learning")
    return "; ".join(parts)


def _column_scale(phi: NDArray) -> NDArray:
    """Each column's RMS (k,) of a regressor phi (rows, k), 1 for a zero column: dividing by
    it gives every column unit RMS."""
    scale = np.sqrt(np.mean(phi**2, axis=0)) if phi.shape[0] else np.ones(phi.shape[1])
    return np.where(scale > 0, scale, 1.0)


def _full_rank_lstsq(
    phi: NDArray, y: NDArray, names: list[str], rtol: float
) -> tuple[NDArray, NDArray]:
    """The least-squares theta (k, r) of y (rows, r) ~ phi (rows, k), solved with phi's
    columns scaled to unit RMS, and the scaled regressor's singular values (k,).  Raises
    RankDeficientError, naming the weakest column by ``names``, when its rank (singular
    values above ``rtol`` times the largest) is short of k."""
    rows, needed = phi.shape
    if rows == 0 or needed == 0:
        raise RankDeficientError(_fit_report(0, needed, rows, np.ones(needed), names), 0, needed)
    scale = _column_scale(phi)
    _, sv, Vt = np.linalg.svd(phi / scale, full_matrices=False)
    rank = int(np.sum(sv > rtol * sv[0])) if sv[0] > 0 else 0
    if rank < needed:
        raise RankDeficientError(_fit_report(rank, needed, rows, Vt[-1], names), rank, needed)
    theta, *_ = np.linalg.lstsq(phi / scale, y, rcond=None)
    return theta / scale[:, None], sv


def _design(
    data: IntegralData,
    length: float,
    stride: float,
    translation: ArrayLike | None,
    smooth: float,
    positions: int,
) -> tuple[NDArray, NDArray, NDArray]:
    """The interval relation's fitted rows y (rho, n - positions) and phi (rho, k + m + q)
    with A's columns reduced to N (n, k), an orthonormal basis of the complement of
    ``translation`` (k = n - 1; without one, N = I and k = n)."""
    n = data.x.shape[1]
    dx, phi = interval_regressors(data, length, stride, smooth)
    N = np.eye(n)
    if translation is not None:
        d = np.asarray(translation, dtype=float).reshape(-1)
        if d.size != n or not np.all(np.isfinite(d)) or not np.any(d):
            raise LearningError(f"translation must be {n} finite numbers, not all zero; got {d}")
        basis, _, _ = np.linalg.svd(np.eye(n) - np.outer(d, d) / (d @ d))
        N = basis[:, : n - 1]
    if not 0 <= 2 * positions <= n:
        raise LearningError(f"positions must lie in [0, n/2] = [0, {n // 2}], got {positions}")
    return dx[:, positions:], np.hstack([phi[:, :n] @ N, phi[:, n:]]), N


def _model(theta: NDArray, N: NDArray, m: int, positions: int) -> tuple[NDArray, ...]:
    """(A, B, D) from the fitted rows' theta (k + m + q, n - positions), the transposed
    [A N, B, D], with the kinematic rows of the first ``positions`` states prepended."""
    n, k = N.shape
    kin = np.eye(n)[positions : 2 * positions]  # position' = velocity
    zero = np.zeros((positions, theta.shape[0] - k))
    A = np.vstack([kin, theta[:k].T @ N.T])
    rest = np.vstack([zero, theta[k:].T])
    return A, rest[:, :m], rest[:, m:]


def fit_linear_model(
    data: IntegralData,
    length: float,
    stride: float,
    translation: ArrayLike | None = None,
    smoothing: float = 0.0,
    rtol: float = 1e-9,
    positions: int = 0,
) -> FittedModel:
    """Least-squares (A, B, D) over the overlapping intervals of ``data``.

    With ``positions`` p > 0 the state is [positions (p); their rates (p); ...]: the first p
    rows are kinematics (A's are [0 I 0], B's and D's zero), not fitted, and only the other
    rows are (a filtered estimate's lag distorts the position rows most).

    ``translation`` (n,), if given, is a direction d the dynamics do not see (A d = 0; for a
    Hill state, the along-track position): A is then fitted as A_r N^T with N (n, n-1) an
    orthonormal basis of d's complement, so the data's far along-track offset does not
    compete with the exostate's constant mode.  Raises RankDeficientError when the scaled
    regressor's rank is short."""
    m, q = data.Iu.shape[1], data.Iv.shape[1]
    dx, phi, N = _design(data, length, stride, translation, smoothing, positions)
    needed, rho = phi.shape[1], phi.shape[0]
    names = [f"int x{k}" for k in range(N.shape[1])] + [f"int u{k}" for k in range(m)]
    names += [f"int v{k}" for k in range(q)]
    # (needed, n - p): the transposed [A N, B, D]'s fitted rows
    theta, sv = _full_rank_lstsq(phi, dx, names, rtol)
    resid = dx - phi @ theta
    dx_rms = float(np.sqrt(np.mean(dx**2)))
    A, B, D = _model(theta, N, m, positions)
    return FittedModel(
        A=A,
        B=B,
        D=D,
        intervals=rho,
        rank=needed,
        needed=needed,
        condition=float(sv[0] / sv[-1]),
        residual=float(np.sqrt(np.mean(resid**2))) / dx_rms if dx_rms > 0 else 0.0,
    )


def prediction_residual(
    model: FittedModel, data: IntegralData, length: float, stride: float, smoothing: float = 0.0
) -> NDArray[np.float64]:
    """The RMS (n,) per state of the interval relation's residual x(b) - x(a) - A int x -
    B int u - D int v of ``model`` on ``data`` (its own intervals, as the fit makes them): on
    data the model was not fitted on, how well it predicts the motion.  Raises LearningError
    when the data hold no interval."""
    dx, phi = interval_regressors(data, length, stride, smoothing)
    if dx.shape[0] == 0:
        raise LearningError(f"no interval of {length:g} s in {data.samples} samples")
    theta = np.hstack([model.A, model.B, model.D]).T
    return np.sqrt(np.mean((dx - phi @ theta) ** 2, axis=0))


@dataclass(frozen=True)
class ModelFitResult:
    """Gains of the fitted model, u = -K x + L v: K (m, n), L (m, q), P (n, n), X (n, q),
    U (m, q), and the fit itself."""

    K: NDArray[np.float64]
    L: NDArray[np.float64]
    P: NDArray[np.float64]
    X: NDArray[np.float64]
    U: NDArray[np.float64]
    model: FittedModel

    @property
    def message(self) -> str:
        f = self.model
        return (
            f"model fit on {f.intervals} intervals: condition {f.condition:.3g}, relative "
            f"residual {f.residual:.3g}"
        )


def gains_from_model(
    model: FittedModel,
    Q: ArrayLike,
    R: ArrayLike,
    C: ArrayLike | None = None,
    E: ArrayLike | None = None,
    F: ArrayLike | None = None,
) -> ModelFitResult:
    """K from the Riccati equation and L = U + K X from the regulator equations of the fitted
    model; Q (n, n), R (m, m), and with an exostate C (p, n), E (q, q), F (p, q).  Raises
    ModelFitError when the fitted model has no stabilising gain or no regulator solution."""
    n, m, q = model.A.shape[0], model.B.shape[1], model.D.shape[1]
    try:
        lqr = solve_lqr(model.A, model.B, Q, R)
    except NotStabilisingError as exc:
        raise ModelFitError(f"the fitted model gives no gain: {exc}") from None
    if q == 0:
        X, U = np.zeros((n, 0)), np.zeros((m, 0))
    else:
        if C is None or E is None or F is None:
            raise LearningError("data carry an exostate (q > 0): C, E and F are required")
        try:
            X, U = solve_regulator_equations(model.A, model.B, C, model.D, E, F)
        except InfeasibleError as exc:
            raise ModelFitError(f"the fitted model gives no feedforward: {exc}") from None
    return ModelFitResult(K=lqr.K, L=feedforward_gain(lqr.K, X, U), P=lqr.P, X=X, U=U, model=model)


def learn_by_model_fit(
    data: IntegralData,
    Q: ArrayLike,
    R: ArrayLike,
    *,
    length: float,
    stride: float,
    C: ArrayLike | None = None,
    E: ArrayLike | None = None,
    F: ArrayLike | None = None,
    translation: ArrayLike | None = None,
    smoothing: float = 0.0,
    positions: int = 0,
) -> ModelFitResult:
    """Fit (A, B, D) on ``data``'s intervals (``length`` s, one every ``stride`` s) and solve
    for the gains (:func:`fit_linear_model`, then :func:`gains_from_model`)."""
    model = fit_linear_model(data, length, stride, translation, smoothing, positions=positions)
    return gains_from_model(model, Q, R, C, E, F)


def _columns(data: IntegralData) -> tuple[NDArray, ...]:
    return (data.t, data.x, data.Ix, data.Iu, data.Iv, data.segment)
