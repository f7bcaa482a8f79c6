"""Black box: ``ddvi run --ros2`` of a short mission seen from the ROS 2 side by two clients that
share no code with the gateway: zenoh-ros2-sdk (another implementation of rmw_zenoh) on a
router of the test's own, which the gateway joins (a user's ``rmw_zenohd``), and a plain Zenoh
client written from rmw_zenoh's design, on the endpoint the gateway serves itself.  What they
decode is held to the run's recording (what the bus carried); the type hashes to the values
ROS 2 Jazzy computes (docs/ros2.md)."""

from __future__ import annotations

import signal
import subprocess
from pathlib import Path
from typing import Any

import numpy as np
import psutil
import pytest
import zenoh

from services.bus import BusSettings, open_session
from services.ground.storage.recording import read_recording
from services.ros2 import conversions as cv
from services.ros2 import keys, messages
from services.ros2.gateway import ros_side
from services.ros2.keys import Endpoint, EntityKind, Node
from tests.ros2.samples import zenoh_router
from tests.support import fly, service_process, wait_until

pytestmark = pytest.mark.integration

DOMAIN = 42
"""A ROS domain no other ROS 2 software on this machine would use by default."""
SHORT = f"""
[run]
name = "ros2"
orbits = 1.0
command_deadline = 20.0
[ros2]
domain_id = {DOMAIN}
[[deputy]]
name = "lqr"
controller = "lqr"
[[deputy]]
name = "ddvi"
controller = "ddvi"
learning = {{ learn_at_orbits = 2.0 }}   # explores for the whole run
"""
# what ROS 2 Jazzy computes for these types (rosidl; docs/ros2.md), not what this package does
JAZZY_HASHES = {
    messages.CLOCK: "RIHS01_692f7a66e93a3c83e71765d033b60349ba68023a8c689a79e48078bcb5c58564",
    messages.ODOMETRY: "RIHS01_3cc97dc7fb7502f8714462c526d369e35b603cfc34d946e3f2eda2766dfec6e0",
}
RUN_TOPICS = {
    "/clock": messages.CLOCK,
    "/diagnostics": messages.DIAGNOSTICS,
    "/tf": messages.TF,
    **{
        name: ros_type
        for sc in ("lqr", "ddvi")
        for name, ros_type in (
            (f"/{sc}/odom", messages.ODOMETRY),
            (f"/{sc}/altitude", messages.ALTITUDE),
            (f"/{sc}/truth/odom", messages.ODOMETRY),
            (f"/{sc}/commanded_attitude", messages.ATTITUDE_COMMAND),
            (f"/{sc}/gains/feedback", messages.GAINS),
            (f"/{sc}/gains/feedforward", messages.GAINS),
            (f"/{sc}/gains/optimal_feedback", messages.GAINS),
            (f"/{sc}/gains/optimal_feedforward", messages.GAINS),
        )
    },
}


def _deployment(tmp_path: Path) -> Path:
    path = tmp_path / "ros2.toml"
    path.write_text(SHORT)
    return path


def _recorded(out: Path) -> dict[str, list[Any]]:
    """The run's recorded messages by topic, in the order recorded."""
    recorded: dict[str, list[Any]] = {}
    for item in read_recording(out / "recording.mcap")[0]:
        recorded.setdefault(item.topic, []).append(item.data)
    return recorded


def _stamp(header: Any) -> float:
    return cv.seconds_from_time(header.stamp.sec, header.stamp.nanosec)


def _check_odometry(received: list[Any], recorded: list[Any]) -> None:
    """Each Odometry received is the navigation message of its time, to the last bit."""
    by_t = {m["t"]: m["body"] for m in recorded}
    for odometry in received:
        body = by_t[_stamp(odometry.header)]
        assert odometry.header.frame_id == "chief_hill"
        assert np.array_equal(cv.hill_state_from_odometry(odometry), body["x_hill"])
        cov = np.array(body["cov"])
        assert np.array_equal(np.reshape(odometry.pose.covariance, (6, 6))[:3, :3], cov[:3, :3])
        assert np.array_equal(np.reshape(odometry.twist.covariance, (6, 6))[:3, :3], cov[3:, 3:])


def _clocks(recorded: dict[str, list[Any]]) -> list[float]:
    return [m["t"] for m in recorded["clock"] if m["src"] == "environment"]


def test_zenoh_ros2_sdk_lists_the_runs_topics_and_decodes_them_equal_to_the_recording(
    sdk: None, tmp_path: Path, free_port: int
) -> None:
    from zenoh_ros2_sdk import ROS2Subscriber, get_topic_names_and_types

    router = zenoh_router(free_port)  # the user's rmw_zenohd, there before the run
    received: dict[str, list[Any]] = {
        "/clock": [],
        "/lqr/odom": [],
        "/ddvi/odom": [],
        "/diagnostics": [],
    }
    subscribers = []
    listing: list[tuple[str, list[str]]] = []

    def during(proc: subprocess.Popen, _folder: Path) -> None:
        environment = service_process(proc, "environment")
        environment.suspend()  # the gateway is there while the mission waits
        try:
            listing[:] = get_topic_names_and_types(
                domain_id=DOMAIN, router_port=free_port, timeout=2.0
            )
        finally:
            environment.resume()

    try:
        for topic, store in received.items():
            subscribers.append(
                ROS2Subscriber(
                    topic=topic,
                    msg_type=RUN_TOPICS[topic],
                    callback=store.append,
                    node_name="sdk_listener",
                    domain_id=DOMAIN,
                    router_port=free_port,
                )
            )
        options = ("--ros2", f"tcp/127.0.0.1:{free_port}")
        status, said, out = fly(_deployment(tmp_path), tmp_path / "runs", during, options)
        # the gateway's final diagnostics left before the run ended; its delivery to the SDK's
        # callback may still be under way on a loaded machine
        wait_until(lambda: _finished(received["/diagnostics"]))
    finally:
        for subscriber in subscribers:
            subscriber.close()
        router.close()
    assert status == 0, said
    assert "ROS 2 on tcp/127.0.0.1" in said
    listed = dict(listing)
    assert {t: listed.get(t) for t in RUN_TOPICS} == {t: [ty] for t, ty in RUN_TOPICS.items()}
    recorded = _recorded(out)
    (stats,) = [m["body"]["counters"] for m in recorded["stats/ros2-gateway"]]
    # the gateway put every navigation message and every clock of the run; what reached the
    # SDK (a loaded machine's queues may drop samples: keep-last publishers, as rmw_zenoh's)
    # is each the bus's message of its time, in order
    for sc in ("lqr", "ddvi"):
        nav = recorded[f"nav/{sc}/state"]
        assert stats[f"published./{sc}/odom"] == len(nav)
        odometry = received[f"/{sc}/odom"]
        times = [_stamp(o.header) for o in odometry]
        assert times and times == sorted(set(times))
        _check_odometry(odometry, nav)
    assert stats["published./clock"] == len(_clocks(recorded))
    clocks = [cv.seconds_from_time(c.clock.sec, c.clock.nanosec) for c in received["/clock"]]
    assert clocks and clocks == sorted(set(clocks)) and set(clocks) <= set(_clocks(recorded))
    (log,) = [m["body"]["text"] for m in recorded["log/ros2-gateway"]]
    assert log.startswith(f"ROS 2 side: joined the Zenoh router at tcp/127.0.0.1:{free_port}")
    # the last diagnostics: every service of the run, the flight services finished
    last = {s.name: s for s in cv.statuses_from_diagnostics(received["/diagnostics"][-1])}
    services = ["environment", "nav-lqr", "ctrl-lqr", "nav-ddvi", "ctrl-ddvi"]
    assert set(last) == {f"ddvi/{s}" for s in [*services, "monitor", "ros2-gateway"]}
    for service in services:
        assert (last[f"ddvi/{service}"].level, last[f"ddvi/{service}"].message) == (
            cv.Level.OK,
            "finished",
        )
    assert ("published./lqr/odom", str(stats["published./lqr/odom"])) in (
        last["ddvi/ros2-gateway"].values
    )


def _finished(diagnostics: list[Any]) -> bool:
    """Whether the newest diagnostics array received says the environment has finished."""
    if not diagnostics:
        return False
    status = {s.name: s for s in cv.statuses_from_diagnostics(diagnostics[-1])}
    return getattr(status.get("ddvi/environment"), "message", None) == "finished"


def _samples(session: zenoh.Session, key: str, into: list[Any]) -> Any:
    return session.declare_subscriber(key, into.append)


def test_a_plain_zenoh_client_finds_the_tokens_and_decodes_the_cdr_and_a_stop_leaves_nothing(
    tmp_path: Path, free_port: int
) -> None:
    endpoint = f"tcp/127.0.0.1:{free_port}"
    tokens: list[Any] = []
    samples: dict[str, list[Any]] = {"/clock": [], "/lqr/odom": []}

    def during(proc: subprocess.Popen, _folder: Path) -> None:
        environment = service_process(proc, "environment")
        environment.suspend()
        try:
            settings = BusSettings(mode="client", listen=[], connect=[endpoint])
            with open_session(settings) as client:  # nothing of ddvi's bus: the ROS 2 side
                pattern = keys.liveliness_pattern(DOMAIN)
                replies = client.liveliness().get(pattern, timeout=2.0)
                tokens[:] = [str(r.ok.key_expr) for r in replies if r.ok is not None]
                found = [keys.parse_token(t) for t in tokens]
                endpoints = {e.topic: e for e in found if isinstance(e, Endpoint)}
                subscriptions = [
                    _samples(client, _key(endpoints[topic]), into)
                    for topic, into in samples.items()
                ]
                environment.resume()
                assert wait_until(lambda: all(len(s) >= 3 for s in samples.values()), 60.0)
                for subscription in subscriptions:
                    subscription.undeclare()
        finally:
            environment.resume()
        proc.send_signal(signal.SIGINT)  # a stop while the mission flies

    status, said, out = fly(_deployment(tmp_path), tmp_path / "runs", during, ("--ros2", endpoint))
    assert status == 128 + signal.SIGINT, said
    found = [keys.parse_token(t) for t in tokens]
    (node,) = [t for t in found if isinstance(t, Node)]
    assert (node.name, node.namespace, node.domain_id) == ("ddvi_gateway", "/", DOMAIN)
    publishers = {
        e.topic: e for e in found if isinstance(e, Endpoint) and e.kind is EntityKind.PUBLISHER
    }
    assert set(publishers) == set(RUN_TOPICS)
    for topic, ros_type in (("/clock", messages.CLOCK), ("/lqr/odom", messages.ODOMETRY)):
        assert publishers[topic].type_name == messages.dds_type_name(ros_type)
        assert publishers[topic].type_hash == JAZZY_HASHES[ros_type]
        assert publishers[topic].node.zid == node.zid
    recorded = _recorded(out)
    odometry = []
    for topic, ros_type in (("/clock", messages.CLOCK), ("/lqr/odom", messages.ODOMETRY)):
        gid = keys.entity_gid(keys.endpoint_token(publishers[topic]))
        numbers = []
        for sample in samples[topic]:
            attachment = keys.decode_attachment(sample.attachment.to_bytes())
            assert attachment.source_gid == gid
            numbers.append(attachment.sequence_number)
            decoded = messages.deserialize(sample.payload.to_bytes(), ros_type)
            if ros_type == messages.ODOMETRY:
                odometry.append(decoded)
            else:
                clock = cv.seconds_from_time(decoded.clock.sec, decoded.clock.nanosec)
                assert clock in _clocks(recorded)
        assert numbers == sorted(set(numbers))  # numbered by the publisher, in order
    _check_odometry(odometry, recorded["nav/lqr/state"])
    # stopped: no process of the run left, and nothing serves the ROS 2 endpoint any more (a
    # new router can: zenoh's listener takes a port its closed connections still wait on)
    mine = [
        p for p in psutil.process_iter(["cmdline"]) if str(out) in " ".join(p.info["cmdline"] or [])
    ]
    assert mine == []
    session, role = ros_side.open_ros_session(endpoint)
    session.close()
    assert role == ros_side.SERVING


def _key(endpoint: Endpoint) -> str:
    return keys.data_key(
        endpoint.node.domain_id, endpoint.topic, endpoint.type_name, endpoint.type_hash
    )
