"""What the gateway shows ROS 2: the topics a deployment's ``[ros2]`` table asks for
(``ros_topics``) and what each bus message becomes on them (``Translator``), in simulation
time, with the frames of docs/ros2.md.  No bus and no Zenoh here: bus messages in, ROS 2
messages out (``services.ros2.conversions`` builds them).

- ``/clock`` (``rosgraph_msgs/msg/Clock``) from the environment's ``clock``;
- ``/<sc>/odom`` (``nav_msgs/msg/Odometry``) from ``nav/<sc>/state``, the navigated state,
  and ``/<sc>/altitude`` (``geometry_msgs/msg/PointStamped``) its altitude;
- ``/<sc>/truth/odom`` (``nav_msgs/msg/Odometry``) from the ``truth/*`` of one time, the true
  relative state;
- ``/<sc>/commanded_attitude`` (``geometry_msgs/msg/QuaternionStamped``) from ``cmd/<sc>/att``;
- ``/<sc>/gains/feedback`` and ``/<sc>/gains/feedforward`` (``std_msgs/msg/Float64MultiArray``:
  K and L) from ``ctrl/<sc>/gains``, with ``/<sc>/gains/optimal_feedback`` and
  ``/<sc>/gains/optimal_feedforward`` (K* and L* of the truth's model) where it has them;
- ``/diagnostics`` (``diagnostic_msgs/msg/DiagnosticArray``, ``services.ros2.gateway.health``);
- ``/tf`` (``tf2_msgs/msg/TFMessage``) from the ``truth/*`` of one time.

The navigated and the true relative state are in the deputy's navigation frame
(``navigation.frame``, the chief's path frame by default), with ``chief_hill``'s axes, so that
the two compare component by component; the true one carries the deputy body's attitude in
``chief_hill``.  ``/tf`` holds ``chief_hill`` -> ``<sc>/base_link`` (the true pose) and
``chief_hill`` -> ``<sc>/hill`` (the deputy's own Hill frame, which its commanded attitude is
given in).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from ddvi_core.orbit import dcm_to_mrp, hill_frame, mrp_to_dcm
from services.config import Deployment
from services.flight.streams import SamplePairs
from services.interface import Message
from services.model import navigation_state, reference_gains
from services.ros2 import conversions as cv
from services.ros2.keys import QoS
from services.ros2.messages import (
    ALTITUDE,
    ATTITUDE_COMMAND,
    CLOCK,
    DIAGNOSTICS,
    GAINS,
    ODOMETRY,
    TF,
)

NODE_NAME = "ddvi_gateway"
"""The gateway's node name (``ros2 node list``: ``/ddvi_gateway``)."""
DEFAULT_QOS = QoS(depth=10)
"""Every publisher's QoS but /tf's: rclcpp's default (reliable, volatile, keep last 10)."""
TF_QOS = QoS(depth=100)
"""/tf's: tf2's broadcaster's (keep last 100)."""
DIAGNOSTICS_TOPIC = "/diagnostics"

Out = tuple[str, Any]
"""A ROS 2 message to publish: (its topic, the message)."""


@dataclass(frozen=True)
class RosTopic:
    """One topic the gateway publishes: its fully qualified ``name``, ``ros_type``, the
    ``[ros2].topics`` entry that asks for it (``kind``), the deputy it is about ("" for none)
    and its QoS."""

    name: str
    ros_type: str
    kind: str
    deputy: str = ""
    qos: QoS = DEFAULT_QOS


def deputy_topics(sc: str) -> dict[str, str]:
    """A deputy's topic names by role: odom, altitude, truth, attitude, feedback, feedforward,
    optimal_feedback, optimal_feedforward; and command, what a ROS 2 node commands a deputy
    flown from ROS 2 on."""
    gains = f"/{sc}/gains/"
    return {
        "odom": f"/{sc}/odom",
        "altitude": f"/{sc}/altitude",
        "command": f"/{sc}/cmd_attitude",
        "truth": f"/{sc}/truth/odom",
        "attitude": f"/{sc}/commanded_attitude",
        "feedback": gains + "feedback",
        "feedforward": gains + "feedforward",
        "optimal_feedback": gains + "optimal_feedback",
        "optimal_feedforward": gains + "optimal_feedforward",
    }


def ros_topics(dep: Deployment, optimal: dict[str, bool] | None = None) -> list[RosTopic]:
    """The topics the gateway of ``dep`` publishes, as its ``[ros2].topics`` asks; a deputy's
    optimal gains only where ``optimal`` (deputy -> whether its truth has K*) says so."""
    kinds = set(dep.ros2.topics)
    out = [RosTopic("/clock", CLOCK, "clock")] if "clock" in kinds else []
    for d in dep.deputy:
        names, sc = deputy_topics(d.name), d.name
        if "odom" in kinds:
            out.append(RosTopic(names["odom"], ODOMETRY, "odom", sc))
        if "altitude" in kinds:
            out.append(RosTopic(names["altitude"], ALTITUDE, "altitude", sc))
        if "truth" in kinds:
            out.append(RosTopic(names["truth"], ODOMETRY, "truth", sc))
        if "attitude" in kinds:
            out.append(RosTopic(names["attitude"], ATTITUDE_COMMAND, "attitude", sc))
        if "gains" in kinds and d.controller != "ros2":  # a ROS 2 node's gains are its own
            roles = ["feedback", "feedforward"]
            if (optimal or {}).get(sc, False):
                roles += ["optimal_feedback", "optimal_feedforward"]
            out += [RosTopic(names[r], GAINS, "gains", sc) for r in roles]
    if "diagnostics" in kinds:
        out.append(RosTopic(DIAGNOSTICS_TOPIC, DIAGNOSTICS, "diagnostics"))
    if "tf" in kinds:
        out.append(RosTopic("/tf", TF, "tf", qos=TF_QOS))
    return out


_K_LABELS = ("input", "state")
_L_LABELS = ("input", "exostate")


class Translator:
    """Bus messages into ROS 2 messages for one deployment.

    Parameters
    ----------
    dep : the deployment (its deputies, their navigation frames, the truth's model).
    wanted : whether a ROS 2 topic has a subscriber: nothing is built for one that has none.
    """

    def __init__(self, dep: Deployment, wanted: Callable[[str], bool]) -> None:
        self.dep, self.wanted = dep, wanted
        self.deputies = {d.name: d for d in dep.deputy}
        self.names = {sc: deputy_topics(sc) for sc in self.deputies}
        self.optimal: dict[str, tuple[Any, Any]] = {}
        if "gains" in dep.ros2.topics:
            for d in (d for d in dep.deputy if d.controller != "ros2"):
                K, L = reference_gains(dep, d)
                if K is not None and L is not None:
                    self.optimal[d.name] = (cv.gains_message(K, _K_LABELS), L)
        self.tf = "tf" in dep.ros2.topics
        # every craft's truth of one time, together: the chief's Hill frame is each deputy's
        self.truths = SamplePairs(("chief", *self.deputies))
        self.horizon = 10 * dep.run.fsw_period  # a half sample older than this never completes
        self.unmatched = 0

    def topics(self) -> list[RosTopic]:
        """The deployment's topics (``ros_topics``), the optimal gains where the truth has them."""
        return ros_topics(self.dep, {sc: sc in self.optimal for sc in self.deputies})

    def translate(self, msg: Message) -> list[Out]:
        """What ``msg`` (a bus message of its topic's publisher) becomes; ValueError for a
        message that has no ROS 2 form (a time before 0, a deputy of no topic)."""
        schema = msg.schema
        if schema == "clock":
            return [("/clock", cv.clock_message(msg.t))] if self.wanted("/clock") else []
        if schema == "nav":
            return self._nav(msg)
        if schema == "truth":
            return self._truth(msg)
        if schema == "cmd":
            return self._command(msg)
        if schema == "gains":
            return self._gains(msg)
        return []

    def _deputy(self, msg: Message) -> dict[str, str]:
        sc = msg.body["sc"]
        if sc not in self.names:
            raise ValueError(f"no deputy {sc!r} in the deployment")
        return self.names[sc]

    def _nav(self, msg: Message) -> list[Out]:
        names, body = self._deputy(msg), msg.body
        out: list[Out] = []
        if self.wanted(topic := names["odom"]):
            odometry = cv.odometry_message(
                msg.t, body["sc"], body["x_hill"], covariance=body["cov"]
            )
            out.append((topic, odometry))
        if self.wanted(topic := names["altitude"]):
            out.append((topic, cv.altitude_message(msg.t, body["sc"], body["altitude"])))
        return out

    def _command(self, msg: Message) -> list[Out]:
        topic, body = self._deputy(msg)["attitude"], msg.body
        if not self.wanted(topic):
            return []
        return [(topic, cv.attitude_command(body["for_t"], body["sc"], body["sigma"]))]

    def _gains(self, msg: Message) -> list[Out]:
        names, body = self._deputy(msg), msg.body
        out: list[Out] = []
        if self.wanted(names["feedback"]):
            out.append((names["feedback"], cv.gains_message(body["K"], _K_LABELS)))
        if self.wanted(names["feedforward"]):
            out.append((names["feedforward"], cv.gains_message(body["L"], _L_LABELS)))
        if (optimal := self.optimal.get(body["sc"])) is not None:
            K_star, L_star = optimal
            if self.wanted(names["optimal_feedback"]):
                out.append((names["optimal_feedback"], K_star))
            if self.wanted(names["optimal_feedforward"]):
                out.append((names["optimal_feedforward"], cv.gains_message(L_star, _L_LABELS)))
        return out

    def _truth(self, msg: Message) -> list[Out]:
        """A craft's truth: once every craft's of its time is in, each deputy's true relative
        state and the frames."""
        sc, body = msg.body["sc"], msg.body
        if sc != "chief" and sc not in self.deputies:
            raise ValueError(f"no craft {sc!r} in the deployment")
        state = np.concatenate([body["r_N"], body["v_N"]])
        sample = self.truths.add(msg.t, sc, (state, np.asarray(body["sigma_BN"])))
        self.unmatched += len(self.truths.forget_before(msg.t - self.horizon))
        return [] if sample is None else self._true_sample(msg.t, sample)

    def _true_sample(self, t: float, sample: dict[Any, Any]) -> list[Out]:
        chief, _ = sample["chief"]
        frames = self.tf and self.wanted("/tf")
        shown = [sc for sc in self.deputies if frames or self.wanted(self.names[sc]["truth"])]
        if not shown:
            return []
        HcN = hill_frame(chief[:3], chief[3:])  # the chief's Hill frame: chief_hill
        states = np.array([sample[sc][0] for sc in shown])
        # every deputy's attitudes in chief_hill at once: its body's, and its own Hill frame's
        bodies = mrp_to_dcm(np.array([sample[sc][1] for sc in shown])) @ HcN.T
        own_hills = hill_frame(states[:, :3], states[:, 3:]) @ HcN.T
        attitudes = dcm_to_mrp(np.concatenate([bodies, own_hills]))
        out: list[Out] = []
        transforms = []
        for k, sc in enumerate(shown):
            relative = navigation_state(self.dep, self.deputies[sc], chief, states[k])
            sigma, own_hill = attitudes[k], attitudes[len(shown) + k]
            if self.wanted(topic := self.names[sc]["truth"]):
                out.append((topic, cv.odometry_message(t, sc, relative, sigma=sigma)))
            if frames:
                transforms.append(cv.hill_transform(t, sc, relative, sigma))
                transforms.append(
                    cv.transform(t, cv.CHIEF_HILL_FRAME, cv.hill_frame(sc), relative[:3], own_hill)
                )
        if transforms:
            out.append(("/tf", cv.tf_message(transforms)))
        return out
