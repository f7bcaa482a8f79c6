"""Detecting a change of the plant from the controller's own data (an actuator fault).

A learner that has switched to its learned gains flies them for the rest of the mission unless
something tells it the plant has changed.  This module gives it that from data alone:

1. ``fit_predictor``: from the samples the learner learned from (x, the input that acted, the
   exostate v, at a fixed sample step), a one-step linear predictor fitted by least squares,

       x_{k+1} - x_k = Phi_d x_k + Gamma u_k + Psi v_k        (on the state coordinates seen)

   With u held between samples and v' = E v this form is exact for a linear plant (zero-order
   hold); it needs no model (A, B, D are never read).  ``translation`` names a direction the
   dynamics do not see (A d = 0: an along-track shift), which is left out of the regressors,
   because the data hold the deputy near one along-track position and that position would
   otherwise be confounded with the exostate's constant mode.

2. ``LinearPredictor.input_equivalent``: a residual r (n,) expressed as the additive input
   error that explains it best, e = (G^T W G)^-1 G^T W r, W = diag(1 / rms^2).  An actuator
   fault (a panel whose area or angle changed) is an error in the input channel, so e is the
   residual where such a fault shows, in the input's own units; effects the predictor cannot
   hold off the input channel (state regions the learning data did not visit) weigh little.

3. ``ChangeDetector``: the mean of e over a sliding window (one orbit in the flight system:
   the predictor's constant coefficients cannot hold the orbit-rate terms of J2 that scale
   with the separation, and they average out over an orbit), against a bound of
   ``bound_factor`` times e's RMS on the learning data.  A full window whose mean leaves the
   bound is a detected change.

Pure functions and plain state; no I/O.
"""

from __future__ import annotations

import collections
import math
from dataclasses import dataclass

import numpy as np
import scipy.linalg
from numpy.typing import ArrayLike, NDArray

from ddvi_core.learning import LearningError

__all__ = [
    "ChangeDetector",
    "DetectionError",
    "LinearPredictor",
    "fit_predictor",
    "step_pairs",
]


class DetectionError(LearningError):
    """Data a predictor cannot be fitted from (too short, not excited, malformed)."""


def step_pairs(t: NDArray[np.float64], step: float) -> NDArray[np.intp]:
    """Indices k (K',) of the samples whose successor is exactly ``step`` later (to 1e-6 of
    it): the pairs a one-step predictor can use (a gap, lost navigation, breaks a pair)."""
    dt = np.diff(t)
    return np.flatnonzero(np.abs(dt - step) <= 1e-6 * step)


def _as_samples(
    t: ArrayLike, x: ArrayLike, u: ArrayLike, v: ArrayLike | None
) -> tuple[NDArray, NDArray, NDArray, NDArray]:
    t = np.asarray(t, dtype=float).reshape(-1)
    k = t.size
    x = np.asarray(x, dtype=float)
    u = np.asarray(u, dtype=float)
    u = u.reshape(k, -1) if u.ndim == 1 else u
    v = np.zeros((k, 0)) if v is None else np.asarray(v, dtype=float)
    v = v.reshape(k, -1) if v.ndim == 1 else v
    if x.ndim != 2 or x.shape[0] != k or u.shape[0] != k or v.shape[0] != k:
        raise DetectionError(
            f"samples must share their length K = {k}: x (K, n), u (K, m), v (K, q); got "
            f"x {x.shape}, u {u.shape}, v {v.shape}"
        )
    for name, a in (("t", t), ("x", x), ("u", u), ("v", v)):
        if not np.all(np.isfinite(a)):
            raise DetectionError(f"samples: {name} has a non-finite value")
    if k > 1 and np.any(np.diff(t) <= 0):
        raise DetectionError("samples: times must increase")
    return t, x, u, v


def _seen_basis(n: int, translation: ArrayLike | None) -> NDArray[np.float64]:
    """N (n, n') orthonormal: the state coordinates the dynamics see (all but ``translation``)."""
    if translation is None:
        return np.eye(n)
    d = np.asarray(translation, dtype=float).reshape(-1)
    if d.size != n or not np.all(np.isfinite(d)) or not np.any(d):
        raise DetectionError(f"translation must be {n} finite numbers, not all zero; got {d}")
    N = scipy.linalg.null_space(d[None, :])
    # keep the unit vectors where they exist, so the coefficients read as state names
    return np.where(np.abs(N) < 1e-12, 0.0, N)


@dataclass(frozen=True)
class LinearPredictor:
    """x_{k+1} = x_k + coef^T [N^T x_k; u_k; v_k], fitted on samples ``step`` seconds apart.

    basis N (n, n'), coef (n' + m + q, n), step (s), residual_rms (n,): each component's RMS
    one-step residual on the fitting data; input_rms (m,): the input-equivalent residual's RMS
    there; pairs: how many sample pairs it was fitted on."""

    basis: NDArray[np.float64]
    coef: NDArray[np.float64]
    step: float
    residual_rms: NDArray[np.float64]
    input_rms: NDArray[np.float64]
    pairs: int
    m: int

    @property
    def n(self) -> int:
        return self.basis.shape[0]

    @property
    def gamma(self) -> NDArray[np.float64]:
        """Gamma (n, m): the predicted change of x per unit input over one step."""
        k = self.basis.shape[1]
        return self.coef[k : k + self.m].T

    def regressors(self, x: NDArray, u: NDArray, v: NDArray) -> NDArray[np.float64]:
        """[N^T x; u; v] row-wise: (K, n' + m + q) from x (K, n), u (K, m), v (K, q)."""
        return np.hstack([x @ self.basis, u, v])

    def residuals(
        self, x0: ArrayLike, u0: ArrayLike, v0: ArrayLike, x1: ArrayLike
    ) -> NDArray[np.float64]:
        """x1 - prediction (K, n) for K pairs: x0, x1 (K, n), u0 (K, m), v0 (K, q)."""
        x0, x1 = np.atleast_2d(x0).astype(float), np.atleast_2d(x1).astype(float)
        u0 = np.asarray(u0, dtype=float).reshape(x0.shape[0], -1)
        v0 = np.asarray(v0, dtype=float).reshape(x0.shape[0], -1)
        return x1 - x0 - self.regressors(x0, u0, v0) @ self.coef

    def input_equivalent(self, residual: ArrayLike) -> NDArray[np.float64]:
        """e (K, m) from residuals (K, n): the input error explaining each residual best in
        the fitted residuals' metric, e = (G^T W G)^-1 G^T W r, W = diag(1 / rms^2)."""
        r = np.atleast_2d(np.asarray(residual, dtype=float))
        w = 1.0 / self.residual_rms**2
        G = self.gamma
        return np.linalg.solve(G.T @ (w[:, None] * G), ((r * w) @ G).T).T


def fit_predictor(
    t: ArrayLike,
    x: ArrayLike,
    u: ArrayLike,
    v: ArrayLike | None = None,
    *,
    step: float | None = None,
    translation: ArrayLike | None = None,
    rank_rtol: float = 1e-9,
) -> LinearPredictor:
    """Least-squares one-step predictor from K samples: t (K,) s, x (K, n), u (K, m) the input
    acting from each sample to the next, v (K, q) the exostate (optional).

    Pairs are consecutive samples ``step`` apart (default: the smallest spacing); others are
    skipped.  Raises DetectionError when the data are malformed, have fewer than twice as many
    pairs as regressors, or do not excite every regressor (the equilibrated regressor matrix is
    rank-deficient: a predictor would be arbitrary along what is missing), or when the input
    has no fitted effect."""
    t, x, u, v = _as_samples(t, x, u, v)
    n, m = x.shape[1], u.shape[1]
    if n < 1 or m < 1:
        raise DetectionError(f"need a state and an input (n, m >= 1), got n={n}, m={m}")
    if step is None:
        step = float(np.min(np.diff(t))) if t.size > 1 else math.nan
    if not (math.isfinite(step) and step > 0):
        raise DetectionError(f"step must be positive seconds, got {step}")
    basis = _seen_basis(n, translation)
    k = step_pairs(t, step)
    columns = basis.shape[1] + m + v.shape[1]
    if k.size < 2 * columns:
        raise DetectionError(
            f"too few sample pairs {step:g} s apart to fit a predictor: {k.size}, need at "
            f"least {2 * columns} (twice the {columns} regressors)"
        )
    Z = np.hstack([x[k] @ basis, u[k], v[k]])
    dx = x[k + 1] - x[k]
    # equilibrate the columns: positions (km), rates (m/s), inputs and exostates differ by
    # orders of magnitude, and the rank test must not mistake scale for collinearity
    scale = np.linalg.norm(Z, axis=0)
    scale = np.where(scale > 0, scale, 1.0)
    sv = np.linalg.svd(Z / scale, compute_uv=False)
    rank = int(np.sum(sv > rank_rtol * sv[0])) if sv[0] > 0 else 0
    if rank < columns:
        raise DetectionError(
            f"the predictor's regressors are not all excited (rank {rank} of {columns}): the "
            "data must vary the state, the input and the exostate independently (explore)"
        )
    coef = np.linalg.lstsq(Z / scale, dx, rcond=None)[0] / scale[:, None]
    res = dx - Z @ coef
    rms = np.sqrt(np.mean(res**2, axis=0))
    # a component predicted exactly (noise-free kinematics) still needs a positive weight
    floor = 1e-12 * max(float(np.max(np.abs(dx))), 1e-300)
    rms = np.maximum(rms, floor)
    pred = LinearPredictor(basis, coef, float(step), rms, np.ones(m), int(k.size), m)
    if not np.all(np.isfinite(pred.gamma)) or np.linalg.matrix_rank(pred.gamma) < m:
        raise DetectionError("the fitted input has no effect on the state: nothing to watch")
    e = pred.input_equivalent(res)
    return LinearPredictor(
        basis, coef, float(step), rms, np.sqrt(np.mean(e**2, axis=0)), int(k.size), m
    )


class ChangeDetector:
    """Watches a ``LinearPredictor`` on new samples, one at a time (``add``).

    Each sample pairs with the previous one when they are the predictor's step apart; the pair's
    input-equivalent residual e (m,) enters a sliding window of ``window`` seconds.  Once the
    window is full (its pairs span at least ``min_fill`` of it), its mean |e| is compared per
    input with ``bound = bound_factor * predictor.input_rms``: ``statistic`` is the largest
    ratio of the two, and ``alarm`` is set when it exceeds 1."""

    def __init__(
        self,
        predictor: LinearPredictor,
        bound_factor: float,
        window: float,
        min_fill: float = 0.9,
    ) -> None:
        if not (bound_factor > 0 and math.isfinite(bound_factor)):
            raise DetectionError(f"bound_factor must be positive, got {bound_factor}")
        if not (window >= predictor.step and math.isfinite(window)):
            raise DetectionError(
                f"window must be finite and at least one step ({predictor.step:g} s), got {window}"
            )
        if not 0 < min_fill <= 1:
            raise DetectionError(f"min_fill must lie in (0, 1], got {min_fill}")
        self.predictor = predictor
        self.bound = bound_factor * predictor.input_rms  # (m,), the input's units
        self.window = float(window)
        self.min_fill = float(min_fill)
        self._pairs: collections.deque[tuple[float, NDArray]] = collections.deque()
        self._sum = np.zeros(predictor.m)
        self._last: tuple[float, NDArray, NDArray, NDArray] | None = None
        self.statistic = 0.0  # largest |window mean| / bound over the inputs; 0 until full
        self.mean = np.zeros(predictor.m)  # the window's mean e
        self.alarm = False

    def add(self, t: float, x: ArrayLike, u: ArrayLike, v: ArrayLike | None = None) -> bool:
        """One sample: time t (s), state x (n,), the input acting from t on (m,), exostate v
        (q,).  Returns ``alarm``."""
        x = np.asarray(x, dtype=float).reshape(-1)
        u = np.asarray(u, dtype=float).reshape(-1)
        v = np.zeros(0) if v is None else np.asarray(v, dtype=float).reshape(-1)
        last, self._last = self._last, (t, x, u, v)
        if last is None or abs(t - last[0] - self.predictor.step) > 1e-6 * self.predictor.step:
            return self.alarm  # no pair across a gap (or before the first sample)
        e = self.predictor.input_equivalent(self.predictor.residuals(last[1], last[2], last[3], x))
        self._pairs.append((t, e[0]))
        self._sum += e[0]
        while self._pairs and self._pairs[0][0] <= t - self.window + 1e-9:
            self._sum -= self._pairs.popleft()[1]
        covered = len(self._pairs) * self.predictor.step
        if covered >= self.min_fill * self.window - 1e-9:
            self.mean = self._sum / len(self._pairs)
            self.statistic = float(np.max(np.abs(self.mean) / self.bound))
            self.alarm = self.alarm or self.statistic > 1.0
        return self.alarm
