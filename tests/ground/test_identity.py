"""A service's stolen credential speaks only for what its own topics name: a command on
``cmd/lqr/att`` for the other deputy, an old command replayed with a new body, stats claiming
to be the environment's and gains claiming to be the other controller's are refused by every
receiver before anything acts on them; the deputies fly, and the report reads, as without
them, and the report names what was refused and from whom."""

from __future__ import annotations

import contextlib
import json
import queue
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from services.bus import open_session
from services.bus.security import OBSERVER, credentials_path, load_credentials
from services.ground.storage.recording import Recorded
from services.interface import decode, encode, unpack_batch
from services.interface.topics import identity_mismatch
from tests.ground.test_security import (
    _client,
    _counters,
    _finish,
    _flight,
    _launch,
    _open,
    _wait_for_run,
)

pytestmark = pytest.mark.integration

END = 8100.0  # the mission's end (1.5 orbits of 5400 s), inside every receiver's window
MARK = 0.777  # the forged commands' attitude: no genuine command flies it


def _forged(
    run: str, t: float, next_seq: dict[str, int], boots: dict[str, int]
) -> list[tuple[str, str, bytes]]:
    """(credential, key, payload) of every forgery at simulation time ``t``; ``next_seq``: the
    genuine publishers' next seq per topic (the forgeries take them: fresh), ``boots`` their
    boot per topic (the forgeries claim it: the genuine publisher's window)."""
    p = f"ddvi/{run}/"
    sigma = np.array([0.0, 0.0, MARK])
    other = {"sc": "ddvi", "sigma": sigma, "for_t": END}  # ctrl-lqr commanding the DDVI deputy
    replay = {"sc": "lqr", "sigma": sigma, "for_t": END}  # an old seq with a new body
    stats = {"service": "environment", "counters": {"rejected": 0, "bad_commands": 0}}
    gains = {
        "sc": "ddvi",
        "K": np.zeros((1, 4)),
        "L": np.zeros((1, 5)),
        "source": "ddvi",
        "iteration": 1,
        "converged": True,
    }
    cmd, gain = next_seq.get("cmd/lqr/att", 0), next_seq.get("ctrl/lqr/gains", 0)
    ctrl = {"src": "ctrl-lqr", "boot": boots["cmd/lqr/att"]}
    nav = {"src": "nav-lqr", "boot": boots.get("stats/nav-lqr", boots["nav/lqr/state"])}
    return [
        ("ctrl-lqr", p + "cmd/lqr/att", encode("cmd", other, seq=cmd, t=t, **ctrl)),
        ("ctrl-lqr", p + "cmd/lqr/att", encode("cmd", replay, seq=0, t=60.0, **ctrl)),
        ("nav-lqr", p + "stats/nav-lqr", encode("stats", stats, seq=10**6, t=END, **nav)),
        ("ctrl-lqr", p + "ctrl/lqr/gains", encode("gains", gains, seq=gain, t=t, **ctrl)),
    ]


def _attack(out: Path, info: dict[str, Any]) -> int:
    """Watch the run as the observer; once it has flown a third of an orbit, put every
    forgery with the stolen credentials of ctrl-lqr and nav-lqr.  Returns how many."""
    run, hub = info["run"], info["hub"]
    creds = {
        u: load_credentials(credentials_path(out, u)) for u in (OBSERVER, "ctrl-lqr", "nav-lqr")
    }
    inbox: queue.SimpleQueue[tuple[str, bytes]] = queue.SimpleQueue()
    watch = _open(hub, creds[OBSERVER])
    next_seq: dict[str, int] = {}
    boots: dict[str, int] = {}
    t = 0.0
    with (
        contextlib.closing(watch),
        open_session(_client(hub, creds["ctrl-lqr"])) as ctrl,
        open_session(_client(hub, creds["nav-lqr"])) as nav,
    ):
        sub = watch.declare_subscriber(
            f"ddvi/{run}/**", lambda s: inbox.put((str(s.key_expr), s.payload.to_bytes()))
        )
        while t < 1800.0:
            key, payload = inbox.get(timeout=60)
            topic = key.split("/", 2)[2]
            for part in unpack_batch(payload) or (payload,):
                msg = decode(part)
                next_seq[topic] = max(next_seq.get(topic, 0), msg.seq + 1)
                boots[topic] = msg.boot
                if topic == "clock":
                    t = max(t, msg.t)
        sessions = {"ctrl-lqr": ctrl, "nav-lqr": nav}
        forged = _forged(run, t, next_seq, boots)
        for user, key, payload in forged:
            sessions[user].put(key, payload)
        sub.undeclare()
    return len(forged)


def _genuine(records: list[Recorded]) -> list[str]:
    """The flight messages of their topics' publishers, without the forgeries (which carry
    their publisher's name: an identity their topic does not name, or the marked attitude)."""
    return [
        r
        for r in _flight(records)
        if identity_mismatch(json.loads(r)[0], json.loads(r)[2]["body"]) is None
        and f", {MARK}]" not in r
    ]


def test_a_stolen_credential_speaks_only_for_its_own_topics(tmp_path: Path) -> None:
    clean, clean_root = _launch(tmp_path, "clean")
    clean_out, clean_records = _finish(clean, clean_root)

    attacked, root = _launch(tmp_path, "attacked")
    out, info = _wait_for_run(root)
    assert _attack(out, info) == 4
    # completed; the refusals make it exit 3
    _, records = _finish(attacked, root, statuses=(3,))

    # every flight message of both deputies is the same as without the attack, bit for bit
    flown = _genuine(records)
    assert sum('["cmd/' in r[:6] for r in flown) > 100
    assert flown == _flight(clean_records)
    # the receivers refused the forgeries before anything acted on them, and counted them;
    # the old seq with a new body did not end the environment's wait for ctrl-lqr
    env, clean_env = _counters(records, "environment"), _counters(clean_records, "environment")
    assert env["rejected.identity"] == 1, env
    assert env["rejected.duplicate"] == 1, env
    for key in ("missing_commands", "late_commands", "stale_commands", "steps"):
        assert env[key] == clean_env[key], key
    # the report is not falsified: the figures, and every service's counters, come from
    # their own publishers
    summary = json.loads((out / "summary.json").read_text())
    clean_summary = json.loads((clean_out / "summary.json").read_text())
    assert summary["deputies"] == clean_summary["deputies"]
    services = summary["messages"]["services"]
    assert services["environment"]["steps"] == clean_env["steps"]
    assert services["environment"]["rejected.identity"] == 1
    assert summary["outcome"]["commands"]["refused"] == 2  # the identity and the replay
    # and it says what was refused, and from whom
    refused = {(r["topic"], r["src"], r["reason"]): r for r in summary["outcome"]["refused"]}
    assert set(refused) == {
        ("cmd/lqr/att", "ctrl-lqr", "identity"),
        ("stats/nav-lqr", "nav-lqr", "identity"),
        ("ctrl/lqr/gains", "ctrl-lqr", "identity"),
    }
    assert refused[("stats/nav-lqr", "nav-lqr", "identity")]["claimed"] == "service = 'environment'"
    report = (out / "report.md").read_text()
    assert "`cmd/lqr/att` from `ctrl-lqr`: 1" in report
    assert "`stats/nav-lqr` from `nav-lqr`: 1" in report
    assert "`ctrl/lqr/gains` from `ctrl-lqr`: 1" in report
    # `ddvi report` from the recording believes and refuses the same
    r = subprocess.run(
        [sys.executable, "-m", "services.cli", "report", str(out)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert r.returncode == 0, r.stderr
    again = json.loads((out / "summary.json").read_text())
    assert again["outcome"]["refused"] == summary["outcome"]["refused"]
    assert again["deputies"] == clean_summary["deputies"]
