"""A deputy flown from ROS 2 (``controller = "ros2"``) in a real ``ddvi run --ros2``: the example
node (docs/examples/ros2_lqr_node.py, zenoh-ros2-sdk in a process of its own) flies it on the
LQR law beside the built-in LQR deputy, both from the same state; bad input from the ROS 2 side
is refused, counted and named while the mission flies on, every command identical to the clean
run's; and lock-step waits for the node, the hang timeout naming it."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import zenoh

from services.bus import BusSettings, open_session
from services.ground.launch.launcher import free_port
from services.ground.storage.recording import read_recording
from services.ros2 import conversions as cv
from services.ros2 import keys, messages
from services.ros2.keys import Endpoint, EntityKind
from tests.ros2.samples import write_definitions, zenoh_router
from tests.support import fly, service_process, wait_until

pytestmark = pytest.mark.integration

ROOT = Path(__file__).resolve().parents[2]
NODE = ROOT / "docs" / "examples" / "ros2_lqr_node.py"
DOMAIN = 43
FLOWN = f"""
[run]
name = "rosfly"
orbits = 2.0
command_deadline = 20.0
[ros2]
enabled = true
domain_id = {DOMAIN}
[[deputy]]
name = "lqr"
controller = "lqr"
[[deputy]]
name = "rosd"
controller = "ros2"
"""
FLOOD_S = 10.0
"""Wall seconds the flood lasts, a command put as fast as a Zenoh session puts them."""
PACE = 500.0
"""Simulated seconds per wall second of the flooded run (``--rate``): its two orbits outlast the
flood, so that every command of the flood reaches a gateway that is up."""


class Flight:
    """One ``ddvi run --ros2`` of ``FLOWN`` with the example node flying ``rosd`` on a router
    the gateway joins: its status, what it said, its run folder, the node's status."""

    def __init__(
        self,
        folder: Path,
        during: Any = None,
        *,
        node: bool = True,
        port: int | None = None,
        text: str = FLOWN,
        options: tuple[str, ...] = (),
    ) -> None:
        self.port = port or free_port()
        self.dep = folder / "flown.toml"
        self.dep.write_text(text)
        definitions = folder / "msg"
        write_definitions(definitions, messages.EXPOSED_TYPES)
        router = zenoh_router(self.port)  # the user's rmw_zenohd
        process = None
        try:
            if node:
                process = self.start_node(definitions, router)
            options = ("--ros2", f"tcp/127.0.0.1:{self.port}", *options)
            self.status, self.said, self.out = fly(self.dep, folder / "runs", during, options)
            if process is not None:
                _, err = process.communicate(timeout=60)
                self.node_status, self.node_said = process.returncode, err
        finally:
            if process is not None and process.poll() is None:
                process.send_signal(signal.SIGTERM)
                process.wait(timeout=30)
            router.close()

    def start_node(self, definitions: Path, router: zenoh.Session) -> subprocess.Popen:
        """The example node, once its subscriptions and publisher are announced on the router
        (the gateway carries nothing to a topic no one reads yet)."""
        path = os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])
        env = {**os.environ, "PYTHONPATH": path}
        cmd = [sys.executable, str(NODE), str(self.dep), "--deputy", "rosd"]
        cmd += ["--router", f"127.0.0.1:{self.port}", "--messages", str(definitions)]
        process = subprocess.Popen(cmd, stderr=subprocess.PIPE, text=True, env=env)
        wanted = {
            ("/clock", EntityKind.SUBSCRIPTION),
            ("/rosd/odom", EntityKind.SUBSCRIPTION),
            ("/rosd/altitude", EntityKind.SUBSCRIPTION),
            ("/rosd/cmd_attitude", EntityKind.PUBLISHER),
        }
        assert wait_until(lambda: wanted <= _announced(router), 60.0), process.poll()
        return process

    def recorded(self) -> dict[str, list[Any]]:
        out: dict[str, list[Any]] = {}
        for item in read_recording(self.out / "recording.mcap")[0]:
            out.setdefault(item.topic, []).append(item.data)
        return out

    def commands(self, sc: str) -> dict[float, tuple[str, list[float]]]:
        """Each step's command of deputy ``sc`` as the bus carried it: (publisher, sigma)."""
        return {
            m["body"]["for_t"]: (m["src"], m["body"]["sigma"])
            for m in self.recorded()[f"cmd/{sc}/att"]
        }


def _announced(session: zenoh.Session) -> set[tuple[str, EntityKind]]:
    pattern = keys.liveliness_pattern(DOMAIN)
    replies = session.liveliness().get(pattern, timeout=1.0)
    found = [keys.parse_token(str(r.ok.key_expr)) for r in replies if r.ok is not None]
    return {(e.topic, e.kind) for e in found if isinstance(e, Endpoint)}


@pytest.fixture(scope="module")
def clean(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Flight]:
    yield Flight(tmp_path_factory.mktemp("clean"))


def test_a_deputy_flown_by_the_example_node_ends_within_1_percent_of_the_lqr_deputy(
    clean: Flight,
) -> None:
    assert clean.status == 0, clean.said
    assert clean.node_status == 0, clean.node_said
    deputies = json.loads((clean.out / "summary.json").read_text())["deputies"]
    lqr, rosd = (deputies[sc]["final_along_track_error_m"] for sc in ("lqr", "rosd"))
    assert deputies["rosd"]["controller"] == "ros2"
    assert abs(rosd - lqr) <= 0.01 * lqr, (lqr, rosd)
    # every step the environment takes flown from ROS 2, through the gateway, as the built-in
    # LQR flies its own (which also flies one at the final clock, which nothing takes)
    flown, built_in = clean.commands("rosd"), clean.commands("lqr")
    final = max(built_in)
    assert set(flown) == set(built_in) - {final} and len(flown) > 100
    assert {src for src, _ in flown.values()} == {"ros2-gateway"}
    for t, (_, sigma) in flown.items():
        assert np.allclose(sigma, built_in[t][1], rtol=0.0, atol=1e-9), t
    (stats,) = [m["body"]["counters"] for m in clean.recorded()["stats/ros2-gateway"]]
    assert stats["commands"] == len(flown) and stats["commands_refused"] == 0


def test_bad_input_from_ros2_is_refused_counted_and_named_and_the_mission_flies_on(
    clean: Flight, tmp_path: Path
) -> None:
    port = free_port()
    flooded = []  # how many commands the flood put
    name = messages.dds_type_name(messages.ATTITUDE_COMMAND)
    digest = messages.type_hash(messages.ATTITUDE_COMMAND)

    def command(sc: str, t: float) -> bytes:
        return messages.serialize(
            cv.attitude_command(t, sc, [0, 0, 0.2]), messages.ATTITUDE_COMMAND
        )

    def attack(proc: subprocess.Popen, _folder: Path) -> None:
        environment = service_process(proc, "environment")
        settings = BusSettings(mode="client", listen=[], connect=[f"tcp/127.0.0.1:{port}"])
        with open_session(settings) as intruder:  # anyone on the ROS 2 side
            block = zenoh.CongestionControl.BLOCK  # every sample delivered, to be counted
            rosd, lqr = (
                intruder.declare_publisher(
                    keys.data_key(DOMAIN, f"/{sc}/cmd_attitude", name, digest),
                    congestion_control=block,
                )
                for sc in ("rosd", "lqr")
            )
            environment.suspend()  # the mission waits while the first two land
            try:
                rosd.put(b"\x00\x01\x00\x00 not a QuaternionStamped")
                lqr.put(command("lqr", 0.0))  # lqr's controller is the run's own
            finally:
                environment.resume()
            off_grid = command("rosd", 5.0)  # no step: a flood of them while the mission flies
            end, n = time.monotonic() + FLOOD_S, 0
            while time.monotonic() < end:
                rosd.put(off_grid)
                n += 1
            flooded.append(n)
            assert proc.poll() is None  # the run outlasted the flood
            rosd.undeclare()
            lqr.undeclare()

    attacked = Flight(tmp_path, attack, port=port, options=("--rate", str(PACE)))
    assert attacked.status == 0, attacked.said
    assert attacked.node_status == 0, attacked.node_said
    recorded = attacked.recorded()
    (stats,) = [m["body"]["counters"] for m in recorded["stats/ros2-gateway"]]
    assert stats["commands_refused.malformed"] == 1
    assert stats["commands_refused.not_ros2"] == 1
    (flood,) = flooded
    assert flood > 10_000
    assert stats["commands_refused.step"] == flood
    assert stats["commands_refused"] == flood + 2
    lines = [m["body"]["text"] for m in recorded["log/ros2-gateway"]]
    refused = [line for line in lines if line.startswith("refused a command on ")]
    assert any(
        "/lqr/cmd_attitude" in line and "lqr is not flown from ROS 2" in line for line in refused
    )
    assert any("/rosd/cmd_attitude" in line and "(malformed #1)" in line for line in refused)
    assert any("(step #1000)" in line for line in refused)  # a flood is said, not every sample
    assert all(" from GID " in line or "without rmw_zenoh" in line for line in refused)
    assert len(refused) <= 12 + flood // 1000  # the first ten of each kind, then each 1000th
    # the mission flew on: every command of both deputies is the clean run's, bit for bit
    for sc in ("lqr", "rosd"):
        assert attacked.commands(sc) == clean.commands(sc), sc


def test_lock_step_waits_for_the_ros2_node_and_its_silence_is_named(tmp_path: Path) -> None:
    text = FLOWN.replace("command_deadline = 20.0", "command_deadline = 1.0\nhang_timeout = 3.0")
    silent = Flight(tmp_path, node=False, text=text)  # nobody flies rosd
    assert silent.status == 1, silent.said
    assert "no command for rosd from ros2-gateway" in silent.said
    assert "the ROS 2 node flying rosd (through ros2-gateway) is hung" in silent.said
    recorded = silent.recorded()
    assert "cmd/rosd/att" not in recorded and "cmd/lqr/att" in recorded  # it waited at once
