"""Exact simulation of the linear plant with its exosystem, for producing learning data.

    x' = A x + B u + D v,  v' = E v,  u held constant over each command period.

The sampled trajectory is exact (one matrix exponential of the augmented system, Van Loan's
construction), so the only approximation left in the learner is its own quadrature.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np
import scipy.linalg
from numpy.typing import ArrayLike, NDArray

__all__ = ["Exploration", "exact_discretisation", "simulate_zoh"]


@dataclass(frozen=True)
class Exploration:
    """Exploration noise eta(t) = (amplitude / k) sum_i sin(w_i t + phi_i), per input.

    ``frequencies`` (rad/s), phases drawn from ``seed`` (a different set per input channel);
    |eta| never exceeds ``amplitude``, so the exploration alone stays inside an actuator limit
    of that size."""

    amplitude: float
    frequencies: tuple[float, ...]
    seed: int = 0

    def __post_init__(self) -> None:
        if not (self.amplitude >= 0 and math.isfinite(self.amplitude)):
            raise ValueError(f"exploration amplitude must be >= 0, got {self.amplitude}")
        if any(not (w > 0 and math.isfinite(w)) for w in self.frequencies):
            raise ValueError(f"exploration frequencies must be positive rad/s: {self.frequencies}")

    @staticmethod
    def spread(
        amplitude: float,
        rate: float,
        count: int = 6,
        lo: float = 0.3,
        hi: float = 30.0,
        seed: int = 0,
    ) -> Exploration:
        """``count`` frequencies spread geometrically over lo*rate .. hi*rate."""
        return Exploration(amplitude, tuple(np.geomspace(lo * rate, hi * rate, count)), seed)

    def __call__(self, t: float, m: int) -> NDArray[np.float64]:
        if not self.frequencies or self.amplitude == 0:
            return np.zeros(m)
        rng = np.random.default_rng(self.seed)
        phases = rng.uniform(0, 2 * np.pi, size=(m, len(self.frequencies)))
        w = np.asarray(self.frequencies)
        return self.amplitude / len(w) * np.sum(np.sin(w[None, :] * t + phases), axis=1)


def exact_discretisation(A: NDArray, B: NDArray, D: NDArray, E: NDArray, h: float) -> NDArray:
    """Transition of z = [x; v; u] over h with u constant: expm of [[A, D, B], [0, E, 0],
    [0, 0, 0]] h, shape (n+q+m, n+q+m)."""
    n, m, q = A.shape[0], B.shape[1], E.shape[0]
    M = np.zeros((n + q + m, n + q + m))
    M[:n, :n], M[:n, n : n + q], M[:n, n + q :] = A, D, B
    M[n : n + q, n : n + q] = E
    return scipy.linalg.expm(M * h)


def simulate_zoh(
    A: ArrayLike,
    B: ArrayLike,
    D: ArrayLike | None,
    E: ArrayLike | None,
    x0: ArrayLike,
    v0: ArrayLike | None,
    *,
    K0: ArrayLike,
    exploration: Exploration,
    sample_period: float,
    command_period: float,
    duration: float,
    input_limit: float | None = None,
) -> Iterator[tuple[float, NDArray, NDArray, NDArray]]:
    """Yield samples (t, x, u, v) every ``sample_period`` up to ``duration``, where u is the
    input applied from t until the next sample: u = -K0 x + eta, recomputed every
    ``command_period`` (a whole number of sample periods) and held in between, clipped to
    +-input_limit if given."""
    A, B = np.asarray(A, float), np.asarray(B, float)
    n, m = B.shape
    E = np.zeros((0, 0)) if E is None else np.asarray(E, float)
    q = E.shape[0]
    D = np.zeros((n, q)) if D is None else np.asarray(D, float)
    K0 = np.asarray(K0, float)
    ratio = command_period / sample_period
    if ratio < 1 or abs(ratio - round(ratio)) > 1e-9:
        raise ValueError("command_period must be a whole multiple of sample_period")
    ratio = round(ratio)
    Phi = exact_discretisation(A, B, D, E, sample_period)
    z = np.concatenate(
        [np.asarray(x0, float), np.zeros(q) if v0 is None else np.asarray(v0, float), np.zeros(m)]
    )
    steps = math.floor(duration / sample_period + 1e-9)
    for k in range(steps + 1):
        t = k * sample_period
        if k % ratio == 0:
            u = -K0 @ z[:n] + exploration(t, m)
            if input_limit is not None:
                u = np.clip(u, -input_limit, input_limit)
            z[n + q :] = u
        yield t, z[:n].copy(), z[n + q :].copy(), z[n : n + q].copy()
        z = Phi @ z
