"""Faults against a running deployment: every service a real process over real Zenoh."""

from __future__ import annotations

import contextlib
import json
import math
import os
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import msgpack
import numpy as np
import pytest
import zenoh

from services.bus import EPHEMERAL_LOOPBACK, BusSettings, open_session
from services.deployment import load_deployment
from services.inprocess import run_in_process
from services.launcher import free_port
from services.monitor import read_recording
from services.schema import MAX_PAYLOAD, encode, schema_for_topic

GARBLED = """
[run]
name = "garbage"
orbits = 1.0
command_deadline = 20.0
[bus]
port = {port}
[[deputy]]
name = "lqr"
controller = "lqr"
[[deputy]]
name = "ddvi"
controller = "ddvi"
learning = {{ learn_at_orbits = 5.0 }}   # explores for the whole run
"""

# what each service subscribes to (its declared inputs)
INPUTS = {
    "environment": ["cmd/*/att"],
    "nav-lqr": ["truth/*"],
    "nav-ddvi": ["truth/*"],
    "ctrl-lqr": ["nav/lqr/state", "exo/state", "clock"],
    "ctrl-ddvi": ["nav/ddvi/state", "exo/state", "clock"],
    "monitor": ["**"],
}
STOP_AT = 3000.0  # s of simulation time: every service is still up to count what it got


def _with_nan(payload: bytes) -> bytes:
    """The message with its first float (in the body, else the header's t) made NaN."""
    raw = msgpack.unpackb(payload, raw=False)

    def poison(v: Any) -> tuple[Any, bool]:
        if isinstance(v, float):
            return math.nan, True
        if isinstance(v, list):
            for i, item in enumerate(v):
                v[i], done = poison(item)
                if done:
                    return v, True
        if isinstance(v, dict):
            for k in v:
                v[k], done = poison(v[k])
                if done:
                    return v, True
        return v, False

    raw["body"], done = poison(raw["body"])
    if not done:
        raw["t"] = math.nan
    return msgpack.packb(raw)


def garbage_for(topic: str, valid: bytes, rng: np.random.Generator) -> dict[str, bytes]:
    """One of each kind of bad message for ``topic``, from a valid payload seen on it."""
    wrong = "stats" if schema_for_topic(topic) == "log" else "log"
    body = (
        {"service": "intruder", "counters": {"x": 1}}
        if wrong == "stats"
        else {"service": "intruder", "level": "info", "text": "x"}
    )
    return {
        "random": rng.bytes(int(rng.integers(1, 200))),
        "truncated": valid[: len(valid) // 2],
        "oversized": b"\x91" + b"\x00" * MAX_PAYLOAD,
        "wrong_schema": encode(wrong, body, seq=10**9, t=0.0, src="intruder"),
        "non_finite": _with_nan(valid),
        "replayed": valid,
    }


@pytest.mark.integration
def test_garbage_on_every_topic_changes_nothing_the_craft_do(tmp_path: Path) -> None:
    """An intruder on the bus puts random bytes, truncated, oversized, wrong-schema,
    NaN-carrying and replayed copies of real messages on every topic of a running mission,
    several times a second.  Every service rejects and counts them and goes on: the mission
    completes, no handler fails, and every command is bit-identical to the same mission run
    in one process with no bus."""
    port = free_port()
    dep_path = tmp_path / "garbage.toml"
    dep_path.write_text(GARBLED.format(port=port))
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1"}
    cmd = [sys.executable, "-m", "services.cli", "run", str(dep_path)]
    cmd += ["--output", str(tmp_path / "runs"), "--quiet"]
    launcher = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env)
    seen: dict[str, bytes] = {}  # key -> the first valid payload on it
    clock = {"t": 0.0}
    lock = threading.Lock()

    def on_sample(sample: zenoh.Sample) -> None:
        key, payload = str(sample.key_expr), sample.payload.to_bytes()
        with lock:
            seen.setdefault(key, payload)  # the first is the mission's: we send on seen keys
            if key.endswith("/clock"):
                with contextlib.suppress(Exception):  # our own garbage loops back too
                    clock["t"] = max(clock["t"], float(msgpack.unpackb(payload)["t"]))

    rounds: dict[str, int] = {}  # key -> how many times each kind of garbage went on it
    rng = np.random.default_rng(7)
    settings = BusSettings(listen=[EPHEMERAL_LOOPBACK], connect=[f"tcp/127.0.0.1:{port}"])
    with open_session(settings) as session:
        sub = session.declare_subscriber("ddvi/**", on_sample)
        try:
            while launcher.poll() is None and clock["t"] < STOP_AT:
                with lock:
                    targets = dict(seen)
                for key, valid in targets.items():
                    if "/alive/" in key:
                        continue
                    topic = key.split("/", 2)[2]
                    for payload in garbage_for(topic, valid, rng).values():
                        session.put(key, payload, congestion_control=zenoh.CongestionControl.BLOCK)
                    rounds[key] = rounds.get(key, 0) + 1
                time.sleep(0.1)
        finally:
            sub.undeclare()
    out_text, err_text = launcher.communicate(timeout=90)
    assert launcher.returncode == 0, err_text.decode()[-3000:]
    assert sum(rounds.values()) > 50, rounds  # the intruder was heard during the run
    out = Path(out_text.decode().strip().splitlines()[-1])
    summary = json.loads((out / "summary.json").read_text())
    assert summary["completed"] is True
    services = summary["messages"]["services"]
    # every bad message a service received is counted, once, by its reason
    for name, inputs in INPUTS.items():
        c = services[name]
        n = sum(k for key, k in rounds.items() if any(zenoh.KeyExpr(f"ddvi/*/{i}").intersects(
            zenoh.KeyExpr(key)) for i in inputs))  # fmt: skip
        assert n > 0, name
        assert c["handler_errors"] == 0, name
        # random bytes and truncated payloads do not unpack; one of each other kind
        assert c["rejected.malformed"] == 2 * n, name
        for reason in ("oversized", "wrong_schema", "non_finite"):
            assert c[f"rejected.{reason}"] == n, (name, reason)
        replays = ("ignored.duplicate", "ignored.stale") if name == "monitor" else (
            "rejected.duplicate", "rejected.stale")  # fmt: skip
        assert c[replays[0]] + c[replays[1]] == n, name
    monitor = services["monitor"]
    # nothing is lost: every payload that reached the monitor is in the recording
    recorded, complete = read_recording(out / "recording.mcap")
    assert complete
    assert len(recorded) == summary["messages"]["recorded"]
    assert sum(r.topic.startswith("rejected/") for r in recorded) == monitor["rejected"]
    # ... and the craft flew exactly as with no intruder
    flown: dict[str, dict[float, float]] = {"lqr": {}, "ddvi": {}}
    for r in recorded:
        if r.schema == "ddvi.cmd" and r.data["src"] == f"ctrl-{r.data['body']['sc']}":
            flown[r.data["body"]["sc"]][r.data["body"]["for_t"]] = r.data["body"]["sigma"][2]
    reference = run_in_process(load_deployment(str(dep_path)))
    for sc, commands in flown.items():
        ref = reference[sc]
        on_step = np.isclose(np.mod(ref["t"], 60.0), 0.0)
        expected = dict(zip(ref["t"][on_step].tolist(), ref["u"][on_step].tolist(), strict=True))
        assert len(commands) == len(expected) > 80, sc
        assert commands == expected, sc
