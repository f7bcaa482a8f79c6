"""A learning deputy's learning cycle: when it learns, what it does with an attempt's outcome,
when it re-learns after a detected change and when it gives re-learning up, and the record of
it all (attempts, switches, ranks, the last result).  No I/O: the controller
(``services.flight.control.Controller``) calls it from its steps and flies the gains its phase
holds (``services.flight.phases``)."""

from __future__ import annotations

import time

import numpy as np

from services.config import Deputy
from services.flight.actuation import Actuation
from services.flight.learners import Learner, LearnerExostate
from services.flight.phases import Gains, Phase, PhaseMachine, Schedule
from services.flight.relearning import ChangeWatch, Relearning


def initial_gains(learner: Learner, exostate: LearnerExostate) -> Gains:
    """K0 and no feedforward, what a learner explores on."""
    q = exostate.exosystem[1].shape[0]
    return Gains(learner.initial_gain(), np.zeros((1, q)), "initial")


class LearningCycle:
    """When the deputy's learner learns and what follows, and its record.

    Parameters
    ----------
    deputy : the deputy (its ``learning`` table).
    orbit : the orbit period, s.
    learner : the deputy's learner (None for the LQR: the record stays empty).
    phases : the controller's phases, moved by the cycle.
    exostate : the learner's exostate (the density ratio added on re-learning).
    watch : the change detector's watch.
    actuation : the commands (when a learner's data start; which were at the attitude limit).
    lqr : the nominal model's LQR gains, K (1, n) and L (1, 5) (source "lqr"): the fallback.
    end : when the mission ends, s (whether a fallback has time left to learn on).
    """

    def __init__(
        self,
        deputy: Deputy,
        orbit: float,
        learner: Learner | None,
        phases: PhaseMachine,
        exostate: LearnerExostate,
        watch: ChangeWatch,
        actuation: Actuation,
        lqr: Gains,
        end: float,
    ) -> None:
        self.deputy, self.orbit = deputy, orbit
        self.learner, self.phases, self.exostate = learner, phases, exostate
        self.watch, self.actuation, self.lqr, self.end = watch, actuation, lqr, end
        self.iteration = 0
        self.learn_info: dict = {}
        self.rank = self.rank_needed = 0
        self.result = None  # the learner's last result (DDVIResult): P, X, U as well as K, L
        self.learn_attempts = 0
        self.learned_at: list[float] = []  # every switch to learned gains (s)
        self.abandoned_at: list[float] = []  # every return to the old gains (s)
        self.fallback_at: list[float] = []  # when it took to the LQR fallback (s)
        self.saturated_fallback = False  # the fallback was taken on saturated data
        self.resumed_at: list[float] = []  # when it explored on the fallback (s)

    def rejoin(self, t: float) -> str:
        """Restarted into a running mission, flying from step t on: nothing of the previous
        process survives, so a learner starts over (exploring with K0, its data from when its
        own commands act, learning ``learn_at_orbits`` from now).  Returns the log line."""
        if self.learner is None:
            return f"restarted: flying the LQR gains from t = {t:.0f} s"
        self.phases.reschedule(
            collect_from=self.actuation.first_acting_step(t),
            next_attempt=t + self.deputy.learning.learn_at_orbits * self.orbit,
        )
        schedule = self.phases.schedule
        return (
            f"restarted: learning starts over (the data and gains of the previous process are "
            f"lost); exploring from t = {t:.0f} s, data from t = {schedule.collect_from:.0f} s, "
            f"learning at t = {schedule.next_attempt:.0f} s"
        )

    def start_relearning(self, t: float) -> str:
        """The detector has seen the plant change at step t: explore again on K0, the
        drift-nulling gain the first learning explored on, with the data from
        ``relearn_settle_orbits`` later on only, and learn again ``relearn_window_orbits`` after
        that.  Not on the learned gains: mid-approach they hold the command at one attitude
        limit or the other, which clips the exploration away (measured: data from the approach
        gave |K - K*|/|K*| = 2.3, and holding the slot with the learned gains swings the
        lightly damped loop through the limits for orbits).  Returns the log line."""
        lrn, learner = self.deputy.learning, self.learner
        seen = self.watch.detected()
        learned = self.learned_at[-1] if self.learned_at else t
        since = t + lrn.relearn_settle_orbits * self.orbit
        window = lrn.relearn_window_orbits * self.orbit
        before = Relearning(
            self.phases.gains.K,
            self.phases.gains.L,
            self.exostate.exosystem,
            learned,
            learner.store,
            (self.rank, self.rank_needed),
            since,
            window,
        )
        self.exostate.add_density_ratio()
        # K0 until it re-learns
        schedule = Schedule(since, since + window)
        self.phases.move(Phase.RELEARNING, initial_gains(learner, self.exostate), schedule, before)
        learner.store = learner.new_store(self.exostate.exosystem[1].shape[0])
        return (
            f"fault detector: at t = {t:.0f} s {seen}; exploring again on K0, re-learning at "
            f"t = {self.phases.schedule.next_attempt:.0f} s from the data from t = {since:.0f} s on"
        )

    def learning_window(self, t: float) -> float:
        """The first sample time (s) an attempt at t learns from: while re-learning, the
        newest window since settling; else the last ``window_orbits`` (0: all the data, a
        window that grows with every retry)."""
        if self.phases.before is not None:
            return self.phases.before.window_start(t)
        return self.learner.window_start(t)

    def learn(self, t: float) -> str:
        """Run the deployment's learner on the data so far; switch gains on success."""
        lrn, learner = self.deputy.learning, self.learner
        t0 = time.perf_counter()
        self.learn_attempts += 1
        since = self.learning_window(t)
        attempt = learner.attempt(
            since,
            self.exostate.exosystem,
            self.phases.schedule.next_attempt,
            self.phases.current is Phase.EXPLORING_ON_FALLBACK,
        )
        if attempt.rank is not None:
            self.rank, self.rank_needed = attempt.rank
        if attempt.refused is not None:
            return self.learning_failed(t, f"learning at t = {t:.0f} s {attempt.refused}")
        r, info = attempt.result, attempt.info
        self.result = r
        relearned = self.phases.before is not None
        self.phases.move(Phase.LEARNED, Gains(r.K, r.L, learner.source))
        self.iteration = info.get("iterations", 0)
        self.learned_at.append(t)
        self.learn_info = {"wall_s": time.perf_counter() - t0, **info}
        armed = self.watch.arm(since, self.exostate.exosystem[1].shape[0]) if lrn.relearn else ""
        learner.learned(t, r, self.exostate.exosystem)
        return (
            f"{'re-learned' if relearned else 'learned'} at t = {t:.0f} s from "
            f"{info['intervals']} intervals {learner.describe(info)} "
            f"({self.learn_info['wall_s']:.2f} s): "
            f"K = {r.K.ravel().tolist()}, L = {r.L.ravel().tolist()}{armed}"
        )

    def learning_failed(self, t: float, why: str) -> str:
        """A learning attempt at t did not give gains (``why``): explore on and try again
        ``retry_orbits`` later; but once re-learning has failed ``relearn_max_attempts``
        times, stop exploring and fly the gains of before the detection again (``fallback =
        "last"``) or the fallback (``"lqr"``), with the detector off (it would only see the
        same change again).  Exploring on K0 for ever is worse than the old gains: K0 holds no
        slot, and the deputy drifts off with the fault's bias (measured: 18.5 km off at orbit
        50 with a panel stuck at 60 deg, against 673 m with the old gains back after 5
        attempts).  So is it where no first gain validates: past ``learn_until_orbits`` (far
        from where it started the linear model no longer holds the data: a deputy that cannot
        hold its slot drifts 100 km and more, so a late fit is not trusted) it flies the
        fallback; and at once where an attempt at the first gain fails on data whose input was
        out of reach in ``saturated_fraction`` of the steps (K0's command at the attitude
        limit: no variation of the input to learn from, and K0 loses ground on the approach).
        An attempt exploring on the fallback retries until ``resume_until``, then flies the
        fallback again.  Returns the log line."""
        lrn, before = self.deputy.learning, self.phases.before
        if before is not None:
            before.failures += 1
            if before.failures >= lrn.relearn_max_attempts:
                self.exostate.exosystem = before.exosystem
                self.learner.store = before.store
                self.rank, self.rank_needed = before.rank
                self.watch.disarm()
                self.abandoned_at.append(t)
                said = f"{why}; re-learning abandoned after {before.failures} attempts"
                if lrn.fallback == "lqr":
                    return self.fall_back(t, said)
                self.phases.move(Phase.LEARNED, Gains(before.K, before.L, "fallback"))
                return (
                    f"{said}: flying the gains learned at t = {before.learned_at:.0f} s again, "
                    "fault detector off"
                )
        retry = t + lrn.retry_orbits * self.orbit
        if self.phases.current is Phase.EXPLORING_ON_FALLBACK:
            if retry > self.resume_until + 1e-6:
                return self.fall_back(t, f"{why}; no gain validated on the fallback")
            self.phases.reschedule(next_attempt=retry)
            return f"{why}, exploring on the fallback"
        if before is None:
            start = max(self.learning_window(t), self.phases.schedule.collect_from)
            saturated = self.actuation.fraction_at_limit(start, t)
            if saturated >= lrn.saturated_fraction:
                self.saturated_fallback = True
                return self.fall_back(
                    t,
                    f"{why}; the attitude was at its limit in {saturated:.0%} of the steps it "
                    "learned from: no variation of the input to learn from, and exploring on K0 "
                    "loses ground on the approach",
                )
            until = lrn.learn_until_orbits
            if retry > until * self.orbit + 1e-6:
                return self.fall_back(t, f"{why}; no gain validated by orbit {until:g}")
        self.phases.reschedule(next_attempt=retry)
        return f"{why}, exploring on"

    @property
    def resume_until(self) -> float:
        """The last attempt on the fallback (s): a gain learned later would fly less than
        ``resume_window_orbits`` before the end."""
        return self.end - self.deputy.learning.resume_window_orbits * self.orbit

    def resume_on_fallback(self, t: float) -> str | None:
        """At step t on a fallback taken on saturated data: once its command has been off the
        attitude limit for an orbit (on station, where the data can vary) and twice
        ``resume_window_orbits`` are left before the mission's end, explore on the fallback's
        gains, the data from when this step's command acts, and learn ``resume_window_orbits``
        later, retrying as after a failed attempt while a gain would still fly that long before
        the end.  Once only.  Returns the log line, or None if it does not resume."""
        lrn = self.deputy.learning
        window = lrn.resume_window_orbits * self.orbit
        if (
            not self.saturated_fallback
            or self.resumed_at
            or window <= 0
            or t - self.fallback_at[-1] < self.orbit - 1e-6
            or t + 2 * window > self.end + 1e-6
            or self.actuation.fraction_at_limit(t - self.orbit, t) > 0
        ):
            return None
        collect_from = self.actuation.first_acting_step(t)
        schedule = Schedule(collect_from, t + window)
        self.phases.move(Phase.EXPLORING_ON_FALLBACK, self.phases.gains, schedule)
        self.learner.store = self.learner.new_store(self.exostate.exosystem[1].shape[0])
        self.watch.disarm()  # nor does the detector's predictor fit K0's samples
        self.resumed_at.append(t)
        return (
            f"the fallback's attitude has been off its limit for an orbit: exploring on the "
            f"fallback from t = {t:.0f} s, data from t = {collect_from:.0f} s, learning at "
            f"t = {schedule.next_attempt:.0f} s"
        )

    def fall_back(self, t: float, why: str) -> str:
        """Fly the fallback from step t, to the end unless it explores on it
        (``resume_on_fallback``): the nominal model's LQR gains (the
        feedforward zero on an exostate mode the model has not: the density ratio).  Returns
        the log line, which says why (``why``)."""
        q = self.exostate.exosystem[1].shape[0]
        L = np.zeros((1, q))
        L[:, : self.lqr.L.shape[1]] = self.lqr.L
        self.phases.move(Phase.FALLBACK, Gains(self.lqr.K, L, "lqr"))
        self.fallback_at.append(t)
        return f"{why}: flying the fallback, the nominal model's LQR gains, from t = {t:.0f} s"
