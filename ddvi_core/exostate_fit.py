"""The exostate's input D refitted with A and B held: what the model-fit learner's feedforward
is solved on (:func:`fit_exosystem_input`), with the exostate's modes grouped as E couples
them (:func:`exostate_groups`, :func:`static_groups`), fitted free or along B, and kept only
where the data tell them from zero (a cluster-robust Wald test, the covariance of
:func:`ddvi_core.fit_uncertainty.gain_standard_error`).  Pure functions on arrays."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ddvi_core.fit_uncertainty import cluster_sums, clusters
from ddvi_core.learning import LearningError
from ddvi_core.model_fit import (
    IntegralData,
    _column_scale,
    _full_rank_lstsq,
    interval_pairs,
    interval_regressors,
)

__all__ = ["exostate_groups", "fit_exosystem_input", "static_groups"]


def exostate_groups(E: ArrayLike) -> list[list[int]]:
    """The exostate's modes (q,) grouped as E (q, q) couples them: the connected components of
    E's nonzero pattern, each in index order (a constant is a group of one, a harmonic its
    cosine and sine).  A mode is kept or dropped from a feedforward whole."""
    E = np.atleast_2d(np.asarray(E, dtype=float))
    q = E.shape[0]
    linked = (E != 0) | (E.T != 0)
    group = list(range(q))
    for i in range(q):
        for j in range(i + 1, q):
            if linked[i, j]:
                old, new = group[j], group[i]
                group = [new if g == old else g for g in group]
    return [[k for k in range(q) if group[k] == g] for g in sorted(set(group))]


def static_groups(E: ArrayLike) -> list[list[int]]:
    """The groups of :func:`exostate_groups` that E holds constant (zero rows and columns):
    a constant, a measured ratio; not a harmonic."""
    E = np.atleast_2d(np.asarray(E, dtype=float))
    return [g for g in exostate_groups(E) if not E[np.ix_(g, g)].any()]


def _wald_p_values(X: NDArray, y: NDArray, cluster: NDArray, groups: list[list[int]]) -> NDArray:
    """Per group of X's columns: the chi-squared tail probability of a Wald statistic as large
    as the fit's, were the group's coefficients zero, under the cluster-robust covariance of
    the least-squares fit of y (rows,) on X (rows, p)."""
    import scipy.stats  # here: it costs a service's start-up a second

    theta, *_ = np.linalg.lstsq(X, y, rcond=None)
    sums = cluster_sums(cluster, (y - X @ theta)[:, None] * X)
    G = np.linalg.pinv(X.T @ X)
    cov = G @ sums.T @ sums @ G
    p_values = []
    for g in groups:
        sub = cov[np.ix_(g, g)]
        dof = int(np.linalg.matrix_rank(sub))
        stat = float(theta[g] @ np.linalg.pinv(sub) @ theta[g]) if dof else 0.0
        p_values.append(float(scipy.stats.chi2.sf(stat, dof)) if dof else 1.0)
    return np.asarray(p_values)


def _columns_of(groups: list[list[int]]) -> list[int]:
    """The exostate columns that ``groups`` hold, in order."""
    return sorted(k for g in groups for k in g)


def _independent_groups(design: Any, groups: list[list[int]], rtol: float) -> list[list[int]]:
    """``groups`` in order, less each whose columns of ``design(cols)`` (scaled to unit RMS)
    the groups before it already span to ``rtol``: on station at a constant altitude the
    density ratio is a constant."""
    kept: list[list[int]] = []
    for g in groups:
        X = design(_columns_of([*kept, g]))
        sv = np.linalg.svd(X / _column_scale(X), compute_uv=False)
        if sv.size and sv[0] > 0 and sv[-1] > rtol * sv[0]:
            kept.append(g)
    return kept


def _checked_groups(groups: list[list[int]] | None, q: int) -> list[list[int]]:
    """``groups`` as lists (default: each of the q columns alone); LearningError unless they
    are disjoint sets of the q columns."""
    kept = [list(g) for g in (groups if groups is not None else [[k] for k in range(q)])]
    cols = _columns_of(kept)
    if len(set(cols)) != len(cols) or not set(cols) <= set(range(q)):
        raise LearningError(f"groups must be disjoint sets of the {q} exostate columns: {groups}")
    return kept


def _held_input(held: ArrayLike | None, cols: list[int], n: int, q: int) -> NDArray:
    """D (n, q) as ``held`` (n, q) has it (default zero), with the fitted columns ``cols``
    zero."""
    D = np.zeros((n, q)) if held is None else np.array(held, dtype=float).reshape(n, q)
    D[:, cols] = 0.0
    return D


def _unexplained(
    y: NDArray, phi: NDArray, A: NDArray, B: NDArray, D: NDArray, positions: int
) -> NDArray:
    """The interval relation's residual y - A int x - B int u - D int v (rho, n - positions) of
    y (rho, n) and phi (rho, n + m + q), on the rows after the first ``positions``
    (kinematic)."""
    n, m = B.shape
    rest = y - phi[:, :n] @ A.T - phi[:, n : n + m] @ B.T - phi[:, n + m :] @ D.T
    return rest[:, positions:]


@dataclass(frozen=True)
class _ExostateRegression:
    """The unexplained motion ``target`` (rho n_f,) on the exostate's integrals phi_v (rho, q),
    where each fitted column k of D is M theta_k with M (n_f, w): the identity on the n_f
    fitted rows, or B's fitted rows when ``matched``."""

    phi_v: NDArray
    M: NDArray
    target: NDArray
    matched: bool

    def design(self, cols: list[int]) -> NDArray:
        """The regressor (rho n_f, len(cols) w) of the columns ``cols``' parameters."""
        return np.kron(self.phi_v[:, cols], self.M)  # rows (interval, state), columns (mode, theta)

    def parameters(self, cols: list[int], group: list[int]) -> list[int]:
        """Where ``group``'s parameters stand among those of the columns ``cols``."""
        w = self.M.shape[1]
        return [cols.index(k) * w + j for k in group for j in range(w)]

    def fit(self, cols: list[int], rtol: float) -> NDArray:
        """theta (len(cols) w, 1), least squares on :meth:`design`; RankDeficientError when
        the columns' parameters are not identifiable to ``rtol``."""
        along = "along B" if self.matched else "row"
        names = [f"int v{k} {along} {j}" for k in cols for j in range(self.M.shape[1])]
        theta, _ = _full_rank_lstsq(self.design(cols), self.target[:, None], names, rtol)
        return theta

    def input_columns(self, cols: list[int], rtol: float) -> NDArray:
        """D's fitted rows (n_f, len(cols)) in the columns ``cols``, fitted: M theta_k each."""
        theta = self.fit(cols, rtol)
        return self.M @ theta.reshape(len(cols), self.M.shape[1]).T


def _significant_groups(
    regression: _ExostateRegression,
    groups: list[list[int]],
    cluster: NDArray,
    significance: float,
) -> list[list[int]]:
    """``groups`` less those whose coefficients the data do not tell from zero: one at a
    time, the least significant first, each time refitting the rest, until every group's
    cluster-robust Wald test (rows in clusters ``cluster`` (rho n_f,)) rejects "zero" at level
    ``significance``."""
    kept = list(groups)
    while kept:
        cols = _columns_of(kept)
        X = regression.design(cols)
        scale = _column_scale(X)
        params = [regression.parameters(cols, g) for g in kept]
        p_values = _wald_p_values(X / scale, regression.target, cluster, params)
        worst = int(np.argmax(p_values))
        if p_values[worst] <= significance:
            break
        kept.pop(worst)
    return kept


def _row_clusters(
    data: IntegralData, length: float, stride: float, smoothing: float, rows: int
) -> NDArray:
    """The cluster (rho rows,) of each row of the flattened regression, ``rows`` rows an
    interval: 2 (length + smoothing) s of interval starts each
    (:func:`ddvi_core.fit_uncertainty.clusters`)."""
    pairs = interval_pairs(data.t, data.segment, length, stride, smoothing)
    return np.repeat(clusters(data, pairs, 2 * (length + smoothing)), rows)


def fit_exosystem_input(
    data: IntegralData,
    A: ArrayLike,
    B: ArrayLike,
    *,
    length: float,
    stride: float,
    smoothing: float = 0.0,
    rtol: float = 1e-9,
    positions: int = 0,
    groups: list[list[int]] | None = None,
    significance: float = 0.0,
    held: ArrayLike | None = None,
    matched: bool = False,
) -> NDArray[np.float64]:
    """D (n, q) refitted with A (n, n) and B (n, m) held: the least-squares D of the interval
    relation's residual x(b) - x(a) - A int x - B int u on int v.  It needs no excitation of
    the input, so it can be fitted on data flown on the learned gains near the slot, where the
    exostate's effect (the drag offset) is what the feedforward must cancel; the first
    ``positions`` rows (kinematics, as in :func:`fit_linear_model`) are zero.

    ``groups`` are the columns fitted, in groups (default: every column, one each; see
    :func:`exostate_groups`); any other column is held at ``held``'s (n, q; default zero).
    ``matched``: each fitted column is B theta_k (theta_k (m,)), a disturbance that acts where
    the input does (a drag offset acts along the drag, whatever the fit's A makes of the
    rest): m numbers a column instead of n - positions, and the regulator equations then give
    X = 0 and U = -theta for it.

    With ``significance`` alpha in (0, 1), a group whose coefficients the data do not tell
    from zero is dropped (its D columns zero), one at a time, the least significant first,
    each time refitting the rest: a group stays when its cluster-robust Wald test rejects
    "zero" at level alpha.  A feedforward solved on noise is worse than none: the loop's
    orbit-rate mode is lightly damped, and a spurious orbit-rate term in D drives it at
    resonance.  Raises RankDeficientError when the fitted columns' integrals do not have full
    rank."""
    A, B = np.asarray(A, dtype=float), np.asarray(B, dtype=float)
    n, m = B.shape
    if not 0 <= significance < 1:
        raise LearningError(f"significance must lie in [0, 1), got {significance}")
    y, phi = interval_regressors(data, length, stride, smoothing)
    q = phi.shape[1] - n - m
    kept = _checked_groups(groups, q)
    D = _held_input(held, _columns_of(kept), n, q)
    target = _unexplained(y, phi, A, B, D, positions).reshape(-1)
    # each fitted column is M theta_k: M = I (free rows) or B's fitted rows (matched)
    M = B[positions:] if matched else np.eye(n - positions)
    regression = _ExostateRegression(phi[:, n + m :], M, target, matched)
    if significance > 0:  # a group the others already span says nothing of its own
        kept = _independent_groups(regression.design, kept, rtol)
    cols = _columns_of(kept)
    if cols:  # the fitted columns must be identifiable before any is dropped
        regression.fit(cols, rtol)
    if significance > 0 and cols:
        cluster = _row_clusters(data, length, stride, smoothing, n - positions)
        kept = _significant_groups(regression, kept, cluster, significance)
    cols = _columns_of(kept)
    if cols:
        D[positions:, cols] = regression.input_columns(cols, rtol)
    return D
