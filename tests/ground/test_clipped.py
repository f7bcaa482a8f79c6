"""Commands the environment clips to a deputy's attitude limit are said per deputy in the run's
outcome (summary.json) and report.md, not only counted among the environment's counters: on a
real run, commands past the limit put with ctrl-lqr's stolen credential are clipped, and the
report says how many, for the lqr deputy alone."""

from __future__ import annotations

import contextlib
import json
import os
import queue
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from benchmarks.flood import DEPLOYMENT
from services.bus import open_session
from services.bus.security import OBSERVER, credentials_path, load_credentials
from services.ground.storage.recording import read_recording
from services.interface import decode, encode, unpack_batch
from tests.ground.test_security import _client, _open, _wait_for_run

pytestmark = pytest.mark.integration

ORBITS = 6.0
LIMIT = 0.2  # the deputies' attitude limit (deployment default)
PAST = 0.9  # the forged commands' sigma3: past the limit
BOOT = 12345  # the forger's own boot: its sequence numbers never touch ctrl-lqr's


def _clip(out: Path, info: dict[str, Any]) -> int:
    """With ctrl-lqr's stolen credential, once ctrl-lqr has commanded step T, put a command
    past the attitude limit for T + 10 s; again every 20 steps until the environment's stats
    count one clipped.  How many were put."""
    hub, p = info["hub"], f"ddvi/{info['run']}/"
    watch_cred = load_credentials(credentials_path(out, OBSERVER))
    inbox: queue.SimpleQueue[tuple[str, bytes]] = queue.SimpleQueue()
    watch = _open(hub, watch_cred)
    put, last_put, clipped = 0, -1e9, 0
    stolen = load_credentials(credentials_path(out, "ctrl-lqr"))
    with contextlib.closing(watch), open_session(_client(hub, stolen)) as ctrl:
        sub = watch.declare_subscriber(
            p + "**", lambda s: inbox.put((str(s.key_expr), s.payload.to_bytes()))
        )
        while clipped == 0:
            key, payload = inbox.get(timeout=60)
            topic = key.removeprefix(p)
            for part in unpack_batch(payload) or (payload,):
                msg = decode(part)
                if topic == "stats/environment":
                    clipped = msg.body["counters"].get("clipped_commands.lqr", 0)
                elif topic == "cmd/lqr/att" and msg.src == "ctrl-lqr" and msg.boot != BOOT:
                    for_t = msg.body["for_t"]
                    if for_t >= 3600.0 and for_t - last_put >= 20 * 60.0:
                        sigma = np.array([0.0, 0.0, PAST])
                        body = {"sc": "lqr", "sigma": sigma, "for_t": for_t + 10.0}
                        forged = encode("cmd", body, seq=put, t=for_t, src="ctrl-lqr", boot=BOOT)
                        ctrl.put(p + "cmd/lqr/att", forged)
                        put, last_put = put + 1, for_t
        sub.undeclare()
    return put


def test_commands_clipped_to_the_attitude_limit_are_said_per_deputy(tmp_path: Path) -> None:
    dep = tmp_path / "clip.toml"
    dep.write_text(DEPLOYMENT.read_text().replace("orbits = 40.0", f"orbits = {ORBITS}", 1))
    root = tmp_path / "run"
    cmd = [sys.executable, "-m", "services.cli", "run", str(dep), "--output", str(root)]
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1"}
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env)
    try:
        out, info = _wait_for_run(root)
        put = _clip(out, info)
        _, err = proc.communicate(timeout=300)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode in (0, 3), err.decode()[-3000:]  # a forged one may come late
    summary = json.loads((out / "summary.json").read_text())
    env_counters = summary["messages"]["services"]["environment"]
    clipped = summary["outcome"]["clipped_commands"]
    n = env_counters["clipped_commands.lqr"]
    assert 1 <= n <= put
    assert clipped == {"total": n, "by_deputy": {"lqr": n, "ddvi": 0}}
    assert env_counters["clipped_commands"] == n and env_counters["clipped_commands.ddvi"] == 0
    # only the forged commands were past the limit, and each the environment took was clipped
    records, _ = read_recording(out / "recording.mcap")
    commands = [r for r in records if r.topic.startswith("cmd/")]
    past = [r for r in commands if max(map(abs, r.data["body"]["sigma"])) > LIMIT]
    assert {r.topic for r in past} == {"cmd/lqr/att"} and len(past) == put
    report = (out / "report.md").read_text()
    assert f"- commands clipped to the attitude limit: lqr {n}, ddvi 0" in report
