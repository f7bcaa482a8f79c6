"""One deputy's flight-software loop as a component: its navigation samples paired with their
exostates, and its steps and samples taken in time order, with no bus, no wall clock and no
I/O, so that the controller service and the one-process executor fly the same code.

Inputs:  ``nav(t, x, altitude, z, valid)`` and ``exo(t, v)``: what the controller's links
         delivered, in any order; ``advance(may_step, final_t)``: run the steps and collect the
         samples that can be, the host saying which steps' inputs are accounted for.
Outputs: per step a ``Step`` (the command sigma (3,), the learning's log line); what to say
         (``Said``); the counters.

Timing: a step at T flies on the newest valid sample measured by T - delay (the input links'
nominal delay: ``newest_sample_time``), and a sample measured at t is collected (fed to the
learner) before the first step after it that could have had it: with no delay, a step before
the sample measured at its own time, exactly ``Controller.on_sample``.  A step whose newest
valid sample is older than run.nav_stale_limit (twice the step by default) past the one it
should have flies the safe attitude (``StaleNavigation``; docs/health.md): navigation in an
outage, held or lost on its links, or away.
"""

from __future__ import annotations

import collections
import math
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np

from services.flight.control import Controller
from services.flight.health import SAFE_SIGMA
from services.flight.streams import SamplePairs
from services.interface import EXOSTATE, nav_state_topic


def newest_sample_time(T: float, delay: float, period: float) -> float:
    """The measurement time (s) of the newest sample a step at T can have, its inputs
    ``delay`` s behind on a grid of ``period`` s (negative: none yet; inf for a step at inf,
    a restarted controller's before it has a sample)."""
    if math.isinf(T):
        return T
    return math.floor((T - delay) / period + 1e-9) * period


def input_delay(dep: Any, sc: str) -> float:
    """The nominal delay (s: delay + jitter) of deputy ``sc``'s controller inputs, its
    navigation and the exostate, as the deployment's [[link]]s give them."""
    ctrl = f"ctrl-{sc}"
    return max(
        dep.link_latency(f"nav-{sc}", ctrl, nav_state_topic(sc)),
        dep.link_latency("environment", ctrl, EXOSTATE),
    )


def stale_limit(run: Any) -> float:
    """How old past the sample it should have a step's newest navigation may be before the
    step flies the safe attitude, s: run.nav_stale_limit, or two flight-software steps."""
    return run.nav_stale_limit or 2.0 * run.fsw_period


@dataclass
class Sample:
    """A navigation sample paired with its exostate: measured at t (s), the estimate x (4,),
    v (q,), altitude (m), the measurement z (4,), and whether it was measured (``valid``: not
    an outage's prediction)."""

    t: float
    x: np.ndarray
    v: np.ndarray
    altitude: float
    z: np.ndarray
    valid: bool = True


@dataclass
class Step:
    """One flight-software step: the ``number``-th (from 1), at T (s), the commanded relative
    MRP ``sigma`` (3,), whether it is the safe attitude (stale navigation), the learning's log
    line if the step learned (its gains then changed), and whether the controller explores
    after it (its gains are beaconed)."""

    number: int
    T: float
    sigma: list[float]
    safe: bool = False
    learn_log: str | None = None
    exploring: bool = False


@dataclass
class Said:
    """What the loop has to say: a level ("info", "warning"), the text, at time t (s);
    ``gains``: the gains changed with it (a restarted learner's)."""

    level: str
    text: str
    t: float
    gains: bool = False


class StaleNavigation:
    """Whether a step flies the safe attitude: its newest valid sample older than ``limit`` s
    past the one it should have; said on the way in and out.

    Parameters
    ----------
    limit : run.nav_stale_limit, s.
    """

    def __init__(self, limit: float) -> None:
        self.limit = limit
        self.safe = False

    def check(self, want: float, newest_t: float | None, first: bool) -> tuple[bool, str | None]:
        """The step whose newest sample should be measured at ``want`` (s; negative: none yet)
        has its newest at ``newest_t`` (None: none); ``first``: no step has flown yet, and a
        step before any sample came holds zero, not the safe attitude.  Returns whether it
        flies safe, and what to say if that changed."""
        if want < -1e-6 or (first and newest_t is None):
            return False, None
        age = want - (newest_t if newest_t is not None else -math.inf)
        safe = age > self.limit + 1e-6
        if safe == self.safe:
            return safe, None
        self.safe = safe
        if safe:
            what = "no navigation yet" if newest_t is None else f"navigation {age:.0f} s old"
            return True, f"{what} (limit {self.limit:g} s): flying the safe attitude"
        return False, "navigation is back: flying the control law"


class ControlLoop:
    """The deputy's steps and samples in time order.

    Parameters
    ----------
    ctrl : the control law it flies.
    run : the deployment's ``[run]`` (fsw_period, nav_stale_limit).
    delay : the nominal delay of the controller's input links, s.
    joining : restarted into a running mission: it flies from the first step it has a sample
        for, and a learner starts over (``LearningCycle.rejoin``).
    """

    def __init__(self, ctrl: Controller, run: Any, delay: float, joining: bool = False) -> None:
        self.ctrl, self.sc, self.delay = ctrl, ctrl.sc, delay
        self.fsw, self.period = run.fsw_period, ctrl.deputy.navigation.period
        self.stale = StaleNavigation(stale_limit(run))
        self.pairs = SamplePairs(("nav", "exo"))  # nav: (x, altitude, z, valid); exo: v
        self.ready: dict[float, Sample] = {}  # paired, not yet collected
        self.last: Sample | None = None  # the newest collected
        # collected valid samples a step may still fly on (up to its delay behind it)
        self.recent: collections.deque[Sample] = collections.deque(
            maxlen=math.ceil(delay / self.period) + 8
        )
        self.counters = {
            "commands": 0,
            "samples_rejected": 0,
            "invalid_samples": 0,
            "learn_attempts": 0,
            "fault_detections": 0,
            "relearning_abandoned": 0,
            "safe_attitude_steps": 0,
        }
        self.steps = 0
        self.next_tick = math.inf if joining else 0.0
        self.out: list[Step | Said] = []

    def expected_sample(self, T: float) -> float:
        """The newest sample the step at T can have (negative: none yet)."""
        return newest_sample_time(T, self.delay, self.period)

    # -- samples ------------------------------------------------------------------------------

    def nav(self, t: float, x: np.ndarray, altitude: float, z: np.ndarray, valid: bool) -> None:
        """Navigation's sample measured at t (its in-plane x, z (4,))."""
        self.pair(t, "nav", (x, altitude, z, valid))

    def exo(self, t: float, v: np.ndarray) -> None:
        """The exostate at t."""
        self.pair(t, "exo", v)

    def pair(self, t: float, part: str, value: Any) -> None:
        """Pair by time; a complete sample newer than the last one collected is ready."""
        pair = self.pairs.add(t, part, value)
        last_t = None if self.last is None else self.last.t
        if pair is not None:
            (x, altitude, z, valid), v = pair["nav"], pair["exo"]
            if last_t is not None and t <= last_t:
                self.counters["samples_rejected"] += 1  # stale or replayed
            else:
                self.ready[t] = Sample(t, x, v, altitude, z, valid)
        if last_t is not None:
            # exostates and samples that nothing will pair any more (their partner was lost
            # on a link, or they repeat collected ones); a lone sample is counted as rejected
            stale = self.pairs.forget_before(last_t)
            self.counters["samples_rejected"] += sum("nav" in s for s in stale)
        if self.next_tick == math.inf and self.ready:  # restarted: the first step it can fly
            first = min(self.ready) + self.delay
            self.next_tick = math.ceil(first / self.fsw - 1e-9) * self.fsw
            said = self.ctrl.rejoin(self.next_tick)
            self.out.append(Said("warning", said, self.next_tick, gains=True))

    def collect(self, t: float) -> None:
        sample = self.ready.pop(t)
        self.last = sample
        if not sample.valid:  # an outage's prediction: nothing measured to learn from
            self.counters["invalid_samples"] += 1
            return
        rejected = self.ctrl.collect(t, sample.x, sample.v, sample.altitude, sample.z)
        if rejected is not None:
            self.counters["samples_rejected"] += 1
            self.out.append(Said("warning", rejected, t))
        self.recent.append(sample)

    # -- steps --------------------------------------------------------------------------------

    def tick(self, T: float) -> None:
        """The flight-software step at T: the command, and any learning it brings."""
        ctrl, counters = self.ctrl, self.counters
        # the newest valid sample measured by T - delay: one a later clock released early (the
        # environment runs ahead of a delayed loop) must not shorten the delay
        limit = self.expected_sample(T) + 1e-6
        candidates = [s for s in self.ready.values() if s.valid and s.t <= limit]
        candidates += [s for s in self.recent if s.t <= limit]
        newest = max(candidates, key=lambda s: s.t) if candidates else None
        learn_log = None
        safe, said = self.stale.check(
            self.expected_sample(T), None if newest is None else newest.t, self.steps == 0
        )
        if said is not None:
            self.out.append(Said("warning", f"ctrl-{self.sc} at t = {T:.0f} s: {said}", T))
        counters["safe_attitude_steps"] += safe
        if safe:
            sigma = list(SAFE_SIGMA)
        else:
            if newest is not None:  # else nothing measured yet (a delayed start): hold zero
                learn_log = ctrl.tick(T, newest.x, newest.v, newest.altitude)
            sigma = [0.0, 0.0, ctrl.u]
        if learn_log is not None:
            counters["learn_attempts"] = ctrl.learning.learn_attempts
            counters["fault_detections"] = ctrl.detections
            counters["relearning_abandoned"] = len(ctrl.learning.abandoned_at)
        counters["commands"] += 1
        self.steps += 1
        self.out.append(Step(self.steps, T, sigma, safe, learn_log, ctrl.exploring))

    def advance(
        self, may_step: Callable[[float], bool], final_t: float | None
    ) -> Iterator[Step | Said]:
        """Collect samples and run steps in time order, each as soon as it can be: a sample
        before the first step that could have had it, a step once ``may_step(T)`` (its clock
        and inputs accounted for).  ``final_t``: the final clock's time, if seen.  Yields what
        is flown and said, in order, as it is (the host publishes a step before the next)."""
        while True:
            yield from self.flush()
            first = min(self.ready, default=math.inf)
            knowable = min(self.next_tick - 1e-6, self.expected_sample(self.next_tick) + 1e-6)
            if first < knowable:
                self.collect(first)
            elif final_t is not None and self.next_tick > final_t + 1e-6:
                if first <= final_t + 1e-6:
                    self.collect(first)
                else:
                    break
            elif not math.isinf(self.next_tick) and may_step(self.next_tick):
                self.tick(self.next_tick)
                self.next_tick += self.fsw
            else:
                break
        yield from self.flush()

    def flush(self) -> list[Step | Said]:
        out, self.out = self.out, []
        return out

    def done(self, final_t: float | None) -> bool:
        """Every step up to the final clock has run, on the last sample it can have."""
        if final_t is None or self.next_tick <= final_t + 1e-6:
            return False
        return self.last is not None and self.last.t >= self.expected_sample(final_t) - 1e-6
