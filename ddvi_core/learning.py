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
unknowns, so an iteration is one small matrix-vector product.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import scipy.linalg
from numpy.typing import ArrayLike, NDArray

from ddvi_core.regulator import solve_equality_constrained_lstsq
from ddvi_core.value_iteration import (
    BoundSchedule,
    Scaling,
    StepSequence,
    value_iteration_loop,
)
from ddvi_core.vec import triangle_size, unvec, vec, vecs, vecv

__all__ = [
    "DDVIResult",
    "IntervalCollector",
    "IntervalData",
    "LearningError",
    "RankDeficientError",
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
    t_end (rho,)."""

    n: int
    m: int
    q: int
    W: NDArray[np.float64]
    G: NDArray[np.float64]
    w_start: NDArray[np.float64]
    w_end: NDArray[np.float64]
    t_start: NDArray[np.float64]
    t_end: NDArray[np.float64]

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
        )


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
        if min(n, m) < 1 or q < 0:
            raise ValueError(f"need n >= 1, m >= 1, q >= 0; got n={n}, m={m}, q={q}")
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

    def _check(self, name: str, value: ArrayLike, size: int) -> NDArray:
        a = np.asarray(value, dtype=float).reshape(-1)
        if a.size != size:
            raise LearningError(f"sample {name}: expected {size} values, got {a.size}")
        if not np.all(np.isfinite(a)):
            raise LearningError(f"sample {name}: contains a non-finite value {a.tolist()}")
        return a

    def add(self, t: float, x: ArrayLike, u: ArrayLike, v: ArrayLike | None = None) -> None:
        if not math.isfinite(t):
            raise LearningError(f"sample time is not finite: {t}")
        x = self._check("x", x, self.n)
        u = self._check("u", u, self.m)
        v = self._check("v", v if v is not None else [], self.q)
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
                self._acc_W += 0.5 * dt * (np.outer(w0, w0) + np.outer(w, w))
                self._acc_G += 0.5 * dt * np.outer(w0 + w, u0)
                if t - self._start[0] >= self.interval - 1e-9 * self.interval:
                    self._close(t, w)
        else:
            self._open(t, w)
        self._last = (t, w, u)
        self.samples += 1

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


def _theta(
    data: IntervalData, T: NDArray, R: NDArray, W: NDArray, G: NDArray, ws: NDArray, we: NDArray
) -> tuple[NDArray, NDArray]:
    """Theta_j (rho, cols) and delta_j (rho, n(n+1)/2) for xbar = T w."""
    n, m, q = data.n, data.m, data.q
    rows, cols = np.triu_indices(n)
    M = np.einsum("ia,lab,jb->lij", T, W, T)
    I_x = M[:, rows, cols]
    Gu = np.einsum("ia,lak->lik", T, G).reshape(len(W), n * m)
    Gv = np.einsum("ia,lak->lik", T, W[:, :, n:]).reshape(len(W), n * q)
    delta = vecv(we @ T.T) - vecv(ws @ T.T)
    Theta = np.hstack([I_x, 2.0 * Gu @ np.kron(np.eye(n), R), 2.0 * Gv])
    return Theta, delta


def _rank_report(
    Theta: NDArray, n: int, m: int, q: int, rank: int, needed: int, rho: int, rtol: float
) -> str:
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


def learn_from_data(
    data: IntervalData,
    Q: ArrayLike,
    R: ArrayLike,
    *,
    time_unit: float,
    C: ArrayLike | None = None,
    E: ArrayLike | None = None,
    F: ArrayLike | None = None,
    steps: StepSequence | None = None,
    bounds: BoundSchedule | None = None,
    tol: float = 1e-6,
    max_iterations: int = 200_000,
    P0: ArrayLike | None = None,
    Qbar: ArrayLike | None = None,
    Rbar: ArrayLike | None = None,
    rank_rtol: float = 1e-10,
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
    """
    n, m, q = data.n, data.m, data.q
    Q = np.asarray(Q, dtype=float)
    R = np.asarray(R, dtype=float)
    if Q.shape != (n, n) or R.shape != (m, m):
        raise LearningError(f"Q must be {n}x{n} and R {m}x{m}, got {Q.shape} and {R.shape}")
    if q and (E is None or C is None or F is None):
        raise LearningError("data carry an exostate (q > 0): C, E and F are required")
    needed = unknowns_count(n, m, q)
    rho = data.intervals

    # ---- scaling: tau = w0 t, x = S x_s, states at their RMS over the data -----------------
    w0 = float(time_unit)
    if state_scale is not None:
        S = np.asarray(state_scale, dtype=float).reshape(-1)
        if S.size != n or not np.all(np.isfinite(S)) or np.any(S <= 0):
            raise LearningError(f"state_scale must be {n} positive finite numbers, got {S}")
    else:
        ends = np.concatenate([data.w_start[:, :n], data.w_end[:, :n]])
        x_rms = np.sqrt(np.mean(ends**2, axis=0)) if rho else np.ones(n)
        S = np.where(x_rms > 0, x_rms, 1.0)
    sw = np.concatenate([S, np.ones(q)])
    q_norm = float(np.linalg.norm(Q * np.outer(S, S) / w0, 2))
    sc = Scaling(w0, S, np.ones(m), 1.0 / q_norm if q_norm > 0 else 1.0)
    Q_s, R_s = sc.weights(Q, R)
    W = w0 * data.W / np.outer(sw, sw)[None]
    G = w0 * data.G / sw[None, :, None]
    ws, we = data.w_start / sw, data.w_end / sw

    # ---- the X_j of Algorithm 2, in scaled coordinates --------------------------------------
    if q:
        C_s = np.asarray(C, dtype=float) * S[None, :]
        F_s = np.asarray(F, dtype=float)
        X_list = [np.zeros((n, q)), -np.linalg.pinv(C_s) @ F_s]
        basis = scipy.linalg.null_space(np.kron(np.eye(q), C_s))
        X_list += [unvec(b, (n, q)) for b in basis.T]
    else:
        X_list = [np.zeros((n, 0))]

    X_off = 0.0 if translation is None else _translation_offset(data, translation, E) / S[:, None]
    # Theta_j with its columns equilibrated: the unknowns (H, K, (D - S)^T P) differ by many
    # orders of magnitude, and an unequilibrated least-squares solve loses them to round-off
    thetas = []
    for X in X_list:
        Th, d = _theta(data, np.hstack([np.eye(n), -(X + X_off)]), R_s, W, G, ws, we)
        norms = np.linalg.norm(Th, axis=0)
        thetas.append((Th, d, np.where(norms > 0, norms, 1.0)))
    ranks, condition = [], math.inf
    for j, (Th, _, cn) in enumerate(thetas):
        sv = np.linalg.svd(Th / cn, compute_uv=False) if rho else np.zeros(1)
        rj = int(np.sum(sv > rank_rtol * sv[0])) if rho and sv[0] > 0 else 0
        if rj < needed:
            prefix = "" if j == 0 else f"Theta_{j} (xbar_{j} = x - X_{j} v): "
            raise RankDeficientError(
                prefix + _rank_report(Th / cn, n, m, q, rj, needed, rho, rank_rtol), rj, needed
            )
        ranks.append(rj)
        if j == 0:
            condition = float(sv[0] / sv[needed - 1])
    rank = ranks[0]
    Theta0, delta0, _ = thetas[0]
    # pinv(Theta_j) delta_j, computed once (the paper's Remark): vecs(P) -> unknowns
    maps = [np.linalg.lstsq(Th / cn, d, rcond=None)[0] / cn[:, None] for Th, d, cn in thetas]
    t_, mn = triangle_size(n), m * n
    rows, cols = np.triu_indices(n)
    weights = np.where(rows == cols, 1.0, 2.0)
    H_map = maps[0][:t_] * np.where(rows == cols, 1.0, 0.5)[:, None]
    K_map = maps[0][t_ : t_ + mn]

    def riccati_map(P: NDArray) -> tuple[NDArray, NDArray]:
        p = weights * P[rows, cols]  # vecs(P)
        H = np.zeros((n, n))
        H[rows, cols] = H_map @ p
        return H + np.triu(H, 1).T, (K_map @ p).reshape(n, m).T

    P0_s = 1e-3 * np.eye(n) if P0 is None else np.asarray(P0, dtype=float)
    P_s, K_s, k, resets, converged, _, history, why = value_iteration_loop(
        riccati_map,
        Q_s,
        R_s,
        P0_s,
        steps or StepSequence(),
        bounds or BoundSchedule(),
        tol,
        max_iterations,
    )
    p_star = vecs(P_s)
    theta0 = maps[0] @ p_star
    K_s = unvec(theta0[t_ : t_ + mn], (m, n))
    residual = float(
        np.linalg.norm(Theta0 @ theta0 - delta0 @ p_star)
        / max(np.linalg.norm(delta0 @ p_star), 1e-300)
    )

    # ---- B, D, S(X_j) from data; (X*, U*) by Problem 1 --------------------------------------
    Pinv = np.linalg.inv(P_s)
    B_s = Pinv @ K_s.T @ R_s
    if q:
        Ms = [unvec((mp @ p_star)[t_ + mn :], (q, n)) for mp in maps]
        D_s = Pinv @ Ms[0].T
        S_X = [Pinv @ (Ms[0] - Mj).T for Mj in Ms]  # S(X_j) = D - P^-1 M_j^T
        Qb = np.eye(n) if Qbar is None else np.asarray(Qbar, dtype=float)
        Rb = np.eye(m) if Rbar is None else np.asarray(Rbar, dtype=float)
        Iq = np.eye(q)
        Nx = (
            np.column_stack([vec(X) for X in X_list[2:]])
            if len(X_list) > 2
            else np.zeros((n * q, 0))
        )
        Ns = (
            np.column_stack([vec(Sx) for Sx in S_X[2:]])
            if len(X_list) > 2
            else np.zeros((n * q, 0))
        )
        h = Nx.shape[1]
        Gc = np.hstack([Ns, -np.kron(Iq, B_s)])
        gc = vec(D_s) - vec(S_X[1])
        Wx = np.kron(Iq, scipy.linalg.sqrtm(Qb).real * S[None, :])  # weights in SI units
        Mo = scipy.linalg.block_diag(Wx @ Nx, np.kron(Iq, scipy.linalg.sqrtm(Rb).real))
        co = np.concatenate([-Wx @ vec(X_list[1]), np.zeros(m * q)])
        z, _ = solve_equality_constrained_lstsq(Mo, co, Gc, gc, rtol=1e-6)
        X_s = X_list[1] + (unvec(Nx @ z[:h], (n, q)) if h else 0.0)
        U_s = unvec(z[h:], (m, q))
        X, U = X_s * S[:, None], U_s
        D_si = D_s * S[:, None] * w0
    else:
        X, U, D_si = np.zeros((n, 0)), np.zeros((m, 0)), np.zeros((n, 0))
    K = sc.unscale_K(K_s)
    L = U + K @ X
    message = (
        f"converged in {k} iterations ({resets} resets)"
        if converged
        else f"not converged after {k} iterations ({why})"
    )
    return DDVIResult(
        K=K,
        L=L,
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
        intervals=rho,
        scaling=sc,
        B_implied=B_s * S[:, None] * w0,
        D_implied=D_si,
        history=history,
        message=message,
    )
