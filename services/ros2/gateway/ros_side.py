"""The gateway's ROS 2 side: a Zenoh session of its own at the ROS 2 endpoint, never the run's
bus, on which the gateway is one ROS 2 node as rmw_zenoh makes one (``services.ros2.keys``).

``open_ros_session`` joins the Zenoh router that answers at the endpoint (a user's
``rmw_zenohd``, as a client: it listens on nothing) and, when none does, serves that endpoint as
the router itself, so that ROS 2 nodes and tools, which look for a router at
``tcp/127.0.0.1:7447`` by default, find one.  No credential of the run is ever given to this
session: what crosses to it is what the gateway publishes, nothing else.

``RosNode`` declares the node's liveliness token and, for each publisher, its token (``MP``),
its data key (``<domain>/<topic>/<DDS type>/<RIHS01 hash>``) and its GID; ``RosPublisher``
puts each CDR payload with rmw_zenoh's attachment (its sequence number from 1, the wall clock's
time, the GID) and knows whether any subscriber matches it, so that nothing is converted for a
topic nobody reads.  A subscription is its token (``MS``, what ROS 2 tools list) and a Zenoh
subscriber on the data keys it reads (``listen``).
"""

from __future__ import annotations

import itertools
import socket
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

import zenoh

from services.bus import BusSettings, error_text, zenoh_config
from services.ros2.keys import (
    Attachment,
    Endpoint,
    EntityKind,
    Node,
    QoS,
    data_key,
    encode_attachment,
    endpoint_token,
    entity_gid,
    node_token,
)
from services.ros2.messages import dds_type_name, serialize, type_hash

JOINED = "joined"
"""The ROS 2 side joined the router that answered at its endpoint."""
SERVING = "serving"
"""The ROS 2 side serves its endpoint as the router (none answered there)."""
ATTEMPTS = 2
"""Times the side tries to join, then to serve: a router may take the port between the two."""
PROBE_TIMEOUT = 1.0
"""Wall seconds a TCP connection to the endpoint has to be accepted for it to be joined."""
JOIN_TIMEOUT_MS = 2000
"""Milliseconds a router that accepted the connection has to open the Zenoh session."""


class RosSideError(RuntimeError):
    """The ROS 2 side can neither join nor serve its endpoint: one line saying what to do."""


def _config(endpoint: str, role: str) -> zenoh.Config:
    if role == SERVING:
        return zenoh_config(BusSettings(mode="router", listen=[endpoint], connect=[]))
    # a client of the user's router, listening on nothing; something at the endpoint that
    # accepts connections but speaks no Zenoh is given up on soon
    config = zenoh_config(BusSettings(mode="client", listen=[], connect=[endpoint]))
    config.insert_json5("transport/unicast/open_timeout", str(JOIN_TIMEOUT_MS))
    return config


def _listened(endpoint: str) -> bool:
    """Whether anything accepts a TCP connection at ``endpoint`` (``tcp/HOST:PORT``): where
    nothing does, no router can be joined, and trying would only log zenoh's warnings."""
    host, _, port = endpoint.removeprefix("tcp/").rpartition(":")
    try:
        with socket.create_connection((host.strip("[]"), int(port)), timeout=PROBE_TIMEOUT):
            return True
    except OSError:
        return False


def open_ros_session(endpoint: str) -> tuple[zenoh.Session, str]:
    """A Zenoh session at ``endpoint`` (``tcp/HOST:PORT``) and its role: ``JOINED`` when a
    router answers there, else ``SERVING`` (a router listening there).  Raises
    ``RosSideError`` when neither can be done (the port taken by something that is no Zenoh
    router, an address not of this machine)."""
    why = ""
    for _ in range(ATTEMPTS):
        for role in (JOINED, SERVING) if _listened(endpoint) else (SERVING,):
            try:
                return zenoh.open(_config(endpoint, role)), role
            except zenoh.ZError as exc:
                why = error_text(exc)
    raise RosSideError(
        f"cannot reach ROS 2 at {endpoint}: no Zenoh router answers there and it cannot be "
        f"served ({why}); give another endpoint with --ros2 tcp/127.0.0.1:PORT or ros2.endpoint"
    )


class RosPublisher:
    """One ROS 2 publisher of ``node``: its token, data key, GID and sample numbering.

    Parameters
    ----------
    session : the ROS 2 side's session.
    endpoint : what its liveliness token names (node, entity id, topic, type, QoS).
    ros_type : its ROS type (``nav_msgs/msg/Odometry``).
    """

    def __init__(self, session: zenoh.Session, endpoint: Endpoint, ros_type: str) -> None:
        self.endpoint, self.ros_type, self.topic = endpoint, ros_type, endpoint.topic
        token = endpoint_token(endpoint)
        self.gid = entity_gid(token)
        self.key = data_key(
            endpoint.node.domain_id, endpoint.topic, endpoint.type_name, endpoint.type_hash
        )
        self.sequence = 0  # samples put so far; rmw_zenoh numbers them from 1
        # a slow ROS 2 subscriber loses samples rather than holding the gateway (and the
        # gateway's bus session) up, as rmw_zenoh's keep-last publishers do
        self._publisher = session.declare_publisher(
            self.key, congestion_control=zenoh.CongestionControl.DROP
        )
        self.wanted = bool(self._publisher.matching_status.matching)
        self._matching = self._publisher.declare_matching_listener(self._on_matching)
        self._token = session.liveliness().declare_token(token)

    def _on_matching(self, status: Any) -> None:
        self.wanted = bool(status.matching)  # a zenoh thread; a bool is set atomically

    def publish(self, message: Any) -> None:
        """Put ``message`` (of ``ros_type``) in CDR, with its attachment."""
        payload = serialize(message, self.ros_type)
        self.sequence += 1
        attachment = Attachment(self.sequence, time.time_ns(), self.gid)
        self._publisher.put(payload, attachment=encode_attachment(attachment))

    def close(self) -> None:
        """Withdraw the token, then the publisher."""
        self._token.undeclare()
        self._matching.undeclare()
        self._publisher.undeclare()


class RosNode:
    """One ROS 2 node on the ROS 2 side's ``session``: its liveliness token and its entities'.

    Parameters
    ----------
    session : the ROS 2 side's session (its id is the tokens' ``zid``).
    domain_id : the ROS domain (``ROS_DOMAIN_ID``).
    name : the node's name, in the root namespace.
    """

    def __init__(self, session: zenoh.Session, domain_id: int, name: str) -> None:
        self.session = session
        self.node = Node(domain_id, str(session.info.zid()), 0, name)
        self._ids = itertools.count(1)  # entity ids within the node's session
        self._lock = threading.Lock()
        self.publishers: dict[str, RosPublisher] = {}
        self._declared: list[Any] = []  # subscriptions' tokens and Zenoh subscribers
        self._token = session.liveliness().declare_token(node_token(self.node))

    def _endpoint(self, kind: EntityKind, topic: str, ros_type: str, qos: QoS) -> Endpoint:
        with self._lock:
            entity_id = next(self._ids)
        return Endpoint(
            self.node, entity_id, kind, topic, dds_type_name(ros_type), type_hash(ros_type), qos
        )

    def publisher(self, topic: str, ros_type: str, qos: QoS) -> RosPublisher:
        """Declare a publisher of ``ros_type`` on ``topic`` (fully qualified) with ``qos``."""
        endpoint = self._endpoint(EntityKind.PUBLISHER, topic, ros_type, qos)
        publisher = self.publishers[topic] = RosPublisher(self.session, endpoint, ros_type)
        return publisher

    def subscription(self, topic: str, ros_type: str, qos: QoS) -> Endpoint:
        """Announce a subscription of ``ros_type`` on ``topic`` (its ``MS`` token); its samples
        come through ``listen``."""
        endpoint = self._endpoint(EntityKind.SUBSCRIPTION, topic, ros_type, qos)
        self._declared.append(self.session.liveliness().declare_token(endpoint_token(endpoint)))
        return endpoint

    def listen(self, key_expr: str, handler: Callable[[zenoh.Sample], None]) -> None:
        """Hand every sample put on ``key_expr`` (data keys, wildcards allowed) to
        ``handler``, on a Zenoh thread."""
        self._declared.append(self.session.declare_subscriber(key_expr, handler))

    def close(self) -> None:
        """Withdraw every entity, then the node."""
        for declared in reversed(self._declared):
            declared.undeclare()
        self._declared.clear()
        for publisher in self.publishers.values():
            publisher.close()
        self.publishers.clear()
        self._token.undeclare()


@contextmanager
def ros_node(endpoint: str, domain_id: int, name: str) -> Iterator[tuple[RosNode, str]]:
    """The gateway's node on a ROS 2 side opened at ``endpoint`` (``open_ros_session``), and
    the side's role; node and session always closed."""
    session, role = open_ros_session(endpoint)
    try:
        node = RosNode(session, domain_id, name)
        try:
            yield node, role
        finally:
            node.close()
    finally:
        session.close()
