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
from dataclasses import dataclass
from typing import Any

import numpy as np

from ddvi_core.learning import IntervalCollector, LearningError, learn_from_data
from ddvi_core.model_fit import IntegralHistory
from ddvi_core.value_iteration import BoundSchedule, StepSequence
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
    store of the data, the model-fit learner's station keeping (None here)."""

    source = ""  # the label of the gains it learns

    def __init__(self, dep: Deployment, deputy: Deputy, problem: Any, q: int) -> None:
        self.lrn, self.problem = deputy.learning, problem
        self.orbit, self.n_rate = orbit_period(dep), mean_motion(dep)
        self.nav_period = deputy.navigation.period
        self.translation = [0.0, 1.0, 0.0, 0.0] if self.lrn.along_track_reference else None
        self.store = self.new_store(q)
        self.station: StationKeeping | None = None

    def new_store(self, q: int) -> IntervalCollector | IntegralHistory:
        """An empty store for exostates of ``q`` components."""
        raise NotImplementedError

    def collect(self, t: float, x: np.ndarray, u: float, v: np.ndarray) -> str | None:
        """Store one sample (x (4,), the input u acting from t on, the learner's exostate v);
        returns why the store refused it, if it did."""
        try:
            self.store.add(t, x, [u], v)
        except LearningError as exc:
            return f"sample at t = {t} rejected: {exc}"
        return None

    def attempt(self, since: float, exosystem: tuple, due: float) -> Attempt:
        """Learn from the data at or after ``since`` with ``exosystem`` (C, E, F), for the
        attempt scheduled at ``due``."""
        try:
            return self.learn(self.store.data().since(since), exosystem, due)
        except LearningError as exc:
            return Attempt(None, {}, f"failed: {exc}", None)

    def learn(self, data: Any, exosystem: tuple, due: float) -> Attempt:
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

    def learn(self, data: Any, exosystem: tuple, due: float) -> Attempt:
        lrn, pr, n = self.lrn, self.problem, self.n_rate
        C, E, F = exosystem
        r = learn_from_data(
            data, pr.Q, pr.R, time_unit=n, C=C, E=E, F=F,
            steps=StepSequence(lrn.step, lrn.step_size),
            bounds=BoundSchedule(lrn.bounds, lrn.bound_base),
            tol=lrn.tol, max_iterations=lrn.max_iterations,
            state_scale=[1.0, 1.0, n, n], translation=self.translation,
        )  # fmt: skip
        info = {"condition": r.condition, "residual": r.residual, "intervals": r.intervals,
                "iterations": r.iterations}  # fmt: skip
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
        return IntegralHistory(4, 1, q, lrn.interval, lrn.fit_stride, max_gap=3 * nav,
                               max_samples=math.ceil(window / nav) + 2)  # fmt: skip

    def learn(self, data: Any, exosystem: tuple, due: float) -> Attempt:
        """With the tolerance in force for the attempt due at ``due``: ``fit_tolerance``, or
        from ``fit_deadline_orbits`` on ``fit_deadline_tolerance``."""
        lrn = self.lrn
        deadline = lrn.fit_deadline_orbits * self.orbit
        late = lrn.fit_deadline_orbits > 0 and due >= deadline - 1e-6
        tolerance = lrn.fit_deadline_tolerance if late else lrn.fit_tolerance
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
