"""The NRLMSIS truth atmosphere: NRLMSIS 2.1 (the ``pymsis`` package) evaluated along each
craft's position, at the deployment's epoch plus simulation time, under its space weather.

The truth integrator evaluates the density at every stage of every step (16 a 60 s step per
craft), where a call of the model would cost more than the whole step.  So the model is
evaluated at anchors along each craft's track, one a step (at the step's ends), each at the
craft's altitude and 2 km above (its local scale height); the integrator flies the local
exponential through the two anchors of its step (``ddvi_core.atmosphere.DensityTrack``).  A
step's end anchor is the next one's start, and the anchors of six steps are evaluated in one
batched call at the positions a third-order two-body Taylor series predicts: a model call
every six steps.  Against the model evaluated at the craft's true position and time, along a
mission's trajectory, the track's density is within the bound tests/model/test_msis.py asserts
and docs/atmosphere.md states.

Space weather is given, never looked up: pymsis downloads an index file only for an index it is
not given, and every call here gives all three (F10.7, its 81-day mean and the seven-element ap
history of MSIS's storm-time mode), so nothing is fetched.  The ap history at time t comes from
the deployment's constant Ap or its storm profile (``Atmosphere`` in
``services.config.deployment``): daily Ap the mean of the 3-hour values over the past day, the
3-hour values now and 3, 6 and 9 hours ago, and the means over 12 to 33 and 36 to 57 hours ago.

pymsis is imported here, not in ``ddvi_core``: the mathematics stays free of compiled model
libraries (``ddvi_core.atmosphere`` holds the track, ``ddvi_core.earth`` the frames), and the
import happens only when a deployment asks for NRLMSIS.
"""

from __future__ import annotations

from datetime import datetime

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ddvi_core.atmosphere import DensityTrack, inverse_scale_height, predict_positions
from ddvi_core.earth import inertial_to_geodetic
from services.config import Deployment, parse_epoch

__all__ = ["ANCHOR_BATCH", "SCALE_HEIGHT_STEP", "MsisDensity", "SpaceWeather"]

ANCHOR_BATCH = 6
"""Anchors evaluated per model call: those of the next six steps, predicted from the state at
the first one's start."""

SCALE_HEIGHT_STEP = 2e3
"""m: the local scale height is taken from the model at the anchor and this far above it."""

_HOUR = 3600.0
_J2000 = datetime(2000, 1, 1, 12, 0, 0)
_HISTORY = (0.0, 3.0, 6.0, 9.0)  # hours before t of ap elements 1 to 4
_EIGHT = 3.0 * np.arange(8)  # hours: eight 3-hour values


class SpaceWeather:
    """F10.7, its 81-day mean and the 3-hour ap at any simulation time, from constants or a
    storm profile (rows [t_s, ap] or [t_s, f107, ap]; linear between breakpoints, held
    outside them)."""

    def __init__(
        self, f107: float, f107a: float, ap: float, storm: ArrayLike | None = None
    ) -> None:
        self.f107a = float(f107a)
        rows = np.asarray(storm if storm is not None else [], dtype=float)
        if rows.size == 0:
            rows = np.array([[0.0, f107, ap]])
        elif rows.ndim != 2 or rows.shape[1] not in (2, 3):
            raise ValueError(f"storm must be rows [t_s, ap] or [t_s, f107, ap], got {rows.shape}")
        elif rows.shape[1] == 2:
            rows = np.column_stack((rows[:, 0], np.full(len(rows), float(f107)), rows[:, 1]))
        if not np.all(np.isfinite(rows)) or np.any(np.diff(rows[:, 0]) <= 0.0):
            raise ValueError("storm: finite values, times strictly increasing")
        self._t, self._f107, self._ap = rows[:, 0], rows[:, 1], rows[:, 2]
        self._constant = len(rows) == 1  # no profile: the same inputs at every time

    def ap(self, t: ArrayLike) -> NDArray[np.float64]:
        """The 3-hour ap at simulation times t (s), same shape."""
        return np.interp(t, self._t, self._ap)

    def f107(self, t: ArrayLike) -> NDArray[np.float64]:
        """The F10.7 given to MSIS at simulation times t (s), same shape."""
        return np.interp(t, self._t, self._f107)

    def ap_history(self, t: ArrayLike) -> NDArray[np.float64]:
        """MSIS's seven ap inputs (M, 7) at simulation times t (M,) s (see the module)."""
        t = np.atleast_1d(np.asarray(t, dtype=float))[:, None]
        if self._constant:
            return np.full((len(t), 7), self._ap[0])
        day = self.ap(t - _HOUR * _EIGHT).mean(axis=1)
        recent = self.ap(t - _HOUR * np.array(_HISTORY))
        early = self.ap(t - _HOUR * (12.0 + _EIGHT)).mean(axis=1)
        late = self.ap(t - _HOUR * (36.0 + _EIGHT)).mean(axis=1)
        return np.column_stack((day, recent, early, late))


class MsisDensity:
    """NRLMSIS 2.1 density along inertial positions at simulation times, and the per-call
    density tracks the truth integrator flies (see the module)."""

    def __init__(
        self,
        epoch: datetime,
        weather: SpaceWeather,
        density_factor: float = 1.0,
        version: float = 2.1,
    ) -> None:
        try:
            import pymsis
        except ImportError as exc:  # pragma: no cover - a dependency of the package
            raise RuntimeError(
                f'atmosphere.model = "nrlmsis" needs pymsis ({exc}): pip install "pymsis>=0.10"'
            ) from exc
        if not density_factor > 0.0:
            raise ValueError(f"density_factor must be positive, got {density_factor}")
        self._calculate = pymsis.calculate
        self._rho_index = int(pymsis.Variable.MASS_DENSITY)
        self.epoch, self.weather, self.version = epoch, weather, version
        self.log_factor = float(np.log(density_factor))
        self._epoch64 = np.datetime64(epoch, "us")
        self._days0 = (epoch - _J2000).total_seconds() / 86400.0  # UT1 days since J2000.0
        # anchors held for the coming calls: {t: (N, 3) [radius, ln rho, 1/H]}
        self._held: dict[float, NDArray[np.float64]] = {}

    @classmethod
    def from_deployment(cls, dep: Deployment) -> MsisDensity:
        """The deployment's NRLMSIS truth atmosphere ([atmosphere], environment.density_factor)."""
        atm = dep.atmosphere
        weather = SpaceWeather(atm.f107, atm.f107a, atm.ap, atm.storm or None)
        return cls(parse_epoch(atm.epoch), weather, dep.environment.density_factor)

    def density(self, t: ArrayLike, r_N: ArrayLike) -> NDArray[np.float64]:
        """NRLMSIS mass density (M,) kg/m^3 at simulation times t (M,) s and inertial positions
        r_N (M, 3) m, times environment.density_factor: the model at every point, as a
        reference for the track."""
        tt = np.atleast_1d(np.asarray(t, dtype=float))
        r = np.asarray(r_N, dtype=float).reshape(-1, 3)
        if len(tt) != len(r):
            raise ValueError(f"t (M,) and r_N (M, 3) must match: {tt.shape}, {r.shape}")
        weather = (self.weather.f107(tt), self.weather.ap_history(tt))
        return np.exp(self._log_density(tt, r, np.zeros(len(tt)), weather) + self.log_factor)

    def _log_density(
        self,
        t: NDArray[np.float64],
        r: NDArray[np.float64],
        dh: NDArray[np.float64],
        weather: tuple[NDArray[np.float64], NDArray[np.float64]],
    ) -> NDArray[np.float64]:
        """ln of the model's density (M,) at times t (M,) s, positions r (M, 3) m, dh (M,) m
        above them, under weather (F10.7 (M,), ap history (M, 7))."""
        if not (np.all(np.isfinite(t)) and np.all(np.isfinite(r))):
            raise ValueError("NRLMSIS needs finite times and positions")
        lat, lon, alt = inertial_to_geodetic(r, self._days0 + t / 86400.0)
        dates = self._epoch64 + np.round(t * 1e6).astype("timedelta64[us]")
        f107, aps = weather
        out = self._calculate(
            dates,
            lon,
            lat,
            (alt + dh) / 1e3,
            f107,
            np.full(len(t), self.weather.f107a),
            aps,
            version=self.version,
            geomagnetic_activity=-1,
        )
        return np.log(out[:, self._rho_index].astype(float))

    def _anchors(self, times: list[float], r: NDArray[np.float64]) -> dict[float, NDArray]:
        """{t: (N, 3) [radius, ln rho with the density factor, 1/H]} at positions r (K, N, 3)
        at the K times: the model at r and SCALE_HEIGHT_STEP above, in one call."""
        k, n = r.shape[0], r.shape[1]
        t = np.repeat(np.asarray(times, dtype=float), n)  # (K N,)
        f107, aps = self.weather.f107(t), self.weather.ap_history(t)
        weather = (np.tile(f107, 2), np.tile(aps, (2, 1)))
        points = r.reshape(-1, 3)
        dh = np.repeat([0.0, SCALE_HEIGHT_STEP], k * n)
        both = self._log_density(np.tile(t, 2), np.concatenate((points, points)), dh, weather)
        low, high = both[: k * n], both[k * n :]
        inv_h = inverse_scale_height(np.exp(low), np.exp(high), SCALE_HEIGHT_STEP)
        rows = np.column_stack((np.linalg.norm(points, axis=1), low + self.log_factor, inv_h))
        return {times[i]: rows[i * n : (i + 1) * n] for i in range(k)}

    def track(self, t0: float, t1: float, state: ArrayLike) -> DensityTrack:
        """Each craft's density track over [t0, t1] from its states (N, 6) at t0.

        Anchors sit at t0 + k (t1 - t0): when none is held for t1, the next ANCHOR_BATCH of
        them are evaluated in one model call at the positions the two-body Taylor series
        predicts from ``state``; the anchor at t0 is the one held for t0 (so the density is
        continuous from step to step), or else the model at the states' positions."""
        x = np.asarray(state, dtype=float)
        if x.ndim != 2 or x.shape[1] != 6:
            raise ValueError(f"state must have shape (N, 6), got {x.shape}")
        t0, t1, n = float(t0), float(t1), len(x)
        held = self._held
        if any(t < t0 or len(a) != n for t, a in held.items()):
            held = {t: a for t, a in held.items() if t >= t0 and len(a) == n}
        if t0 not in held:
            held.update(self._anchors([t0], x[:, :3][None]))
        if t1 not in held:
            times = t0 + (t1 - t0) * np.arange(1, ANCHOR_BATCH + 1)
            held.update(self._anchors(times.tolist(), predict_positions(x, times - t0)))
        self._held = held
        pair = np.stack((held[t0], held[t1]), axis=2)  # (N, 3, 2)
        return DensityTrack(t0, t1, pair[:, 0], pair[:, 1], pair[:, 2])
