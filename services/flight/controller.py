"""Controller service, one per deputy: the flight software under test.  It flies the control
law of ``services.flight.control.Controller`` (modes, learning, change detection) on the bus.

Inputs:  nav/<deputy>/state (nav), exo/state (exo), clock.
Outputs: cmd/<deputy>/att (cmd) every flight-software step; ctrl/<deputy>/gains (gains), beaconed
         every step while learning and published whenever the gains change; ctrl/<deputy>/status
         (status); stats/ctrl-<deputy>.

Timing (``services.flight.control_loop``, the component the one-process executor flies too):
a flight-software step runs at each multiple of run.fsw_period of the clock, on the newest
valid navigation sample it has; with a link delay d on its inputs (the deployment's [[link]])
that is the sample measured at T - d, and the step waits until that sample is accounted for
(delivered, or lost by its link).  Samples and steps are taken in time order.
While its navigation service is away (liveliness token gone for a grace, until the token is
back) a step flies on the newest sample there is (``services.flight.step_gate``).  Restarted
into a running mission (``--join``) it flies from the first step it has a sample for; a learner
starts over (``LearningCycle.rejoin``) and says so in its log.
Health (docs/health.md): in lock-step a step whose sample does not come is said after
run.command_deadline and given up past run.hang_timeout (exit HANG_STATUS, naming nav-<deputy>);
in either mode a step whose newest sample is older than run.nav_stale_limit flies the safe
attitude (counted in safe_attitude_steps).  A flood on an input, dropped unread by the bus's
rate budget, counts as that step's sample lost.
"""

from __future__ import annotations

import sys
from typing import Any

from services.flight.control import Controller
from services.flight.control_loop import ControlLoop, Said, Step, input_delay
from services.flight.host import Listen, ServiceHost, Watch
from services.flight.inputs import LOST, OBSERVED, PRESENCE
from services.flight.runtime import ServiceContext, run_service
from services.flight.step_gate import StepGate
from services.interface import (
    CLOCK,
    EXOSTATE,
    command_topic,
    gains_topic,
    nav_state_topic,
    status_topic,
)
from services.model import IN_PLANE


def main(ctx: ServiceContext) -> int:
    ctrl = Controller(ctx.deployment, ctx.name.removeprefix("ctrl-"))
    return ServiceHost(ctx).react(ControllerService(ctx, ctrl))


class ControllerService:
    """The controller as a service (run by ``ServiceHost``): feeds its ``ControlLoop`` what
    the links deliver, lets a step fly once its clock and inputs are accounted for
    (``StepGate``), and publishes the commands, gains, status, log lines and counters.

    Parameters
    ----------
    ctx : the service's context (its bus, deployment, stop request).
    ctrl : the control law this service flies.
    """

    ready_at_start = True
    batched = False  # a command leaves as soon as its step has flown

    def __init__(self, ctx: ServiceContext, ctrl: Controller) -> None:
        self.ctx, self.ctrl = ctx, ctrl
        self.sc = sc = ctrl.sc
        run = ctx.deployment.run
        self.inputs = (
            Listen(nav_state_topic(sc), "nav", accounted=True),
            Listen(EXOSTATE, "exo", accounted=True),
            Listen(CLOCK, "clock"),
            Watch(f"nav-{sc}"),
        )
        self.status_every = run.status_every
        self.fsw = run.fsw_period
        self.loop = ControlLoop(ctrl, run, input_delay(ctx.deployment, sc), ctx.joining)
        self.gate = StepGate(run, sc, self.loop.expected_sample)
        self.counters = self.loop.counters

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
                "iteration": ctrl.learning.iteration,
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
                "rank": ctrl.learning.rank,
                "rank_needed": ctrl.learning.rank_needed,
                "counters": self.counters,
            },
            t,
        )

    # -- as the service host runs it (services.flight.host.Reactive) ---------------------------

    def poll(self) -> float:
        # while navigation is away, a step waits for its grace to run out, not for a message
        return 0.5 if self.gate.nav_gone is None else 0.1

    def start(self) -> None:
        if not self.ctx.joining:
            self.publish_gains(0.0)

    def settle(self, final_t: float | None) -> None:
        """Fly what the loop can (``ControlLoop.advance``), publish it, and in lock-step have
        the step whose clock has come but not its sample wait (``StepGate.check``)."""
        for item in self.loop.advance(self.gate.ready, final_t):
            if isinstance(item, Said):
                self.ctx.log(item.level, item.text, item.t)
                if item.gains:
                    self.publish_gains(item.t)
            else:
                self.publish_step(item)
        T = self.loop.next_tick
        self.gate.check(T, lambda said: self.ctx.log("warning", said, T))

    def done(self, final_t: float | None) -> bool:
        return self.loop.done(final_t)

    def finish(self) -> tuple[float, dict[str, int]]:
        t_end = self.loop.next_tick - self.fsw
        self.publish_gains(t_end)
        self.publish_status(t_end)
        return t_end, self.counters

    def take(self, kind: str, msg: Any) -> None:
        """One inbox entry (``services.flight.inputs``): navigation's presence, a sample
        accounted for by its link, a flood's drops, or a message: a clock, a sample."""
        if kind == PRESENCE:
            self.gate.presence(bool(msg[1]))
        elif kind == OBSERVED:
            self.gate.accounted("nav" if msg.schema == "nav" else "exo", msg.t)
        elif kind == LOST:  # flooded past its budget: the pending step's sample may be lost
            self.gate.flooded("exo" if msg == EXOSTATE else "nav", self.loop.next_tick)
        elif msg.schema == "clock":
            self.gate.clock(msg.t)
            self.ctx.bus.pump(msg.t)  # release what the links held until now
        elif msg.schema == "exo":
            self.loop.exo(msg.t, msg.body["v"])
        else:
            b = msg.body
            x, z = (b[k][list(IN_PLANE)] for k in ("x_hill", "z_hill"))
            self.loop.nav(msg.t, x, b["altitude"], z, bool(b["valid"]))

    def publish_step(self, step: Step) -> None:
        """A step's log line and gains if it learned, its command, the gains' beacon while
        learning, and the status and counters every run.status_every steps."""
        T = step.T
        if step.learn_log is not None:
            self.ctx.log("info", step.learn_log, T)
            self.publish_gains(T)
        self.ctx.bus.publish(
            command_topic(self.sc), "cmd", {"sc": self.sc, "sigma": step.sigma, "for_t": T}, T
        )
        if step.exploring:
            self.publish_gains(T)  # beaconed during learning
        if step.number % self.status_every == 0:
            self.publish_status(T)
            self.ctx.publish_stats(T, self.counters)


if __name__ == "__main__":
    sys.exit(run_service(main, "ctrl"))
