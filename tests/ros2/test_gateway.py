"""The ROS 2 gateway's parts in one process: the topics a deployment asks for, what each bus
message becomes on them (decoded back with this package's inverses), the services' health as
diagnostics, and its ROS 2 side on real Zenoh sessions (joined or served, its tokens, GIDs and
attachments read back by a plain Zenoh session)."""

from __future__ import annotations

import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from services.cli import main as ddvi
from services.config import DeploymentError, deployment_from_table
from services.flight.inprocess import run_in_process
from services.interface import Message, decode, encode
from services.model import initial_states, navigation_state, reference_gains
from services.ros2 import conversions as cv
from services.ros2 import keys, messages
from services.ros2.gateway import ros_side
from services.ros2.gateway.commands import REASONS, CommandIntake
from services.ros2.gateway.exposure import NODE_NAME, Translator, ros_topics
from services.ros2.gateway.health import Health
from services.ros2.gateway.service import bus_inputs
from services.ros2.keys import EntityKind, Node, QoS
from tests.ros2.samples import zenoh_router
from tests.support import wait_until

TABLE: dict[str, Any] = {
    "run": {"name": "gw", "orbits": 1.0},
    "deputy": [{"name": "lqr", "controller": "lqr"}, {"name": "ddvi", "controller": "ddvi"}],
    "ros2": {"enabled": True},
}


def _dep(**ros2: Any) -> Any:
    return deployment_from_table({**TABLE, "ros2": {"enabled": True, **ros2}})


def _message(schema: str, body: dict[str, Any], t: float, src: str) -> Message:
    """A bus message as a receiver has it (encoded and decoded: arrays as numpy)."""
    return decode(encode(schema, body, seq=0, t=t, src=src))


def _everyone(_topic: str) -> bool:
    return True


# ---- the topics ---------------------------------------------------------------------------


def test_every_topic_of_the_table_and_only_those() -> None:
    dep = _dep()
    names = {t.name: t.ros_type for t in ros_topics(dep, {"lqr": True, "ddvi": True})}
    expected = {"/clock": messages.CLOCK, "/diagnostics": messages.DIAGNOSTICS, "/tf": messages.TF}
    for sc in ("lqr", "ddvi"):
        expected |= {
            f"/{sc}/odom": messages.ODOMETRY,
            f"/{sc}/altitude": messages.ALTITUDE,
            f"/{sc}/truth/odom": messages.ODOMETRY,
            f"/{sc}/commanded_attitude": messages.ATTITUDE_COMMAND,
            **{
                f"/{sc}/gains/{g}": messages.GAINS
                for g in ("feedback", "feedforward", "optimal_feedback", "optimal_feedforward")
            },
        }
    assert names == expected
    for topic in names:  # every one a valid ROS 2 name
        assert keys.fully_qualified_name(topic) == topic
    assert [t.qos for t in ros_topics(dep) if t.name == "/tf"] == [QoS(depth=100)]

    only = _dep(topics=["clock", "odom"])
    assert [t.name for t in ros_topics(only)] == ["/clock", "/lqr/odom", "/ddvi/odom"]
    kinds = {t.kind for t in ros_topics(only)}
    assert {i.topic for i in bus_inputs(kinds) if hasattr(i, "topic")} == {"clock", "nav/*/state"}
    # no K* where the truth has none: its topics are not announced
    assert not any("optimal" in t.name for t in ros_topics(dep, {"lqr": False}))


def test_the_gateway_is_a_service_of_the_run_only_when_enabled() -> None:
    on, off = _dep(), deployment_from_table({**TABLE, "ros2": {}})
    assert "ros2-gateway" in on.services and on.services[-1] == "environment"
    assert off.services == [
        "monitor",
        "nav-lqr",
        "ctrl-lqr",
        "nav-ddvi",
        "ctrl-ddvi",
        "environment",
    ]
    assert off.ros2.endpoint == "tcp/127.0.0.1:7447" and off.ros2.domain_id == 0


# ---- what bus messages become -------------------------------------------------------------


def test_navigation_becomes_odometry_and_altitude_equal_to_the_bus_message() -> None:
    dep = _dep()
    x = np.array([-12.5, -29000.25, 3.25, 0.0125, -0.031, 0.0042])
    cov = np.diag([4.0, 9.0, 1.0, 1e-4, 2e-4, 5e-5])
    body = {"sc": "lqr", "x_hill": x, "z_hill": x, "cov": cov, "altitude": 3e5, "valid": True}
    (topic, odometry), (where, altitude) = Translator(dep, _everyone).translate(
        _message("nav", body, 5430.0, "nav-lqr")
    )
    assert (topic, where) == ("/lqr/odom", "/lqr/altitude")
    assert cv.altitude_from_message(altitude) == 3e5 and altitude.header.stamp.sec == 5430
    back = messages.deserialize(messages.serialize(odometry, messages.ODOMETRY), messages.ODOMETRY)
    assert back.header.frame_id == "chief_hill" and back.child_frame_id == "lqr/base_link"
    assert cv.seconds_from_time(back.header.stamp.sec, back.header.stamp.nanosec) == 5430.0
    assert np.array_equal(cv.hill_state_from_odometry(back), x)
    assert np.array_equal(np.reshape(back.pose.covariance, (6, 6))[:3, :3], cov[:3, :3])
    assert np.array_equal(np.reshape(back.twist.covariance, (6, 6))[:3, :3], cov[3:, 3:])


def test_clock_command_and_gains_become_their_ros_messages() -> None:
    dep = _dep()
    translate = Translator(dep, _everyone).translate
    clock = {"step": 6, "dt": 10.0, "fsw": True, "mode": "lockstep", "final": False}
    ((topic, msg),) = translate(_message("clock", clock, 60.0, "environment"))
    assert topic == "/clock" and (msg.clock.sec, msg.clock.nanosec) == (60, 0)

    sigma = np.array([0.0, 0.0, -0.15])
    cmd = {"sc": "ddvi", "sigma": sigma, "for_t": 120.0}
    ((topic, msg),) = translate(_message("cmd", cmd, 120.0, "ctrl-ddvi"))
    assert topic == "/ddvi/commanded_attitude" and msg.header.frame_id == "ddvi/hill"
    assert np.allclose(cv.attitude_command_mrp(msg), sigma, rtol=0, atol=1e-15)

    K, L = np.array([[1e-3, -2e-4, 3.0, -40.0]]), np.array([[0.1, 0.2, 0.3, 0.4, 0.5]])
    gains = {"sc": "lqr", "K": K, "L": L, "source": "lqr", "iteration": 0, "converged": True}
    out = dict(translate(_message("gains", gains, 0.0, "ctrl-lqr")))
    assert np.array_equal(cv.gains_from_message(out["/lqr/gains/feedback"]), K)
    assert np.array_equal(cv.gains_from_message(out["/lqr/gains/feedforward"]), L)
    K_star, L_star = reference_gains(dep, dep.deputy[0])
    assert np.array_equal(cv.gains_from_message(out["/lqr/gains/optimal_feedback"]), K_star)
    assert np.array_equal(cv.gains_from_message(out["/lqr/gains/optimal_feedforward"]), L_star)
    assert [d.label for d in out["/lqr/gains/feedforward"].layout.dim] == ["input", "exostate"]


def test_one_times_truths_become_true_odometry_and_frames() -> None:
    dep = _dep()
    translator = Translator(dep, _everyone)
    X = initial_states(dep)
    sigmas = {"chief": np.zeros(3), "lqr": np.array([0.0, 0.0, 0.1]), "ddvi": np.zeros(3)}
    out: list[Any] = []
    for i, craft in enumerate(("lqr", "chief", "ddvi")):  # any order: paired by time
        index = {"chief": 0, "lqr": 1, "ddvi": 2}[craft]
        body = {"sc": craft, "r_N": X[index, :3], "v_N": X[index, 3:], "sigma_BN": sigmas[craft]}
        out += translator.translate(_message("truth", body, 0.0, "environment"))
        assert (out == []) == (i < 2)  # nothing until every craft of that time is in
    by_topic = dict(out)
    truth = by_topic["/lqr/truth/odom"]
    expected = navigation_state(dep, dep.deputy[0], X[0], X[1])
    assert np.allclose(cv.hill_state_from_odometry(truth), expected, rtol=1e-14, atol=1e-12)
    frames = {(f.header.frame_id, f.child_frame_id) for f in by_topic["/tf"].transforms}
    assert frames == {
        (p, c) for sc in ("lqr", "ddvi") for p, c in [("chief_hill", f"{sc}/base_link")]
    } | {("chief_hill", f"{sc}/hill") for sc in ("lqr", "ddvi")}


def test_nothing_is_built_for_a_topic_nobody_reads() -> None:
    dep = _dep()
    translator = Translator(dep, lambda topic: topic == "/lqr/odom")
    x = np.zeros(6)
    nav = {"sc": "ddvi", "x_hill": x, "z_hill": x, "cov": np.eye(6), "altitude": 3e5, "valid": True}
    assert translator.translate(_message("nav", nav, 10.0, "nav-ddvi")) == []
    clock = {"step": 1, "dt": 10.0, "fsw": False, "mode": "lockstep", "final": False}
    assert translator.translate(_message("clock", clock, 10.0, "environment")) == []


def test_a_message_with_no_ros_form_is_a_value_error() -> None:
    dep = _dep()
    translate = Translator(dep, _everyone).translate
    with pytest.raises(ValueError, match="simulation time"):  # ROS time starts at 0
        translate(_message("cmd", {"sc": "lqr", "sigma": np.zeros(3), "for_t": -60.0}, 0.0, "x"))
    x = np.zeros(6)
    nav = {"sc": "evil", "x_hill": x, "z_hill": x, "cov": np.eye(6), "altitude": 3e5, "valid": True}
    with pytest.raises(ValueError, match="no deputy 'evil'"):
        translate(_message("nav", nav, 0.0, "nav-evil"))


# ---- health -------------------------------------------------------------------------------


def test_health_is_each_services_liveliness_log_and_counters() -> None:
    health = Health(["monitor", "nav-lqr", "ctrl-lqr", "environment"])
    by_name = {s.name: s for s in health.statuses()}
    assert {s.level for s in by_name.values()} == {cv.Level.STALE}  # nobody alive yet
    for service in ("monitor", "nav-lqr", "ctrl-lqr", "environment"):
        health.presence(service, True)
    assert not health.presence("intruder", True)  # not one of the run's
    status = {
        "sc": "lqr",
        "mode": "lqr",
        "phase": "lqr",
        "samples": 0,
        "intervals": 0,
        "rank": 0,
        "rank_needed": 0,
        "counters": {},
    }
    assert health.take(_message("status", status, 600.0, "ctrl-lqr"))
    stats = {"service": "nav-lqr", "counters": {"published": 60}}
    assert health.take(_message("stats", stats, 600.0, "nav-lqr"))
    warning = {"service": "environment", "level": "warning", "text": "lock-step paused"}
    assert health.take(_message("log", warning, 600.0, "environment"))
    by_name = {s.name: s for s in health.statuses()}
    assert by_name["ddvi/ctrl-lqr"].level == cv.Level.OK
    assert by_name["ddvi/ctrl-lqr"].message == "lqr, lqr"
    assert by_name["ddvi/ctrl-lqr"].hardware_id == "lqr"
    assert ("published", "60") in by_name["ddvi/nav-lqr"].values
    assert (by_name["ddvi/environment"].level, by_name["ddvi/environment"].message) == (
        cv.Level.WARN,
        "lock-step paused",
    )
    health.presence("nav-lqr", False)  # gone during the mission
    assert {s.name: s.level for s in health.statuses()}["ddvi/nav-lqr"] == cv.Level.STALE
    health.final = True  # gone after the final clock: finished
    finished = {s.name: s for s in health.statuses()}["ddvi/nav-lqr"]
    assert (finished.level, finished.message) == (cv.Level.OK, "finished")
    # the array ROS 2 gets decodes back to the same statuses
    array = cv.diagnostic_array(600.0, health.statuses())
    wire = messages.serialize(array, messages.DIAGNOSTICS)
    back = messages.deserialize(wire, messages.DIAGNOSTICS)
    assert cv.statuses_from_diagnostics(back) == health.statuses()


# ---- the ROS 2 side -----------------------------------------------------------------------


def _tokens(session: Any, domain: int) -> list[Any]:
    """The rmw_zenoh liveliness tokens of ``domain`` that ``session`` sees, parsed."""
    return [
        keys.parse_token(str(reply.ok.key_expr))
        for reply in session.liveliness().get(keys.liveliness_pattern(domain), timeout=1.0)
        if reply.ok is not None
    ]


def test_the_side_serves_an_endpoint_nobody_serves_and_joins_one_a_router_serves(
    free_port: int,
) -> None:
    endpoint = f"tcp/127.0.0.1:{free_port}"
    session, role = ros_side.open_ros_session(endpoint)
    try:
        assert role == ros_side.SERVING
        joined, again = ros_side.open_ros_session(endpoint)  # a second finds the first
        joined.close()
        assert again == ros_side.JOINED
    finally:
        session.close()


def test_an_endpoint_taken_by_no_zenoh_router_is_one_line(free_port: int) -> None:
    import socket

    with socket.socket() as taken:
        taken.bind(("127.0.0.1", free_port))
        taken.listen()
        with pytest.raises(ros_side.RosSideError, match="give another endpoint"):
            ros_side.open_ros_session(f"tcp/127.0.0.1:{free_port}")


def test_node_and_publishers_are_announced_and_every_sample_carries_rmw_zenohs_attachment(
    free_port: int,
) -> None:
    router = zenoh_router(free_port)  # the user's rmw_zenohd
    received: list[Any] = []
    try:
        with ros_side.ros_node(f"tcp/127.0.0.1:{free_port}", 7, NODE_NAME) as (node, role):
            assert role == ros_side.JOINED
            publisher = node.publisher("/lqr/odom", messages.ODOMETRY, QoS(depth=10))
            tokens: list[Any] = []

            def announced() -> bool:
                tokens[:] = _tokens(router, 7)
                return len(tokens) == 2

            assert wait_until(announced)  # a token takes a moment to reach the router
            (found_node,) = [t for t in tokens if isinstance(t, Node)]
            (found,) = [t for t in tokens if not isinstance(t, Node)]
            assert found_node.name == NODE_NAME and found_node.zid == node.node.zid
            assert found.kind is EntityKind.PUBLISHER and found.topic == "/lqr/odom"
            assert found.type_hash == messages.type_hash(messages.ODOMETRY)
            assert keys.entity_gid(keys.endpoint_token(found)) == publisher.gid
            assert not publisher.wanted  # nobody reads it yet
            subscriber = router.declare_subscriber(publisher.key, received.append)
            assert wait_until(lambda: publisher.wanted)
            odometry = cv.odometry_message(10.0, "lqr", np.arange(6.0))
            for _ in range(2):
                publisher.publish(odometry)
            assert wait_until(lambda: len(received) == 2)
            subscriber.undeclare()
            assert wait_until(lambda: not publisher.wanted)
        # closed: no token of the node is left
        assert wait_until(lambda: _tokens(router, 7) == [])
    finally:
        router.close()
    now = time.time_ns()
    for number, sample in enumerate(received, start=1):
        attachment = keys.decode_attachment(sample.attachment.to_bytes())
        assert attachment.sequence_number == number and attachment.source_gid == publisher.gid
        assert 0 < now - attachment.source_timestamp < 60e9
        decoded = messages.deserialize(sample.payload.to_bytes(), messages.ODOMETRY)
        assert np.array_equal(cv.hill_state_from_odometry(decoded), np.arange(6.0))


# ---- the command --------------------------------------------------------------------------


def test_ros2_without_its_packages_is_bad_input_naming_the_pip_command(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    monkeypatch.setitem(sys.modules, "rosbags", None)  # import rosbags raises ImportError
    assert ddvi(["run", "--ros2", "--output", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "pip install 'ddvi-fsw[ros2]'" in err
    assert not list(tmp_path.iterdir())  # no run was started


def test_ros2_beyond_loopback_is_said(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    from services.ground.launch import launcher

    monkeypatch.setattr(launcher.Launcher, "execute", lambda self: 0)  # start nothing
    assert ddvi(["run", "--ros2", "tcp/0.0.0.0:7447", "--output", str(tmp_path)]) == 0
    assert "reaches beyond this machine" in capsys.readouterr().err
    assert ddvi(["run", "--ros2", "--output", str(tmp_path)]) == 0
    assert "beyond" not in capsys.readouterr().err


# ---- a deputy flown from ROS 2 ------------------------------------------------------------

FLOWN: dict[str, Any] = {
    **TABLE,
    "deputy": [{"name": "lqr", "controller": "lqr"}, {"name": "rosd", "controller": "ros2"}],
}


def test_a_deputy_flown_from_ros2_has_the_gateway_for_its_controller() -> None:
    dep = deployment_from_table(FLOWN)
    assert dep.services == [
        "monitor",
        "nav-lqr",
        "ctrl-lqr",
        "nav-rosd",
        "ros2-gateway",
        "environment",
    ]
    assert (dep.commander("rosd"), dep.commander("lqr")) == ("ros2-gateway", "ctrl-lqr")
    assert dep.publisher_of("cmd/rosd/att") == "ros2-gateway"
    assert dep.publisher_of("cmd/lqr/att") == "ctrl-lqr"
    assert dep.publisher_of("nav/rosd/state") == "nav-rosd"
    assert dep.deputy[1].label == "ros2"
    names = {t.name for t in ros_topics(dep) if t.deputy == "rosd"}
    assert names == {f"/rosd/{t}" for t in ("odom", "altitude", "truth/odom", "commanded_attitude")}
    with pytest.raises(DeploymentError, match=r"deputy\[1\].controller: 'ros2' .* --ros2"):
        deployment_from_table({**FLOWN, "ros2": {}})
    with pytest.raises(DeploymentError, match="the one-process executor has no ROS 2 node"):
        run_in_process(dep)


class _Node:
    """What the command intake uses of a RosNode: its announcements and its listener."""

    def __init__(self) -> None:
        self.node = Node(42, "aac3178e146ba6f1fc6e6a4085e77f21", 0, NODE_NAME)
        self.announced: list[str] = []
        self.listening: list[str] = []

    def subscription(self, topic: str, ros_type: str, qos: QoS) -> None:
        self.announced.append(topic)

    def listen(self, key_expr: str, handler: Any) -> None:
        self.listening.append(key_expr)


class _Sample:
    def __init__(self, key: str, payload: bytes, attachment: bytes | None) -> None:
        self.key_expr, self.payload = key, _Bytes(payload)
        self.attachment = None if attachment is None else _Bytes(attachment)


class _Bytes:
    def __init__(self, data: bytes) -> None:
        self.data = data

    def to_bytes(self) -> bytes:
        return self.data


def _command(sc: str, t: float, sigma3: float = 0.1, frame: str = "") -> bytes:
    message = cv.attitude_command(t, sc, [0.0, 0.0, sigma3])
    if frame:
        message.header.frame_id = frame
    return messages.serialize(message, messages.ATTITUDE_COMMAND)


def test_commands_from_ros2_reach_the_bus_only_when_every_check_passes() -> None:
    dep = deployment_from_table(FLOWN)
    node, put, said = _Node(), [], []
    intake = CommandIntake(dep, node, lambda *a: put.append(a), said.append)
    assert node.announced == ["/rosd/cmd_attitude"]
    assert node.listening == [
        "42/*/cmd_attitude/geometry_msgs::msg::dds_::QuaternionStamped_/"
        + messages.type_hash(messages.ATTITUDE_COMMAND)
    ]
    gid = bytes(range(16))
    attachment = keys.encode_attachment(keys.Attachment(1, time.time_ns(), gid))

    def on(sc: str, payload: bytes, with_attachment: bool = True) -> None:
        key = f"42/{sc}/cmd_attitude/QuaternionStamped_/RIHS01_{'0' * 64}"
        intake.on_sample(_Sample(key, payload, attachment if with_attachment else None))

    intake.carried(60.0)  # the gateway has carried the mission to t = 60 s
    on("rosd", _command("rosd", 0.0))
    on("rosd", _command("rosd", 60.0, -0.05))
    ((sc, sigma, t), (_, sigma60, t60)) = put
    assert (sc, t, t60) == ("rosd", 0.0, 60.0)
    assert np.allclose(sigma, [0.0, 0.0, 0.1], atol=1e-15)
    assert np.allclose(sigma60, [0.0, 0.0, -0.05], atol=1e-15)
    bad = {
        "not_ros2": ("lqr", _command("lqr", 60.0)),
        "malformed": ("rosd", b"\x00\x01\x00\x00garbage"),
        "frame": ("rosd", _command("rosd", 120.0, frame="chief_hill")),
        "step": ("rosd", _command("rosd", 65.0)),
        "ahead": ("rosd", _command("rosd", 120.0)),
        "repeated": ("rosd", _command("rosd", 60.0)),
    }
    for sc, payload in bad.values():
        on(sc, payload)
    on("rosd", _command("rosd", 0.0), with_attachment=False)  # an earlier step: repeated too
    zero = cv.attitude_command(120.0, "rosd", np.zeros(3))
    zero.quaternion.w = 0.0
    intake.carried(120.0)
    on("rosd", messages.serialize(zero, messages.ATTITUDE_COMMAND))
    assert len(put) == 2  # nothing more reached the bus
    counters = intake.stats()
    assert counters["commands"] == 2 and counters["commands_refused"] == 8
    assert {r: counters[f"commands_refused.{r}"] for r in REASONS} == {
        **dict.fromkeys(REASONS, 1),
        "repeated": 2,
    }
    named = "GID 00.01.02.03.04.05.06.07.08.09.0a.0b.0c.0d.0e.0f"
    assert said[0] == (
        f"refused a command on /lqr/cmd_attitude from {named}: lqr is not flown from ROS 2 "
        "(flown: ['rosd']) (not_ros2 #1)"
    )
    assert all(line.startswith("refused a command on /") for line in said) and len(said) == 8
    assert "from a publisher without rmw_zenoh's attachment" in said[6]
    assert "is no rotation" in said[7]
