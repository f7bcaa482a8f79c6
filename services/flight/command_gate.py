"""The environment's commands in force, and in lock-step its wait for them.

Each deputy's commanded relative MRP (clipped to its attitude limit) is in force from the step
its link delivers it on.  In lock-step the step at t_k waits until every controller's command
for the step its link delay maps to (issued at T, it arrives at T + delay, so the newest that
can act from t_k is for floor((t_k - delay) / fsw) steps) is accounted for: delivered, or
dropped by its link or by the bus's rate budget.  A controller that is there (its liveliness
token alive) but silent pauses the mission (said after run.command_deadline wall seconds,
counted in paused_steps) and, past run.hang_timeout, ends it (``HangError``); one that goes
away is waited for once, up to run.command_deadline, and its deputy holds its last command
(docs/health.md).  The step also waits for the recorder when the mission is more than its lead
past what the monitor has acknowledged recording (``services.flight.recorder_lead``).
"""

from __future__ import annotations

import math
import queue
import time
from collections.abc import Callable

from services.bus import worth_saying
from services.flight.control_loop import newest_sample_time
from services.flight.environment_model import CommandsInForce
from services.flight.health import HANG_MARGIN, HangError, Waiting
from services.flight.inputs import LOST, OBSERVED, PRESENCE
from services.flight.recorder_lead import RECORDER, RecorderLead
from services.flight.runtime import ServiceContext
from services.interface import ROS2_GATEWAY, Message, command_topic, fault_topic

RECORDED_TAG = "recorded"  # inbox tag: the monitor's acknowledgement of what it recorded
RECORDER_PRESENCE = "recorder presence"  # inbox tag: the monitor's liveliness change
PANEL = fault_topic("panel")  # topic of run-time panel faults

STOP_POLL = 0.25
"""Wall seconds the command wait blocks before it looks at a stop request again."""


class CommandGate:
    """What the environment's step takes from its inbox: the commands its links deliver, put
    in ``commands`` (the commands in force), and in lock-step the wait for them.

    Parameters
    ----------
    ctx : the environment's context (its bus, deployment, stop request, log).
    commands : the deputies' commands in force.
    inbox : where the subscriptions put ``(topic or tag, message)``: commands, commands
        observed by the link layer, commands lost to a flood, panel faults, controllers'
        presence.
    present : the deputies whose controller is alive (waited for in lock-step).
    counters : the environment's counters; the gate keeps its own among them.
    on_fault : called with a panel fault taken from the inbox.
    recorder : how far the mission may run ahead of the monitor's recording (waited for in
        lock-step as the commands are).
    """

    def __init__(
        self,
        ctx: ServiceContext,
        commands: CommandsInForce,
        inbox: queue.SimpleQueue,
        present: set[str],
        counters: dict[str, int],
        on_fault: Callable[[Message], None],
        recorder: RecorderLead,
    ) -> None:
        self.ctx, self.bus, self.inbox, self.present = ctx, ctx.bus, inbox, present
        self.commands, self.latest_for_t = commands, commands.latest_for_t
        self.counters, self.on_fault, self.recorder = counters, on_fault, recorder
        dep = ctx.deployment
        self.run, self.fsw = dep.run, dep.run.fsw_period
        self.deputies = [d.name for d in dep.deputy]
        # who puts each deputy's commands: its controller, or the ROS 2 gateway for a deputy
        # flown from ROS 2 (behind which its ROS 2 node is what a silence blames)
        self.commander = {sc: dep.commander(sc) for sc in self.deputies}
        self.behind = {
            sc: f"the ROS 2 node flying {sc} (through {who})"
            for sc, who in self.commander.items()
            if who == ROS2_GATEWAY
        }
        self.now = 0.0  # the step being taken
        self.seen_for_t = dict.fromkeys(self.deputies, -math.inf)  # newest accounted for
        self.away_since: dict[str, float] = {}  # wall time each away controller went
        self.returned_at: dict[str, float] = {}  # step at which each came back
        # a command issued at T reaches the truth at T + the link's delay (docs/design.md,
        # "Time")
        self.cmd_delay = {
            sc: self.bus.latency(self.commander[sc], command_topic(sc)) for sc in self.deputies
        }

    def expected_step(self, sc: str, t_k: float) -> float:
        """The newest command step that can be in force from t_k on (negative: none yet)."""
        return newest_sample_time(t_k, self.cmd_delay[sc], self.fsw)

    def take(self, t_k: float, wait: bool) -> None:
        """Apply the newest command of each deputy that its link has delivered by t_k; in
        lock-step wait until the one for the step its delay maps to is accounted for: the
        mission pauses for a controller that is there but silent (said after
        run.command_deadline), up to the hang timeout (``HangError``)."""
        self.bus.pump(t_k)  # release what the links held until t_k
        self.now = t_k
        deputies, counters = self.deputies, self.counters
        expected = {sc: self.expected_step(sc, t_k) for sc in deputies}
        waiting = Waiting(self.run.command_deadline, self.run.hang_timeout + HANG_MARGIN)
        if wait and self.recorder.behind(t_k):
            counters["recorder_waits"] += 1  # steps held back for the recorder
        while not self.ctx.stop.is_set():
            late = self.awaited(t_k, expected)
            if wait and late and waiting.said_at(time.monotonic()):
                counters["paused_steps"] += 1
                names = ", ".join(f"{what} from {name}" for name, what, _ in late)
                self.ctx.log(
                    "warning",
                    f"lock-step paused at t = {t_k:.0f} s: no {names} for {waiting.said:g} s",
                    t_k,
                )
            if wait and late and waiting.over(time.monotonic()):
                service, what, sc = late[0]
                behind = self.behind.get(sc, "") if sc else ""
                raise HangError(service, what, t_k, self.run.hang_timeout, behind=behind)
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
            if kind == PANEL:
                self.on_fault(msg)
            elif kind == RECORDED_TAG:
                self.recorder.acknowledged(msg.t)
            elif kind == RECORDER_PRESENCE:
                self.recorder.presence(msg[1])
            elif kind == PRESENCE:
                for sc in self.commanded_by(msg[0]):
                    self.on_presence(sc, msg[1], t_k)
            elif kind == LOST:
                self.on_lost(msg, expected)
            else:
                self.on_command(kind, msg, expected)
        if wait:
            self.commands.count_missing(expected)
        counters["controller_away_steps"] += len(set(deputies) - self.present)

    def awaited(self, t_k: float, expected: dict[str, float]) -> list[tuple[str, str, str]]:
        """What the step at t_k still waits for, as (service, what, deputy) triples: each
        silent commander's command (a controller's, or the ROS 2 gateway's for a deputy flown
        from ROS 2), then the recorder's acknowledgement (no deputy)."""
        late = [
            (self.commander[sc], "command" if sc not in self.behind else f"command for {sc}", sc)
            for sc in self.deputies
            if self.outstanding(sc, t_k, expected[sc])
        ]
        if self.recorder.behind(t_k):
            late.append((RECORDER, "acknowledgement of the recording", ""))
        return late

    def commanded_by(self, service: str) -> list[str]:
        """The deputies whose commands ``service`` puts."""
        return [sc for sc, who in self.commander.items() if who == service]

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
        until = self.away_since[sc] + self.run.command_deadline
        return until if until > time.monotonic() else None

    def on_command(self, kind: str, msg: Message, expected: dict[str, float]) -> None:
        """A command delivered (``CommandsInForce.deliver``), or observed by its link; one
        from another service than the deputy's commander (the topology lets the ROS 2 gateway
        command any deputy, the run only those flown from ROS 2) is refused and counted."""
        sc, for_t = msg.body["sc"], msg.body["for_t"]
        if msg.src != self.commander.get(sc, msg.src):
            if kind != OBSERVED:  # counted once, when it is delivered (none in a clean run)
                n = self.counters["foreign_commands"] = self.counters.get("foreign_commands", 0) + 1
                if worth_saying(n):
                    self.ctx.log(
                        "warning",
                        f"refused a command for {sc} from {msg.src}: {self.commander[sc]} "
                        f"commands {sc} (#{n})",
                        self.now,
                    )
            return
        if kind != OBSERVED:
            self.commands.deliver(sc, for_t, msg.body["sigma"], self.now, expected.get(sc, 0.0))
        elif sc in self.seen_for_t and for_t <= self.now + 1e-6:
            self.seen_for_t[sc] = max(self.seen_for_t[sc], for_t)

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
            self.ctx.log(
                "warning",
                f"controller of {sc} went away at t = {t_k:.0f} s; holding its last command",
                t_k,
            )
