"""Environment service: the truth and the time master.

Inputs:  cmd/<deputy>/att (cmd) from each controller; fault/panel (fault: target = deputy,
         params.area_factor and/or params.normal_angle) from the ground; the deployment's
         scheduled [[fault]] panels.
Outputs: truth/<sc> (truth) for the chief and every deputy and exo/state (exo) at every
         navigation sample; clock (clock) at every flight-software step in lock-step (at every
         sample in real time); stats/environment.

Propagates every craft in one ODE (two-body + J2 + facet drag, ddvi_core.truth), one
flight-software step at a time, with each deputy's commanded relative MRP (clipped to its
attitude limit) held over the step.  Lock-step mode: after publishing the samples of step t_k it
waits until every controller's command for the step its link delay maps to is accounted for
(``services.flight.command_gate``: a silent controller pauses the mission, past
run.hang_timeout ends it with status 1 naming the controller; one that goes away is waited for
once and its deputy holds its last command; docs/health.md).
Real-time mode: paces the samples to
wall time times run.rate and never waits.
A pace (``ddvi run --rate R``, the ``--rate`` argument here) flies lock-step no faster than R
simulated seconds per wall second, for a person to watch: each step's samples leave once wall
time has caught up with their simulation time over R; nothing else changes, so the mission
flown is the one flown at full speed.
"""

from __future__ import annotations

import argparse
import contextlib
import functools
import queue
import sys
import time

import numpy as np

from services.bus import wait_for_alive
from services.config import Fault, check_fault
from services.flight.command_gate import PANEL, RECORDED_TAG, RECORDER_PRESENCE, CommandGate
from services.flight.environment_model import EnvironmentModel
from services.flight.host import Listen, ServiceHost, Watch
from services.flight.inputs import PRESENCE
from services.flight.recorder_lead import RECORDER, RecorderLead
from services.flight.runtime import ServiceContext, run_service
from services.interface import (
    CLOCK,
    EXOSTATE,
    RECORDED,
    ROS2_GATEWAY,
    Message,
    command_topic,
    truth_topic,
)
from services.model import ReentryError, Truth, duration, on_grid, open_truth


def main(ctx: ServiceContext, pace: float = 0.0) -> int:
    """Fly the mission (``pace``: lock-step's simulated seconds per wall second at most; 0 as
    fast as it goes)."""
    truth = open_truth(ctx.deployment)
    try:
        return ServiceHost(ctx).drive(EnvironmentService(ctx, truth, pace))
    finally:
        truth.close()


class EnvironmentService:
    """The environment as a service (driven by ``ServiceHost``): once every service is alive,
    propagates its ``EnvironmentModel`` one flight-software step at a time, with each deputy's
    command in force (its ``CommandGate``), and publishes truth, exostate and clock at every
    sample.

    Parameters
    ----------
    ctx : the service's context (its bus, deployment, stop request).
    truth : the truth model every craft is propagated with.
    pace : in lock-step, simulated seconds per wall second at most (0: as fast as it goes).
    """

    ready_at_start = True

    def __init__(self, ctx: ServiceContext, truth: Truth, pace: float = 0.0) -> None:
        self.ctx = ctx
        self.pace = pace if ctx.deployment.run.mode == "lockstep" else 0.0
        dep = self.dep = ctx.deployment
        self.run_cfg = run = dep.run
        # every command that reaches this service is also observed after its link has
        # delivered, held or dropped it: the lock-step wait ends when the command it waits for
        # is accounted for
        self.inputs = (
            Listen(command_topic("*"), "cmd", accounted=True),  # every deputy's
            Listen(PANEL, "fault"),
            Listen(RECORDED, "recorded", tag=RECORDED_TAG),
            Watch("ctrl-*", PRESENCE),
            Watch(RECORDER, RECORDER_PRESENCE),
        )
        if any(dep.commander(d.name) == ROS2_GATEWAY for d in dep.deputy):
            self.inputs += (Watch(ROS2_GATEWAY, PRESENCE),)  # it commands them
        self.model = EnvironmentModel(dep, truth)
        self.names = self.model.names
        self.dt, self.fsw, self.t_end = run.nav_period, run.fsw_period, duration(dep)
        self.counters = self.model.counters
        self.counters.update(
            controller_away_steps=0,
            paused_steps=0,
            recorder_waits=0,
        )
        self.wall0 = time.monotonic()
        self.step = 0  # samples published so far (the clock's step)
        self.t_k = 0.0  # the step being flown
        self.completed = False

    def fly(self, inbox: queue.SimpleQueue) -> int:
        """Once every service is alive, fly the mission with the controllers and the recorder
        that are there (their liveliness watched from then on); returns 0 if the mission
        completed, 1 if a service never came, 3 if it ended early."""
        dep, run = self.dep, self.run_cfg
        others = [s for s in dep.services if s != self.ctx.name]
        alive = wait_for_alive(self.ctx.bus.session, self.ctx.run, others, run.startup_timeout)
        if set(others) - alive:
            missing = sorted(set(others) - alive)
            self.ctx.log("error", f"services not alive after {run.startup_timeout} s: {missing}")
            return 1
        present = {d.name for d in dep.deputy if dep.commander(d.name) in alive}  # waited for
        recorder = RecorderLead(run.fsw_period, present=RECORDER in alive)
        self.commands = CommandGate(
            self.ctx, self.model.commands, inbox, present, self.counters, self.on_fault, recorder
        )
        self.wall0 = time.monotonic()
        return self.run()

    def finish(self) -> tuple[float, dict[str, int]]:
        return self.t_k, {**self.counters, "completed": int(self.completed)}

    # -- the step loop ------------------------------------------------------------------------

    def run(self) -> int:
        """Propagate to the end of the mission (or a stop request, or a re-entry); returns 0
        if the mission completed, 3 if not, HANG_STATUS if lock-step hung on a service."""
        run, model, counters = self.run_cfg, self.model, self.counters
        state = model.truth.state
        self.publish_sample(0.0, state, model.attitudes(state[None])[0], final=self.t_end <= 0)
        t_k = 0.0
        while t_k < self.t_end - 1e-6 and not self.ctx.stop.is_set():
            self.commands.take(t_k, wait=run.mode == "lockstep")  # HangError: the host gives up
            t_next = t_k + self.fsw
            try:
                samples, traj, said = model.step(t_k)
            except ReentryError as exc:
                self.ctx.log("error", f"mission ended early: {exc}", t_k)
                # tell every service the run is over at the last published sample
                self.publish_clock(t_k, fsw_step=True, final=True)
                break
            for level, text in said:
                self.ctx.log(level, text, t_k)
            sigma_BN = model.attitudes(traj)
            self.keep_pace(t_next)
            # lock-step: the step's samples leave together, one zenoh sample per topic (each
            # message keeps its own seq and time); real time paces them one by one
            with self.ctx.bus.batch() if run.mode == "lockstep" else contextlib.nullcontext():
                for k, t in enumerate(samples):
                    self.step += 1
                    final = abs(t - self.t_end) < 1e-6
                    self.publish_sample(float(t), traj[k], sigma_BN[k], final=final)
            t_k = self.t_k = t_next
            if counters["steps"] % run.status_every == 0:
                self.ctx.publish_stats(t_k, counters)
        self.completed = t_k >= self.t_end - 1e-6
        return 0 if self.completed else 3

    def keep_pace(self, t: float) -> None:
        """With a pace, wait until wall time has caught up with simulation time ``t`` (a stop
        request ends the wait); a mission slower than its pace never waits."""
        if self.pace > 0:
            delay = self.wall0 + t / self.pace - time.monotonic()
            if delay > 0:
                self.ctx.stop.wait(delay)

    # -- publishing ---------------------------------------------------------------------------

    def publish_sample(self, t: float, X: np.ndarray, sigma_BN: np.ndarray, final: bool) -> None:
        """Truth of every craft (X (1 + N, 6), sigma_BN (1 + N, 3)) and the exostate at t, and
        the clock on flight-software boundaries (every sample in real time)."""
        run, bus = self.run_cfg, self.ctx.bus
        if run.mode == "realtime":
            delay = self.wall0 + t / run.rate - time.monotonic()
            if delay > 0:
                time.sleep(delay)
        for i, sc in enumerate(self.names):
            body = {"sc": sc, "r_N": X[i, :3], "v_N": X[i, 3:], "sigma_BN": sigma_BN[i]}
            bus.publish(truth_topic(sc), "truth", body, t)
        v, phase = self.model.exostate(t)
        bus.publish(EXOSTATE, "exo", {"v": v, "phase": phase}, t)
        fsw_step = on_grid(t, self.fsw)
        # lock-step services step on flight-software boundaries: a clock between them would
        # only cost every subscriber a message; real time keeps one a sample (its wall-clock
        # links are released at clock messages)
        if fsw_step or final or run.mode == "realtime":
            self.publish_clock(t, fsw_step, final)

    def publish_clock(self, t: float, fsw_step: bool, final: bool) -> None:
        body = {
            "step": self.step,
            "dt": self.dt,
            "fsw": fsw_step,
            "mode": self.run_cfg.mode,
            "final": final,
        }
        self.ctx.bus.publish(CLOCK, "clock", body, t)

    # -- panel faults from the ground ---------------------------------------------------------

    def on_fault(self, msg: Message) -> None:
        """``fault/panel`` from the ground: checked now, as a [[fault]] of the deployment
        (``check_fault``), and applied at the next step."""
        sc, params = msg.body["target"], msg.body["params"]
        factor, angle = params.get("area_factor"), params.get("normal_angle")
        try:
            fault = Fault(kind="panel", deputy=sc, area_factor=factor, normal_angle=angle)
            check_fault(self.ctx.deployment, "panel", fault)
        except ValueError as exc:
            self.counters["bad_faults"] += 1
            self.ctx.log("warning", f"fault panel {sc}: refused ({exc}; got {msg.body})", msg.t)
            return
        factor, angle = (None if a is None else float(a) for a in (factor, angle))
        self.model.panel_from_ground((sc, factor, angle), msg.src)


if __name__ == "__main__":
    # --rate R is the environment's own argument (ddvi run --rate); the rest are every service's
    options = argparse.ArgumentParser(add_help=False)
    options.add_argument("--rate", type=float, default=0.0)
    known, rest = options.parse_known_args()
    sys.exit(run_service(functools.partial(main, pace=known.rate), "environment", rest))
