"""Controller service, one per deputy: the flight software under test.  It flies the control
law of ``services.flight.control.Controller`` (modes, learning, change detection) on the bus.

Inputs:  nav/<deputy>/state (nav), exo/state (exo), clock.
Outputs: cmd/<deputy>/att (cmd) every flight-software step; ctrl/<deputy>/gains (gains), beaconed
         every step while learning and published whenever the gains change; ctrl/<deputy>/status
         (status); stats/ctrl-<deputy>.

Timing: a flight-software step runs at each multiple of run.fsw_period of the clock, on the
newest navigation sample it has; with a link delay d on its inputs (the deployment's [[link]])
that is the sample measured at T - d, and the step waits until that sample is accounted for
(delivered, or lost by its link).  Samples and steps are taken in time order, a step before the
sample measured at its own time: with no delay this is exactly ``Controller.on_sample``.
While its navigation service is away (liveliness token gone for a grace, until the token is
back) a step flies on the newest sample there is (``services.flight.step_gate``).  Restarted
into a running mission (``--join``) it flies from the first step it has a sample for; a learner
starts over (``Controller.rejoin``) and says so in its log.
Health (docs/health.md): in lock-step a step whose sample does not come is said after
run.command_deadline and given up past run.hang_timeout (exit HANG_STATUS, naming nav-<deputy>);
in either mode a step whose newest sample is older than run.nav_stale_limit flies the safe
attitude (counted in safe_attitude_steps).  A flood on an input, dropped unread by the bus's
rate budget, counts as that step's sample lost.
"""

from __future__ import annotations

import collections
import math
import queue
import sys
from typing import Any

import numpy as np

from services.bus import queue_handler, watch_alive
from services.flight.control import Controller
from services.flight.health import SAFE_SIGMA, HangError
from services.flight.runtime import ServiceContext, run_service
from services.flight.step_gate import StepGate
from services.flight.streams import FinalClock, SamplePairs
from services.interface import (
    CLOCK,
    EXOSTATE,
    Message,
    command_topic,
    gains_topic,
    nav_state_topic,
    status_topic,
)
from services.model import IN_PLANE

_SEEN = "seen"  # inbox tag: a nav or exo message accounted for by its link (see Bus.subscribe)
_PRESENCE = "presence"  # inbox tag: the navigation service came or went
_LOST = "lost"  # inbox tag: the bus's rate budget dropped nav or exo messages unread (a flood)

Sample = tuple[float, np.ndarray, np.ndarray, float, np.ndarray]
"""A navigation sample paired with its exostate: (t (s), the estimate x (4,), v (q,),
altitude (m), the measurement z (4,))."""


def main(ctx: ServiceContext) -> int:
    sc = ctx.name.removeprefix("ctrl-")
    ctrl = Controller(ctx.deployment, sc)
    inbox: queue.SimpleQueue = queue.SimpleQueue()

    def seen(_topic: str, msg: Message) -> None:
        inbox.put((_SEEN, msg))

    def lost(topic: str) -> None:
        inbox.put((_LOST, topic))

    ctx.bus.subscribe(
        nav_state_topic(sc), queue_handler(inbox), expected_schema="nav", observe=seen, lost=lost
    )
    ctx.bus.subscribe(
        EXOSTATE, queue_handler(inbox), expected_schema="exo", observe=seen, lost=lost
    )
    ctx.bus.subscribe(CLOCK, queue_handler(inbox), expected_schema="clock")
    presence = watch_alive(
        ctx.bus.session, ctx.run, f"nav-{sc}", lambda _name, up: inbox.put((_PRESENCE, up))
    )
    try:
        ctx.ready()
        return ControllerService(ctx, ctrl, inbox).run()
    finally:
        presence.undeclare()


class ControllerService:
    """The controller's main loop: pairs each navigation sample with its exostate, runs the
    flight-software steps and collects the samples in time order, and publishes the commands,
    gains, status and counters.

    Parameters
    ----------
    ctx : the service's context (its bus, deployment, stop request).
    ctrl : the control law this service flies.
    inbox : where the subscriptions put ``(topic or tag, message)``.
    """

    def __init__(self, ctx: ServiceContext, ctrl: Controller, inbox: queue.SimpleQueue) -> None:
        self.ctx, self.ctrl, self.inbox = ctx, ctrl, inbox
        self.sc = sc = ctrl.sc
        run = ctx.deployment.run
        self.status_every = run.status_every
        self.fsw, nav_period = run.fsw_period, ctrl.deputy.navigation.period
        # A sample measured at t reaches this controller at t + delay (its links' nominal
        # delay): the flight-software step at T flies on the newest sample measured by T - delay.
        delay = max(
            ctx.bus.latency(f"nav-{sc}", nav_state_topic(sc)),
            ctx.bus.latency("environment", EXOSTATE),
        )
        self.gate = StepGate(run, sc, nav_period, delay)
        self.pairs = SamplePairs(("nav", "exo"))  # nav: (x, altitude, z); exo: v
        # samples not yet collected: t -> (x, v, altitude, z), as Sample without its t
        self.ready: dict[float, tuple[np.ndarray, np.ndarray, float, np.ndarray]] = {}
        self.last: Sample | None = None  # newest collected sample
        # collected samples a step may still fly on (up to its delay behind it)
        self.recent: collections.deque[Sample] = collections.deque(
            maxlen=math.ceil(delay / nav_period) + 8
        )
        self.counters = {
            "commands": 0,
            "samples_rejected": 0,
            "learn_attempts": 0,
            "fault_detections": 0,
            "relearning_abandoned": 0,
            "safe_attitude_steps": 0,
        }
        self.steps = 0
        # a restarted controller flies from the first step it has a sample for (on_sample)
        self.next_tick = math.inf if ctx.joining else 0.0
        self.final = FinalClock()

    # -- publishing ---------------------------------------------------------------------------

    def publish_gains(self, t: float) -> None:
        ctrl = self.ctrl
        self.ctx.bus.publish(
            gains_topic(self.sc),
            "gains",
            {
                "sc": self.sc,
                "K": ctrl.K,
                "L": ctrl.L,
                "source": ctrl.source,
                "iteration": ctrl.iteration,
                "converged": ctrl.converged,
            },
            t,
        )

    def publish_status(self, t: float) -> None:
        ctrl = self.ctrl
        c = ctrl.collector if ctrl.mode == "ddvi" else None
        self.ctx.bus.publish(
            status_topic(self.sc),
            "status",
            {
                "sc": self.sc,
                "mode": ctrl.mode,
                "phase": ctrl.phase,
                "samples": c.samples if c else 0,
                "intervals": c.intervals if c else 0,
                "rank": ctrl.rank,
                "rank_needed": ctrl.rank_needed,
                "counters": self.counters,
            },
            t,
        )

    # -- the main loop ------------------------------------------------------------------------

    def run(self) -> int:
        """Take messages until the mission is over or a stop is requested; returns 0, or
        HANG_STATUS when lock-step hung on this controller's inputs (``HangError``)."""
        if not self.ctx.joining:
            self.publish_gains(0.0)
        status = 0
        try:
            while not self.ctx.stop.is_set():
                try:
                    kind, msg = self.inbox.get(timeout=0.5 if self.gate.nav_gone is None else 0.1)
                except queue.Empty:
                    if self.final.grace_over():
                        break  # the last samples were lost on their links
                    self.advance()  # a step may wait for navigation's grace to run out
                    self.check_waiting()
                    if self.done():
                        break
                    continue
                self.take(kind, msg)
                if self.inbox.empty():  # what pump() just released is queued: take it in first
                    self.advance()
                    self.check_waiting()
                if self.done():
                    break
        except HangError as exc:
            status = self.ctx.give_up(exc)
        t_end = self.next_tick - self.fsw
        self.publish_gains(t_end)
        self.publish_status(t_end)
        self.ctx.publish_stats(t_end, self.counters)
        return status

    def check_waiting(self) -> None:
        """Lock-step: the step whose clock has come but not its sample waits (StepGate.check)."""
        self.gate.check(self.next_tick, lambda said: self.ctx.log("warning", said, self.next_tick))

    def take(self, kind: str, msg: Any) -> None:
        """One inbox entry: navigation's presence (``msg``: up or not), or a message: a sample
        accounted for by its link, a clock, a sample."""
        if kind == _PRESENCE:
            self.gate.presence(bool(msg))
        elif kind == _SEEN:
            self.gate.accounted("nav" if msg.schema == "nav" else "exo", msg.t)
        elif kind == _LOST:  # flooded past its budget: the pending step's sample may be lost
            self.gate.flooded("exo" if msg == EXOSTATE else "nav", self.next_tick)
        elif msg.schema == "clock":
            self.gate.clock(msg.t)
            self.ctx.bus.pump(msg.t)  # release what the links held until now
            self.final.on_clock(msg)
        else:
            self.on_sample(msg)

    def on_sample(self, msg: Message) -> None:
        """A nav or exo message: pair it by time; a complete sample newer than the last one
        collected is ready for ``advance``."""
        if msg.schema == "exo":
            pair = self.pairs.add(msg.t, "exo", msg.body["v"])
        else:
            x, z = (msg.body[k][list(IN_PLANE)] for k in ("x_hill", "z_hill"))
            pair = self.pairs.add(msg.t, "nav", (x, msg.body["altitude"], z))
        last_t = None if self.last is None else self.last[0]
        if pair is not None:
            (x, altitude, z), v = pair["nav"], pair["exo"]
            if last_t is not None and msg.t <= last_t:
                self.counters["samples_rejected"] += 1  # stale or replayed
            else:
                self.ready[msg.t] = (x, v, altitude, z)
        if last_t is not None:
            # exostates and samples that nothing will pair any more (their partner was lost
            # on a link, or they repeat collected ones); a lone sample is counted as rejected
            stale = self.pairs.forget_before(last_t)
            self.counters["samples_rejected"] += sum("nav" in s for s in stale)
        if self.next_tick == math.inf and self.ready:  # restarted: the first step it can fly
            first = min(self.ready) + self.gate.delay
            self.next_tick = math.ceil(first / self.fsw - 1e-9) * self.fsw
            self.ctx.log("warning", self.ctrl.rejoin(self.next_tick), self.next_tick)
            self.publish_gains(self.next_tick)

    # -- steps and samples, in time order -----------------------------------------------------

    def tick(self, T: float) -> None:
        """The flight-software step at T: the command, and any learning it brings."""
        ctrl, counters = self.ctrl, self.counters
        # the newest sample measured by T - delay: a sample a later clock's pump released
        # early (the environment runs ahead of a delayed loop) must not shorten the delay
        limit = self.gate.expected_sample(T) + 1e-6
        candidates = [(t, *self.ready[t]) for t in self.ready if t <= limit]
        candidates += [s for s in self.recent if s[0] <= limit]
        newest = max(candidates, key=lambda s: s[0]) if candidates else None
        learn_log = None
        if self.fly_safe(T, newest):
            sigma = list(SAFE_SIGMA)
        else:
            if newest is not None:  # else nothing measured yet (a delayed start): hold zero
                _, x, v, altitude, _ = newest
                learn_log = ctrl.tick(T, x, v, altitude)
            sigma = [0.0, 0.0, ctrl.u]
        if learn_log is not None:
            counters["learn_attempts"] = ctrl.learn_attempts
            counters["fault_detections"] = ctrl.detections
            counters["relearning_abandoned"] = len(ctrl.abandoned_at)
            self.ctx.log("info", learn_log, T)
            self.publish_gains(T)
        self.ctx.bus.publish(
            command_topic(self.sc),
            "cmd",
            {"sc": self.sc, "sigma": sigma, "for_t": T},
            T,
        )
        counters["commands"] += 1
        self.steps += 1
        if ctrl.exploring:
            self.publish_gains(T)  # beaconed during learning
        if self.steps % self.status_every == 0:
            self.publish_status(T)
            self.ctx.publish_stats(T, counters)

    def fly_safe(self, T: float, newest: Sample | None) -> bool:
        """Whether the step at T flies the safe attitude (StepGate.stale: its navigation too
        old); said on the way in and out, counted in safe_attitude_steps."""
        newest_t = newest[0] if newest is not None else None
        safe, said = self.gate.stale(T, newest_t, first=self.steps == 0)
        if said is not None:
            self.ctx.log("warning", f"ctrl-{self.sc} at t = {T:.0f} s: {said}", T)
        self.counters["safe_attitude_steps"] += safe
        return safe

    def collect(self, t: float) -> None:
        x, v, altitude, z = self.ready.pop(t)
        rejected = self.ctrl.collect(t, x, v, altitude, z)
        if rejected is not None:
            self.counters["samples_rejected"] += 1
            self.ctx.log("warning", rejected, t)
        self.last = (t, x, v, altitude, z)
        self.recent.append(self.last)

    def advance(self) -> None:
        """Collect samples and run flight-software steps in time order (a step before the
        sample measured at its own time), each as soon as it can be."""
        final_t = self.final.t
        while True:
            first = min(self.ready, default=math.inf)
            if first < self.next_tick - 1e-6:
                self.collect(first)
            elif final_t is not None and self.next_tick > final_t + 1e-6:
                if first <= final_t + 1e-6:
                    self.collect(first)
                else:
                    return
            elif self.gate.ready(self.next_tick):
                self.tick(self.next_tick)
                self.next_tick += self.fsw
            else:
                return

    def done(self) -> bool:
        """Every step up to the final clock has run, on the last sample it can have."""
        final_t = self.final.t
        if final_t is None or self.next_tick <= final_t + 1e-6:
            return False
        return self.last is not None and self.last[0] >= self.gate.expected_sample(final_t) - 1e-6


if __name__ == "__main__":
    sys.exit(run_service(main, "ctrl"))
