"""What a service says of itself is checked (docs/health.md, "Counters are checked"): on a real
run, stats forged with stolen credentials that claim more than a service can have sent, a
counter lower than its own process said before, or more safe-attitude steps than were flown are
named impossible in report.md and summary.json, never believed (the counters reported are the
services' own, the record whole) and make the completed run exit 3; ``ddvi report`` finds the
same from the recording.  And, in one process, the rules themselves."""

from __future__ import annotations

import contextlib
import json
import os
import queue
import re
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from benchmarks.flood import DEPLOYMENT
from services.bus import open_session
from services.bus.budget import BUDGET_BURST, BUDGET_SLACK
from services.bus.guards import REPLAY_WINDOW
from services.bus.security import OBSERVER, credentials_path, load_credentials
from services.config import deployment_from_table, load_deployment
from services.ground.analysis.claims import IN_FLIGHT, Claims
from services.ground.storage.recording import Recorded, read_recording
from services.interface import decode, encode, unpack_batch
from tests.ground.test_security import _client, _open, _wait_for_run

ORBITS = 8.0
ATTACK_T = 12_000.0  # s: the forgeries are put once the mission has flown this far
CLAIM = 10**12  # nav-lqr's claimed sent
STEPS_CLAIM = 10**6  # ctrl-lqr's claimed safe-attitude steps
AHEAD = REPLAY_WINDOW // 2  # the lowered stats' sequence number, past the one seen


def _deployment(tmp: Path) -> Path:
    path = tmp / "claims.toml"
    path.write_text(DEPLOYMENT.read_text().replace("orbits = 40.0", f"orbits = {ORBITS}", 1))
    return path


def _forge(out: Path, info: dict[str, Any]) -> dict[str, Any]:
    """Watch the run as the observer; past ATTACK_T, with the stolen credentials of nav-lqr
    and ctrl-lqr, put: nav-lqr's stats in its own process (its boot) claiming CLAIM sent;
    ctrl-lqr's latest stats again with ``commands`` 5 lower; ctrl-lqr's stats from a new
    process claiming STEPS_CLAIM safe-attitude steps.  What was forged from."""
    hub, p = info["hub"], f"ddvi/{info['run']}/"
    users = (OBSERVER, "nav-lqr", "ctrl-lqr")
    creds = {u: load_credentials(credentials_path(out, u)) for u in users}
    inbox: queue.SimpleQueue[tuple[str, bytes]] = queue.SimpleQueue()
    watch = _open(hub, creds[OBSERVER])
    seen: dict[str, Any] = {}
    t = 0.0
    with (
        contextlib.closing(watch),
        open_session(_client(hub, creds["nav-lqr"])) as nav,
        open_session(_client(hub, creds["ctrl-lqr"])) as ctrl,
    ):
        sub = watch.declare_subscriber(
            p + "**", lambda s: inbox.put((str(s.key_expr), s.payload.to_bytes()))
        )
        while t < ATTACK_T or "ctrl" not in seen or "nav_boot" not in seen:
            key, payload = inbox.get(timeout=60)
            topic = key.removeprefix(p)
            for part in unpack_batch(payload) or (payload,):
                msg = decode(part)
                if topic == "clock":
                    t = max(t, msg.t)
                elif topic == "nav/lqr/state":
                    seen["nav_boot"] = msg.boot
                elif topic == "stats/ctrl-lqr":
                    seen["ctrl"] = msg
        stats = seen["ctrl"]
        lower = {**stats.body["counters"], "commands": stats.body["counters"]["commands"] - 5}
        steps = {"sent": 0, "safe_attitude_steps": STEPS_CLAIM}
        forged = [
            # seq 1: nav-lqr's one genuine stats, its final ones, are seq 0
            (nav, "nav-lqr", {"sent": CLAIM}, seen["nav_boot"], 1),
            # a number within the receivers' window that ctrl-lqr's own stats never reach: the
            # one it will publish next may be on its way already, and whichever arrives second
            # would be refused as a duplicate, unread by the claims
            (ctrl, "ctrl-lqr", lower, stats.boot, stats.seq + AHEAD),
            (ctrl, "ctrl-lqr", steps, stats.boot ^ 1, 0),
        ]
        for session, user, counters, boot, seq in forged:
            body = {"service": user, "counters": counters}
            payload = encode("stats", body, seq=seq, t=t, src=user, boot=boot)
            session.put(p + f"stats/{user}", payload)
        sub.undeclare()
    return {
        "lowered_from": stats.body["counters"]["commands"],
        "at": t,
        "counters": [counters for _, _, counters, _, _ in forged],
    }


def _genuine(records: list[Recorded], service: str, forged: list[dict]) -> list[Recorded]:
    """What ``service`` itself published, in the recording: its messages from the processes
    that published its flight topics, but the forged stats."""
    boots = {
        r.data["boot"]
        for r in records
        if r.data.get("src") == service and not r.topic.startswith("stats/")
    }
    return [
        r
        for r in records
        if r.data.get("src") == service
        and r.data["boot"] in boots
        and r.data["body"].get("counters") not in forged
    ]


@pytest.mark.integration
def test_impossible_claims_are_named_never_believed_and_exit_3(tmp_path: Path) -> None:
    root = tmp_path / "run"
    dep = _deployment(tmp_path)
    cmd = [sys.executable, "-m", "services.cli", "run", str(dep), "--output", str(root)]
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1"}
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env)
    try:
        out, info = _wait_for_run(root)
        forged = _forge(out, info)
        _, err = proc.communicate(timeout=300)
    finally:
        if proc.poll() is None:
            proc.kill()
    said = err.decode()
    assert proc.returncode == 3, said[-3000:]
    assert "mission completed, but impossible claims were made" in said, said[-3000:]
    assert "nav-lqr sent = 1,000,000,000,000" in said

    summary = json.loads((out / "summary.json").read_text())
    assert summary["completed"] is True
    found = {(c["src"], c["counter"], c["reason"]): c for c in summary["outcome"]["impossible"]}
    assert set(found) == {
        ("nav-lqr", "sent", "budget"),
        ("ctrl-lqr", "commands", "decreased"),
        ("ctrl-lqr", "safe_attitude_steps", "steps"),
    }
    budget = found[("nav-lqr", "sent", "budget")]
    # nav-lqr's three keys (nav/lqr/state and log/nav-lqr a navigation period, stats/nav-lqr
    # run.status_every steps) at most, by the time the claim came
    assert budget["claimed"] == CLAIM
    # at the time the ground had flown when the claim reached it (the forger may be behind
    # the mission, or ahead of the ground), plus the steps a service may be ahead of it
    flown = float(re.search(r"in the ([\d,.]+) s flown", budget["text"])[1].replace(",", ""))
    assert 0.0 < flown <= ORBITS * 5400.0
    most = 3 * BUDGET_BURST + BUDGET_SLACK * (flown + 2 * 60.0) * (2 / 10.0 + 1 / 600.0)
    assert budget["limit"] <= most
    lowered = found[("ctrl-lqr", "commands", "decreased")]
    assert lowered["claimed"] == forged["lowered_from"] - 5
    # what the process said last before the forgery reached the ground: the stats it was
    # forged from, or (the forger behind the mission) a later one
    assert lowered["limit"] >= forged["lowered_from"]
    run = load_deployment(dep).run
    assert ORBITS * 5400 / run.fsw_period / run.status_every < AHEAD  # ctrl-lqr's stay below
    steps = found[("ctrl-lqr", "safe_attitude_steps", "steps")]
    assert steps["claimed"] == STEPS_CLAIM and steps["limit"] < ORBITS * 5400 / 60.0 + 3

    # never believed: every counter reported is the service's own last word, what the ground
    # received from it adds up, and nothing is made a loss
    records, complete = read_recording(out / "recording.mcap")
    assert complete
    services = summary["messages"]["services"]
    for name in ("nav-lqr", "ctrl-lqr"):
        mine = _genuine(records, name, forged["counters"])
        last = [r.data["body"]["counters"] for r in mine if r.topic == f"stats/{name}"][-1]
        assert services[name] == last
        assert services[name]["sent"] == len(mine) - 1  # all it sent before its final stats
    assert services["nav-lqr"]["sent"] < 10_000
    assert summary["outcome"]["health"]["safe_attitude_steps"] == {}
    assert summary["messages"]["unrecorded"] == {}
    assert summary["outcome"]["record"]["complete"] is True
    report = (out / "report.md").read_text()
    assert "Published but never recorded" not in report
    assert "**3 impossible claims**" in report
    assert "`nav-lqr` claimed sent = 1,000,000,000,000: impossible" in report

    # the report written again from the recording finds the same
    again_cmd = [sys.executable, "-m", "services.cli", "report", str(out)]
    r = subprocess.run(again_cmd, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    again = json.loads((out / "summary.json").read_text())
    assert {(c["src"], c["counter"], c["reason"]) for c in again["outcome"]["impossible"]} == set(
        found
    )
    assert again["messages"]["services"]["nav-lqr"] == services["nav-lqr"]


DEP = deployment_from_table({"deputy": [{"name": "alpha"}]})


def _stats(claims: Claims, service: str, counters: dict[str, int], boot: int, t: float) -> bool:
    """``service``'s stats from process ``boot`` received at ``t``: whether believed."""
    body = {"service": service, "counters": counters}
    msg = decode(encode("stats", body, seq=0, t=t, src=service, boot=boot))
    claims.seen(msg)
    return claims.claim(msg, t)


def _seen(claims: Claims, service: str, boot: int, n: int) -> None:
    body = {"service": service, "level": "info", "text": "x"}
    for _ in range(n):
        claims.seen(decode(encode("log", body, seq=0, t=0.0, src=service, boot=boot)))


def test_a_claim_beyond_what_arrived_and_one_batch_is_impossible_and_not_a_loss() -> None:
    claims = Claims(DEP, "r")
    _seen(claims, "nav-alpha", 7, 100)
    assert _stats(claims, "nav-alpha", {"sent": 100 + IN_FLIGHT}, 7, 600.0)  # a batch on its way
    assert claims.unrecorded() == {"nav-alpha": IN_FLIGHT}  # a loss, said as one
    assert not _stats(claims, "nav-alpha", {"sent": 101 + IN_FLIGHT + 1}, 7, 600.0)
    assert claims.stats["nav-alpha"]["sent"] == 100 + IN_FLIGHT  # the believed word stays
    assert claims.unrecorded() == {"nav-alpha": IN_FLIGHT - 1}  # its own stats did arrive
    (kind,) = claims.impossible()
    assert (kind["src"], kind["counter"], kind["reason"]) == ("nav-alpha", "sent", "unseen")
    # what the ground's budget dropped unread from it is what it may also have sent
    dropping = Claims(DEP, "r", dropped=lambda publisher: 1000 if publisher == "nav-alpha" else 0)
    assert _stats(dropping, "nav-alpha", {"sent": 1000}, 7, 600.0)


def test_a_restarted_process_counts_from_zero_and_one_that_goes_down_is_impossible() -> None:
    claims = Claims(DEP, "r")
    _seen(claims, "ctrl-alpha", 1, 11)
    assert _stats(claims, "ctrl-alpha", {"sent": 10, "commands": 10}, 1, 600.0)
    _seen(claims, "ctrl-alpha", 2, 3)
    assert _stats(claims, "ctrl-alpha", {"sent": 2, "commands": 2}, 2, 720.0)  # a new boot
    assert claims.stats["ctrl-alpha"] == {"sent": 12, "commands": 12}
    assert not _stats(claims, "ctrl-alpha", {"sent": 3, "commands": 1}, 2, 780.0)
    assert not _stats(claims, "ctrl-alpha", {"sent": 3, "commands": -1}, 3, 780.0)
    assert claims.stats["ctrl-alpha"] == {"sent": 12, "commands": 12}
    reasons = {(k["counter"], k["reason"], k["claimed"], k["limit"]) for k in claims.impossible()}
    assert reasons == {("commands", "decreased", 1, 2), ("commands", "negative", -1, 0)}
    # a recording without boots (all 0): a lower ``sent`` is a new process
    old = Claims(DEP, "r")
    for sent in (5, 8, 2):
        assert _stats(old, "ctrl-alpha", {"sent": sent}, 0, 600.0)
    assert old.stats["ctrl-alpha"] == {"sent": 10}


def test_a_service_the_run_does_not_have_or_too_many_steps_is_impossible() -> None:
    claims = Claims(DEP, "r")
    assert not _stats(claims, "nav-ghost", {"sent": 0}, 1, 600.0)
    # 600 s flown: 10 flight-software steps, 2 of margin
    assert _stats(claims, "ctrl-alpha", {"safe_attitude_steps": 12}, 1, 600.0)
    assert not _stats(claims, "ctrl-alpha", {"safe_attitude_steps": 13}, 1, 600.0)
    assert {(k["src"], k["reason"]) for k in claims.impossible()} == {
        ("nav-ghost", "unknown"),
        ("ctrl-alpha", "steps"),
    }
