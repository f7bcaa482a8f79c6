"""Data-driven value iteration for optimal output regulation (the paper's Algorithm 2).

The learner never reads A, B or D.  It knows what a flight computer knows: the cost (Q, R),
the output map and reference (C, F), the exosystem E, and a time unit (the orbit rate).

Data.  With w = [x; v] (n + q), every xbar_j = x - X_j v is T_j w for T_j = [I, -X_j], so the
collector accumulates only, per interval [t_l, t_l+1]:

    W_l = integral of w w^T dt        (n+q, n+q)
    G_l = integral of w u^T dt        (n+q, m)     u held between samples, integrated exactly
    w(t_l), w(t_l+1)

from which I_xbar_j, Gamma_xbar_j_u, Gamma_xbar_j_v and delta_xbar_j follow exactly for every
j = 0..h+1.  Memory per interval is fixed, whatever the interval's length or h.

Regression (eq. VI data-driven): for each j,
    Theta_j [vecs(H_k); vec(K_k+1); vec((D - S(X_j))^T P_k)] = delta_j vecs(P_k),
    Theta_j = [I_xbar_j, 2 Gamma_xbar_j_u (I_n kron R), 2 Gamma_xbar_j_v],
with Theta_j's pseudo-inverse applied once: G_j = pinv(Theta_j) delta_j maps vecs(P) to the
unknowns, so an iteration is one small matrix-vector product.  The regression's steps are the
pure functions of :mod:`ddvi_core.regression`; this module holds the data and the learner.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ddvi_core.policy_learning import IterationSettings, iterate
from ddvi_core.regression import (
    EquilibratedTheta,
    RiccatiMap,
    equilibrated_thetas,
    exostate_offsets,
    implied_matrices,
    rank_report,
    regression_maps,
    regression_solution,
    scale_intervals,
    solve_output_regulation,
)
from ddvi_core.scaling import Scaling
from ddvi_core.vec import triangle_size

RANK_RTOL = 1e-10
"""Theta_j's rank counts the singular values above this times the largest."""

__all__ = [
    "DDVIResult",
    "IntervalCollector",
    "IntervalData",
    "LearningError",
    "RankDeficientError",
    "check_dimensions",
    "check_sample",
    "learn_from_data",
    "unknowns_count",
]


class LearningError(ValueError):
    """Data that cannot be learned from (bad sample, too few intervals)."""


class RankDeficientError(LearningError):
    """Theta_j is not of full column rank: the data do not excite every unknown.

    ``report`` says which unknowns are missing and what to do."""

    def __init__(self, report: str, rank: int, needed: int) -> None:
        super().__init__(report)
        self.report = report
        self.rank = rank
        self.needed = needed


def unknowns_count(n: int, m: int, q: int) -> int:
    """n(n+1)/2 + (m+q)n: columns of Theta_j, hence the least number of intervals."""
    return triangle_size(n) + (m + q) * n


@dataclass(frozen=True)
class IntervalData:
    """Interval integrals of rho intervals (N = n + q).

    W (rho, N, N), G (rho, N, m), w_start (rho, N), w_end (rho, N), t_start (rho,),
    t_end (rho,); ``increments`` (rho, N, N): a windowed collector's value-increment matrices
    (None: the increments are taken between the end points)."""

    n: int
    m: int
    q: int
    W: NDArray[np.float64]
    G: NDArray[np.float64]
    w_start: NDArray[np.float64]
    w_end: NDArray[np.float64]
    t_start: NDArray[np.float64]
    t_end: NDArray[np.float64]
    increments: NDArray[np.float64] | None = None

    @property
    def intervals(self) -> int:
        return self.W.shape[0]

    def since(self, t: float) -> IntervalData:
        """The intervals that start at or after t (s): a learning window."""
        keep = self.t_start >= t
        return IntervalData(
            self.n,
            self.m,
            self.q,
            self.W[keep],
            self.G[keep],
            self.w_start[keep],
            self.w_end[keep],
            self.t_start[keep],
            self.t_end[keep],
            None if self.increments is None else self.increments[keep],
        )


def check_dimensions(n: int, m: int, q: int) -> None:
    """A streaming store's sizes: n >= 1 states, m >= 1 inputs, q >= 0 exostates."""
    if min(n, m) < 1 or q < 0:
        raise ValueError(f"need n >= 1, m >= 1, q >= 0; got n={n}, m={m}, q={q}")


def check_sample(name: str, value: ArrayLike | None, size: int) -> NDArray:
    """One sample's ``name`` (x, u or v; None: no values) as ``size`` finite floats; raises
    LearningError naming what is wrong."""
    a = np.asarray(value if value is not None else [], dtype=float).reshape(-1)
    if a.size != size:
        raise LearningError(f"sample {name}: expected {size} values, got {a.size}")
    if not np.all(np.isfinite(a)):
        raise LearningError(f"sample {name}: contains a non-finite value {a.tolist()}")
    return a


class IntervalCollector:
    """Streaming accumulator of the interval integrals, for an on-board learner.

    ``add(t, x, u, v)`` takes one navigation sample: time t (s), state x (n,), the input u (m,)
    applied from t until the next sample (a zero-order hold, integrated exactly), exostate v
    (q,).  Integrals of w w^T use the trapezoidal rule between samples, whose relative error for
    content at frequency w is about (w dt)^2 / 12 (1e-5 at the orbit rate with 10 s samples).
    An interval closes at the first sample at or after its start + ``interval``.  A gap longer
    than ``max_gap`` seconds between samples (lost navigation) discards the open interval and
    starts a new one there, so no integral spans missing data; ``discarded`` counts them.
    """

    def __init__(
        self,
        n: int,
        m: int,
        q: int,
        interval: float,
        max_gap: float | None = None,
        max_intervals: int = 100_000,
    ) -> None:
        check_dimensions(n, m, q)
        if not (interval > 0 and math.isfinite(interval)):
            raise ValueError(f"interval must be positive seconds, got {interval}")
        self.n, self.m, self.q = n, m, q
        self.interval = float(interval)
        self.max_gap = float(max_gap) if max_gap is not None else math.inf
        self.max_intervals = int(max_intervals)
        N = n + q
        self._W: list[NDArray] = []
        self._G: list[NDArray] = []
        self._ws: list[NDArray] = []
        self._we: list[NDArray] = []
        self._ts: list[float] = []
        self._te: list[float] = []
        self._acc_W = np.zeros((N, N))
        self._acc_G = np.zeros((N, m))
        self._start: tuple[float, NDArray] | None = None
        self._last: tuple[float, NDArray, NDArray] | None = None  # t, w, u held from t
        self.samples = 0
        self.discarded = 0

    @property
    def intervals(self) -> int:
        return len(self._W)

    def reset(self) -> None:
        """Forget every interval (for example after an actuator fault changes the plant)."""
        self.__init__(self.n, self.m, self.q, self.interval, self.max_gap, self.max_intervals)

    def add(self, t: float, x: ArrayLike, u: ArrayLike, v: ArrayLike | None = None) -> None:
        if not math.isfinite(t):
            raise LearningError(f"sample time is not finite: {t}")
        x, u = check_sample("x", x, self.n), check_sample("u", u, self.m)
        v = check_sample("v", v, self.q)
        w = np.concatenate([x, v])
        if self._last is not None:
            t0, w0, u0 = self._last
            dt = t - t0
            if dt <= 0:
                raise LearningError(f"sample time {t} does not increase (last was {t0})")
            if dt > self.max_gap:
                self.discarded += self._start is not None and self._start[0] < t0
                self._open(t, w)
            else:
                self._accumulate(t0, w0, u0, t, w)
                if t - self._start[0] >= self.interval - 1e-9 * self.interval:
                    self._close(t, w)
        else:
            self._open(t, w)
        self._last = (t, w, u)
        self.samples += 1

    def _accumulate(self, t0: float, w0: NDArray, u0: NDArray, t: float, w: NDArray) -> None:
        """Add the segment from the sample (t0, w0), with u0 held, to the sample (t, w)."""
        dt = t - t0
        self._acc_W += 0.5 * dt * (np.outer(w0, w0) + np.outer(w, w))
        self._acc_G += 0.5 * dt * np.outer(w0 + w, u0)

    def _open(self, t: float, w: NDArray) -> None:
        self._start = (t, w)
        self._acc_W = np.zeros_like(self._acc_W)
        self._acc_G = np.zeros_like(self._acc_G)

    def _close(self, t: float, w: NDArray) -> None:
        if len(self._W) < self.max_intervals:
            self._W.append(self._acc_W)
            self._G.append(self._acc_G)
            self._ws.append(self._start[1])
            self._we.append(w)
            self._ts.append(self._start[0])
            self._te.append(t)
        self._open(t, w)

    def data(self) -> IntervalData:
        N = self.n + self.q
        if not self._W:
            empty = np.zeros((0, N))
            return IntervalData(
                self.n,
                self.m,
                self.q,
                np.zeros((0, N, N)),
                np.zeros((0, N, self.m)),
                empty,
                empty,
                np.zeros(0),
                np.zeros(0),
            )
        return IntervalData(
            self.n,
            self.m,
            self.q,
            np.array(self._W),
            np.array(self._G),
            np.array(self._ws),
            np.array(self._we),
            np.array(self._ts),
            np.array(self._te),
        )


@dataclass(frozen=True)
class DDVIResult:
    """Gains learned from data, in SI units: u = -K x + L v.

    K (m,n), L (m,q), P (n,n), X (n,q), U (m,q); rank / rank_needed of Theta_0;
    ``condition`` its condition number; ``residual`` the relative least-squares residual of
    the regression at the final P; B and D are what the data imply (for diagnostics only)."""

    K: NDArray[np.float64]
    L: NDArray[np.float64]
    P: NDArray[np.float64]
    X: NDArray[np.float64]
    U: NDArray[np.float64]
    iterations: int
    resets: int
    converged: bool
    rank: int
    rank_needed: int
    condition: float
    residual: float
    intervals: int
    scaling: Scaling
    B_implied: NDArray[np.float64] = field(repr=False)
    D_implied: NDArray[np.float64] = field(repr=False)
    history: NDArray[np.float64] = field(repr=False)
    message: str = ""


def _checked_weights(
    data: IntervalData,
    Q: ArrayLike,
    R: ArrayLike,
    C: ArrayLike | None,
    E: ArrayLike | None,
    F: ArrayLike | None,
) -> tuple[NDArray, NDArray]:
    """Q (n, n) and R (m, m) as float arrays, after checking them and the exosystem against
    the data's n, m and q."""
    n, m, q = data.n, data.m, data.q
    Q = np.asarray(Q, dtype=float)
    R = np.asarray(R, dtype=float)
    if Q.shape != (n, n) or R.shape != (m, m):
        raise LearningError(f"Q must be {n}x{n} and R {m}x{m}, got {Q.shape} and {R.shape}")
    if q and (E is None or C is None or F is None):
        raise LearningError("data carry an exostate (q > 0): C, E and F are required")
    return Q, R


def _state_scale(data: IntervalData, state_scale: ArrayLike | None) -> NDArray[np.float64]:
    """S (n,): the states' units in the iteration, as given or each state's RMS over the
    data's interval end points (1 where that is zero, or when there are no intervals)."""
    n = data.n
    if state_scale is not None:
        S = np.asarray(state_scale, dtype=float).reshape(-1)
        if S.size != n or not np.all(np.isfinite(S)) or np.any(S <= 0):
            raise LearningError(f"state_scale must be {n} positive finite numbers, got {S}")
        return S
    ends = np.concatenate([data.w_start[:, :n], data.w_end[:, :n]])
    x_rms = np.sqrt(np.mean(ends**2, axis=0)) if data.intervals else np.ones(n)
    return np.where(x_rms > 0, x_rms, 1.0)


def _scaling(Q: NDArray, S: NDArray, w0: float, m: int) -> Scaling:
    """tau = w0 t, x = S x_s, inputs unscaled, and the cost normalised to |Q_s| = 1."""
    q_norm = float(np.linalg.norm(Q * np.outer(S, S) / w0, 2))
    return Scaling(w0, S, np.ones(m), 1.0 / q_norm if q_norm > 0 else 1.0)


def _translation_offset(
    data: IntervalData, direction: ArrayLike, E: ArrayLike | None
) -> NDArray[np.float64]:
    """X_off (n, q): the data's time-mean position along ``direction`` (n,), on the
    exosystem's constant mode (the column and row of E that are zero)."""
    n, q = data.n, data.q
    d = np.asarray(direction, dtype=float).reshape(-1)
    if d.size != n or not np.all(np.isfinite(d)) or not np.any(d):
        raise LearningError(f"translation must be {n} finite numbers, not all zero; got {d}")
    Ea = np.zeros((0, 0)) if E is None else np.asarray(E, dtype=float)
    constant = [i for i in range(q) if not np.any(Ea[:, i]) and not np.any(Ea[i, :])]
    if not constant:
        raise LearningError(
            "translation needs an exosystem with a constant mode (a zero row and column of E) "
            "to carry the offset; add one or drop translation"
        )
    i = constant[0]
    duration = float(np.sum(data.t_end - data.t_start))
    if duration <= 0:
        return np.zeros((n, q))
    v_i = data.W[:, n + i, n + i].sum() / duration  # the constant mode's value squared
    if v_i <= 0:
        return np.zeros((n, q))
    d = d / np.linalg.norm(d)
    # time-mean of (d . x) v_i over the data, divided by v_i^2: the offset's amplitude
    c = float(d @ data.W[:, :n, n + i].sum(axis=0)) / (duration * v_i)
    X = np.zeros((n, q))
    X[:, i] = c * d
    return X


def _checked_rank(
    thetas: list[EquilibratedTheta], data: IntervalData, needed: int, rtol: float
) -> tuple[int, float]:
    """Theta_0's numerical rank and condition number, after checking that every Theta_j is of
    full column rank (``needed``); raises RankDeficientError with a report if one is not."""
    n, m, q, rho = data.n, data.m, data.q, data.intervals
    ranks, condition = [], math.inf
    for j, th in enumerate(thetas):
        sv = np.linalg.svd(th.scaled, compute_uv=False) if rho else np.zeros(1)
        rj = int(np.sum(sv > rtol * sv[0])) if rho and sv[0] > 0 else 0
        if rj < needed:
            prefix = "" if j == 0 else f"Theta_{j} (xbar_{j} = x - X_{j} v): "
            report = rank_report(th.scaled, n, m, q, rj, needed, rho, rtol)
            raise RankDeficientError(prefix + report, rj, needed)
        ranks.append(rj)
        if j == 0:
            condition = float(sv[0] / sv[needed - 1])
    return ranks[0], condition


def _regulator_in_si(
    X_list: list[NDArray],
    S_X: list[NDArray],
    B_s: NDArray,
    D_s: NDArray,
    S: NDArray,
    Qbar: ArrayLike | None,
    Rbar: ArrayLike | None,
    m: int,
) -> tuple[NDArray, NDArray]:
    """(X (n, q), U (m, q)) in SI units from the scaled Problem 1; empty without an exostate."""
    n, q = X_list[0].shape
    if not q:
        return np.zeros((n, 0)), np.zeros((m, 0))
    X_s, U = solve_output_regulation(X_list, S_X, B_s, D_s, S, Qbar, Rbar)
    return X_s * S[:, None], U


def _outcome(iterations: int, resets: int, converged: bool, why: str) -> str:
    if converged:
        met = f": {why}" if why else ""
        return f"converged in {iterations} iterations ({resets} resets){met}"
    return f"not converged after {iterations} iterations ({why})"


def learn_from_data(
    data: IntervalData,
    Q: ArrayLike,
    R: ArrayLike,
    *,
    time_unit: float,
    C: ArrayLike | None = None,
    E: ArrayLike | None = None,
    F: ArrayLike | None = None,
    iteration: IterationSettings | None = None,
    P0: ArrayLike | None = None,
    K0: ArrayLike | None = None,
    Qbar: ArrayLike | None = None,
    Rbar: ArrayLike | None = None,
    state_scale: ArrayLike | None = None,
    translation: ArrayLike | None = None,
) -> DDVIResult:
    """Algorithm 2 on collected interval data.

    Q (n,n), R (m,m); with an exosystem C (p,n), E (q,q), F (p,q).  ``time_unit`` (1/s) is
    the iteration's time unit (see :mod:`ddvi_core.value_iteration`).  ``state_scale`` (n,)
    gives the states' units in the iteration (for a Hill state [positions; velocities],
    metres and metres per time unit: [1, .., w0, ..]); by default each state's RMS over the
    data.  The cost is normalised to |Q_s| = 1.  Raises RankDeficientError
    with a report when Theta_j is not of full column rank.

    ``translation`` (n,) is a direction d the dynamics do not see (A d = 0: for a Hill state,
    an along-track shift, because no point of a circular orbit is special).  Every xbar_j is
    then taken about the data's mean position along d, carried on the exosystem's constant
    mode: X_j + c d e_0^T with S(c d e_0^T) = c (d e_0^T E - A d e_0^T) = 0, so the unknowns
    are exactly Algorithm 2's.  It matters far from the origin: at 35 km behind the chief,
    xbar = x is all along-track offset, the regression is dominated by P_yy y^2, and any
    unmodelled acceleration enters it scaled by the offset.

    ``iteration`` says how it iterates (:class:`ddvi_core.policy_learning.IterationSettings`:
    value iteration by default; policy iteration and the hybrid start from the stabilising
    gain ``K0`` (m, n), SI units, value iteration from ``P0``); an ``adaptive`` step takes a
    fraction of the Euler stability limit of the current closed loop, read off the matrices
    the data's map implies (:func:`ddvi_core.regression.implied_plant`), and an ``implicit``
    step grows from that towards Newton's on the derivative of the data's map
    (:mod:`ddvi_core.continuation`).
    """
    n, m, q = data.n, data.m, data.q
    Q, R = _checked_weights(data, Q, R, C, E, F)
    needed = unknowns_count(n, m, q)
    w0 = float(time_unit)
    S = _state_scale(data, state_scale)
    sc = _scaling(Q, S, w0, m)
    Q_s, R_s = sc.weights(Q, R)
    scaled = scale_intervals(data.W, data.G, data.w_start, data.w_end, w0, S, data.increments)
    X_list = exostate_offsets(C, F, S, n, q)
    X_off = 0.0 if translation is None else _translation_offset(data, translation, E) / S[:, None]
    thetas = equilibrated_thetas(n, m, q, X_list, X_off, R_s, scaled)
    rank, condition = _checked_rank(thetas, data, needed, RANK_RTOL)
    maps = regression_maps(thetas)
    P0_s = 1e-3 * np.eye(n) if P0 is None else np.asarray(P0, dtype=float)
    K0_s = np.zeros((m, n)) if K0 is None else np.asarray(K0, dtype=float) * S[None, :]
    P_s, _, k, resets, converged, _, history, why = iterate(
        RiccatiMap(maps[0], n, m), Q_s, R_s, P0_s, K0_s, iteration or IterationSettings()
    )
    K_s, residual = regression_solution(maps[0], thetas[0], P_s, n, m)
    B_s, D_s, S_X = implied_matrices(maps, P_s, K_s, R_s, n, m, q)
    X, U = _regulator_in_si(X_list, S_X, B_s, D_s, S, Qbar, Rbar, m)
    K = sc.unscale_K(K_s)
    return DDVIResult(
        K=K,
        L=U + K @ X,
        P=sc.unscale_P(P_s),
        X=X,
        U=U,
        iterations=k,
        resets=resets,
        converged=converged,
        rank=rank,
        rank_needed=needed,
        condition=condition,
        residual=residual,
        intervals=data.intervals,
        scaling=sc,
        B_implied=B_s * S[:, None] * w0,
        D_implied=D_s * S[:, None] * w0,
        history=history,
        message=_outcome(k, resets, converged, why),
    )
