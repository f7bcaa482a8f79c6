"""The control law of a deputy's controller, with its learner: no bus, no processes.  The
controller service (``services.flight.controller``) and the one-process baseline
(``services.flight.inprocess``) both fly it (through ``services.flight.control_loop``).  Its
phases and their moves: services.flight.phases; when it learns and what follows:
services.flight.learning_cycle; its learners: services.flight.learners; re-learning:
services.flight.relearning.

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
(services.flight.learners.LearnerExostate), switches to the new gains and re-arms the
detector; after ``relearn_max_attempts`` failed attempts it flies the gains of before the
detection again (source "fallback"; with ``learning.fallback = "lqr"`` the nominal model's
LQR gains, phase "fallback") and watches no more until it is restarted.  A learner that has
validated no gain by ``learn_until_orbits`` flies the LQR gains too (phase "fallback"), and so
does one whose attempt at a first gain fails on data with the attitude at its limit, which
explores and learns on those gains once their command is off the limit (phase
"exploring-on-fallback").  Every
command goes through ddvi_core.models.drag_allocation, scheduled on the deputy's altitude (its
nav message), which makes the facet's drag linear in u and the same at every altitude.  The
learner gets what a flight computer knows: Q, R, the output map and reference (C, F), the
exosystem E and the orbit rate; never A, B or D.  Control input u = sigma3, the relative MRP
about the orbit normal; sigma1 = sigma2 = 0.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ddvi_core.learning import IntervalCollector
from ddvi_core.model_fit import IntegralHistory
from services.config import Deployment
from services.flight.actuation import Actuation
from services.flight.learners import Learner, LearnerExostate, make_learner
from services.flight.learning_cycle import LearningCycle, initial_gains
from services.flight.phases import Gains, Phase, PhaseMachine, Schedule
from services.flight.relearning import ChangeWatch
from services.model import (
    duration,
    lqr_gains,
    mean_motion,
    nominal_problem,
    on_grid,
    orbit_period,
)


@dataclass
class SampleOutcome:
    """What one navigation sample did: a flight-software step (a new command in
    ``Controller.u``), a learning attempt (its log line), a sample the collector refused."""

    fsw: bool
    learn_log: str | None = None
    rejected: str | None = None


class Controller:
    """The control law, its phase and its learner (``learner``; None for the LQR), the change
    watch and, while re-learning, what flew before the detection; no I/O (the service loop
    does that)."""

    def __init__(self, dep: Deployment, sc: str) -> None:
        self.dep, self.sc = dep, sc
        self.deputy = dep.deputy_named(sc)
        self.problem = nominal_problem(dep, self.deputy)  # Q, R, C, E, F used by the learner
        self.n_rate, self.orbit = mean_motion(dep), orbit_period(dep)
        self.fsw = dep.run.fsw_period
        lrn = self.deputy.learning
        self.mode = self.deputy.controller
        self.actuation = Actuation(dep, sc)  # the commands, and which acts when
        density_ratio = self.actuation.density_ratio
        self.exostate = LearnerExostate(self.problem, lrn.carries_density_ratio, density_ratio)
        self.learner: Learner | None = None
        lqr = Gains(*lqr_gains(dep, self.deputy), "lqr")  # a learner's fallback
        if self.mode == "lqr":
            self.phases = PhaseMachine(Phase.LQR, lqr)
        else:
            q = self.exosystem[1].shape[0]
            self.learner = make_learner(dep, self.deputy, self.problem, q)
            # samples before data_from_orbits are not the learner's (the initial transient)
            schedule = Schedule(lrn.data_from_orbits * self.orbit, lrn.learn_at_orbits * self.orbit)
            gains = initial_gains(self.learner, self.exostate)
            self.phases = PhaseMachine(Phase.EXPLORING, gains, schedule)
        self.watch = ChangeWatch(lrn, self.deputy.navigation.period, self.orbit)
        self.learning = LearningCycle(
            self.deputy,
            self.orbit,
            self.learner,
            self.phases,
            self.exostate,
            self.watch,
            self.actuation,
            lqr,
            duration(dep),
        )

    @property
    def phase(self) -> str:
        """The phase's word: "lqr", "exploring", "learned", "relearning", "fallback" or
        "exploring-on-fallback"."""
        return self.phases.current.value

    @property
    def K(self) -> np.ndarray:
        """The feedback gain (1, 4) the phase flies."""
        return self.phases.gains.K

    @property
    def L(self) -> np.ndarray:
        """The feedforward gain (1, q) the phase flies."""
        return self.phases.gains.L

    @property
    def source(self) -> str:
        """Where the gains flown came from (``phases.Gains``)."""
        return self.phases.gains.source

    @property
    def converged(self) -> bool:
        return self.phases.converged

    @property
    def next_attempt(self) -> float:
        """When an exploring phase attempts to learn next (s; inf: not exploring, or no more)."""
        schedule = self.phases.schedule
        return math.inf if schedule is None else schedule.next_attempt

    @property
    def collect_from(self) -> float:
        """From when an exploring phase collects for its learner (s; inf: not exploring)."""
        schedule = self.phases.schedule
        return math.inf if schedule is None else schedule.collect_from

    @property
    def u(self) -> float:
        """The attitude command in force, sigma3."""
        return self.actuation.u

    @property
    def exploring(self) -> bool:
        return self.phases.exploring

    @property
    def collector(self) -> IntervalCollector | IntegralHistory | None:
        """The learner's store of the data (None for the LQR)."""
        return self.learner.store if self.learner is not None else None

    @property
    def detections(self) -> int:
        return self.watch.detections

    @property
    def exosystem(self) -> tuple:
        """(C, E, F) of the exosystem the learner and L work with."""
        return self.exostate.exosystem

    @property
    def density_mode(self) -> bool:
        return self.exostate.density_mode

    def rejoin(self, t: float) -> str:
        """Restarted into a running mission, flying from step t on (``LearningCycle.rejoin``:
        a learner starts over).  Returns the log line."""
        return self.learning.rejoin(t)

    def command(self, t: float, x: np.ndarray, v: np.ndarray, altitude: float) -> float:
        """The attitude command sigma3 for a flight-software step at t, from state x (4,) and
        exostate v; ``actuation.u_applied`` is the linear-model input it realises (what the
        learner records)."""
        u = float((-self.K @ x + self.L @ self.exostate(v, altitude))[0])
        if self.exploring:
            u += float(self.learner.exploration(t, 1)[0])
        return self.actuation.allocate(t, u, altitude)

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

    def tick(self, t: float, x: np.ndarray, v: np.ndarray, altitude: float) -> str | None:
        """A flight-software step at t with the newest navigation sample (x (4,), exostate v,
        altitude), measured at t or earlier: learn if it is time to, start re-learning if
        the detector has seen the plant change, or keep station on the learned gains (returns
        the log line), then compute the command in force from t on (``self.u``)."""
        learn_log = None
        learned = self.phases.current is Phase.LEARNED
        if self.exploring and t >= self.next_attempt - 1e-6:
            learn_log = self.learning.learn(t)
        elif learned and self.watch.alarm:
            learn_log = self.learning.start_relearning(t)
        elif learned and self.learner is not None and self.learner.station is not None:
            L, learn_log = self.learner.station.step(t, self.L, self.learning.learning_window(t))
            self.phases.trim(L)
        elif self.phases.current is Phase.FALLBACK:
            learn_log = self.learning.resume_on_fallback(t)
        self.command(t, x, v, altitude)
        return learn_log

    def collect(
        self, t: float, x: np.ndarray, v: np.ndarray, altitude: float, z: np.ndarray | None = None
    ) -> str | None:
        """While exploring, feed the learner the sample with the input acting on the plant
        from t on (``Actuation.input_acting``); returns why its store refused it, if it did.  Once
        learned, feed the station keeping and the change detector (if armed) instead.  x (4,)
        is the navigation estimate, z (4,) the measurement it came from (None: x): with
        ``learning.learn_from = "measurement"`` the learner, the refresh and the detector get
        z, the trim x."""
        lrn = self.deputy.learning
        error = float(x[1]) - self.deputy.y_ref
        if lrn.learn_from == "measurement" and z is not None:
            # the filter's estimate lags what its model leaves out (the commanded drag), a
            # bias the fit would learn; the measurement's noise is white, which it averages
            x = z
        u, v = self.actuation.input_acting(t), self.exostate(v, altitude)
        if self.phases.current is Phase.LEARNED:
            station = self.learner.station if self.learner is not None else None
            rejected = station.add(t, x, u, v, error) if station is not None else None
            if rejected is not None or self.watch.add(t, x, u, v):
                return rejected
        if not self.exploring or t < self.collect_from - 1e-6:
            return None
        rejected = self.learner.collect(t, x, u, v)
        if rejected is None and lrn.relearn:
            self.watch.record(t, x, u, v)
        return rejected
