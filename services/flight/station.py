"""The model-fit learner's work on station once a gain is learned: the feedforward refitted
on the data flown on the learned gains (``learning.refresh_orbits``) and the slow trim of its
constant term (``learning.trim_orbits``, services.flight.trim).  The gain K is not touched."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ddvi_core.learning import LearningError
from ddvi_core.learning_config import LearningConfig
from ddvi_core.model_fit import IntegralHistory
from ddvi_core.regulator import InfeasibleError, feedforward_gain, solve_regulator_equations
from services.flight.fitting import select_feedforward_modes
from services.flight.trim import StationTrim


class StationKeeping:
    """On the gains (K, the fitted ``model``, ``exosystem`` (C, E, F)) learned at ``start``:
    ``refresh``, the running integrals flown on them on station (None: no refresh), the next
    refit's time, and ``trim`` (None: no trim).  ``orbit`` is the orbit period (s)."""

    def __init__(
        self,
        lrn: LearningConfig,
        orbit: float,
        start: float,
        K: np.ndarray,
        model: Any,
        exosystem: tuple,
        refresh: IntegralHistory | None,
    ) -> None:
        self.lrn, self.K, self.model, self.exosystem = lrn, K, model, exosystem
        self.refresh_period = lrn.refresh_orbits * orbit
        self.refresh = refresh if lrn.refresh_orbits > 0 else None
        self.next_refresh = math.inf
        if self.refresh is not None:
            self.next_refresh = start + 2 * self.refresh_period
        self.trim: StationTrim | None = None
        if lrn.trim_orbits > 0:
            trim_period = lrn.trim_orbits * orbit
            self.trim = StationTrim(trim_period, lrn.station_radius, lrn.trim_gain, start=start)

    def add(self, t: float, x: np.ndarray, u: float, v: np.ndarray, error: float) -> str | None:
        """One sample flown on the learned gains: its along-track error ``error`` (m, from the
        estimate) for the trim, and on station (|error| within ``station_radius``) x, u, v for
        the refit.  Returns why the refit's store refused it, if it did."""
        if self.trim is not None:
            self.trim.add(t, error)
        if self.refresh is not None and abs(error) <= self.lrn.station_radius:
            try:  # the gaps off station split the data (no interval spans one)
                self.refresh.add(t, x, [u], v)
            except LearningError as exc:
                return f"sample at t = {t} rejected: {exc}"
        return None

    def step(self, t: float, L: np.ndarray, since: float) -> tuple[np.ndarray, str | None]:
        """A flight-software step at t flying feedforward L: refit it if due, else trim it if
        due.  Returns the L to fly (the trim moves L's constant term in place) and the log
        line (None: nothing was due)."""
        if self.refresh is not None and t >= self.next_refresh:
            return self.refit(t, L, since)
        if self.trim is not None and self.trim.due(t):
            delta, log = self.trim.update(t, float(self.K[0, 1]))
            L[0, 0] += delta
            return L, log
        return L, None

    def refit(self, t: float, L: np.ndarray, since: float) -> tuple[np.ndarray, str]:
        """Refit the model fit's D, with its A and B held, on the data flown on the learned
        gains in the deputy's newest stay on station (within ``station_radius`` of the slot
        without a break, at least ``refresh_orbits`` P of it), and fly the feedforward
        L = U + K X of the regulator equations on it: the drag offset the exploration saw far
        behind the slot is not the one at the slot.  The window is the stay less its first P
        (the settling), but never shorter than the last P and one interval: a stay shorter
        than 2 P + interval is refitted from its last P + interval, its settling included.
        ``since``: the learning window's first sample time.  Returns the L to fly and the log
        line; a refit that fails keeps L."""
        lrn, period, (C, E, F) = self.lrn, self.refresh_period, self.exosystem
        self.next_refresh = t + period
        # the newest stay on station only (a fly-through is not one), less its first period,
        # the approach's settling, where the fit's A errors leak into D; a window that grows
        # with the stay, for the noise (a sliding one of 2 to 6 orbits swung the deputy
        # kilometres off at 10 m of noise)
        data = self.refresh.data().since(since)
        if data.samples:
            data = data.since(float(data.t[data.segment == data.segment[-1]][0]))
        if data.samples:
            data = data.since(min(float(data.t[0]) + period, t - period - lrn.interval))
        span = float(data.t[-1] - data.t[0]) if data.samples else 0.0
        if span < period - 1e-6:
            return L, (
                f"feedforward not refitted at t = {t:.0f} s: on station for {span:.0f} s, "
                f"less than refresh_orbits; L kept"
            )
        try:
            D = select_feedforward_modes(data, self.model, lrn, E, on_station=True)
            X, U = solve_regulator_equations(self.model.A, self.model.B, C, D, E, F)
        except (LearningError, InfeasibleError) as exc:
            return L, f"feedforward refit at t = {t:.0f} s failed, L kept: {exc}"
        L = feedforward_gain(self.K, X, U)
        if self.trim is not None:
            # the refit saw the trim in the inputs it was fitted on: it replaces it, and the
            # errors flown before it are no one's to correct
            self.trim.restart(t)
        return L, (
            f"feedforward refitted at t = {t:.0f} s from {data.samples} samples on the learned "
            f"gains: D[:, 0] = {np.round(D[:, 0], 12).tolist()}, L = {L.ravel().tolist()}"
        )
