"""The control law of a deputy's controller, with its learner: no bus, no processes.  The
controller service (``services.flight.controller``) and the one-process baseline
(``services.flight.inprocess``) both fly it.

Modes: ``lqr`` flies u = -K x + L v with gains from the nominal linear model.  ``ddvi`` flies
u = -K0 x + eta(t) (K0 need not stabilise; eta a multi-sine inside the attitude limit), feeds
every navigation sample to ddvi_core's IntervalCollector, runs data-driven value iteration at
the configured time and switches to the learned K, L (``learning.method = "model-fit"``:
ddvi_core.model_fit's first-order interval fit and the Riccati and regulator equations on the
fitted model instead (services.flight.fitting), retried on a growing window until the gain's
predicted error is small, its feedforward's constant trimmed on station by the mean
along-track error (services.flight.trim)).  With ``learning.relearn`` it then
watches its own data for a change of the plant (an actuator fault: ddvi_core.detection's
one-step predictor, fitted on the data it learned from, and the one-orbit mean of its
input-equivalent residual against the bound it states in its log); on a detection it explores
again on K0 (phase "relearning"), learns again from the newest ``relearn_window_orbits`` of data
after ``relearn_settle_orbits``, with the density ratio added to its exostate
(``Controller.learner_exostate``), switches to the new gains and re-arms the detector; after
``relearn_max_attempts`` failed attempts it flies the gains of before the detection again
(source "fallback") and watches no more until it is restarted.  Every
command goes through ddvi_core.models.drag_allocation, scheduled on the deputy's altitude (its
nav message), which makes the facet's drag linear in u and the same at every altitude.  The
learner gets what a flight computer knows: Q, R, the output map and reference (C, F), the
exosystem E and the orbit rate; never A, B or D.  Control input u = sigma3, the relative MRP
about the orbit normal; sigma1 = sigma2 = 0.
"""

from __future__ import annotations

import bisect
import collections
import math
import time
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.linalg

from ddvi_core.constants import R_EARTH
from ddvi_core.detection import ChangeDetector, DetectionError, fit_predictor
from ddvi_core.learning import IntervalCollector, LearningError, learn_from_data
from ddvi_core.model_fit import IntegralHistory
from ddvi_core.models import drag_allocation
from ddvi_core.regulator import InfeasibleError, feedforward_gain, solve_regulator_equations
from ddvi_core.simulate import Exploration
from ddvi_core.value_iteration import BoundSchedule, StepSequence
from services.config import Deployment
from services.flight.fitting import fit_attempt, select_feedforward_modes
from services.flight.trim import StationTrim
from services.interface import command_topic
from services.model import lqr_gains, mean_motion, nominal_problem, on_grid, orbit_period


@dataclass
class SampleOutcome:
    """What one navigation sample did: a flight-software step (a new command in
    ``Controller.u``), a learning attempt (its log line), a sample the collector refused."""

    fsw: bool
    learn_log: str | None = None
    rejected: str | None = None


class Controller:
    """The control law and the learner's state; no I/O (the service loop does that)."""

    def __init__(self, dep: Deployment, sc: str) -> None:
        self.dep, self.sc = dep, sc
        self.deputy = dep.deputy_named(sc)
        self.problem = nominal_problem(dep, self.deputy)  # Q, R, C, E, F used by the learner
        self.n_rate = mean_motion(dep)
        self.fsw = dep.run.fsw_period
        self.limit = self.deputy.attitude_limit
        lrn = self.deputy.learning
        self.mode = self.deputy.controller
        if self.mode == "lqr":
            self.K, self.L = lqr_gains(dep, self.deputy)
            self.phase, self.source = "lqr", "lqr"
        else:
            self.K = self.initial_gain()
            self.L = np.zeros((1, self.problem.q))
            self.phase, self.source = "exploring", "initial"
            freqs = tuple(lrn.exploration_frequencies) or tuple(
                np.geomspace(0.3 * self.n_rate, 30 * self.n_rate, 6)
            )
            self.exploration = Exploration(lrn.exploration_amplitude, freqs, lrn.seed)
            self.learn_at = lrn.learn_at_orbits * orbit_period(dep)
            self.next_attempt = self.learn_at
        # a command issued at T acts from the environment's first step at or after T + this
        # (docs/design.md, "Time"): the flight software knows its actuation link's latency
        self.actuation_delay = dep.link_latency(f"ctrl-{sc}", "environment", command_topic(sc))
        self.normal_angle = math.radians(dep.spacecraft.normal_angle)
        self.h_model = dep.chief.a - R_EARTH
        self.scale_height = dep.atmosphere.scale_height
        self.u = 0.0  # the attitude command in force, sigma3
        self.u_applied = 0.0  # the linear-model input it realises (drag_allocation)
        self.steps: list[tuple[float, float]] = []  # (T, u_applied) of every step so far
        self.iteration = 0
        self.converged = self.mode == "lqr"
        self.learn_info: dict = {}
        self.rank = self.rank_needed = 0
        # samples before this are not the learner's (the initial transient; see rejoin)
        self.collect_from = self.deputy.learning.data_from_orbits * orbit_period(dep)
        self.result = None  # the learner's last result (DDVIResult): P, X, U as well as K, L
        self.learn_attempts = 0
        # change detection (learning.relearn): the samples the learner collects (t, x, u, v),
        # for the predictor the detector fits when it learns; the detector once armed
        self.learning_samples: collections.deque = collections.deque()
        self.detector: ChangeDetector | None = None
        self.detections = 0
        self.relearn_since: float | None = None  # data for re-learning start here
        # after a detected change the learner's exostate gains the density ratio (see
        # learner_exostate; a fallback restores the old one): (C, E, F) of the exosystem the
        # learner and L work with
        self.exosystem = (self.problem.C, self.problem.E, self.problem.F)
        if lrn.carries_density_ratio:  # from the start: craft that may differ
            self.exosystem = density_exosystem(*self.exosystem)
        if self.mode != "lqr":
            self.L = np.zeros((1, self.exosystem[1].shape[0]))
            self.collector = self.new_collector()
        self.learned_at: list[float] = []  # every switch to learned gains (s)
        # model fit with learning.refresh_orbits: the running integrals flown on the learned
        # gains, from which the feedforward is refitted (refresh_feedforward), and when next
        self.refresh: IntegralHistory | None = None
        self.next_refresh = math.inf
        self.trim: StationTrim | None = None  # model fit with learning.trim_orbits
        # while re-learning: what was flown before the detection (K, L, exosystem, when
        # learned, and the collector and rank that learned them), flown again if re-learning
        # fails relearn_max_attempts times; and the count of failures
        self.before_relearning: tuple | None = None
        self.relearn_failures = 0
        self.abandoned_at: list[float] = []  # every return to the old gains (s)

    def new_collector(self) -> IntervalCollector | IntegralHistory:
        """An empty store for the learner's data, for the exostate in force: the interval
        integrals of value iteration, or the running integrals of the model fit (at most
        ``window_orbits`` of samples kept when a window is set)."""
        lrn, q = self.deputy.learning, self.exosystem[1].shape[0]
        nav = self.deputy.navigation.period
        if lrn.method == "model-fit":
            window = lrn.window_orbits * orbit_period(self.dep) if lrn.window_orbits > 0 else 1e6
            return IntegralHistory(4, 1, q, lrn.interval, lrn.fit_stride, max_gap=3 * nav,
                                   max_samples=math.ceil(window / nav) + 2)  # fmt: skip
        return IntervalCollector(4, 1, q, lrn.interval, max_gap=3 * nav)

    def initial_gain(self) -> np.ndarray:
        """K0 (1, 4), the gain a learner explores on (the deployment gives 4 values)."""
        return np.reshape(np.asarray(self.deputy.learning.K0, dtype=float), (1, 4))

    def rejoin(self, t: float) -> str:
        """Restarted into a running mission, flying from step t on: nothing of the previous
        process survives, so a learner starts over (exploring with K0, its data from when its
        own commands act, learning ``learn_at_orbits`` from now).  Returns the log line."""
        if self.mode == "lqr":
            return f"restarted: flying the LQR gains from t = {t:.0f} s"
        self.collect_from = math.ceil((t + self.actuation_delay) / self.fsw - 1e-9) * self.fsw
        self.learn_at = self.next_attempt = t + self.deputy.learning.learn_at_orbits * orbit_period(
            self.dep
        )
        return (
            f"restarted: learning starts over (the data and gains of the previous process are "
            f"lost); exploring from t = {t:.0f} s, data from t = {self.collect_from:.0f} s, "
            f"learning at t = {self.learn_at:.0f} s"
        )

    @property
    def density_mode(self) -> bool:
        """The learner's exostate carries the density ratio (after a detected change, unless
        re-learning fell back to gains learned without it)."""
        return self.exosystem[1].shape[0] > self.problem.q

    def learner_exostate(self, v: np.ndarray, altitude: float) -> np.ndarray:
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

    def density_ratio(self, altitude: float) -> float:
        """rho(h) / rho(h_0) of the nominal exponential atmosphere: how much more drag the
        facet makes at altitude h (m) than the linear model's reference altitude h_0 (the
        chief's initial orbit).  The pair decays about 1.4 km in 15 orbits, and the drag, hence
        B, rises about 19% with it."""
        return math.exp(-(altitude - self.h_model) / self.scale_height)

    def command(self, t: float, x: np.ndarray, v: np.ndarray, altitude: float) -> float:
        """The attitude command sigma3 for a flight-software step at t, from state x (4,) and
        exostate v; ``u_applied`` is the linear-model input it realises (what the learner
        records)."""
        u = float((-self.K @ x + self.L @ self.learner_exostate(v, altitude))[0])
        if self.exploring:
            u += float(self.exploration(t, 1)[0])
        # schedule on the measured altitude: the drag the linear model's u stands for is the
        # same at every altitude, so the learner sees one B (and the LQR its design B)
        ratio = self.density_ratio(altitude)
        self.u, u_area = drag_allocation(u / ratio, self.normal_angle, self.limit)
        self.u_applied = u_area * ratio
        self.steps.append((t, self.u_applied))
        return self.u

    def on_sample(
        self, t: float, x: np.ndarray, v: np.ndarray, altitude: float, z: np.ndarray | None = None
    ) -> SampleOutcome:
        """One navigation sample, in time order, when it arrives undelayed: on a
        flight-software step, ``tick`` with it, then ``collect`` it (estimate x, measurement
        z).  The in-process baseline runs exactly this; the service runs the same two steps,
        ordered by time."""
        outcome = SampleOutcome(fsw=on_grid(t, self.fsw))
        if outcome.fsw:
            outcome.learn_log = self.tick(t, x, v, altitude)
        outcome.rejected = self.collect(t, x, v, altitude, z)
        return outcome

    @property
    def exploring(self) -> bool:
        """Exploring and collecting for the learner: before the first learning or, after a
        detected change, before re-learning (both on K0)."""
        return self.phase in ("exploring", "relearning")

    def tick(self, t: float, x: np.ndarray, v: np.ndarray, altitude: float) -> str | None:
        """A flight-software step at t with the newest navigation sample (x (4,), exostate v,
        altitude), measured at t or earlier: learn if it is time to, or start re-learning if
        the detector has seen the plant change (returns the log line), then compute the
        command in force from t on (``self.u``)."""
        learn_log = None
        if self.exploring and t >= self.next_attempt - 1e-6:
            learn_log = self.learn(t)
        elif self.phase == "learned" and self.detector is not None and self.detector.alarm:
            learn_log = self.start_relearning(t)
        elif self.phase == "learned" and self.refresh is not None and t >= self.next_refresh:
            learn_log = self.refresh_feedforward(t)
        elif self.phase == "learned" and self.trim is not None and self.trim.due(t):
            delta, learn_log = self.trim.update(t, float(self.K[0, 1]))
            self.L[0, 0] += delta
        self.command(t, x, v, altitude)
        return learn_log

    def start_relearning(self, t: float) -> str:
        """The detector has seen the plant change at step t: explore again on K0, the
        drift-nulling gain the first learning explored on, with the data from
        ``relearn_settle_orbits`` later on only, and learn again ``relearn_window_orbits`` after
        that.  Not on the learned gains: mid-approach they hold the command at one attitude
        limit or the other, which clips the exploration away (measured: data from the approach
        gave |K - K*|/|K*| = 2.3, and holding the slot with the learned gains swings the
        lightly damped loop through the limits for orbits).  Returns the log line."""
        det, lrn = self.detector, self.deputy.learning
        self.detections += 1
        learned = self.learned_at[-1] if self.learned_at else t
        self.before_relearning = (
            self.K,
            self.L,
            self.exosystem,
            learned,
            self.collector,
            self.rank,
            self.rank_needed,
        )
        self.relearn_failures = 0
        self.phase, self.converged, self.detector = "relearning", False, None
        self.source = "initial"  # flying K0 again until it re-learns
        if not self.density_mode:
            self.exosystem = density_exosystem(*self.exosystem)
        self.K, self.L = self.initial_gain(), np.zeros((1, self.exosystem[1].shape[0]))
        self.collector = self.new_collector()
        self.learning_samples.clear()
        period = orbit_period(self.dep)
        self.relearn_since = self.collect_from = t + lrn.relearn_settle_orbits * period
        self.next_attempt = self.relearn_since + lrn.relearn_window_orbits * period
        return (
            f"fault detector: at t = {t:.0f} s the {lrn.detector_window_orbits:g}-orbit mean "
            f"input-equivalent prediction residual {det.mean[0]:+.4g} left the bound "
            f"+-{det.bound[0]:.4g} ({det.statistic:.2f} x the bound): the plant has changed; "
            f"exploring again on K0, re-learning at t = {self.next_attempt:.0f} s from the data "
            f"from t = {self.relearn_since:.0f} s on"
        )

    def input_at(self, t: float) -> float:
        """The linear-model input this controller had in force at time t: that of its newest
        step at or before t (a delayed sample is collected after later steps have run)."""
        k = bisect.bisect_right(self.steps, t + 1e-6, key=lambda step: step[0])
        return self.steps[k - 1][1] if k else 0.0

    def input_acting(self, t: float) -> float:
        """The linear-model input acting on the plant from t to the next sample: the
        environment takes commands at each flight-software boundary T_k, the newest issued by
        T_k - actuation delay (none yet: the zero command).  With no delay, ``input_at(t)``.
        Exact for a fixed delay; with jitter the environment may apply a command a step sooner
        than this assumes, and a command lost on its link leaves the previous one acting."""
        t_k = math.floor(t / self.fsw + 1e-9) * self.fsw
        issued = math.floor((t_k - self.actuation_delay) / self.fsw + 1e-9) * self.fsw
        return self.input_at(issued) if issued > -1e-6 else 0.0

    def collect(
        self, t: float, x: np.ndarray, v: np.ndarray, altitude: float, z: np.ndarray | None = None
    ) -> str | None:
        """While exploring, feed the collector the sample with the input acting on the plant
        from t on (``input_acting``); returns why the collector refused it, if it did.  Once
        learned, feed the change detector (if armed) instead.  x (4,) is the navigation
        estimate, z (4,) the measurement it came from (None: x): with ``learning.learn_from =
        "measurement"`` the learner, the refresh and the detector get z, the trim x."""
        error = float(x[1]) - self.deputy.y_ref
        if self.trim is not None and self.phase == "learned":
            self.trim.add(t, error)
        if self.deputy.learning.learn_from == "measurement" and z is not None:
            # the filter's estimate lags what its model leaves out (the commanded drag), a
            # bias the fit would learn; the measurement's noise is white, which it averages
            x = z
        on_station = abs(error) <= self.deputy.learning.station_radius
        u, v = self.input_acting(t), self.learner_exostate(v, altitude)
        if self.refresh is not None and self.phase == "learned" and on_station:
            try:  # the gaps off station split the data (no interval spans one)
                self.refresh.add(t, x, [u], v)
            except LearningError as exc:
                return f"sample at t = {t} rejected: {exc}"
        if self.phase == "learned" and self.detector is not None:
            self.detector.add(t, x, [u], v)
            return None
        if not self.exploring or t < self.collect_from - 1e-6:
            return None
        try:
            self.collector.add(t, x, [u], v)
        except LearningError as exc:
            return f"sample at t = {t} rejected: {exc}"
        if self.deputy.learning.relearn:
            self.learning_samples.append((t, np.array(x, dtype=float), u, np.array(v, dtype=float)))
        return None

    def learning_failed(self, t: float, why: str) -> str:
        """A learning attempt at t did not give gains (``why``): explore on and try again
        ``retry_orbits`` later; but once re-learning has failed ``relearn_max_attempts``
        times, stop exploring and fly the gains of before the detection again, with the
        detector off (it would only see the same change again).  Exploring on K0 for ever
        is worse than the old gains: K0 holds no slot, and the deputy drifts off with the
        fault's bias (measured: 18.5 km off at orbit 50 with a panel stuck at 60 deg, against
        673 m with the old gains back after 5 attempts).  Returns the log line."""
        lrn = self.deputy.learning
        if self.before_relearning is not None:
            self.relearn_failures += 1
            if self.relearn_failures >= lrn.relearn_max_attempts:
                (self.K, self.L, self.exosystem, learned, self.collector, self.rank,
                 self.rank_needed) = self.before_relearning  # fmt: skip
                self.before_relearning = self.relearn_since = None
                self.learning_samples.clear()
                self.phase, self.source, self.converged = "learned", "fallback", True
                self.abandoned_at.append(t)
                return (
                    f"{why}; re-learning abandoned after {self.relearn_failures} attempts: "
                    f"flying the gains learned at t = {learned:.0f} s again, fault detector off"
                )
        self.next_attempt = t + lrn.retry_orbits * orbit_period(self.dep)
        until = lrn.learn_until_orbits * orbit_period(self.dep)
        if lrn.learn_until_orbits > 0 and self.next_attempt > until + 1e-6:
            # far from where it started the linear model no longer holds the data (a deputy
            # that cannot hold its slot drifts 100 km and more), so a late fit is not trusted
            self.next_attempt = math.inf
            return f"{why}; no gain accepted by orbit {lrn.learn_until_orbits:g}: learning stops"
        return f"{why}, exploring on"

    def arm_detector(self, since: float) -> str:
        """Fit the one-step predictor on the samples the learner just learned from (those at
        or after ``since``) and watch it from now on; returns the bound it states."""
        lrn = self.deputy.learning
        samples = [s for s in self.learning_samples if s[0] >= since - 1e-6]
        try:
            predictor = fit_predictor(
                [s[0] for s in samples],
                np.reshape([s[1] for s in samples], (len(samples), 4)),
                [s[2] for s in samples],
                np.reshape([s[3] for s in samples], (len(samples), self.exosystem[1].shape[0])),
                step=self.deputy.navigation.period,
                translation=[0.0, 1.0, 0.0, 0.0] if lrn.along_track_reference else None,
            )
            window = lrn.detector_window_orbits * orbit_period(self.dep)
            self.detector = ChangeDetector(predictor, lrn.detector_bound, window)
        except DetectionError as exc:
            self.detector = None
            return f"; fault detector NOT armed (no re-learning): {exc}"
        finally:
            self.learning_samples.clear()
        return (
            f"; fault detector: bound = +-{self.detector.bound[0]:.4g} on the "
            f"{lrn.detector_window_orbits:g}-orbit mean input-equivalent one-step prediction "
            f"residual ({lrn.detector_bound:g} x its RMS {predictor.input_rms[0]:.3g} on the "
            f"{predictor.pairs} sample pairs learned from; one-step residual RMS "
            f"{np.array2string(predictor.residual_rms, precision=3)})"
        )

    def learning_window(self, t: float) -> float:
        """The first sample time (s) an attempt at t learns from: while re-learning, the
        newest window since settling; else the last ``window_orbits`` (0: all the data, a
        window that grows with every retry)."""
        lrn, period = self.deputy.learning, orbit_period(self.dep)
        if self.relearn_since is not None:
            return max(self.relearn_since, t - lrn.relearn_window_orbits * period)
        return t - lrn.window_orbits * period if lrn.window_orbits > 0 else -math.inf

    def run_learner(self, since: float) -> tuple[Any, dict, str | None]:
        """Learn from the data at or after ``since``: (the result with K, L; what the
        learning log reports; why it did not converge, or None).  Raises LearningError."""
        lrn, pr, n = self.deputy.learning, self.problem, self.n_rate
        C, E, F = self.exosystem
        translation = [0.0, 1.0, 0.0, 0.0] if lrn.along_track_reference else None
        data = self.collector.data().since(since)
        if lrn.method == "model-fit":
            return self.fit_model(data, translation)
        r = learn_from_data(
            data, pr.Q, pr.R, time_unit=n, C=C, E=E, F=F,
            steps=StepSequence(lrn.step, lrn.step_size),
            bounds=BoundSchedule(lrn.bounds, lrn.bound_base),
            tol=lrn.tol, max_iterations=lrn.max_iterations,
            state_scale=[1.0, 1.0, n, n], translation=translation,
        )  # fmt: skip
        self.rank, self.rank_needed = r.rank, r.rank_needed
        info = {"condition": r.condition, "residual": r.residual, "intervals": r.intervals,
                "iterations": r.iterations}  # fmt: skip
        return r, info, None if r.converged else r.message

    def fit_model(self, data: Any, translation: list | None) -> tuple[Any, dict, str | None]:
        """The model-fit learner on ``data`` (IntegralData), as ``run_learner``
        (services.flight.fitting): with the tolerance in force for the attempt due now."""
        lrn = self.deputy.learning
        deadline = lrn.fit_deadline_orbits * orbit_period(self.dep)
        late = lrn.fit_deadline_orbits > 0 and self.next_attempt >= deadline - 1e-6
        tolerance = lrn.fit_deadline_tolerance if late else lrn.fit_tolerance
        holdout = lrn.validation_orbits * orbit_period(self.dep)
        r, info, why = fit_attempt(
            data, lrn, self.problem, self.exosystem, translation, tolerance, holdout
        )
        self.rank, self.rank_needed = info["rank"], info["needed"]
        return r, info, why

    def learn(self, t: float) -> str:
        """Run the deployment's learner on the data so far; switch gains on success."""
        lrn = self.deputy.learning
        t0 = time.perf_counter()
        self.learn_attempts += 1
        since = self.learning_window(t)
        try:
            r, info, not_converged = self.run_learner(since)
        except LearningError as exc:
            return self.learning_failed(t, f"learning at t = {t:.0f} s failed: {exc}")
        if not_converged is not None:
            return self.learning_failed(t, f"learning at t = {t:.0f} s did not converge "
                                        f"({not_converged})")  # fmt: skip
        self.K, self.L = r.K, r.L
        self.result = r
        relearned = self.relearn_since is not None
        self.phase = "learned"
        self.source = "model-fit" if lrn.method == "model-fit" else "ddvi"
        self.iteration, self.converged = info.get("iterations", 0), True
        self.relearn_since = self.before_relearning = None
        self.learned_at.append(t)
        self.learn_info = {"wall_s": time.perf_counter() - t0, **info}
        armed = self.arm_detector(since) if lrn.relearn else ""
        if lrn.method == "model-fit" and lrn.refresh_orbits > 0:
            period = lrn.refresh_orbits * orbit_period(self.dep)
            self.refresh = self.new_collector()
            self.next_refresh = t + 2 * period
        if lrn.method == "model-fit" and lrn.trim_orbits > 0:
            period = lrn.trim_orbits * orbit_period(self.dep)
            self.trim = StationTrim(period, lrn.station_radius, lrn.trim_gain, start=t)
        how = (
            f"by a model fit (condition {info['condition']:.3g}, relative residual "
            f"{info['residual']:.3g}, predicted gain error {info['error']:.3g}, "
            f"B = {info['B']}{validated(info)})"
            if lrn.method == "model-fit"
            else f"in {self.iteration} iterations"
        )
        return (
            f"{'re-learned' if relearned else 'learned'} at t = {t:.0f} s from "
            f"{info['intervals']} intervals {how} ({self.learn_info['wall_s']:.2f} s): "
            f"K = {r.K.ravel().tolist()}, L = {r.L.ravel().tolist()}{armed}"
        )

    def refresh_feedforward(self, t: float) -> str:
        """Refit the model fit's D, with its A and B held, on the data flown on the learned
        gains in the deputy's newest stay on station (within ``station_radius`` of the slot
        without a break, at least ``refresh_orbits`` P of it), and fly the feedforward
        L = U + K X of the regulator equations on it: the drag offset the exploration saw far
        behind the slot is not the one at the slot.  The window is the stay less its first P
        (the settling), but never shorter than the last P and one interval: a stay shorter
        than 2 P + interval is refitted from its last P + interval, its settling included.
        Returns the log line; a refit that fails keeps the L in force."""
        lrn, C, E, F = self.deputy.learning, *self.exosystem
        period = lrn.refresh_orbits * orbit_period(self.dep)
        self.next_refresh = t + period
        # the newest stay on station only (a fly-through is not one), less its first period,
        # the approach's settling, where the fit's A errors leak into D; a window that grows
        # with the stay, for the noise (a sliding one of 2 to 6 orbits swung the deputy
        # kilometres off at 10 m of noise)
        data = self.refresh.data().since(self.learning_window(t))
        if data.samples:
            data = data.since(float(data.t[data.segment == data.segment[-1]][0]))
        if data.samples:
            data = data.since(min(float(data.t[0]) + period, t - period - lrn.interval))
        span = float(data.t[-1] - data.t[0]) if data.samples else 0.0
        if span < period - 1e-6:
            return (
                f"feedforward not refitted at t = {t:.0f} s: on station for {span:.0f} s, "
                f"less than refresh_orbits; L kept"
            )
        model = self.result.model
        try:
            D = select_feedforward_modes(data, model, lrn, E, on_station=True)
            X, U = solve_regulator_equations(model.A, model.B, C, D, E, F)
        except (LearningError, InfeasibleError) as exc:
            return f"feedforward refit at t = {t:.0f} s failed, L kept: {exc}"
        self.L = feedforward_gain(self.K, X, U)
        if self.trim is not None:
            # the refit saw the trim in the inputs it was fitted on: it replaces it, and the
            # errors flown before it are no one's to correct
            self.trim.restart(t)
        return (
            f"feedforward refitted at t = {t:.0f} s from {data.samples} samples on the learned "
            f"gains: D[:, 0] = {np.round(D[:, 0], 12).tolist()}, L = {self.L.ravel().tolist()}"
        )


def validated(info: dict) -> str:
    """The learning log's words on a model-fit gain's validation (none when it was off)."""
    if "validation" not in info:
        return ""
    return (
        f"; validated on the hold-out: relative prediction residual {info['validation']:.3g}, "
        f"closed-loop decay {info['validation_margin']:.3g} 1/s, gain "
        f"{info['validation_gain']:.3g} from that of the fit without it"
    )


def density_exosystem(C: np.ndarray, E: np.ndarray, F: np.ndarray) -> tuple:
    """(C, E, F) of an exosystem extended by the density ratio: a mode E holds constant (its
    row and column of E zero), which the reference F does not see."""
    F_rho = np.hstack([F, np.zeros((F.shape[0], 1))])
    return C, scipy.linalg.block_diag(E, 0.0), F_rho
