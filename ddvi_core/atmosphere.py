"""A density model the truth integrator can evaluate at every stage for the cost of one
exponential: each craft's density along its own track over one propagation call, built from a
few evaluations of an expensive model (NRLMSIS) at the call's two ends.

Over a call [t0, t1] each craft i has, at both ends, an anchor: its radius R, the log density
ln rho there and the local inverse scale height 1/H = -d ln rho / dh.  Between them the three
are linear in time, and the density at a radius |r| is the local exponential about the
anchor's radius:

    ln rho_i(t, r) = L_i(t) - (|r| - R_i(t)) / H_i(t).

The horizontal structure the craft flies through (the diurnal bulge, latitude, the storm's
rise) enters through L_i(t); the altitude structure through H_i.  The anchors come from the
caller (``services.model.msis`` evaluates NRLMSIS there); the error against evaluating the
model at every stage is measured in tests/model/test_msis.py and stated in docs/atmosphere.md.
Pure functions and a frozen dataclass: no I/O, no model library.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ddvi_core.constants import MU_EARTH

FloatArray = NDArray[np.float64]

__all__ = ["DensityTrack", "inverse_scale_height", "predict_positions"]


def predict_positions(state: ArrayLike, dt: ArrayLike, mu: float = MU_EARTH) -> FloatArray:
    """Positions (K, N, 3) m after each of dt (K,) s of states (N, 6) [r m, v m/s], by the
    third-order two-body Taylor series r + v dt + a dt^2 / 2 + j dt^3 / 6 (a the two-body
    acceleration, j its rate).  Its error is the fourth-order term, about n^4 |r| dt^4 / 24:
    100 m at 120 s, 8 km at 360 s in low orbit; it moves where an anchor sits along the track,
    not the density the track gives at the craft's true radius."""
    x = np.asarray(state, dtype=float)
    steps = np.atleast_1d(np.asarray(dt, dtype=float))[:, None, None]
    if x.ndim != 2 or x.shape[1] != 6 or not np.all(np.isfinite(x)):
        raise ValueError(f"state must be finite with shape (N, 6), got shape {x.shape}")
    r, v = x[:, :3], x[:, 3:]
    rn = np.linalg.norm(r, axis=1)[:, None]
    k = mu / rn**3
    a = -k * r
    rv = np.einsum("ij,ij->i", r, v)[:, None] / (rn * rn)
    j = -k * v + 3.0 * k * rv * r
    return r + steps * (v + steps * (0.5 * a + steps * j / 6.0))


def inverse_scale_height(rho_low: ArrayLike, rho_high: ArrayLike, dh: float) -> FloatArray:
    """1/H = ln(rho_low / rho_high) / dh, 1/m, (M,) from densities (M,) kg/m^3 at two altitudes
    dh m apart (rho_high above).  Densities must be positive."""
    lo, hi = np.asarray(rho_low, dtype=float), np.asarray(rho_high, dtype=float)
    if not (np.all(lo > 0.0) and np.all(hi > 0.0)) or not dh > 0.0:
        raise ValueError("densities must be positive and dh > 0 for a scale height")
    return np.log(lo / hi) / dh


@dataclass(frozen=True)
class DensityTrack:
    """Each craft's density over one propagation call [t0, t1] (see the module docstring).

    Attributes
    ----------
    t0, t1 : the call's interval, s (t1 > t0).
    radius : (N, 2) anchor radii |r| at t0 and t1, m.
    log_rho : (N, 2) ln of the density at the anchors, ln(kg/m^3) (any scaling included).
    inv_scale_height : (N, 2) 1/H at the anchors, 1/m (> 0: density falls with height).
    """

    t0: float
    t1: float
    radius: FloatArray
    log_rho: FloatArray
    inv_scale_height: FloatArray

    def __post_init__(self) -> None:
        if not (math.isfinite(self.t0) and math.isfinite(self.t1) and self.t1 > self.t0):
            raise ValueError(f"t0 and t1 must be finite with t1 > t0, got {self.t0}, {self.t1}")
        names = ("radius", "log_rho", "inv_scale_height")
        arrays = [np.asarray(getattr(self, name), dtype=float) for name in names]
        shape = arrays[0].shape
        if len(shape) != 2 or shape[1] != 2 or any(a.shape != shape for a in arrays):
            raise ValueError(
                f"radius, log_rho and inv_scale_height must share a shape (N, 2), got "
                f"{[a.shape for a in arrays]}"
            )
        if not np.isfinite(arrays).all():
            bad = [name for name, a in zip(names, arrays, strict=True) if not np.isfinite(a).all()]
            raise ValueError(f"{', '.join(bad)} must be finite")
        if not (arrays[2] > 0.0).all():
            raise ValueError("inv_scale_height must be positive (density falls with height)")
        for name, a in zip(names, arrays, strict=True):
            object.__setattr__(self, name, a)

    @property
    def arrays(self) -> tuple[FloatArray, FloatArray, FloatArray]:
        return self.radius, self.log_rho, self.inv_scale_height

    @property
    def n(self) -> int:
        """The number of craft."""
        return int(self.radius.shape[0])

    def coefficients(self) -> tuple[list[float], ...]:
        """Per craft, as lists for a scalar right-hand side: (R0, dR/dt, L0, dL/dt, 1/H0,
        d(1/H)/dt), each (N,), the three quantities' values at t0 and slopes per second."""
        dt = self.t1 - self.t0
        out: list[list[float]] = []
        for a in self.arrays:
            out += [a[:, 0].tolist(), ((a[:, 1] - a[:, 0]) / dt).tolist()]
        return tuple(out)

    def density(self, t: float, r_N: ArrayLike) -> FloatArray:
        """Density (N,) kg/m^3 of the N craft at time t (s) at inertial positions r_N (N, 3) m."""
        r = np.asarray(r_N, dtype=float)
        if r.shape != (self.n, 3):
            raise ValueError(f"r_N must have shape ({self.n}, 3), got {r.shape}")
        w = (float(t) - self.t0) / (self.t1 - self.t0)
        radius, log_rho, inv_h = ((1.0 - w) * a[:, 0] + w * a[:, 1] for a in self.arrays)
        return np.exp(log_rho - (np.linalg.norm(r, axis=1) - radius) * inv_h)
