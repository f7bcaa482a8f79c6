"""A secure bus under attack: a running mission, an unauthenticated client and a service's
stolen credentials try every forgery; the deputies fly exactly as without them."""

from __future__ import annotations

import json
import os
import queue
import socket
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import zenoh

from services.bus import BusSettings, open_session, zenoh_config
from services.bus.security import OBSERVER, Credentials, credentials_path, load_credentials
from services.ground.storage.recording import Recorded, read_recording
from services.interface import decode, encode, unpack_batch
from services.interface.topics import may_publish
from tests.support import wait_until

pytestmark = pytest.mark.integration

MISSION = """
[run]
name = "sec"
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
DEPUTIES = ("lqr", "ddvi")
# the topics whose every message must be the same with and without the attack
FLIGHT = ("cmd/", "ctrl/", "nav/", "clock", "exo/", "truth/")


def _launch(tmp_path: Path, name: str) -> tuple[subprocess.Popen, Path]:
    """``ddvi run`` of MISSION into ``tmp_path/name``; its process and its output root."""
    dep = tmp_path / "mission.toml"
    dep.write_text(MISSION)
    root = tmp_path / name
    cmd = [sys.executable, "-m", "services.cli", "run", str(dep), "--output", str(root), "--quiet"]
    log = (tmp_path / f"{name}.log").open("w")
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1"}
    proc = subprocess.Popen(cmd, stdout=log, stderr=log, env=env)
    return proc, root


def _finish(
    proc: subprocess.Popen, root: Path, statuses: tuple[int, ...] = (0,)
) -> tuple[Path, list[Recorded]]:
    """Wait for the run to end with one of ``statuses``; its folder and its recording."""
    assert proc.wait(timeout=150) in statuses
    (out,) = [p.parent for p in root.glob("*/bus.json")]
    assert json.loads((out / "summary.json").read_text())["completed"] is True
    records, complete = read_recording(out / "recording.mcap")
    assert complete
    return out, records


def _wait_for_run(
    root: Path, timeout: float = 60.0, security: bool = True
) -> tuple[Path, dict[str, Any]]:
    """The run folder under ``root`` once its bus description (and credentials) are there."""

    def written() -> bool:
        found = list(root.glob("*/bus.json"))
        return bool(found) and (
            not security or (found[0].parent / "security" / "users.txt").is_file()
        )

    assert wait_until(written, timeout), f"no run folder under {root}"
    (found,) = root.glob("*/bus.json")
    return found.parent, json.loads(found.read_text())


def _client(hub: str, cred: Credentials | None) -> BusSettings:
    if cred is None:
        return BusSettings(mode="client", listen=[], connect=[hub])
    return BusSettings(
        mode="client", listen=[], connect=[hub], user=cred.user, password=cred.password
    )


def _open(hub: str, cred: Credentials, timeout: float = 60.0) -> zenoh.Session:
    """A session of ``cred``'s user on ``hub``, once its router takes it."""
    opened: list[zenoh.Session] = []

    def connected() -> bool:
        try:
            opened.append(zenoh.open(zenoh_config(_client(hub, cred))))
        except zenoh.ZError:
            return False
        return True

    assert wait_until(connected, timeout), f"{hub} never took {cred.user}"
    return opened[0]


def _forgeries(run: str, seen: dict[str, bytes], t: float) -> list[tuple[str, bytes]]:
    """(key, payload) of every forgery, made from genuine messages ``seen`` (key -> payload)."""
    p = f"ddvi/{run}/"
    out: list[tuple[str, bytes]] = []
    step = int(t // 60.0)
    for sc in DEPUTIES:
        cmd = {"sc": sc, "sigma": np.array([0.0, 0.0, 0.9]), "for_t": 1e12}
        out.append((p + f"cmd/{sc}/att", encode("cmd", cmd, seq=0, t=t, src="intruder")))
        for seq in range(step, step + 4):  # the genuine publisher's next seqs
            cmd = {"sc": sc, "sigma": np.array([0.0, 0.0, 0.9]), "for_t": 60.0 * (seq + 1)}
            out.append((p + f"cmd/{sc}/att", encode("cmd", cmd, seq=seq, t=t, src=f"ctrl-{sc}")))
        if (nav := seen.get(p + f"nav/{sc}/state")) is not None:
            msg = decode(nav)
            body = {**msg.body, "x_hill": msg.body["x_hill"] + 1e5}
            out.append(
                (p + f"nav/{sc}/state", encode("nav", body, seq=msg.seq + 1, t=t, src="nav-evil"))
            )
        if (gains := seen.get(p + f"ctrl/{sc}/gains")) is not None:
            msg = decode(gains)
            body = {**msg.body, "K": np.zeros_like(msg.body["K"])}
            out.append(
                (
                    p + f"ctrl/{sc}/gains",
                    encode("gains", body, seq=msg.seq + 1, t=t, src=f"ctrl-{sc}"),
                )
            )
        kill = {"kind": "kill", "target": f"ctrl-{sc}", "params": {}}
        out.append((p + "fault/kill", encode("fault", kill, seq=0, t=t, src="ground-1")))
    if (clock := seen.get(p + "clock")) is not None:
        msg = decode(clock)
        body = {**msg.body, "final": True}
        out.append((p + "clock", encode("clock", body, seq=msg.seq + 1, t=t, src="environment")))
    return out


def _wrong(user: str, topic: str, payload: bytes) -> bool:
    """Whether ``user`` putting ``payload`` on ``topic`` is a forgery across a boundary: a
    topic not its own, or its own under another's name (the owner itself is not an intruder)."""
    return not may_publish(user, topic) or decode(payload).src != user


def _attack(out: Path, info: dict[str, Any], proc: subprocess.Popen) -> dict[str, int]:
    """Watch the run as the observer; once it flies, refuse-check the strangers, then put
    every forgery with a stolen credential and from an unauthenticated peer until the mission
    ends.  Returns how many of each were put."""
    run, hub = info["run"], info["hub"]
    observer = load_credentials(credentials_path(out, OBSERVER))
    stolen = {
        u: load_credentials(credentials_path(out, u)) for u in ("nav-lqr", "ctrl-ddvi", "monitor")
    }
    inbox: queue.SimpleQueue[tuple[str, bytes]] = queue.SimpleQueue()
    watch = _open(hub, observer)
    put = {"stolen": 0, "peer": 0, "rounds": 0}
    try:
        sub = watch.declare_subscriber(
            f"ddvi/{run}/**", lambda s: inbox.put((str(s.key_expr), s.payload.to_bytes()))
        )
        # strangers are refused at connect: no password, a wrong one, an unknown user
        for cred in (None, Credentials("ctrl-lqr", "guess"), Credentials("intruder", "x")):
            with pytest.raises(zenoh.ZError):
                zenoh.open(zenoh_config(_client(hub, cred)))
        peer = BusSettings(mode="peer", listen=["tcp/127.0.0.1:0"], connect=[hub])
        with (
            open_session(peer) as stranger,
            open_session(_client(hub, stolen["nav-lqr"])) as nav,
            open_session(_client(hub, stolen["ctrl-ddvi"])) as ctrl,
            open_session(_client(hub, stolen["monitor"])) as mon,
        ):
            seen: dict[str, bytes] = {}
            t, final, attacked_at = 0.0, False, 0.0
            while not final and proc.poll() is None:
                try:  # the run's next message
                    key, payload = inbox.get(timeout=1.0)
                except queue.Empty:
                    continue
                for part in unpack_batch(payload) or (payload,):
                    seen.setdefault(key, part)
                    if key.endswith("/clock"):
                        msg = decode(part)
                        t, final = max(t, msg.t), final or msg.body["final"]
                # a round each time the mission's clock moves on: as the mission flies, at a
                # rate its receivers' budgets (by simulated time) take, however fast it flies
                if t > attacked_at and not final:
                    attacked_at = t
                    for key, payload in _forgeries(run, seen, t):
                        for user, session in (
                            ("nav-lqr", nav),
                            ("ctrl-ddvi", ctrl),
                            ("monitor", mon),
                        ):
                            if _wrong(user, key[len(f"ddvi/{run}/") :], payload):
                                session.put(key, payload)
                                put["stolen"] += 1
                        stranger.put(key, payload)
                        put["peer"] += 1
                    put["rounds"] += 1
            assert list(stranger.info.routers_zid()) == [] and list(stranger.info.peers_zid()) == []
        sub.undeclare()
    finally:
        watch.close()
    return put


def _flight(records: list[Recorded], owners: bool = True) -> list[str]:
    """The flight messages of a recording from their topics' publishers (``owners``), or from
    anyone else (not ``owners``), exactly (JSON with every float's repr) but for the boot each
    process draws, in (topic, seq) order."""
    return sorted(
        json.dumps([r.topic, r.data["seq"], {**r.data, "boot": None}], sort_keys=True)
        for r in records
        if r.topic.startswith(FLIGHT)
        and "src" in r.data
        and bool(may_publish(r.data["src"], r.topic)) == owners
    )


def _counters(records: list[Recorded], service: str) -> dict[str, int]:
    """The last counters ``service`` published."""
    return [r.data["body"]["counters"] for r in records if r.topic == f"stats/{service}"][-1]


def test_every_forgery_is_refused_and_the_deputies_fly_as_without_them(tmp_path: Path) -> None:
    clean, clean_root = _launch(tmp_path, "clean")
    _, clean_records = _finish(clean, clean_root)

    attacked, root = _launch(tmp_path, "attacked")
    out, info = _wait_for_run(root)
    assert info["security"] is True
    put = _attack(out, info, attacked)
    # completed; the refusals make it exit 3 (docs/faults.md, "Stopping a run")
    _, records = _finish(attacked, root, statuses=(0, 3))

    assert put["rounds"] >= 3, put  # the forgeries went out while the mission flew
    # every command of both deputies, and every gain, clock, truth, exosystem and navigation
    # message of its genuine publisher, is the same as without the attack, bit for bit
    flown = _flight(records)
    assert sum('["cmd/' in r[:6] for r in flown) > 100
    assert flown == _flight(clean_records)
    assert _flight(clean_records, owners=False) == []
    # the router let a stolen credential put only on its own user's topics (under another's
    # name: nav-lqr's "nav-evil" state, ctrl-ddvi's "intruder" command), and the receivers
    # refused those by their owner check and counted them
    foreign = {json.loads(r)[0] for r in _flight(records, owners=False)}
    assert foreign <= {"nav/lqr/state", "cmd/ddvi/att", "ctrl/ddvi/gains"}
    assert "nav/lqr/state" in foreign and "cmd/ddvi/att" in foreign
    assert _counters(records, "ctrl-lqr")["rejected.src"] >= 1
    assert _counters(records, "environment")["rejected.src"] >= 1
    assert not any(r.topic.startswith("fault/") for r in records)  # nobody put a fault
    finals = [r.data["src"] for r in records if r.topic == "clock" and r.data["body"]["final"]]
    assert finals == ["environment"]
    # the credentials stay in the run folder, private, and out of the recording and the logs
    secrets = [load_credentials(p).password for p in (out / "security").glob("*.json")]
    text = json.dumps([r.data for r in records]) + "".join(
        p.read_text() for p in (out / "logs").iterdir()
    )
    assert secrets and not any(s in text for s in secrets)
    assert all(p.stat().st_mode & 0o077 == 0 for p in (out / "security").iterdir())


OPERATED = """
[run]
name = "ops"
orbits = 1.0
mode = "realtime"
rate = 300.0            # 18 wall seconds: time for the ground's commands
[[deputy]]
name = "lqr"
controller = "lqr"
"""


def _ddvi(*args: str) -> subprocess.CompletedProcess:
    cmd = [sys.executable, "-m", "services.cli", *args]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=60)


def test_the_operator_and_the_observer_find_a_secure_run_by_its_folder(tmp_path: Path) -> None:
    """`ddvi fault` (the operator's credentials) and `ddvi monitor` (the observer's) reach a
    secure run by its folder or its name; without the run folder's credentials nothing
    connects."""
    dep = tmp_path / "ops.toml"
    dep.write_text(OPERATED)
    root = tmp_path / "runs"
    cmd = [sys.executable, "-m", "services.cli", "run", str(dep), "--output", str(root)]
    log = (tmp_path / "ops.log").open("w")
    proc = subprocess.Popen([*cmd, "--quiet"], stdout=log, stderr=log)
    try:
        out, info = _wait_for_run(root)
        # bus.json is written once the hub listens: a tool started at once connects
        host, port = info["hub"].split("/", 1)[1].rsplit(":", 1)
        socket.create_connection((host, int(port)), timeout=5).close()
        seen = _ddvi("monitor", "--run", str(out), "--count", "3", "--seconds", "30")
        assert seen.returncode == 0 and len(seen.stdout.splitlines()) == 3, seen.stderr
        assert all(f"ddvi/{info['run']}/" in line for line in seen.stdout.splitlines())
        r = _ddvi(
            "fault", info["run"], "panel", "lqr", "--area-factor", "0.9", "--output", str(root)
        )
        assert r.returncode == 0 and "fault panel lqr:" in r.stdout, r.stdout + r.stderr
        # the observer's credentials do not put a fault: the same command with them is dropped
        (out / "security" / "ground-operator.json").write_text(
            (out / "security" / "observer.json").read_text()
        )
        r = _ddvi("fault", str(out), "panel", "lqr", "--area-factor", "0.5", "--timeout", "3")
        assert r.returncode == 1 and "no answer" in r.stderr, r.stdout + r.stderr
        lost = _ddvi("monitor", "--run", str(tmp_path / "nowhere"))
        assert lost.returncode == 2 and "no run" in lost.stderr
    finally:
        assert proc.wait(timeout=120) in (0, 3)
    records, _ = read_recording(out / "recording.mcap")
    faults = [r.data["body"]["params"] for r in records if r.topic == "fault/panel"]
    assert faults == [{"area_factor": 0.9}]


def test_an_open_bus_is_said_and_its_receivers_still_refuse_foreign_and_far_times(
    tmp_path: Path,
) -> None:
    """``security = false``: the launcher says the bus is open (even with --quiet), no
    credentials are made, anyone can connect; the receivers still refuse a command from
    another publisher or for a time outside the mission (the seq far ahead that would make
    every genuine command stale), and the commands fly as without them."""
    clean, clean_root = _launch(tmp_path, "clean")
    _, clean_records = _finish(clean, clean_root)
    open_bus = MISSION.replace("[run]", "[bus]\nsecurity = false\n\n[run]", 1)
    dep = tmp_path / "open.toml"
    dep.write_text(open_bus)
    root = tmp_path / "open"
    log_path = tmp_path / "open.log"
    cmd = [sys.executable, "-m", "services.cli", "run", str(dep), "--output", str(root), "--quiet"]
    proc = subprocess.Popen(cmd, stdout=log_path.open("w"), stderr=subprocess.STDOUT)
    out, info = _wait_for_run(root, security=False)
    assert info["security"] is False and not (out / "security").exists()
    p = f"ddvi/{info['run']}/"
    sent = 0
    clocks: queue.SimpleQueue[bytes] = queue.SimpleQueue()
    with open_session(BusSettings(listen=["tcp/127.0.0.1:0"], connect=[info["hub"]])) as anyone:
        sub = anyone.declare_subscriber(p + "clock", lambda s: clocks.put(s.payload.to_bytes()))
        clocks.get(timeout=60)  # the mission flies: the environment is there to hear them
        while proc.poll() is None and sent < 500:
            try:  # a round each time the mission's clock moves on
                clocks.get(timeout=1.0)
            except queue.Empty:
                continue
            for sc in DEPUTIES:
                body = {"sc": sc, "sigma": np.array([0.0, 0.0, 0.9]), "for_t": 1e12}
                anyone.put(p + f"cmd/{sc}/att", encode("cmd", body, seq=0, t=60.0, src="intruder"))
                far = encode("cmd", body, seq=10**6, t=60.0, src=f"ctrl-{sc}")
                anyone.put(p + f"cmd/{sc}/att", far)
                sent += 1
        sub.undeclare()
    assert proc.wait(timeout=150) in (0, 3)
    assert "bus.security = false: the bus is open" in log_path.read_text()
    records, _ = read_recording(out / "recording.mcap")
    env = _counters(records, "environment")
    assert env["rejected.src"] >= 1 and env["rejected.time"] >= 1, env
    # the monitor records what it hears (the far ones under ctrl-X's name too); the commands
    # the deputies flew are the same as without them
    forged = '"for_t": 1000000000000.0'
    genuine = [r for r in _flight(records) if '["cmd/' in r[:6] and forged not in r]
    assert len(genuine) > 100
    assert genuine == [r for r in _flight(clean_records) if '["cmd/' in r[:6]]
    truth = [r for r in _flight(records) if '["truth/' in r[:8]]
    assert truth == [r for r in _flight(clean_records) if '["truth/' in r[:8]]
