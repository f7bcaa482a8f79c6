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
waits until every controller's command for the step its link delay maps to (issued at T, it
arrives at T + delay, so the newest that can act from t_k is for floor((t_k - delay) / fsw)
steps) is accounted for (delivered, or dropped by its link).  Simulated time never moves past a
controller that is there (its liveliness token alive) but silent: the mission pauses (said after
run.command_deadline wall seconds, counted in paused_steps) and, past run.hang_timeout, ends
with status 1 naming the controller (docs/health.md).  A controller that goes away (its token
gone: crashed, restarting) is not waited for step by step: lock-step pauses once, up to
run.command_deadline wall seconds, for it to come back (a restart takes a few), and from its
return it is waited for again from the next step; while it is away its deputy holds its last
command (counted in controller_away_steps, and missing commands in missing_commands).
Real-time mode: paces the samples to
wall time times run.rate and never waits.
"""

from __future__ import annotations

import contextlib
import math
import queue
import sys
import time

import numpy as np

from ddvi_core.orbit import dcm_to_mrp, hill_frame, mrp_to_dcm
from services.bus import queue_handler, wait_for_alive, watch_alive
from services.config import check_panel
from services.flight.health import HANG_STATUS, HangError, Waiting
from services.flight.runtime import ServiceContext, run_service
from services.flight.streams import FaultQueue
from services.interface import CLOCK, EXOSTATE, Message, command_topic, fault_topic, truth_topic
from services.model import (
    ReentryError,
    Truth,
    describe_panel,
    duration,
    exostate,
    on_grid,
    open_truth,
    panel_schedule,
)

_OBSERVED = "observed"  # inbox tag of a command seen by the link layer (see subscribe)
_PRESENCE = "presence"  # inbox tag of a controller's liveliness change
_LOST = "lost"  # inbox tag: the bus's rate budget dropped commands unread (a flood)
_PANEL = fault_topic("panel")  # topic of run-time panel faults


def main(ctx: ServiceContext) -> int:
    truth = open_truth(ctx.deployment)
    try:
        return _serve(ctx, truth)
    finally:
        truth.close()


def _serve(ctx: ServiceContext, truth: Truth) -> int:
    dep = ctx.deployment
    run = dep.run
    deputies = [d.name for d in dep.deputy]
    inbox: queue.SimpleQueue = queue.SimpleQueue()
    # every command that reaches this service is also observed after its link has delivered,
    # held or dropped it: the lock-step wait ends when the command it waits for is accounted for
    ctx.bus.subscribe(
        command_topic("*"),  # every deputy's
        queue_handler(inbox),
        expected_schema="cmd",
        observe=lambda _topic, msg: inbox.put((_OBSERVED, msg)),
        lost=lambda topic: inbox.put((_LOST, topic)),
    )
    ctx.bus.subscribe(_PANEL, queue_handler(inbox), expected_schema="fault")
    ctx.ready()
    others = [s for s in dep.services if s != ctx.name]
    alive = wait_for_alive(ctx.bus.session, ctx.run, others, run.startup_timeout)
    if set(others) - alive:
        ctx.log(
            "error",
            f"services not alive after {run.startup_timeout} s: {sorted(set(others) - alive)}",
        )
        return 1

    present = {sc for sc in deputies if f"ctrl-{sc}" in alive}  # controllers to wait for

    def on_presence(service: str, up: bool) -> None:
        inbox.put((_PRESENCE, (service.removeprefix("ctrl-"), up)))

    presence = watch_alive(ctx.bus.session, ctx.run, "ctrl-*", on_presence)
    try:
        return EnvironmentService(ctx, truth, inbox, present).run()
    finally:
        presence.undeclare()


STOP_POLL = 0.25
"""Wall seconds the command wait blocks before it looks at a stop request again."""
HANG_MARGIN = 5.0
"""Wall seconds the environment waits for a controller past run.hang_timeout: a controller
waiting on its own navigation gives up first and names it (``services.flight.controller``)."""


class EnvironmentService:
    """Propagates the truth one flight-software step at a time, with each deputy's command in
    force, and publishes truth, exostate and clock at every sample.

    Parameters
    ----------
    ctx : the service's context (its bus, deployment, stop request).
    truth : the truth model every craft is propagated with.
    inbox : where the subscriptions put ``(topic or tag, message)``: commands, commands
        observed by the link layer, panel faults, controllers' presence.
    present : the deputies whose controller is alive (waited for in lock-step).
    """

    def __init__(
        self, ctx: ServiceContext, truth: Truth, inbox: queue.SimpleQueue, present: set[str]
    ) -> None:
        self.ctx, self.truth, self.inbox, self.present = ctx, truth, inbox, present
        dep = self.dep = ctx.deployment
        self.run_cfg = run = dep.run
        self.deputies = [d.name for d in dep.deputy]
        self.names = ["chief", *self.deputies]
        self.limits = np.array([d.attitude_limit for d in dep.deputy])
        self.dt, self.fsw, self.t_end = run.nav_period, run.fsw_period, duration(dep)
        self.counters = {
            "steps": 0,
            "late_commands": 0,
            "missing_commands": 0,
            "stale_commands": 0,
            "clipped_commands": 0,
            "bad_commands": 0,
            "controller_away_steps": 0,
            "paused_steps": 0,
            "panel_faults": 0,
            "bad_faults": 0,
        }
        # panel faults: (deputy, area factor, normal angle), the deployment's at their times
        self.panel_faults: FaultQueue[tuple[str, float | None, float | None]] = FaultQueue(
            [(t, (sc, factor, angle)) for t, sc, factor, angle in panel_schedule(dep)]
        )
        self.away_since: dict[str, float] = {}  # wall time each away controller went
        self.returned_at: dict[str, float] = {}  # step at which each came back
        self.sigma = np.zeros((len(self.deputies), 3))  # commands in force
        self.latest_for_t = dict.fromkeys(self.deputies, -math.inf)  # step of the one in force
        self.seen_for_t = dict.fromkeys(self.deputies, -math.inf)  # newest accounted for
        # a command issued at T reaches the truth at T + the link's delay (docs/design.md,
        # "Time")
        self.cmd_delay = {
            sc: ctx.bus.latency(f"ctrl-{sc}", command_topic(sc)) for sc in self.deputies
        }
        self.wall0 = time.monotonic()
        self.step = 0  # samples published so far (the clock's step)

    # -- the step loop ------------------------------------------------------------------------

    def run(self) -> int:
        """Propagate to the end of the mission (or a stop request, or a re-entry); returns 0
        if the mission completed, 3 if not, HANG_STATUS if lock-step hung on a service."""
        run, truth, counters = self.run_cfg, self.truth, self.counters
        state = truth.state
        self.publish_sample(0.0, state, self.attitudes(state[None])[0], final=self.t_end <= 0)
        t_k = 0.0
        while t_k < self.t_end - 1e-6 and not self.ctx.stop.is_set():
            try:
                self.take_commands(t_k, wait=run.mode == "lockstep")
            except HangError as exc:
                self.ctx.log("error", str(exc), t_k)
                self.ctx.publish_stats(t_k, {**counters, "completed": 0})
                return HANG_STATUS
            self.apply_panel_faults(t_k)
            t_next = t_k + self.fsw
            try:
                samples, traj = truth.step(t_k, self.sigma)
            except ReentryError as exc:
                self.ctx.log("error", f"mission ended early: {exc}", t_k)
                # tell every service the run is over at the last published sample
                self.publish_clock(t_k, fsw_step=True, final=True)
                break
            sigma_BN = self.attitudes(traj)
            # lock-step: the step's samples leave together, one zenoh sample per topic (each
            # message keeps its own seq and time); real time paces them one by one
            with self.ctx.bus.batch() if run.mode == "lockstep" else contextlib.nullcontext():
                for k, t in enumerate(samples):
                    self.step += 1
                    final = abs(t - self.t_end) < 1e-6
                    self.publish_sample(float(t), traj[k], sigma_BN[k], final=final)
            t_k = t_next
            counters["steps"] += 1
            if counters["steps"] % run.status_every == 0:
                self.ctx.publish_stats(t_k, counters)
        completed = t_k >= self.t_end - 1e-6
        self.ctx.publish_stats(t_k, {**counters, "completed": int(completed)})
        return 0 if completed else 3

    # -- publishing ---------------------------------------------------------------------------

    def attitudes(self, traj: np.ndarray) -> np.ndarray:
        """sigma_BN (K, 1 + N, 3) of states (K, 1 + N, 6): the chief Hill-pointing, each
        deputy Hill-pointing composed with its command in force (one batched call a step)."""
        k, n = traj.shape[0], len(self.names)
        HN = hill_frame(traj[..., :3].reshape(-1, 3), traj[..., 3:].reshape(-1, 3))
        HN = HN.reshape(k, n, 3, 3)
        BN = HN.copy()
        BN[:, 1:] = mrp_to_dcm(self.sigma) @ HN[:, 1:] if len(self.deputies) else HN[:, 1:]
        return dcm_to_mrp(BN.reshape(-1, 3, 3)).reshape(k, n, 3)

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
        v, phase = exostate(self.dep, t)
        bus.publish(EXOSTATE, "exo", {"v": v, "phase": phase}, t)
        fsw_step = on_grid(t, self.fsw)
        # lock-step services step on flight-software boundaries: a clock between them would
        # only cost every subscriber a message; real time keeps one a sample (its wall-clock
        # links are released at clock messages)
        if fsw_step or final or run.mode == "realtime":
            self.publish_clock(t, fsw_step, final)

    def publish_clock(self, t: float, fsw_step: bool, final: bool) -> None:
        body = {"step": self.step, "dt": self.dt, "fsw": fsw_step, "mode": self.run_cfg.mode,
                "final": final}  # fmt: skip
        self.ctx.bus.publish(CLOCK, "clock", body, t)

    # -- commands and faults -----------------------------------------------------------------

    def expected_step(self, sc: str, t_k: float) -> float:
        """The newest command step that can be in force from t_k on (negative: none yet)."""
        return math.floor((t_k - self.cmd_delay[sc]) / self.fsw + 1e-9) * self.fsw

    def take_commands(self, t_k: float, wait: bool) -> None:
        """Apply the newest command of each deputy that its link has delivered by t_k; in
        lock-step wait until the one for the step its delay maps to is accounted for: the
        mission pauses for a controller that is there but silent (said after
        run.command_deadline), up to the hang timeout (``HangError``)."""
        self.ctx.bus.pump(t_k)  # release what the links held until t_k
        deputies, counters = self.deputies, self.counters
        expected = {sc: self.expected_step(sc, t_k) for sc in deputies}
        waiting = Waiting(self.run_cfg.command_deadline, self.run_cfg.hang_timeout + HANG_MARGIN)
        while not self.ctx.stop.is_set():
            late = [sc for sc in deputies if self.outstanding(sc, t_k, expected[sc])]
            if wait and late and waiting.said_at(time.monotonic()):
                counters["paused_steps"] += 1
                names = ", ".join(f"ctrl-{sc}" for sc in late)
                self.ctx.log("warning", f"lock-step paused at t = {t_k:.0f} s: no command from "
                             f"{names} for {waiting.said:g} s", t_k)  # fmt: skip
            if wait and late and waiting.over(time.monotonic()):
                raise HangError(f"ctrl-{late[0]}", "command", t_k, self.run_cfg.hang_timeout)
            waits = [waiting.until] if late else []
            waits += [u for sc in deputies if (u := self.returning(sc)) is not None]
            try:
                if wait and waits:
                    # in slices, so a stop request (the launcher gone, and with it the
                    # router that would have said the controllers left) ends the wait
                    timeout = min(max(min(waits) - time.monotonic(), 0.0), STOP_POLL)
                    kind, msg = self.inbox.get(timeout=timeout)
                else:
                    kind, msg = self.inbox.get_nowait()
            except queue.Empty:
                if wait and waits and min(waits) > time.monotonic():
                    continue
                if wait and late:
                    continue  # the hang timeout decides
                break
            if kind == _PANEL:
                self.on_fault(msg)
            elif kind == _PRESENCE:
                self.on_presence(*msg, t_k)
            elif kind == _LOST:
                self.on_lost(msg, expected)
            else:
                self.on_command(kind, msg, expected)
        if wait:
            counters["missing_commands"] += sum(
                expected[sc] >= 0 and self.latest_for_t[sc] < expected[sc] - 1e-6 for sc in deputies
            )
        counters["controller_away_steps"] += len(set(deputies) - self.present)

    def outstanding(self, sc: str, t_k: float, expected: float) -> bool:
        """The step at t_k waits for the command of ``sc`` for step ``expected``."""
        due = expected - 1e-6
        return (
            sc in self.present
            and self.returned_at.get(sc, -math.inf) < t_k  # back since before this step
            and expected >= 0
            and self.latest_for_t[sc] < due
            and self.seen_for_t[sc] < due
        )

    def returning(self, sc: str) -> float | None:
        """Wall time until which to wait for an away controller to come back."""
        if sc in self.present or sc not in self.away_since:
            return None
        until = self.away_since[sc] + self.run_cfg.command_deadline
        return until if until > time.monotonic() else None

    def on_command(self, kind: str, msg: Message, expected: dict[str, float]) -> None:
        """A command delivered (put in force unless a replay), or observed by its link."""
        counters = self.counters
        sc = msg.body["sc"]
        if sc not in self.latest_for_t:
            counters["bad_commands"] += kind != _OBSERVED
            return
        for_t = msg.body["for_t"]
        if kind == _OBSERVED:
            self.seen_for_t[sc] = max(self.seen_for_t[sc], for_t)
            return
        if for_t <= self.latest_for_t[sc]:
            counters["stale_commands"] += 1  # not newer than the one in force: a replay
            return
        if for_t < expected[sc] - 1e-6:
            counters["late_commands"] += 1
        i = self.deputies.index(sc)
        s_cmd = msg.body["sigma"]
        clipped = np.clip(s_cmd, -self.limits[i], self.limits[i])
        counters["clipped_commands"] += int(np.any(clipped != s_cmd))
        self.sigma[i] = clipped
        self.latest_for_t[sc] = for_t

    def on_lost(self, topic: str, expected: dict[str, float]) -> None:
        """Its publisher flooded ``topic`` past its rate budget: the command the step waits
        for may be among what was dropped unread, so it is taken as lost, as on its link (the
        deputy holds its last command; counted missing)."""
        sc = topic.removeprefix("cmd/").removesuffix("/att")
        if sc in self.seen_for_t:
            self.seen_for_t[sc] = max(self.seen_for_t[sc], expected[sc])

    def on_presence(self, sc: str, up: bool, t_k: float) -> None:
        """A controller's liveliness token came or went during the step at t_k."""
        if sc in self.latest_for_t and up and sc not in self.present:
            self.present.add(sc)
            self.returned_at[sc] = t_k
            self.ctx.log("warning", f"controller of {sc} is back at t = {t_k:.0f} s", t_k)
        elif sc in self.latest_for_t and not up and sc in self.present:
            self.present.discard(sc)
            self.away_since[sc] = time.monotonic()
            self.ctx.log("warning", f"controller of {sc} went away at t = {t_k:.0f} s; "
                         "holding its last command", t_k)  # fmt: skip

    def on_fault(self, msg: Message) -> None:
        """``fault/panel`` from the ground: checked now, applied at the next step."""
        sc, params = msg.body["target"], msg.body["params"]
        factor, angle = params.get("area_factor"), params.get("normal_angle")
        try:
            if sc not in self.deputies:
                raise ValueError(f"{sc!r} is not a deputy of this run")
            check_panel(factor, angle)
        except ValueError as exc:
            self.counters["bad_faults"] += 1
            self.ctx.log("warning", f"fault panel {sc}: refused ({exc}; got {msg.body})", msg.t)
            return
        factor, angle = (None if a is None else float(a) for a in (factor, angle))
        self.panel_faults.from_ground((sc, factor, angle), msg.src)

    def apply_panel_faults(self, t_k: float) -> None:
        """Set the panels of the faults due at t_k, in time order (the ground's first)."""
        for fault in sorted(self.panel_faults.pop_due(t_k), key=lambda f: f.t):
            sc, factor, angle = fault.value
            try:
                self.truth.set_panel(self.deputies.index(sc), factor, angle)
            except (ValueError, RuntimeError) as exc:
                self.counters["bad_faults"] += 1
                self.ctx.log("warning", f"fault panel {sc}: refused ({exc})", t_k)
                continue
            self.counters["panel_faults"] += 1
            self.ctx.log("warning", f"fault panel {sc}: {describe_panel(factor, angle)} "
                         f"from t = {t_k:.0f} s ({fault.origin})", t_k)  # fmt: skip


if __name__ == "__main__":
    sys.exit(run_service(main, "environment"))
