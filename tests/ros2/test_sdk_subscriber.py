"""Black box: a ROS 2 subscriber of another implementation (zenoh-ros2-sdk), on a Zenoh router
of this test's own on a free loopback port, receives and decodes what this package puts on the
wire (its key, CDR payload and attachment), and its liveliness tokens read back with this
package's parser.  Offline: the SDK reads the ``.msg`` definitions the module writes."""

from __future__ import annotations

import itertools
import time

import pytest
import zenoh

from services.ros2 import keys, messages
from services.ros2.keys import Attachment, Endpoint, EntityKind, Node, QoS
from tests.ros2.samples import plain, sample, zenoh_router
from tests.support import wait_until

DOMAIN = 42
"""A ROS domain no other ROS 2 software on this machine would use by default."""


def _publish_until_received(
    router: zenoh.Session, key: str, payload: bytes, gid: bytes, inbox: list
) -> bool:
    """Put ``payload`` on ``key`` as an rmw_zenoh publisher does (sequence numbers from 1, the
    system time, the GID) until it arrives in ``inbox``: a subscription takes a moment to reach
    the router."""
    sequence = itertools.count(1)

    def put_and_wait() -> bool:
        attachment = Attachment(next(sequence), time.time_ns(), gid)
        router.put(key, payload, attachment=keys.encode_attachment(attachment))
        return wait_until(lambda: bool(inbox), timeout=0.2)

    return wait_until(put_and_wait)


@pytest.mark.integration
def test_zenoh_ros2_sdk_subscribers_decode_every_exposed_message(sdk, free_port: int) -> None:
    from zenoh_ros2_sdk import ROS2Subscriber

    router = zenoh_router(free_port)
    subscribers = []
    try:
        gateway = Node(DOMAIN, str(router.info.zid()), 0, "ddvi_gateway")
        received: dict[str, list] = {t: [] for t in messages.EXPOSED_TYPES}
        topics = {t: f"/ddvi/{t.split('/')[-1].lower()}" for t in messages.EXPOSED_TYPES}
        for ros_type in messages.EXPOSED_TYPES:
            subscribers.append(
                ROS2Subscriber(
                    topic=topics[ros_type],
                    msg_type=ros_type,
                    callback=received[ros_type].append,
                    node_name="sdk_listener",
                    domain_id=DOMAIN,
                    router_ip="127.0.0.1",
                    router_port=free_port,
                )
            )
        for i, ros_type in enumerate(messages.EXPOSED_TYPES):
            name, digest = messages.dds_type_name(ros_type), messages.type_hash(ros_type)
            key = keys.data_key(DOMAIN, topics[ros_type], name, digest)
            assert subscribers[i].keyexpr == key  # the SDK subscribes on the same key
            endpoint = Endpoint(
                gateway, i + 1, EntityKind.PUBLISHER, topics[ros_type], name, digest
            )
            gid = keys.entity_gid(keys.endpoint_token(endpoint))
            payload = messages.serialize(sample(ros_type), ros_type)
            assert _publish_until_received(router, key, payload, gid, received[ros_type]), (
                f"no {ros_type} reached the SDK subscriber"
            )
            assert plain(received[ros_type][0]) == plain(sample(ros_type))

        tokens = [
            keys.parse_token(str(reply.ok.key_expr))
            for reply in router.liveliness().get(keys.liveliness_pattern(DOMAIN), timeout=5.0)
            if reply.ok is not None
        ]
        sdk_subscriptions = {
            t.topic: t
            for t in tokens
            if isinstance(t, Endpoint) and t.kind is EntityKind.SUBSCRIPTION
        }
        assert set(sdk_subscriptions) == set(topics.values())
        for ros_type, topic in topics.items():
            endpoint = sdk_subscriptions[topic]
            assert endpoint.node.name == "sdk_listener" and endpoint.node.namespace == "/"
            assert endpoint.type_name == messages.dds_type_name(ros_type)
            assert endpoint.type_hash == messages.type_hash(ros_type)
            assert endpoint.qos == QoS(depth=10)
        assert any(isinstance(t, Node) and t.name == "sdk_listener" for t in tokens)
    finally:
        for subscriber in subscribers:
            subscriber.close()
        router.close()
