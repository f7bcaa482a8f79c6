"""Attitude commands from ROS 2: what the gateway takes from the ROS 2 side for the deputies
flown from ROS 2 (``controller = "ros2"``) and puts on the bus as their commands.

A ROS 2 node commands deputy ``<sc>`` on ``/<sc>/cmd_attitude``
(``geometry_msgs/msg/QuaternionStamped``, as ``services.ros2.conversions.attitude_command``
writes it): the orientation of the commanded body in the deputy's own Hill frame (frame id
``<sc>/hill``), stamped with the flight-software step it is for, in simulation time.  The
gateway announces a subscription of that topic for each deputy it flies and reads every
deputy's (``<domain>/*/cmd_attitude/...``), so that a command for another deputy is seen and
refused too.  Nothing of a sample reaches the bus before it has passed every check; a refusal is
counted (``commands_refused``, ``commands_refused.<reason>``) and logged, naming the topic, the
sender (its GID, as ``ros2 topic info -v`` shows it) and why:

- ``not_ros2``: for a deputy that is not flown from ROS 2 (or of no deployment);
- ``malformed``: a payload that is no QuaternionStamped in CDR;
- ``frame``: a frame id other than ``<sc>/hill``;
- ``attitude``: a quaternion that is no rotation (zero, not finite);
- ``step``: a stamp that is no flight-software step of the mission;
- ``ahead``: for a step past the newest time the gateway has carried (no node can have flown it);
- ``repeated``: for a step already commanded, or an earlier one (one command a step: what a flood
  of commands is made of).

An accepted command goes on the bus as ``cmd/<sc>/att`` (its MRP, ``for_t`` the step), where the
environment's lock-step waits for it as for any controller's.
"""

from __future__ import annotations

import logging
import math
import threading
from collections.abc import Callable
from typing import Any

import numpy as np
import zenoh

from services.bus import worth_saying
from services.config import Deployment
from services.model import duration, on_grid
from services.ros2.conversions import attitude_command_mrp, hill_frame, seconds_from_time
from services.ros2.gateway.exposure import DEFAULT_QOS, deputy_topics
from services.ros2.gateway.ros_side import RosNode
from services.ros2.keys import decode_attachment
from services.ros2.messages import ATTITUDE_COMMAND, dds_type_name, deserialize, type_hash

log = logging.getLogger("ddvi.ros2")

REASONS = ("not_ros2", "malformed", "frame", "attitude", "step", "ahead", "repeated")
"""Why a command from ROS 2 is refused (the module's docstring)."""


class RefusedCommandError(Exception):
    """A command from ROS 2 that does not reach the bus: ``reason`` (of ``REASONS``), and why
    in words."""

    def __init__(self, reason: str, why: str) -> None:
        super().__init__(why)
        self.reason = reason


def sender(attachment: Any) -> str:
    """Who put a sample: its publisher's GID from its rmw_zenoh attachment, dotted hex as
    ``ros2 topic info -v`` prints it, or what is wrong with the attachment."""
    if attachment is None:
        return "a publisher without rmw_zenoh's attachment"
    try:
        gid = decode_attachment(attachment.to_bytes()).source_gid
    except ValueError:
        return "a publisher with a malformed attachment"
    return "GID " + ".".join(f"{b:02x}" for b in gid)


class CommandIntake:
    """The commands of the deputies flown from ROS 2, as their ROS 2 node puts them.

    Parameters
    ----------
    dep : the deployment (which deputies are flown from ROS 2, the steps of its mission).
    node : the gateway's ROS 2 node: its subscriptions are announced and read on it.
    publish : puts an accepted command on the bus: ``publish(sc, sigma, for_t)``.
    say : logs a line (a refusal) for the ground.
    """

    def __init__(
        self,
        dep: Deployment,
        node: RosNode,
        publish: Callable[[str, np.ndarray, float], None],
        say: Callable[[str], None],
    ) -> None:
        self.flown = [d.name for d in dep.deputy if d.controller == "ros2"]
        self.fsw, self.end = dep.run.fsw_period, duration(dep)
        self.publish, self.say = publish, say
        self.now = 0.0  # the newest simulation time the gateway has carried to ROS 2
        self.last = dict.fromkeys(self.flown, -math.inf)  # the newest step commanded
        self.counters = {"commands": 0, "commands_refused": 0}
        self.counters.update({f"commands_refused.{r}": 0 for r in REASONS})
        self._lock = threading.Lock()  # samples come on Zenoh's threads
        for sc in self.flown:
            node.subscription(deputy_topics(sc)["command"], ATTITUDE_COMMAND, DEFAULT_QOS)
        name, digest = dds_type_name(ATTITUDE_COMMAND), type_hash(ATTITUDE_COMMAND)
        node.listen(f"{node.node.domain_id}/*/cmd_attitude/{name}/{digest}", self.on_sample)

    def carried(self, t: float) -> None:
        """The gateway has carried what the mission measured up to ``t`` (s) to ROS 2."""
        if t > self.now:
            self.now = t

    def on_sample(self, sample: zenoh.Sample) -> None:
        """One sample on a command topic (a Zenoh thread): checked, then put on the bus or
        refused; never raises."""
        topic = "/" + "/".join(str(sample.key_expr).split("/")[1:3])
        try:
            with self._lock:
                sc, sigma, for_t = self.check(topic, sample.payload.to_bytes())
                self.last[sc] = for_t
                self.counters["commands"] += 1
            self.publish(sc, sigma, for_t)
        except RefusedCommandError as refused:
            self.refuse(topic, refused, sender(sample.attachment))
        except Exception:  # a command must never take the gateway down
            log.exception("a command on %s could not be taken", topic)

    def check(self, topic: str, payload: bytes) -> tuple[str, np.ndarray, float]:
        """(deputy, MRP, step) of a command on ``topic`` (``/<sc>/cmd_attitude``);
        ``RefusedCommandError`` saying why not."""
        sc = topic.split("/")[1]
        if sc not in self.last:
            raise RefusedCommandError(
                "not_ros2", f"{sc} is not flown from ROS 2 (flown: {self.flown})"
            )
        try:
            message = deserialize(payload, ATTITUDE_COMMAND)
            stamp = message.header.stamp
            for_t = seconds_from_time(stamp.sec, stamp.nanosec)
            frame = message.header.frame_id
        except Exception as exc:  # whatever the bytes: rosbags raises what it meets
            raise RefusedCommandError(
                "malformed", f"not a {ATTITUDE_COMMAND} in CDR ({exc})"
            ) from None
        if frame != hill_frame(sc):
            raise RefusedCommandError("frame", f"its frame is {frame!r}, not {hill_frame(sc)!r}")
        try:
            sigma = attitude_command_mrp(message)
        except ValueError as exc:
            raise RefusedCommandError("attitude", str(exc)) from None
        if not (0.0 <= for_t <= self.end + 1e-6 and on_grid(for_t, self.fsw)):
            raise RefusedCommandError(
                "step", f"its stamp, t = {for_t:g} s, is no flight-software step of the mission"
            )
        if for_t > self.now + 1e-6:
            raise RefusedCommandError(
                "ahead", f"for t = {for_t:g} s, past the mission's {self.now:g} s"
            )
        if for_t <= self.last[sc] + 1e-6:
            raise RefusedCommandError(
                "repeated",
                f"for t = {for_t:g} s; {sc} is commanded up to t = {self.last[sc]:g} s",
            )
        return sc, sigma, for_t

    def refuse(self, topic: str, refused: RefusedCommandError, who: str) -> None:
        with self._lock:
            self.counters["commands_refused"] += 1
            key = f"commands_refused.{refused.reason}"
            n = self.counters[key] = self.counters[key] + 1
        if worth_saying(n):
            self.say(f"refused a command on {topic} from {who}: {refused} ({refused.reason} #{n})")

    def stats(self) -> dict[str, int]:
        """Its counters, now."""
        with self._lock:
            return dict(self.counters)
