"""Windowed value increments: Algorithm 2's regression with the interval's end points replaced
by integrals, for data whose samples carry navigation noise.

On an interval [a, b] the paper's regression equates the value increment
x(b)^T P x(b) - x(a)^T P x(a) with the integral of its derivative.  Both end points are single
noisy samples: with a navigation filter that passes most of its velocity measurement's white
noise through (0.7 of 1 mm/s, 0.6 m in the iteration's units against a 15-30 m signal), their
error is the largest in the regression (docs/methods.md, "Value iteration through navigation
noise").  Multiplying the same identity by a window g that vanishes at a and b and
integrating by parts gives

    integral of g d(xbar^T P xbar) = g(b) xbar(b)^T P xbar(b) - integral of g' xbar^T P xbar,

so the increment becomes an integral of the samples (their white noise averages out over the
interval), and every regressor is weighted by g.  The unknowns, the map from vecs(P) to them
and the iteration are Algorithm 2's; only the rows of Theta_j and delta_j change.  With
g(t) = sin^2(pi (t - a) / L), L the interval, g(b) = 0 when b = a + L exactly (the term is kept
for an interval that closes on a later sample).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ddvi_core.learning import IntervalCollector, IntervalData

__all__ = ["WindowedCollector", "window"]


def window(s: float, length: float) -> tuple[float, float]:
    """g and dg/dt (1/s) of the sin^2 window at ``s`` seconds into an interval of ``length``."""
    phase = math.pi * s / length
    return math.sin(phase) ** 2, math.pi / length * math.sin(2.0 * phase)


class WindowedCollector(IntervalCollector):
    """An :class:`~ddvi_core.learning.IntervalCollector` whose integrals are weighted by the
    sin^2 window of their interval and whose data carry the value-increment matrices
    D = g(b) w(b) w(b)^T - integral of g' w w^T (``IntervalData.increments``), which
    :func:`ddvi_core.learning.learn_from_data` then regresses on instead of the end points.
    Same arguments, gaps and memory per interval (one more N x N matrix)."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._D: list[NDArray] = []
        self._acc_D = np.zeros_like(self._acc_W)
        self._end_weight = 0.0  # g at the newest sample of the open interval

    def _accumulate(self, t0: float, w0: NDArray, u0: NDArray, t: float, w: NDArray) -> None:
        dt, start = t - t0, self._start[0]
        g0, dg0 = window(t0 - start, self.interval)
        g, dg = window(t - start, self.interval)
        outer0, outer = np.outer(w0, w0), np.outer(w, w)
        self._acc_W += 0.5 * dt * (g0 * outer0 + g * outer)
        self._acc_G += 0.5 * dt * np.outer(g0 * w0 + g * w, u0)
        self._acc_D -= 0.5 * dt * (dg0 * outer0 + dg * outer)
        self._end_weight = g

    def _open(self, t: float, w: NDArray) -> None:
        super()._open(t, w)
        self._acc_D = np.zeros_like(self._acc_W)
        self._end_weight = 0.0

    def _close(self, t: float, w: NDArray) -> None:
        if len(self._W) < self.max_intervals:
            self._D.append(self._acc_D + self._end_weight * np.outer(w, w))
        super()._close(t, w)

    def data(self) -> IntervalData:
        plain = super().data()
        N = self.n + self.q
        D = np.array(self._D) if self._D else np.zeros((0, N, N))
        return IntervalData(
            plain.n,
            plain.m,
            plain.q,
            plain.W,
            plain.G,
            plain.w_start,
            plain.w_end,
            plain.t_start,
            plain.t_end,
            D,
        )
