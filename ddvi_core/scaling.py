"""The units value iteration runs in (the time/state/cost scaling that makes it converge on
orbital problems): ``Scaling`` maps a problem and its solution between its own units and the
iteration's, ``balanced_scaling`` chooses them for a known model (:mod:`ddvi_core.value_iteration`
says why)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.linalg
from numpy.typing import ArrayLike, NDArray

__all__ = ["DEFAULT_TIME_UNIT_DIVISOR", "Scaling", "balanced_scaling"]


@dataclass(frozen=True)
class Scaling:
    """Units of the iteration: time unit w0 (1/s), state scales S (n,), input scales s_u (m,),
    cost factor c.  ``Scaling.identity(n, m)`` iterates in the problem's own units."""

    time_unit: float
    state_scale: NDArray[np.float64]
    input_scale: NDArray[np.float64]
    cost_scale: float

    @staticmethod
    def identity(n: int, m: int) -> Scaling:
        return Scaling(1.0, np.ones(n), np.ones(m), 1.0)

    def __post_init__(self) -> None:
        if not (self.time_unit > 0 and math.isfinite(self.time_unit)):
            raise ValueError(f"time_unit must be positive and finite, got {self.time_unit}")
        if not (self.cost_scale > 0 and math.isfinite(self.cost_scale)):
            raise ValueError(f"cost_scale must be positive and finite, got {self.cost_scale}")
        for name in ("state_scale", "input_scale"):
            s = np.asarray(getattr(self, name), dtype=float)
            if s.ndim != 1 or not np.all(np.isfinite(s)) or np.any(s <= 0):
                raise ValueError(f"{name} must be a vector of positive finite numbers")
            object.__setattr__(self, name, s)

    def dynamics(self, A: NDArray, B: NDArray) -> tuple[NDArray, NDArray]:
        S, su, w0 = self.state_scale, self.input_scale, self.time_unit
        return A * S[None, :] / S[:, None] / w0, B * su[None, :] / S[:, None] / w0

    def weights(self, Q: NDArray, R: NDArray) -> tuple[NDArray, NDArray]:
        S, su, c, w0 = self.state_scale, self.input_scale, self.cost_scale, self.time_unit
        return c * Q * np.outer(S, S) / w0, c * R * np.outer(su, su) / w0

    def unscale_P(self, P_s: NDArray) -> NDArray:
        S = self.state_scale
        return P_s / np.outer(S, S) / self.cost_scale

    def scale_P(self, P: NDArray) -> NDArray:
        S = self.state_scale
        return P * np.outer(S, S) * self.cost_scale

    def unscale_K(self, K_s: NDArray) -> NDArray:
        return K_s * self.input_scale[:, None] / self.state_scale[None, :]

    def as_dict(self) -> dict:
        return {
            "time_unit": self.time_unit,
            "state_scale": self.state_scale.tolist(),
            "input_scale": self.input_scale.tolist(),
            "cost_scale": self.cost_scale,
        }


DEFAULT_TIME_UNIT_DIVISOR = 100.0
"""With eps_k = 1/k the iteration needs about (w^2/alpha) exp(L / (2 alpha)) steps (alpha the
slowest closed-loop decay rate and w its frequency, both in the iteration's time unit, L the
log of the wanted accuracy), which is least for alpha near L / 2, a few units.  Lightly damped
orbital problems have alpha between w0/20 and w0/40 for w0 the orbit rate, so the default unit
is two decades below A's fastest rate."""


def balanced_scaling(
    A: ArrayLike, B: ArrayLike, Q: ArrayLike, R: ArrayLike, time_unit: float | None = None
) -> Scaling:
    """Scaling for a known model: time in units of ``time_unit`` (default: A's largest
    eigenvalue modulus / DEFAULT_TIME_UNIT_DIVISOR, the orbit rate / 100 for Hill models),
    states balanced by scipy's ``matrix_balance`` of A / w0 (powers of two, so exact), cost
    normalised to |Q_s|_2 = 1."""
    A, B, Q, R = (np.asarray(M, dtype=float) for M in (A, B, Q, R))
    if time_unit is None:
        fastest = float(np.max(np.abs(np.linalg.eigvals(A)))) if A.size else 0.0
        if fastest <= 1e-300:
            fastest = float(np.linalg.norm(A, 2)) or 1.0
        time_unit = fastest / DEFAULT_TIME_UNIT_DIVISOR
    # a weak all-to-all coupling pins the scale of states that A does not feed back (the
    # along-track position of Hill's equations), which balancing alone would send to extremes
    As = np.abs(A) / time_unit
    As = As + 1e-3 * float(np.max(As)) * np.ones_like(As)
    _, (S, _) = scipy.linalg.matrix_balance(As, permute=False, separate=True)
    S = np.asarray(S, dtype=float) / float(np.max(S))
    q_norm = float(np.linalg.norm(Q * np.outer(S, S) / time_unit, 2))
    cost = 1.0 / q_norm if q_norm > 0 else 1.0
    return Scaling(time_unit, S, np.ones(B.shape[1]), cost)
