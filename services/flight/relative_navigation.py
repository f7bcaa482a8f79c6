"""One deputy's relative navigation as a component: what its navigation service computes,
with no bus, no wall clock and no I/O, so that the service and the one-process runner fly the
same code.

Inputs:  ``measure(t, chief, deputy)``: the chief's and the deputy's inertial truth (6,) at a
         sample time on the navigation grid; ``bias_from_ground(bias, src)`` and
         ``outage_from_ground(duration, src)``: a bias or outage fault the ground sent, in
         force from the next sample; the deployment's scheduled [[fault]]
         biases and outages, at their times.
Outputs: ``NavSample``: the estimate (the filter's, ``ddvi_core.navfilter``, or the
         measurement itself with ``navigation.filter = "none"``), the measurement (truth in
         navigation's frame, the bias in force, white noise) and the covariance; with the
         faults that came into force at that sample, for the host to say.  During an outage
         nothing is measured: no noise is drawn, the filter propagates (its covariance grows)
         and the sample is not valid; without a filter the last estimate is held.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass

import numpy as np

from ddvi_core.constants import R_EARTH
from ddvi_core.navfilter import RelativeNavFilter
from services.config import Deployment, Deputy
from services.flight.streams import Fault, FaultQueue
from services.model import mean_motion, navigation_state, orbit_period


def noise_generator(dep: Deployment, deputy: Deputy) -> np.random.Generator:
    """The deputy's navigation noise draws: seeded by run.seed, navigation.seed and its name
    (its CRC-32: names of the same letters differ), so each deputy's noise is its own,
    whichever other deputies fly."""
    name = zlib.crc32(deputy.name.encode())
    return np.random.default_rng([dep.run.seed, deputy.navigation.seed, name])


def navigation_filter(dep: Deployment, deputy: Deputy) -> RelativeNavFilter | None:
    """The deputy's relative navigation filter as its deployment sets it (HCW at the chief's
    mean motion, the measurement's sigmas, the unmodelled acceleration), or None for
    ``navigation.filter = "none"``."""
    nav = deputy.navigation
    if nav.filter == "none":
        return None
    sigma = [nav.position_noise] * 3 + [nav.velocity_noise] * 3
    return RelativeNavFilter(mean_motion(dep), sigma, nav.acceleration_noise, nav.period)


@dataclass(frozen=True)
class NavSample:
    """One navigation sample: the estimate x (6,) and its covariance (6, 6), the measurement
    z (6,) and the truth it measured (6,), all in navigation's frame (m, m/s), and the
    deputy's altitude (m); ``valid``: measured (not in an outage, where z is the estimate);
    ``biased``: the bias faults that came into force at it; ``outage``: the outage that began
    at it (its end, s), if one did."""

    truth: np.ndarray
    x: np.ndarray
    z: np.ndarray
    cov: np.ndarray
    altitude: float
    valid: bool = True
    biased: tuple[Fault[np.ndarray], ...] = ()
    outage: Fault[float] | None = None


class RelativeNavigation:
    """The measurement model (bias in force, white noise) and the filter of one deputy.

    Parameters
    ----------
    dep : the deployment.
    deputy : the deputy it navigates.
    """

    def __init__(self, dep: Deployment, deputy: Deputy) -> None:
        self.dep, self.deputy = dep, deputy
        cfg = deputy.navigation
        self.period = cfg.period
        self.rng = noise_generator(dep, deputy)
        self.sigma = np.array([cfg.position_noise] * 3 + [cfg.velocity_noise] * 3)
        self.bias = np.array(cfg.position_bias + cfg.velocity_bias)
        self.filter = navigation_filter(dep, deputy)  # None: the measurement as is
        self.R = np.diag(self.sigma**2)  # the covariance of the measurement alone
        orbit = orbit_period(dep)
        self.bias_faults: FaultQueue[np.ndarray] = FaultQueue(
            [
                (f.at_orbits * orbit, np.array(f.position_bias + f.velocity_bias))
                for f in dep.fault
                if f.kind == "bias" and f.deputy == deputy.name
            ]
        )
        # outages: (start, duration) s, the deployment's
        self.outages: FaultQueue[float] = FaultQueue(
            [
                (f.at_orbits * orbit, f.duration_orbits * orbit)
                for f in dep.fault
                if f.kind == "outage" and f.deputy == deputy.name
            ]
        )
        self.outage_until = -np.inf  # the end of the outage in force (s)
        self.last: tuple[np.ndarray, np.ndarray] | None = None  # the last estimate, covariance

    def bias_from_ground(self, bias: np.ndarray, src: str) -> None:
        """A bias fault (6,) from the ground's service ``src``: in force from the next sample."""
        self.bias_faults.from_ground(np.asarray(bias, dtype=float), src)

    def outage_from_ground(self, duration: float, src: str) -> None:
        """An outage of ``duration`` s from the ground's service ``src``: from the next sample."""
        self.outages.from_ground(float(duration), src)

    def measure(self, t: float, chief: np.ndarray, deputy: np.ndarray) -> NavSample:
        """The sample at ``t`` from the chief's and the deputy's inertial states (6,): the
        measurement (the bias in force from ``t`` on; a draw of white noise unless the
        deployment sets none) through the filter; in an outage, the filter's prediction."""
        due = tuple(self.bias_faults.pop_due(t))
        for fault in due:
            self.bias = fault.value
        began = None
        for outage in self.outages.pop_due(t):
            start = outage.t if np.isfinite(outage.t) else t  # scheduled, or the ground's: now
            self.outage_until = max(self.outage_until, start + outage.value)
            began = outage._replace(value=self.outage_until)
        truth = navigation_state(self.dep, self.deputy, chief, deputy)
        altitude = float(np.linalg.norm(deputy[:3])) - R_EARTH
        if t < self.outage_until - 1e-6 and self.last is not None:
            x, cov = self.last if self.filter is None else self.filter.predict(t)
            self.last = (x, cov)
            return NavSample(truth, x, x, cov, altitude, False, due, began)
        z = truth + self.bias
        if self.sigma.any():  # no draw without noise: the generator's stream stays the same
            z = z + self.rng.normal(0.0, 1.0, 6) * self.sigma
        x, cov = (z, self.R) if self.filter is None else self.filter.update(t, z)
        self.last = (x, cov)
        return NavSample(truth, x, z, cov, altitude, True, due, began)
