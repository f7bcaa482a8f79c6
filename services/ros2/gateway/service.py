"""The ROS 2 gateway service, ``ros2-gateway``: the run's declared topics carried to ROS 2.

Inputs:  clock; truth/<craft> (truth), nav/<sc>/state (nav), cmd/<sc>/att (cmd),
         ctrl/<sc>/gains (gains), as its ``[ros2].topics`` ask; ctrl/<sc>/status (status),
         stats/<service> (stats), log/<service> (log) and every service's liveliness for
         /diagnostics.
         On the ROS 2 side, /<sc>/cmd_attitude of the deputies flown from ROS 2
         (``services.ros2.gateway.commands``).
Outputs: on the ROS 2 side, the topics of ``services.ros2.gateway.exposure``; on the bus
         cmd/<sc>/att (cmd) of the deputies flown from ROS 2, stats/ros2-gateway (published,
         published.<ROS 2 topic>, refused, publish_errors, unmatched, commands,
         commands_refused, commands_refused.<reason>) and log/ros2-gateway.

It is one more bus service, with its own credential and the access rules the topology gives it
(it puts only its stats, its log and the commands of the deputies flown from ROS 2 on the bus),
hosted like every flight service (``services.flight.host``: a reactive component).  Its ROS 2
side is a second Zenoh session (``services.ros2.gateway.ros_side``) at the deployment's
``ros2.endpoint``, where it is the ROS 2 node ``/ddvi_gateway``.  What it carries never holds
the mission up (lock-step waits for it only as the commander of a deputy flown from ROS 2): a
ROS 2 topic without a subscriber costs no conversion, a slow ROS 2 subscriber loses samples.
A bus message that has no ROS 2 form is refused, counted and logged, and the gateway goes on.
It ends once the mission's final clock has come, every flight service has left and every
deputy's final navigation sample is carried, or ``END_GRACE`` after the final clock.
"""

from __future__ import annotations

import math
import sys
import time
from typing import Any

from services.bus import worth_saying
from services.flight.host import Listen, ServiceHost, Watch
from services.flight.inputs import PRESENCE
from services.flight.runtime import ServiceContext, run_service
from services.interface import (
    CLOCK,
    ROS2_GATEWAY,
    Message,
    command_topic,
    gains_topic,
    log_topic,
    nav_state_topic,
    stats_topic,
    status_topic,
    truth_topic,
)
from services.ros2.conversions import diagnostic_array
from services.ros2.gateway.commands import CommandIntake
from services.ros2.gateway.exposure import DIAGNOSTICS_TOPIC, NODE_NAME, Translator
from services.ros2.gateway.health import Health
from services.ros2.gateway.ros_side import RosNode, RosSideError, ros_node

SIDE_FAILED = 2
"""The gateway's exit status when its ROS 2 side cannot be opened (the endpoint is bad input)."""
HEALTH_SCHEMAS = ("stats", "status", "log")
DIAGNOSTICS_PERIOD = 1.0
"""Wall seconds between two /diagnostics whose levels and messages are unchanged (only counters
moved): diagnostic_updater's default rate.  A changed level or message goes out at once."""


def main(ctx: ServiceContext) -> int:
    ros2 = ctx.deployment.ros2
    try:
        with ros_node(ros2.endpoint, ros2.domain_id, NODE_NAME) as (node, role):
            return ServiceHost(ctx).react(GatewayService(ctx, node, role))
    except RosSideError as exc:
        ctx.log("error", str(exc))
        return SIDE_FAILED


def bus_inputs(kinds: set[str]) -> tuple[Listen | Watch, ...]:
    """What the gateway subscribes for the ``[ros2].topics`` entries ``kinds``: the clock and
    every service's liveliness always (its own end), the rest as the topics need."""
    inputs: list[Listen | Watch] = [Listen(CLOCK, "clock"), Watch("*")]
    if kinds & {"truth", "tf"}:
        inputs.append(Listen(truth_topic("*"), "truth"))
    if kinds & {"odom", "altitude"}:
        inputs.append(Listen(nav_state_topic("*"), "nav"))
    if "attitude" in kinds:
        inputs.append(Listen(command_topic("*"), "cmd"))
    if "gains" in kinds:
        inputs.append(Listen(gains_topic("*"), "gains"))
    if "diagnostics" in kinds:
        inputs += [
            Listen(status_topic("*"), "status"),
            Listen(stats_topic("*"), "stats"),
            Listen(log_topic("*"), "log"),
        ]
    return tuple(inputs)


class GatewayService:
    """The gateway as a reactive component of the service host: each bus message translated
    (``Translator``) and published on the ROS 2 side, the services' health kept (``Health``)
    and published on /diagnostics when a service's level or message changes (counters alone:
    at most once a ``DIAGNOSTICS_PERIOD``).

    Parameters
    ----------
    ctx : the service's context (its bus, deployment, stop request, log).
    node : its ROS 2 node, on the ROS 2 side's session.
    role : how the side was opened (``ros_side.JOINED`` or ``ros_side.SERVING``).
    """

    ready_at_start = True
    batched = False  # it puts nothing on the bus but its stats and log

    def __init__(self, ctx: ServiceContext, node: RosNode, role: str) -> None:
        self.ctx = ctx
        dep = ctx.deployment
        self.translator = Translator(dep, self.wanted)
        topics = self.translator.topics()
        self.publishers = {t.name: node.publisher(t.name, t.ros_type, t.qos) for t in topics}
        self.inputs = bus_inputs({t.kind for t in topics})
        self.health = Health(dep.services)
        self.diagnosed: tuple[Any, ...] = ()  # the levels and messages last on /diagnostics
        self.diagnosed_at = -math.inf  # and when (monotonic wall seconds)
        self.flight = {s for s in dep.services if s not in ("monitor", ROS2_GATEWAY)}
        self.alive: set[str] = set()
        # each deputy's newest navigation sample carried, when it carries them: a service's
        # liveliness and its messages come on different subscriptions, so its token can be
        # seen gone before its last sample is in
        navigated = any(t.kind in ("odom", "altitude") for t in topics)
        self.navigated = dict.fromkeys([d.name for d in dep.deputy] if navigated else [], -1.0)
        self.t = 0.0  # the newest clock's time
        self.counters: dict[str, int] = {"published": 0, "refused": 0, "publish_errors": 0}
        self.counters.update({f"published.{name}": 0 for name in self.publishers})
        self.intake: CommandIntake | None = None
        if any(d.controller == "ros2" for d in dep.deputy):  # ROS 2 flies them
            self.intake = CommandIntake(dep, node, self.publish_command, self.say)
        where = "joined the Zenoh router at" if role == "joined" else "serves (no router answered)"
        ctx.log(
            "info",
            f"ROS 2 side: {where} {dep.ros2.endpoint}, domain {dep.ros2.domain_id}, node "
            f"/{NODE_NAME}, {len(topics)} topics: {', '.join(t.name for t in topics)}",
        )

    def wanted(self, topic: str) -> bool:
        """Whether a ROS 2 subscriber reads ``topic``."""
        publisher = self.publishers.get(topic)
        return publisher is not None and publisher.wanted

    # -- as the service host runs it (services.flight.host.Reactive) ---------------------------

    def poll(self) -> float:
        return 0.5

    def start(self) -> None:
        self.publish_health()

    def take(self, kind: str, msg: Any) -> None:
        if kind == PRESENCE:
            service, up = msg
            (self.alive.add if up else self.alive.discard)(service)
            if self.health.presence(service, up):
                self.publish_health()
            return
        if msg.schema == "clock":
            self.t = max(self.t, msg.t)
            self.ctx.bus.pump(msg.t)  # what a link held until now (a deployment's [[link]])
            self.health.final = self.health.final or bool(msg.body["final"])
        if self.intake is not None and msg.schema in ("clock", "nav"):
            self.intake.carried(msg.t)  # before ROS 2 can see it: a node may command up to it
        if msg.schema == "nav" and msg.body["sc"] in self.navigated:
            self.navigated[msg.body["sc"]] = max(self.navigated[msg.body["sc"]], msg.t)
        if msg.schema in HEALTH_SCHEMAS:
            if self.health.take(msg) and self.diagnosis_due():
                self.publish_health(msg.t)
            return
        try:
            out = self.translator.translate(msg)
        except ValueError as exc:
            self.refuse(kind, msg, exc)
            return
        for topic, message in out:
            self.publish(topic, message)

    def settle(self, final_t: float | None) -> None:
        self.ctx.bus.pump()  # in real time the links release by the wall clock

    def done(self, final_t: float | None) -> bool:
        """The final clock is in, every flight service has left, and every deputy's final
        navigation sample is carried (a sample lost on its link: the host's grace ends it)."""
        if final_t is None or self.alive & self.flight:
            return False
        return all(t >= final_t - 1e-6 for t in self.navigated.values())

    def finish(self) -> tuple[float, dict[str, int]]:
        self.health.final = True
        self.publish_health()
        return self.t, self.stats()

    # -- publishing ---------------------------------------------------------------------------

    def stats(self) -> dict[str, int]:
        commands = self.intake.stats() if self.intake is not None else {}
        return {**self.counters, "unmatched": self.translator.unmatched, **commands}

    def publish_command(self, sc: str, sigma: Any, for_t: float) -> None:
        """A command from ROS 2 that passed every check, on the bus (``CommandIntake``)."""
        body = {"sc": sc, "sigma": sigma, "for_t": for_t}
        self.ctx.bus.publish(command_topic(sc), "cmd", body, for_t)

    def say(self, text: str) -> None:
        self.ctx.log("warning", text, self.t)

    def publish(self, topic: str, message: Any) -> None:
        """Put one ROS 2 message; a failure is counted and said, never raised."""
        try:
            self.publishers[topic].publish(message)
        except Exception as exc:  # the ROS 2 side must never take the gateway down
            self.counters["publish_errors"] += 1
            if worth_saying(self.counters["publish_errors"]):
                self.ctx.log("warning", f"could not publish on {topic}: {exc}", self.t)
            return
        self.counters["published"] += 1
        self.counters[f"published.{topic}"] += 1

    def diagnosis_due(self) -> bool:
        """Whether /diagnostics should go out: a service's level or message has changed, or
        ``DIAGNOSTICS_PERIOD`` has passed."""
        if time.monotonic() - self.diagnosed_at >= DIAGNOSTICS_PERIOD:
            return True
        return self.health.headlines() != self.diagnosed

    def publish_health(self, t: float | None = None) -> None:
        """/diagnostics now, if anyone reads it."""
        if not self.wanted(DIAGNOSTICS_TOPIC):
            return
        self.health.own(ROS2_GATEWAY, {**self.ctx.bus.counters, **self.stats()})
        stamp = max(self.t, t or 0.0)
        self.diagnosed, self.diagnosed_at = self.health.headlines(), time.monotonic()
        self.publish(DIAGNOSTICS_TOPIC, diagnostic_array(stamp, self.health.statuses()))

    def refuse(self, topic: str, msg: Message, exc: Exception) -> None:
        """A bus message with no ROS 2 form: counted and said, the gateway goes on."""
        self.counters["refused"] += 1
        if worth_saying(self.counters["refused"]):
            self.ctx.log(
                "warning",
                f"refused {topic} from {msg.src} at t = {msg.t:g} s: no ROS 2 form ({exc}; "
                f"#{self.counters['refused']})",
                self.t,
            )


if __name__ == "__main__":
    sys.exit(run_service(main, ROS2_GATEWAY))
