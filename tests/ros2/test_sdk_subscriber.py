"""Black box: a ROS 2 subscriber of another implementation (zenoh-ros2-sdk), on a Zenoh router
of this test's own on a free loopback port, receives and decodes what this package puts on the
wire (its key, CDR payload and attachment), and its liveliness tokens read back with this
package's parser.  Offline: the SDK reads the ``.msg`` definitions the module writes."""

from __future__ import annotations

import itertools
import json
import time
from pathlib import Path

import pytest
import zenoh

from services.ros2 import keys, messages
from services.ros2.keys import Attachment, Endpoint, EntityKind, Node, QoS
from tests.ros2.samples import plain, sample, write_definitions
from tests.support import wait_until

DOMAIN = 42
"""A ROS domain no other ROS 2 software on this machine would use by default."""


def _router(port: int) -> zenoh.Session:
    """A Zenoh router listening on 127.0.0.1:``port`` only, scouting off."""
    config = zenoh.Config()
    config.insert_json5("mode", json.dumps("router"))
    config.insert_json5("listen/endpoints", json.dumps([f"tcp/127.0.0.1:{port}"]))
    config.insert_json5("connect/endpoints", "[]")
    config.insert_json5("scouting/multicast/enabled", "false")
    return zenoh.open(config)


@pytest.fixture
def sdk(tmp_path: Path, monkeypatch: pytest.MonkeyPatch):
    """zenoh-ros2-sdk reading this package's ``.msg`` files, never downloading, its session
    config the bundled rmw_zenoh one (loopback) without environment overrides."""
    from zenoh_ros2_sdk import message_registry
    from zenoh_ros2_sdk.session import ZenohSession

    monkeypatch.delenv("ZENOH_SESSION_CONFIG_URI", raising=False)
    monkeypatch.delenv("ZENOH_CONFIG_OVERRIDE", raising=False)
    monkeypatch.delenv("ROS_DOMAIN_ID", raising=False)
    write_definitions(tmp_path, messages.EXPOSED_TYPES)
    downloads: list[str] = []

    def no_download(package: str) -> None:
        downloads.append(package)
        raise RuntimeError(f"offline: no download of {package}")

    monkeypatch.setattr(message_registry, "get_repository_for_package", no_download)
    monkeypatch.setattr(
        message_registry, "_registry", message_registry.MessageRegistry(str(tmp_path))
    )
    yield
    if ZenohSession._instance is not None:
        ZenohSession._instance.close()
    assert downloads == [], f"zenoh-ros2-sdk tried to download {downloads}"


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

    router = _router(free_port)
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
