"""The controller's learners, one per ``learning.method``, behind one small interface: each
keeps its store of the data (``store``), takes samples (``collect``), makes an attempt on the
data from a given time on (``attempt``: the gains, or why they are not taken) and says how it
learned (``describe``).  The model-fit learner also keeps station on the gains it learned
(``station``: services.flight.station).

- value iteration: ddvi_core.learning's ``learn_from_data`` on an IntervalCollector's
  interval integrals;
- model fit: ddvi_core.model_fit's first-order interval fit and the Riccati and regulator
  equations on the fitted model (services.flight.fitting), on an IntegralHistory's running
  integrals, retried on a growing window until the gain's predicted error is small.

A learner gets what a flight computer knows: Q, R, the output map and reference (C, F), the
exosystem E and the orbit rate; never A, B or D.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.linalg

from ddvi_core.learning import IntervalCollector, LearningError, learn_from_data
from ddvi_core.model_fit import IntegralHistory
from ddvi_core.simulate import Exploration
from services.config import Deployment, Deputy
from services.flight.fitting import fit_attempt
from services.flight.station import StationKeeping
from services.model import mean_motion, orbit_period


@dataclass
class Attempt:
    """One learning attempt: ``result`` (K, L and what else the method gives; None when the
    learner gave no gains), what the learning log reports (``info``), ``refused``: why its
    gains are not taken (None: taken), and the rank of its data and the rank needed (None
    when the learner failed before it knew them)."""

    result: Any
    info: dict
    refused: str | None
    rank: tuple[int, int] | None


class Learner:
    """What both learners share: the deputy's learning settings, Q and R (``problem``), the
    exploration, the store of the data, the model-fit learner's station keeping (None
    here)."""

    source = ""  # the label of the gains it learns

    def __init__(self, dep: Deployment, deputy: Deputy, problem: Any, q: int) -> None:
        self.lrn, self.problem = deputy.learning, problem
        self.orbit, self.n_rate = orbit_period(dep), mean_motion(dep)
        self.nav_period = deputy.navigation.period
        self.translation = [0.0, 1.0, 0.0, 0.0] if self.lrn.along_track_reference else None
        # the multi-sine eta(t) flown on K0 while exploring, inside the attitude limit
        freqs = tuple(self.lrn.exploration_frequencies) or tuple(
            np.geomspace(0.3 * self.n_rate, 30 * self.n_rate, 6)
        )
        self.exploration = Exploration(self.lrn.exploration_amplitude, freqs, self.lrn.seed)
        self.store = self.new_store(q)
        self.station: StationKeeping | None = None

    def new_store(self, q: int) -> IntervalCollector | IntegralHistory:
        """An empty store for exostates of ``q`` components."""
        raise NotImplementedError

    def initial_gain(self) -> np.ndarray:
        """K0 (1, 4), the gain it explores on (the deployment gives 4 values)."""
        return np.reshape(np.asarray(self.lrn.K0, dtype=float), (1, 4))

    def window_start(self, t: float) -> float:
        """The first sample time (s) an attempt at t learns from: the last ``window_orbits``
        (0: all the data, a window that grows with every retry)."""
        lrn = self.lrn
        return t - lrn.window_orbits * self.orbit if lrn.window_orbits > 0 else -math.inf

    def collect(self, t: float, x: np.ndarray, u: float, v: np.ndarray) -> str | None:
        """Store one sample (x (4,), the input u acting from t on, the learner's exostate v);
        returns why the store refused it, if it did."""
        try:
            self.store.add(t, x, [u], v)
        except LearningError as exc:
            return f"sample at t = {t} rejected: {exc}"
        return None

    def attempt(
        self, since: float, exosystem: tuple, due: float, on_fallback: bool = False
    ) -> Attempt:
        """Learn from the data at or after ``since`` with ``exosystem`` (C, E, F), for the
        attempt scheduled at ``due``, exploring on the fallback or not (``on_fallback``)."""
        try:
            return self.learn(self.store.data().since(since), exosystem, due, on_fallback)
        except LearningError as exc:
            return Attempt(None, {}, f"failed: {exc}", None)

    def learn(self, data: Any, exosystem: tuple, due: float, on_fallback: bool) -> Attempt:
        """The method's attempt on ``data``; raises LearningError when it gives no gains."""
        raise NotImplementedError

    def describe(self, info: dict) -> str:
        """The learning log's words on how the gains were learned."""
        raise NotImplementedError

    def learned(self, t: float, result: Any, exosystem: tuple) -> None:
        """The gains of ``result`` fly from t on."""


class ValueIterationLearner(Learner):
    """Data-driven value iteration on the interval integrals."""

    source = "ddvi"

    def new_store(self, q: int) -> IntervalCollector:
        return IntervalCollector(4, 1, q, self.lrn.interval, max_gap=3 * self.nav_period)

    def learn(self, data: Any, exosystem: tuple, due: float, on_fallback: bool) -> Attempt:
        lrn, pr, n = self.lrn, self.problem, self.n_rate
        C, E, F = exosystem
        r = learn_from_data(
            data,
            pr.Q,
            pr.R,
            time_unit=n,
            C=C,
            E=E,
            F=F,
            iteration=lrn.iteration_settings(),
            state_scale=[1.0, 1.0, n, n],
            translation=self.translation,
        )
        info = {
            "condition": r.condition,
            "residual": r.residual,
            "intervals": r.intervals,
            "iterations": r.iterations,
        }
        refused = None if r.converged else f"did not converge ({r.message})"
        return Attempt(r, info, refused, (r.rank, r.rank_needed))

    def describe(self, info: dict) -> str:
        return f"in {info.get('iterations', 0)} iterations"


class ModelFitLearner(Learner):
    """The model fit on the running integrals (at most ``window_orbits`` of samples kept
    when a window is set), its feedforward refitted and trimmed on station."""

    source = "model-fit"

    def new_store(self, q: int) -> IntegralHistory:
        lrn, nav = self.lrn, self.nav_period
        window = lrn.window_orbits * self.orbit if lrn.window_orbits > 0 else 1e6
        return IntegralHistory(
            4,
            1,
            q,
            lrn.interval,
            lrn.fit_stride,
            max_gap=3 * nav,
            max_samples=math.ceil(window / nav) + 2,
        )

    def learn(self, data: Any, exosystem: tuple, due: float, on_fallback: bool) -> Attempt:
        """With the tolerance in force for the attempt due at ``due``: ``fit_tolerance``, from
        ``fit_deadline_orbits`` on ``fit_deadline_tolerance``, and on the fallback
        ``resume_fit_tolerance`` (past the time to learn, on station, the nominal model's gains
        the alternative; the gain still passes the hold-out validation before it flies)."""
        lrn = self.lrn
        deadline = lrn.fit_deadline_orbits * self.orbit
        if on_fallback:
            tolerance = lrn.resume_fit_tolerance
        elif lrn.fit_deadline_orbits > 0 and due >= deadline - 1e-6:
            tolerance = lrn.fit_deadline_tolerance
        else:
            tolerance = lrn.fit_tolerance
        holdout = lrn.validation_orbits * self.orbit
        r, info, why = fit_attempt(
            data, lrn, self.problem, exosystem, self.translation, tolerance, holdout
        )
        refused = None if why is None else f"did not converge ({why})"
        return Attempt(r, info, refused, (info["rank"], info["needed"]))

    def describe(self, info: dict) -> str:
        return (
            f"by a model fit (condition {info['condition']:.3g}, relative residual "
            f"{info['residual']:.3g}, predicted gain error {info['error']:.3g}, "
            f"B = {info['B']}{validated(info)})"
        )

    def learned(self, t: float, result: Any, exosystem: tuple) -> None:
        """Keep station on the new gains: a fresh refit store, the trim started at t."""
        q = exosystem[1].shape[0]
        refresh = self.new_store(q) if self.lrn.refresh_orbits > 0 else None
        self.station = StationKeeping(
            self.lrn, self.orbit, t, result.K, result.model, exosystem, refresh
        )


class LearnerExostate:
    """The exosystem (C, E, F) the learner and L work with, and the exostate it makes of the
    environment's v: ``density`` (craft that may differ) adds the density ratio from the start,
    a detected change adds it later (``add_density_ratio``; a fallback restores the exosystem
    of before).  ``density_ratio``: rho(h) / rho(h_0) at altitude h (m)."""

    def __init__(
        self, problem: Any, density: bool, density_ratio: Callable[[float], float]
    ) -> None:
        self.q_model = problem.q
        self.exosystem = (problem.C, problem.E, problem.F)
        self.density_ratio = density_ratio
        if density:
            self.add_density_ratio()

    @property
    def density_mode(self) -> bool:
        """The exostate carries the density ratio (after a detected change, unless re-learning
        fell back to gains learned without it)."""
        return self.exosystem[1].shape[0] > self.q_model

    def add_density_ratio(self) -> None:
        if not self.density_mode:
            self.exosystem = density_exosystem(*self.exosystem)

    def __call__(self, v: np.ndarray, altitude: float) -> np.ndarray:
        """The exostate the learner collects and L multiplies: v itself, or after a detected
        change [v; rho(h) / rho(h_0)].  Craft whose drag no longer matches (a panel fault)
        feel a differential-drag bias proportional to the density at their altitude, which
        oscillates about 50 % around the orbit and doubles in 20 orbits as the pair decays:
        the exosystem's constant and harmonics cannot carry it (measured: re-learning
        windows then never converge).  The bias acts where the input does, so it is
        regulated with X = 0 and U constant whatever the ratio does; its row of E is zero."""
        if not self.density_mode:
            return v
        return np.append(v, self.density_ratio(altitude))


def density_exosystem(C: np.ndarray, E: np.ndarray, F: np.ndarray) -> tuple:
    """(C, E, F) of an exosystem extended by the density ratio: a mode E holds constant (its
    row and column of E zero), which the reference F does not see."""
    F_rho = np.hstack([F, np.zeros((F.shape[0], 1))])
    return C, scipy.linalg.block_diag(E, 0.0), F_rho


def make_learner(dep: Deployment, deputy: Deputy, problem: Any, q: int) -> Learner:
    """The learner of the deputy's ``learning.method`` (anything but "model-fit": value
    iteration), its store for exostates of ``q`` components."""
    kind = ModelFitLearner if deputy.learning.method == "model-fit" else ValueIterationLearner
    return kind(dep, deputy, problem, q)


def validated(info: dict) -> str:
    """The learning log's words on a model-fit gain's validation (none when it was off)."""
    if "validation" not in info:
        return ""
    return (
        f"; validated on the hold-out: relative prediction residual {info['validation']:.3g}, "
        f"closed-loop decay {info['validation_margin']:.3g} 1/s, gain "
        f"{info['validation_gain']:.3g} from that of the fit without it"
    )
