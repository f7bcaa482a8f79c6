"""A client that joins a watchable mission late: ``ddvi run --live --rate 3000`` joined 15 s after
launch by a client of Foxglove's WebSocket protocol (``benchmarks.foxglove_client``, written from
the protocol's specification, not from the server's code) still sees the mission flying, is
sent who is alive and the learner's K* within 3 s of subscribing, and decodes the 3D scene
with the schemas of Foxglove's SDK."""

from __future__ import annotations

import base64
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest

from benchmarks.foxglove_client import FoxgloveClient, Received
from services.config import load_deployment
from services.ground.monitoring.scene import FORMATION_TOPIC, TRANSFORMS_TOPIC
from tests.ground.test_live import free_port
from tests.ground.test_live_scene import protobuf_class
from tests.support import wait_until

foxglove = pytest.importorskip("foxglove")
from foxglove import messages as fm  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
JOIN_AFTER = 15.0  # s after launch: the point of the test
PROMPT = 3.0  # s after subscribing by which the state must have come


def _first(client: FoxgloveClient, topic: str) -> Received | None:
    return next((m for m in list(client.messages) if m.topic == topic), None)


def _decode(client: FoxgloveClient, topic: str) -> Any:
    """``topic``'s first message, decoded as Foxglove would: by the schema its channel
    advertises, which must be the SDK's."""
    advert = client.advertised()[topic]
    assert advert["schemaEncoding"] == "protobuf" and advert["encoding"] == "protobuf"
    data = base64.b64decode(advert["schema"])
    kind = getattr(fm, advert["schemaName"].removeprefix("foxglove."))
    assert data == kind.get_schema().data
    message = _first(client, topic)
    assert message is not None
    return protobuf_class(advert["schemaName"], data).FromString(message.payload)


@pytest.mark.integration
def test_a_client_joining_a_paced_mission_late_sees_it_fly_with_its_state(
    tmp_path: Path,
) -> None:
    dep = load_deployment(str(ROOT / "deployments" / "rendezvous.toml"))
    flight = [s for s in dep.services if s != "monitor"]
    learner = next(d.name for d in dep.deputy if d.controller != "lqr")
    port = free_port()
    cmd = [sys.executable, "-m", "services.cli", "run", "--output", str(tmp_path)]
    cmd += ["--live", f"127.0.0.1:{port}", "--rate", "3000"]
    launched = time.monotonic()
    run = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    client = None
    try:
        time.sleep(JOIN_AFTER)
        assert run.poll() is None
        client = FoxgloveClient(f"ws://127.0.0.1:{port}", timeout=10)
        assert wait_until(lambda: "clock" in client.subscribed, timeout=10)
        joined = client.subscribed["clock"]
        assert joined - launched >= JOIN_AFTER

        def state_came() -> bool:
            alive = all(_first(client, f"alive/{s}") is not None for s in flight)
            gains = _first(client, f"live/{learner}/gains")
            return alive and gains is not None and bool(gains.json()["K_star"])

        assert wait_until(state_came, timeout=PROMPT + 2.0)
        for s in flight:  # one latched liveliness message each, within 3 s of subscribing
            said = _first(client, f"alive/{s}")
            assert said is not None and said.json() == {"service": s, "alive": True}
            assert said.at - client.subscribed[f"alive/{s}"] <= PROMPT
        gains = _first(client, f"live/{learner}/gains")
        assert gains is not None and gains.at - client.subscribed[gains.topic] <= PROMPT
        assert len(gains.json()["K_star"]) == 4 and len(gains.json()["L_star"]) == 5

        # the mission still flying: the first clock well before its end, and more after it
        assert wait_until(lambda: client.counts.get("clock", 0) >= 2, timeout=10)
        clocks = [m.json() for m in list(client.messages) if m.topic == "clock"]
        assert clocks[0]["t"] < 120_000 and not clocks[0]["body"]["final"]
        assert clocks[-1]["t"] > clocks[0]["t"]

        # the 3D scene, decoded with the SDK's schemas
        assert wait_until(lambda: FORMATION_TOPIC in client.counts, timeout=10)
        assert wait_until(lambda: TRANSFORMS_TOPIC in client.counts, timeout=10)
        update = _decode(client, FORMATION_TOPIC)
        ids = {e.id for e in update.entities}
        assert {"chief", *(f"body/{d.name}" for d in dep.deputy)} <= ids
        frames = _decode(client, TRANSFORMS_TOPIC)
        assert [f.child_frame_id for f in frames.transforms] == [d.name for d in dep.deputy]
    finally:
        if client is not None:
            client.close()
        if run.poll() is None:  # enough seen: stop the mission as Ctrl-C would
            run.send_signal(signal.SIGINT)
        try:
            run.communicate(timeout=120)
        except subprocess.TimeoutExpired:
            run.kill()
            run.communicate()
    assert run.returncode == 128 + signal.SIGINT
