"""The smoother the RTS benchmark measures with (``benchmarks.rts_smoother``): on a linear
Gaussian model its backward pass over a Kalman filter's forward pass is the batch least-squares
estimate of every state from every measurement, and its fixed-lag pass with a lag past the end
is the same."""

from __future__ import annotations

import numpy as np

from benchmarks.rts_smoother import rts_full, rts_gains, rts_lag


def _kalman(Phi, Q, R, z):
    """A Kalman filter over z (K, n) measuring the whole state, started on the first
    measurement: the forward pass as the benchmark records it."""
    nav = []
    x, P = z[0].copy(), R.copy()
    nav.append((0.0, None, None, None, x.copy(), P.copy()))
    for k in range(1, len(z)):
        xp, Pp = Phi @ x, Phi @ P @ Phi.T + Q
        K = Pp @ np.linalg.inv(Pp + R)
        x, P = xp + K @ (z[k] - xp), (np.eye(len(x)) - K) @ Pp
        nav.append((float(k), Phi, xp, Pp, x.copy(), P.copy()))
    return nav


def _batch(Phi, Q, R, z):
    """argmin of sum |z_k - x_k|^2_R^-1 + sum |x_k+1 - Phi x_k|^2_Q^-1 over every x_k."""
    K, n = z.shape
    rows, rhs = [], []
    Wr, Wq = np.linalg.cholesky(np.linalg.inv(R)).T, np.linalg.cholesky(np.linalg.inv(Q)).T
    for k in range(K):
        row = np.zeros((n, K * n))
        row[:, k * n : (k + 1) * n] = Wr
        rows.append(row)
        rhs.append(Wr @ z[k])
    for k in range(K - 1):
        row = np.zeros((n, K * n))
        row[:, k * n : (k + 1) * n] = -Wq @ Phi
        row[:, (k + 1) * n : (k + 2) * n] = Wq
        rows.append(row)
        rhs.append(np.zeros(n))
    x, *_ = np.linalg.lstsq(np.vstack(rows), np.concatenate(rhs), rcond=None)
    return x.reshape(K, n)


def test_the_rts_pass_is_the_batch_estimate_and_a_long_lag_is_the_full_pass() -> None:
    rng = np.random.default_rng(7)
    dt = 10.0
    Phi = np.array([[1.0, dt], [0.0, 1.0]])
    Q = 1e-4**2 * np.array([[dt**3 / 3, dt**2 / 2], [dt**2 / 2, dt]])
    R = np.diag([1.0, 1e-3]) ** 2
    x = np.zeros((60, 2))
    x[0] = [100.0, -0.05]
    for k in range(1, 60):
        x[k] = Phi @ x[k - 1] + rng.multivariate_normal(np.zeros(2), Q)
    z = x + rng.multivariate_normal(np.zeros(2), R, size=60)

    _, xf, Pf, xp, Pp, C = rts_gains(_kalman(Phi, Q, R, z))
    smoothed, _ = rts_full(xf, Pf, xp, Pp, C, 59)
    np.testing.assert_allclose(smoothed, _batch(Phi, Q, R, z), rtol=1e-7, atol=1e-9)
    # it averages: closer to the truth than the filter, most of all at the start
    assert np.abs(smoothed - x)[:, 0].mean() < np.abs(xf - x)[:, 0].mean()
    np.testing.assert_allclose(rts_lag(xf, xp, C, 100, 59), smoothed, rtol=1e-10, atol=1e-10)
    lag5 = rts_lag(xf, xp, C, 5, 59)
    np.testing.assert_allclose(lag5[-6:], smoothed[-6:], rtol=1e-10, atol=1e-10)
