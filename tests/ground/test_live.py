"""The live view (services.ground.monitoring.live): a Foxglove WebSocket client (the protocol's
``foxglove.sdk.v1``) against the server in one process, against ``ddvi run --live`` and
against ``ddvi monitor --live`` on a running mission; and the recording's timeline."""

from __future__ import annotations

import json
import re
import signal
import socket
import subprocess
import sys
import threading
import tomllib
from collections import Counter
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from mcap.reader import make_reader

from benchmarks.foxglove_client import SUBPROTOCOL, FoxgloveClient, Received
from services.cli import main as ddvi
from services.config import deployment_from_table, load_deployment
from services.ground.monitoring.live import (
    DEPLOYMENT_TOPIC,
    LIVE_GAINS_SCHEMA,
    LiveServer,
    live_gains_topic,
    reference_gains,
)
from services.ground.monitoring.live_address import LiveAddress, LiveError, parse_address
from services.ground.storage.recording import (
    ALIVE_SCHEMA,
    message_json_schema,
    ns,
    read_recording,
)
from services.interface import SCHEMAS, decode, encode
from tests.support import wait_until

ROOT = Path(__file__).resolve().parents[2]
SHORT = """
[run]
name = "live"
orbits = 1.5
command_deadline = 20.0
[[deputy]]
name = "lqr"
controller = "lqr"
[[deputy]]
name = "ddvi"
controller = "ddvi"
learning = { learn_at_orbits = 1.0, interval = 120.0, max_iterations = 20000 }
"""
SCENE_ESTIMATES = ("scene/lqr/estimate", "scene/ddvi/estimate")
# every topic of SHORT's topology (docs/interface.md) and the schema it carries
SERVICES = ["monitor", "nav-lqr", "ctrl-lqr", "nav-ddvi", "ctrl-ddvi", "environment", "launcher"]
TOPOLOGY_OF_SHORT = {
    "clock": "clock",
    "exo/state": "exo",
    **{f"truth/{c}": "truth" for c in ("chief", "lqr", "ddvi")},
    **{f"nav/{d}/state": "nav" for d in ("lqr", "ddvi")},
    **{f"cmd/{d}/att": "cmd" for d in ("lqr", "ddvi")},
    **{f"ctrl/{d}/gains": "gains" for d in ("lqr", "ddvi")},
    **{f"ctrl/{d}/status": "status" for d in ("lqr", "ddvi")},
    **{f"fault/{k}": "fault" for k in ("kill", "panel", "bias", "outage", "link")},
    **{f"stats/{s}": "stats" for s in SERVICES},
    **{f"log/{s}": "log" for s in SERVICES},
    "recorded": "recorded",
}


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def schema_of(channel: dict[str, Any]) -> dict[str, Any]:
    assert channel["encoding"] == "json" and channel["schemaEncoding"] == "jsonschema"
    return json.loads(channel["schema"])


def check_channels(advertised: dict[str, dict[str, Any]]) -> None:
    """Every topic of the topology advertised with the recording's schema; the others are
    the live view's gains against K*, the deployment, the 3D scene and each service's
    liveliness."""
    for topic, schema in TOPOLOGY_OF_SHORT.items():
        assert advertised[topic]["schemaName"] == f"ddvi.{schema}", topic
        assert schema_of(advertised[topic]) == message_json_schema(SCHEMAS[schema]), topic
    extra = {live_gains_topic(d): "ddvi.live_gains" for d in ("lqr", "ddvi")}
    extra |= {DEPLOYMENT_TOPIC: "ddvi.deployment"}
    extra |= {"scene/transforms": "foxglove.FrameTransforms"}
    extra |= {t: "foxglove.SceneUpdate" for t in ("scene/formation", *SCENE_ESTIMATES)}
    extra |= {f"alive/{s}": "ddvi.alive" for s in SERVICES if s != "launcher"}
    assert {t: c["schemaName"] for t, c in advertised.items() if t not in TOPOLOGY_OF_SHORT} == (
        extra
    )
    assert schema_of(advertised["live/ddvi/gains"]) == LIVE_GAINS_SCHEMA
    assert schema_of(advertised["alive/monitor"]) == ALIVE_SCHEMA


def check_times(messages: list[Received]) -> None:
    """Every bus message's time is its simulation time t (the recording's JSON); the live
    gains carry their gains message's, the deployment t = 0, and the scene the time of the
    step it draws (its own stamps: ``test_live_scene``)."""
    for m in messages:
        if m.topic == DEPLOYMENT_TOPIC:
            assert m.timestamp == 0
        elif not m.topic.startswith(("alive/", "scene/")):
            assert m.timestamp == ns(m.json()["t"]), m.topic


# ---- in one process -------------------------------------------------------------------------


def test_an_address_is_host_and_port_and_anything_else_says_what_to_give() -> None:
    assert parse_address("127.0.0.1:8765") == LiveAddress("127.0.0.1", 8765)
    assert parse_address("9000") == LiveAddress("127.0.0.1", 9000)
    assert parse_address("[::1]:9000").url == "ws://[::1]:9000"
    # the URL the live view says it serves on, pasted back
    assert parse_address("ws://127.0.0.1:8765") == LiveAddress("127.0.0.1", 8765)
    assert parse_address("WS://localhost:9000/") == LiveAddress("localhost", 9000)
    assert parse_address("ws://[::1]:9000").url == "ws://[::1]:9000"
    for bad in ("deployments/rendezvous.toml", "host:0", "host:70000", ":x", "ws://", "http://h:1"):
        with pytest.raises(LiveError, match="give HOST:PORT or ws://HOST:PORT"):
            parse_address(bad)


def test_live_without_foxglove_sdk_is_bad_input_naming_the_pip_command(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    monkeypatch.setitem(sys.modules, "foxglove", None)  # import foxglove raises ImportError
    assert ddvi(["run", "--live", "--output", str(tmp_path)]) == 2
    assert "pip install 'foxglove-sdk>=0.30'" in capsys.readouterr().err
    assert ddvi(["monitor", "--run", str(tmp_path), "--live"]) == 2
    assert "pip install 'foxglove-sdk>=0.30'" in capsys.readouterr().err
    assert not list(tmp_path.iterdir())  # no run was started


def test_live_on_a_port_in_use_is_bad_input(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        assert ddvi(["run", "--live", f"127.0.0.1:{port}", "--output", str(tmp_path)]) == 2
    assert f"--live 127.0.0.1:{port}: cannot listen there" in capsys.readouterr().err
    assert not list(tmp_path.iterdir())


def test_the_topics_of_a_run_are_the_topology_with_its_names() -> None:
    dep = load_deployment(str(ROOT / "deployments" / "rendezvous.toml"))
    assert dep.topics() == TOPOLOGY_OF_SHORT


def nav(t: float, seq: int = 0) -> Any:
    body = {
        "sc": "lqr",
        "x_hill": np.arange(6.0),
        "z_hill": np.arange(6.0),
        "cov": np.eye(6),
        "altitude": 3e5,
        "valid": True,
    }
    return decode(encode("nav", body, seq=seq, t=t, src="nav-lqr"), "nav")


def clock(t: float, src: str = "environment") -> Any:
    body = {"step": 1, "dt": 10.0, "fsw": True, "mode": "lockstep", "final": False}
    return decode(encode("clock", body, seq=0, t=t, src=src), "clock")


@pytest.fixture
def server() -> Iterator[tuple[LiveServer, str]]:
    port = free_port()
    nav_schema = ("ddvi.nav", message_json_schema(SCHEMAS["nav"]))
    clock_schema = ("ddvi.clock", message_json_schema(SCHEMAS["clock"]))
    live = LiveServer(
        LiveAddress("127.0.0.1", port),
        "test",
        {"nav/lqr/state": nav_schema, "clock": clock_schema},
        {},
    )
    try:
        yield live, f"ws://127.0.0.1:{port}"
    finally:
        live.close()


def test_the_server_sends_the_recordings_json_at_simulation_time(
    server: tuple[LiveServer, str],
) -> None:
    live, url = server
    live.message("nav/lqr/state", nav(5.0))  # nobody subscribed: not even encoded
    assert live.counters["served"] == 0
    client = FoxgloveClient(url, timeout=10)
    try:
        assert client.subprotocol == SUBPROTOCOL
        assert wait_until(lambda: "time" in client.info.get("capabilities", []))
        assert wait_until(lambda: live.subscribed("nav/lqr/state") and live.subscribed("clock"))
        live.message("clock", clock(20.0, src="nav-lqr"))  # not the time master: no time
        live.message("clock", clock(10.0))
        live.message("nav/lqr/state", nav(12.5, seq=3))
        assert wait_until(lambda: client.counts.get("nav/lqr/state") == 1)
        got = next(m for m in client.messages if m.topic == "nav/lqr/state")
        assert got.timestamp == ns(12.5)
        assert got.json() == {
            "schema": "nav",
            "version": 2,
            "seq": 3,
            "t": 12.5,
            "src": "nav-lqr",
            "boot": 0,
            "body": {
                "sc": "lqr",
                "x_hill": list(range(6)),
                "z_hill": list(range(6)),
                "cov": np.eye(6).tolist(),
                "altitude": 3e5,
                "valid": True,
            },
        }
        assert wait_until(lambda: client.times == [ns(10.0)])
        assert live.counters == {"served": 3, "errors": 0, "unserved": 0}
    finally:
        client.close()


def test_a_recorded_message_is_served_as_the_recording_wrote_it(
    server: tuple[LiveServer, str],
) -> None:
    """The monitor hands over the JSON it recorded: those bytes go out, not a new encoding."""
    live, url = server
    client = FoxgloveClient(url, timeout=10)
    try:
        assert wait_until(lambda: live.subscribed("nav/lqr/state"))
        recorded = b'{"schema":"nav","t":12.5,"as":"recorded"}'
        live.message("nav/lqr/state", nav(12.5, seq=3), recorded)
        live.message("nav/lqr/state", nav(13.0, seq=4))  # not recorded: encoded here
        assert wait_until(lambda: client.counts.get("nav/lqr/state") == 2)
        first, second = (m for m in client.messages if m.topic == "nav/lqr/state")
        assert first.payload == recorded and first.timestamp == ns(12.5)
        assert second.json()["seq"] == 4 and second.timestamp == ns(13.0)
    finally:
        client.close()


def test_a_topic_outside_the_advertised_ones_gets_its_channel_on_its_first_message(
    server: tuple[LiveServer, str],
) -> None:
    live, url = server
    client = FoxgloveClient(url, timeout=10)
    try:
        live.alive("nav-lqr", True, 30.0)  # advertised now: the client subscribes after
        assert wait_until(lambda: "alive/nav-lqr" in client.advertised())
        assert wait_until(lambda: live.subscribed("alive/nav-lqr"))
        live.alive("nav-lqr", False, 40.0)
        assert wait_until(lambda: client.counts.get("alive/nav-lqr") == 1)
        assert client.messages[-1].json() == {"service": "nav-lqr", "alive": False}
        assert client.messages[-1].timestamp == ns(40.0)
    finally:
        client.close()


@pytest.mark.integration  # 25 MB through a WebSocket: seconds
def test_a_client_that_stops_reading_never_holds_the_sender_up(
    server: tuple[LiveServer, str],
) -> None:
    """A client subscribed and then silent: its socket and its queue fill, its oldest
    messages are dropped, and every ``message`` call still returns (the monitor's loop goes
    on); a client connecting after is served."""
    import threading

    from websockets.sync.client import connect

    live, url = server
    with connect(url, subprotocols=[SUBPROTOCOL], max_queue=1) as stalled:  # type: ignore[list-item]
        advertise = json.loads(stalled.recv())
        while advertise["op"] != "advertise":
            advertise = json.loads(stalled.recv())
        subs = [{"id": c["id"], "channelId": c["id"]} for c in advertise["channels"]]
        stalled.send(json.dumps({"op": "subscribe", "subscriptions": subs}))
        assert wait_until(lambda: live.subscribed("nav/lqr/state"))
        many = [nav(10.0 * k, seq=k) for k in range(30_000)]  # ~25 MB of JSON, never read
        sender = threading.Thread(target=lambda: [live.message("nav/lqr/state", m) for m in many])
        sender.start()
        sender.join(timeout=120)  # a safety net, not a speed figure: blocked, it never ends
        assert not sender.is_alive()
        assert live.counters["served"] == 30_000 and live.counters["errors"] == 0
        fresh = FoxgloveClient(url, timeout=10)
        try:

            def served() -> bool:  # a clock each poll: the first ones may precede its subscription
                live.message("clock", clock(1.0))
                return fresh.counts.get("clock", 0) > 0

            assert wait_until(served)
        finally:
            fresh.close()


# ---- a run ----------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def live_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, FoxgloveClient, float]:
    """A short mission through ``ddvi run --live`` watched by one client from the start; its
    folder, the client (closed) and its simulated duration."""
    tmp = tmp_path_factory.mktemp("live")
    (tmp / "short.toml").write_text(SHORT)
    port = free_port()
    cmd = [
        sys.executable,
        "-m",
        "services.cli",
        "run",
        str(tmp / "short.toml"),
        "--output",
        str(tmp / "runs"),
        "--live",
        f"127.0.0.1:{port}",
    ]
    run = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    client = FoxgloveClient(f"ws://127.0.0.1:{port}", timeout=60)
    out, err = run.communicate(timeout=300)
    assert run.returncode == 0, err[-3000:]
    assert client.wait_closed(30)  # the monitor stopped serving
    folder = Path(out.strip().splitlines()[-1])
    summary = json.loads((folder / "summary.json").read_text())
    return folder, client, summary["sim_time_s"]


@pytest.mark.integration
def test_ddvi_run_live_serves_every_topic_at_simulation_time(
    live_run: tuple[Path, FoxgloveClient, float],
) -> None:
    folder, client, sim_time = live_run
    check_channels(client.advertised())
    check_times(client.messages)
    # at least one message of every topic the recording has, each decoding as it does there
    recorded, _ = read_recording(folder / "recording.mcap")
    served = {m.topic for m in client.messages}
    recorded_topics = {r.topic for r in recorded if r.topic != "alive/monitor"}
    assert recorded_topics <= served, recorded_topics - served
    first = {m.topic: m.json() for m in reversed(client.messages) if m.topic in recorded_topics}
    for r in recorded:
        if not r.topic.startswith("alive/") and r.data["seq"] == first[r.topic]["seq"]:
            assert r.data == first[r.topic]

    # the flown gains against K* (solved beside the server: known by the end)
    def last(topic: str) -> Any:
        return next(m.json() for m in reversed(client.messages) if m.topic == topic)

    K_star, L_star = reference_gains(deployment_from_table(tomllib.loads(SHORT)))["ddvi"]
    flown = last("ctrl/ddvi/gains")
    assert last("live/ddvi/gains") == {
        "sc": "ddvi",
        "t": flown["t"],
        "source": flown["body"]["source"],
        "K": flown["body"]["K"][0],
        "L": flown["body"]["L"][0],
        "K_star": K_star,
        "L_star": L_star,
    }
    assert len(K_star) == 4 and len(L_star) == 5
    # the server's clock: the environment's simulation time, from the step the client joined
    # at (the mission waits for no viewer: on a loaded machine it may fly before the client is
    # in) to the end of the mission
    assert client.times == sorted(client.times) and 0 <= client.times[0] < ns(sim_time)
    assert client.times[-1] == ns(sim_time)


@pytest.mark.integration
def test_a_recordings_timeline_spans_the_simulated_mission(
    live_run: tuple[Path, FoxgloveClient, float],
) -> None:
    folder, _, sim_time = live_run
    with (folder / "recording.mcap").open("rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None and summary.statistics is not None
    stats = summary.statistics
    assert (stats.message_start_time, stats.message_end_time) == (0, ns(sim_time))
    recorded, _ = read_recording(folder / "recording.mcap")
    for r in recorded:  # a message's own t; the receive wall time beside it
        if not r.topic.startswith(("alive/", "rejected/")):
            assert r.log_time == ns(r.data["t"])
        assert r.publish_time > 1.6e18
    # the report's wall time is still the receive wall time's span
    wall = (max(r.publish_time for r in recorded) - min(r.publish_time for r in recorded)) / 1e9
    report = json.loads((folder / "summary.json").read_text())
    assert 0 < report["wall_s"] <= wall < sim_time


@pytest.mark.integration
def test_ddvi_monitor_live_serves_a_running_mission(tmp_path: Path) -> None:
    (tmp_path / "short.toml").write_text(SHORT)
    cmd = [
        sys.executable,
        "-m",
        "services.cli",
        "run",
        str(tmp_path / "short.toml"),
        "--output",
        str(tmp_path / "runs"),
    ]
    run = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    tap = None
    try:
        assert run.stderr is not None
        folder = None
        for line in run.stderr:  # "ddvi run: run NAME, output FOLDER, hub ..."
            if (found := re.search(r"output (\S+), hub", line)) is not None:
                folder = found.group(1)
                break
        assert folder is not None
        port = free_port()
        tap = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "services.cli",
                "monitor",
                "--run",
                folder,
                "--live",
                f"127.0.0.1:{port}",
            ],
            stderr=(tmp_path / "tap.err").open("w"),
            text=True,
            # as a script's `ddvi monitor ... &` starts it: SIGINT ignored; Ctrl-C still stops it
            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_IGN),
        )
        client = FoxgloveClient(f"ws://127.0.0.1:{port}", timeout=60)
        ended: dict[str, str] = {}
        drain = threading.Thread(target=lambda: ended.update(err=run.communicate(timeout=300)[1]))
        drain.start()  # the run's pipes read while it flies
        # the final clock served: the tap heard the mission to its end; it is stopped while
        # the run's router is still there (the report is being written)
        assert wait_until(lambda: _final_clock_served(client), timeout=300)
        tap.send_signal(signal.SIGINT)
        try:
            assert tap.wait(timeout=30) == 0
        except subprocess.TimeoutExpired:  # say what the tap said, and how it took signals
            status = Path(f"/proc/{tap.pid}/status").read_text()
            sig = [line for line in status.splitlines() if line.startswith("Sig")]
            raise AssertionError((tmp_path / "tap.err").read_text()[-3000:] + str(sig)) from None
        assert client.wait_closed(30)
        drain.join(300)
        assert run.returncode == 0, ended.get("err", "")[-3000:]
    finally:
        for proc in (run, tap):
            if proc is not None and proc.poll() is None:
                proc.kill()
                proc.wait()
    check_channels(client.advertised())
    check_times(client.messages)
    # every topic the recording has twice or more after the client's first message, served
    # too (a topic said once, as the LQR's gains, may come before the client subscribed to
    # it); but the monitor's own final stats, which follow the final clock the tap stopped on
    recorded, _ = read_recording(Path(folder) / "recording.mcap")
    start = min(m.timestamp for m in client.messages)
    after = Counter(
        r.topic for r in recorded if r.log_time > start and not r.topic.startswith("alive/")
    )
    heard = {topic for topic, n in after.items() if n >= 2}
    assert heard - {"stats/monitor"} <= set(client.counts)
    # each service's liveliness, up when the tap started: sent to the client as it joined
    alive = [
        m.json() for m in client.messages if m.topic.startswith("alive/") and m.json()["alive"]
    ]
    assert {a["service"] for a in alive} >= {s for s in SERVICES if s != "launcher"}


def _final_clock_served(client: FoxgloveClient) -> bool:
    clocks = [m for m in list(client.messages) if m.topic == "clock"]
    return bool(clocks) and clocks[-1].json()["body"]["final"]


# ---- the layout -----------------------------------------------------------------------------


def layout_paths(node: Any) -> Iterator[str]:
    """Every message path of a Foxglove layout's panel configurations."""
    if isinstance(node, dict):
        for key, value in node.items():
            if key in ("value", "topicPath") and isinstance(value, str):
                yield value
            else:
                yield from layout_paths(value)
    elif isinstance(node, list):
        for item in node:
            yield from layout_paths(item)


def resolve(schema: dict[str, Any], path: str) -> dict[str, Any]:
    """The JSON schema of the field ``path`` (``a.b[2].c``) names; KeyError when it names none."""
    for part in path.split("."):
        name, _, index = part.partition("[")
        schema = schema["properties"][name]
        if index:
            i = int(index.rstrip("]"))
            assert schema["type"] == "array" and i < schema.get("maxItems", i + 1), path
            schema = schema["items"]
    return schema


def test_the_layout_plots_fields_the_live_view_serves() -> None:
    """Each path of docs/foxglove-layout.json names a topic the default mission serves and a
    number, string or boolean field of its schema; each panel it places is configured."""
    layout = json.loads((ROOT / "docs" / "foxglove-layout.json").read_text())
    dep = load_deployment(str(ROOT / "deployments" / "rendezvous.toml"))
    schemas = {t: message_json_schema(SCHEMAS[s]) for t, s in dep.topics().items()}
    schemas |= {live_gains_topic(d.name): LIVE_GAINS_SCHEMA for d in dep.deputy}
    schemas |= {f"alive/{s}": ALIVE_SCHEMA for s in dep.services}
    paths = list(layout_paths(layout["configById"]))
    assert len(paths) >= 20
    for path in paths:
        topic, _, fields = path.partition(".")
        leaf = resolve(schemas[topic], fields)
        assert leaf["type"] in ("number", "string", "boolean", "object"), path
    served = {p.partition(".")[0] for p in paths}
    for d in dep.deputy:  # along-track, Hill x-y, attitude and status of each deputy
        assert {f"nav/{d.name}/state", f"cmd/{d.name}/att", f"ctrl/{d.name}/status"} <= served
    assert {"live/ddvi/gains"} | {f"alive/{s}" for s in dep.services} <= served

    def placed(node: Any) -> Iterator[str]:
        if isinstance(node, str):
            yield node
        elif isinstance(node, dict):
            yield from placed(node.get("first"))
            yield from placed(node.get("second"))

    assert sorted(placed(layout["layout"])) == sorted(layout["configById"])
