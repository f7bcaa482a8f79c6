"""How well the data determine an interval fit (``ddvi_core.model_fit``): the cluster-robust
covariance of its parameters and the gain's predicted relative error drawn from it
(:func:`gain_standard_error`), and the clusters the model-fit learner's significance tests
share (``ddvi_core.exostate_fit``).  Overlapping intervals and a filtered estimate's coloured
error make neighbouring rows dependent, so the rows are grouped in clusters of interval starts
far enough apart to be nearly independent.  Pure functions on arrays."""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ddvi_core.lqr import NotStabilisingError, relative_gain_error, solve_lqr
from ddvi_core.model_fit import IntegralData, _column_scale, _design, _model, interval_pairs

__all__ = ["cluster_sums", "clusters", "gain_standard_error"]


def clusters(data: IntegralData, pairs: NDArray, cluster_s: float) -> NDArray:
    """The cluster (rho,) of each interval: ``cluster_s`` s of interval starts each.
    Overlapping intervals and a filtered estimate's coloured error make neighbouring rows
    dependent, rows that far apart nearly independent."""
    start = data.t[pairs[:, 0]]
    return np.floor((start - start[0]) / cluster_s).astype(int)


def cluster_sums(cluster: NDArray, score: NDArray) -> NDArray:
    """The rows' scores (rows, k) summed per cluster (clusters, k)."""
    sums = np.zeros((cluster[-1] + 1, score.shape[1]))
    np.add.at(sums, cluster, score)
    return sums


def gain_standard_error(
    data: IntegralData,
    K: ArrayLike,
    Q: ArrayLike,
    R: ArrayLike,
    *,
    length: float,
    stride: float,
    translation: ArrayLike | None = None,
    smoothing: float = 0.0,
    positions: int = 0,
    draws: int = 32,
    seed: int = 0,
) -> float:
    """The predicted relative error of the gain K (m, n) fitted on ``data``: the RMS of
    |K_i - K| / |K| over ``draws`` gains K_i of models drawn from the fit's parameter
    covariance (a fixed ``seed``: the same data give the same answer); inf when a draw has
    no stabilising gain.

    The covariance is the cluster-robust sandwich (Phi'Phi)^-1 (sum_c s_c s_c') (Phi'Phi)^-1
    with clusters of 2 (length + smoothing) s of interval starts and s_c the sum over a
    cluster of the rows' residual times regressor: overlapping intervals share their
    noise, and a filtered navigation estimate's error is coloured, so the rows are not
    independent, but clusters that far apart nearly are.  It holds for noise and for model
    error alike, and measured on the default mission it is 1x to 10x the true error."""
    dx, phi, N = _design(data, length, stride, translation, smoothing, positions)
    rho, p = phi.shape
    n, m = dx.shape[1], np.shape(K)[0]
    if rho <= p:
        return math.inf
    scale = _column_scale(phi)
    Z = phi / scale
    theta, *_ = np.linalg.lstsq(Z, dx, rcond=None)  # (p, n)
    pairs = interval_pairs(data.t, data.segment, length, stride, smoothing)
    score = np.einsum("ij,ik->ijk", dx - Z @ theta, Z).reshape(rho, n * p)
    sums = cluster_sums(clusters(data, pairs, 2 * (length + smoothing)), score)
    G = np.kron(np.eye(n), np.linalg.pinv(Z.T @ Z))
    cov = G @ sums.T @ sums @ G
    w, V = np.linalg.eigh(0.5 * (cov + cov.T))
    noise = np.random.default_rng(seed).standard_normal((draws, n * p))
    K = np.asarray(K, dtype=float)
    errors = []
    for dtheta in (noise * np.sqrt(np.clip(w, 0, None))) @ V.T:
        t = (theta + dtheta.reshape(n, p).T) / scale[:, None]
        A, B, _ = _model(t, N, m, positions)
        try:
            Ki = solve_lqr(A, B, Q, R).K
        except NotStabilisingError:
            return math.inf
        errors.append(relative_gain_error(Ki, K))
    return float(np.sqrt(np.mean(np.square(errors))))
