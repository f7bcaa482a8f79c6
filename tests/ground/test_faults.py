"""Faults against a running deployment: every service a real process over real Zenoh."""

from __future__ import annotations

import contextlib
import itertools
import json
import math
import os
import queue
import signal
import subprocess
import sys
import threading
import tomllib
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import msgpack
import numpy as np
import pytest
import zenoh

from services.bus import EPHEMERAL_LOOPBACK, Bus, BusSettings, open_session, zenoh_config
from services.cli import main as ddvi
from services.config import deployment_from_table, load_deployment, resolve
from services.flight.inprocess import run_in_process
from services.ground.storage.recording import read_recording
from services.interface import MAX_PAYLOAD, encode, schema_for_topic, topics
from tests.support import wait_until

# every test here starts a mission through `ddvi run` (or the `ddvi fault` command)
pytestmark = pytest.mark.integration

GARBLED = """
[run]
name = "garbage"
orbits = 8.0
command_deadline = 20.0
[bus]
port = {port}
security = false        # an open bus: the test's plain zenoh session joins it
[[deputy]]
name = "lqr"
controller = "lqr"
[[deputy]]
name = "ddvi"
controller = "ddvi"
learning = {{ learn_at_orbits = 9.0 }}   # explores for the whole run
"""

# what each service subscribes to (its declared inputs)
INPUTS = {
    "environment": ["cmd/*/att", "recorded"],
    "nav-lqr": ["truth/*"],
    "nav-ddvi": ["truth/*"],
    "ctrl-lqr": ["nav/lqr/state", "exo/state", "clock"],
    "ctrl-ddvi": ["nav/ddvi/state", "exo/state", "clock"],
    "monitor": ["**"],
}
# s of simulation time: every service is still up to count what it got. The intruder starts
# about half a wall second after the first clock (gossip) and needs several rounds before this:
# at 3.6 ms a 60 s step (measured), 10,000 s went by within a second
STOP_AT = 40000.0
# s of simulation time between the intruder's rounds. Every receiver budgets each key by its
# simulated time (services.bus.budget): paced in simulated time, the garbage stays within the
# budgets however fast or slow the mission flies (a flood would be dropped unread, uncounted).
# A round puts 6 messages on each key: a status-rate key's budget refills 8 in 1200 s.
ROUND_EVERY = 1200.0


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


def test_garbage_on_every_topic_changes_nothing_the_craft_do(
    start_mission: Callable[[str], Mission],
) -> None:
    """An intruder on the bus puts random bytes, truncated, oversized, wrong-schema,
    NaN-carrying and replayed copies of real messages on every topic of a running mission,
    every 20 steps.  Every service rejects and counts them and goes on: the mission
    completes, no handler fails, and every command is bit-identical to the same mission run
    in one process with no bus."""
    mission = start_mission(GARBLED)
    seen: dict[str, bytes] = {}  # key -> the first valid payload on it
    lock = threading.Lock()

    def on_sample(sample: zenoh.Sample) -> None:
        with lock:  # the first is the mission's: we send on seen keys
            seen.setdefault(str(sample.key_expr), sample.payload.to_bytes())

    rounds: dict[str, int] = {}  # key -> how many times each kind of garbage went on it
    rng = np.random.default_rng(7)
    sub = mission.session.declare_subscriber("ddvi/**", on_sample)
    try:
        # every service's subscriptions reach this session by gossip: once this session knows
        # each service's subscription to each of its inputs, each gets every garbage message
        mission.wait_for(0.0)
        assert wait_until(lambda: _inputs_known(mission), 30.0), _known(mission.session)
        next_round = mission.t
        while True:
            mission.wait_for(next_round)
            if mission.t >= STOP_AT:
                break
            next_round = mission.t + ROUND_EVERY
            with lock:
                targets = dict(seen)
            for key, valid in targets.items():
                if "/alive/" in key:
                    continue
                topic = key.split("/", 2)[2]
                for payload in garbage_for(topic, valid, rng).values():
                    mission.session.put(
                        key, payload, congestion_control=zenoh.CongestionControl.BLOCK
                    )
                rounds[key] = rounds.get(key, 0) + 1
    finally:
        sub.undeclare()
    rc, out, err = mission.finish()
    # completed, with the intruder's commands refused: exit status 3 (docs/faults.md)
    assert rc == 3 and "refused" in err, err[-3000:]
    assert sum(rounds.values()) > 50, rounds  # the intruder was heard during the run
    summary = json.loads((out / "summary.json").read_text())
    assert summary["completed"] is True
    _check_rejections(summary["messages"]["services"], rounds)
    monitor = summary["messages"]["services"]["monitor"]
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
    reference = run_in_process(load_deployment(str(mission.path)))
    for sc, commands in flown.items():
        ref = reference[sc]
        on_step = np.isclose(np.mod(ref["t"], 60.0), 0.0)
        expected = dict(zip(ref["t"][on_step].tolist(), ref["u"][on_step].tolist(), strict=True))
        assert len(commands) == len(expected) > 80, sc
        assert commands == expected, sc


# 10 orbits: long enough that the `ddvi fault` calls (a process each, seconds to start on a busy
# host) land while the run still flies
RESTARTED = """
[run]
name = "restarts"
orbits = 10.0
command_deadline = 20.0
[bus]
port = {port}
security = false        # an open bus: the test's plain zenoh session joins it
[[deputy]]
name = "lqr"
controller = "lqr"
[[deputy]]
name = "ddvi"
controller = "ddvi"
learning = {{ learn_at_orbits = 0.6, interval = 120.0, max_iterations = 20000 }}
{restart}
"""
RESTART_POLICY = """
[[restart]]
service = "ctrl-*"
[[restart]]
service = "nav-*"
max_restarts = 1
"""


def _known(session: zenoh.Session) -> dict[str, dict[str, set[str]]]:
    """What ``session`` knows of the other peers, from its own admin space: by kind
    (``subscriber``, ``token``), each key expression declared and the peers that declared it."""
    known: dict[str, dict[str, set[str]]] = {"subscriber": {}, "token": {}}
    for kind, keys in known.items():
        prefix = f"@/{session.zid()}/peer/{kind}/"
        for reply in session.get(prefix + "**"):
            if reply.ok is not None:
                peers = json.loads(reply.ok.payload.to_string())["peers"]
                keys[str(reply.ok.key_expr).removeprefix(prefix)] = set(peers)
    return known


def _inputs_known(mission: Mission) -> bool:
    """Whether the mission's session knows every service's subscription to each of its
    INPUTS (the service by its liveliness token's peer): a put there then reaches it."""
    known = _known(mission.session)
    prefix = f"ddvi/{mission.run}/"
    peer_of = {
        key.removeprefix(prefix + "alive/"): peer
        for key, peers in known["token"].items()
        for peer in peers
    }
    return all(
        name in peer_of
        and any(
            peer_of[name] in peers and zenoh.KeyExpr(key).intersects(zenoh.KeyExpr(prefix + i))
            for key, peers in known["subscriber"].items()
        )
        for name, inputs in INPUTS.items()
        for i in inputs
    )


def _check_rejections(services: dict[str, dict[str, int]], rounds: dict[str, int]) -> None:
    """Every bad message a service received is counted, once, by its reason (``rounds``: key
    -> how many times each kind of garbage went on it)."""
    for name, inputs in INPUTS.items():
        c = services[name]
        n = sum(
            k
            for key, k in rounds.items()
            if any(zenoh.KeyExpr(f"ddvi/*/{i}").intersects(zenoh.KeyExpr(key)) for i in inputs)
        )
        assert n > 0, name
        assert c["handler_errors"] == 0, name
        # random bytes and truncated payloads do not unpack; one of each other kind
        assert c["rejected.malformed"] == 2 * n, name
        for reason in ("oversized", "wrong_schema", "non_finite"):
            assert c[f"rejected.{reason}"] == n, (name, reason)
        replays = (
            ("ignored.duplicate", "ignored.stale")
            if name == "monitor"
            else ("rejected.duplicate", "rejected.stale")
        )
        assert c[replays[0]] + c[replays[1]] == n, name


class Mission:
    """A deployment started through ``ddvi run``, watched from a plain zenoh session."""

    def __init__(self, tmp_path: Path, text: str, port: int) -> None:
        self.port = port
        path = self.path = tmp_path / "mission.toml"
        path.write_text(text.format(port=self.port))
        env = {**os.environ, "OPENBLAS_NUM_THREADS": "1"}
        cmd = [sys.executable, "-m", "services.cli", "run", str(path)]
        cmd += ["--output", str(tmp_path / "runs"), "--quiet"]
        self.launcher = subprocess.Popen(
            cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env
        )
        self.hub = f"tcp/127.0.0.1:{self.port}"
        self.runs = tmp_path / "runs"
        self.run = ""
        self.t = -1.0
        self._stack = contextlib.ExitStack()
        config = zenoh_config(BusSettings(listen=[EPHEMERAL_LOOPBACK], connect=[self.hub]))
        # its own admin space readable: what it knows of the services' subscriptions (_known)
        config.insert_json5("adminspace", '{"enabled": true, "permissions": {"read": true}}')
        session = self.session = zenoh.open(config)
        self._stack.callback(session.close)  # an open session hangs the interpreter at exit
        sub = session.declare_subscriber("ddvi/*/clock", self._on_clock)
        self._stack.callback(sub.undeclare)

    def _on_clock(self, sample: zenoh.Sample) -> None:
        with contextlib.suppress(Exception):
            self.run = str(sample.key_expr).split("/")[1]
            self.t = max(self.t, float(msgpack.unpackb(sample.payload.to_bytes())["t"]))

    def wait_for(self, t: float, timeout: float = 60.0) -> None:
        """Until the mission's clock reaches ``t`` s (the launcher still running)."""
        wait_until(lambda: self.t >= t or self.launcher.poll() is not None, timeout)
        if self.t < t:
            assert self.launcher.poll() is None, self.launcher.communicate()[1].decode()[-3000:]
            raise AssertionError(f"simulation time {self.t} < {t}")

    def kill(self, service: str) -> None:
        """What ``ddvi fault RUN kill SERVICE`` sends, put at once (no CLI start-up)."""
        self.put_fault("kill", service, {})

    def put_fault(self, kind: str, target: str, params: dict[str, Any]) -> None:
        """A fault message put on the run's bus as a ground tool would, unchecked (each kind
        from a publisher of its own: one sequence each)."""
        body = {"kind": kind, "target": target, "params": params}
        payload = encode("fault", body, seq=0, t=self.t, src=f"ground-test-{kind}")
        key = f"ddvi/{self.run}/{topics.fault_topic(kind)}"
        self.session.put(key, payload, congestion_control=zenoh.CongestionControl.BLOCK)

    def fault(self, *args: str) -> subprocess.CompletedProcess:
        cmd = [sys.executable, "-m", "services.cli", "fault", self.run, *args, "--hub", self.hub]
        return subprocess.run(cmd, capture_output=True, text=True, timeout=60)

    def fault_by_folder(self, *args: str) -> subprocess.CompletedProcess:
        """``ddvi fault`` given the run folder, not a hub: it checks the fault against the
        run's deployment (the folder's copy) before it sends anything."""
        folder = str(self.runs / self.run)
        cmd = [sys.executable, "-m", "services.cli", "fault", folder, *args]
        return subprocess.run(cmd, capture_output=True, text=True, timeout=60)

    def finish(self) -> tuple[int, Path, str]:
        try:
            _, err = self.launcher.communicate(timeout=120)
        finally:
            self.close()
        # the run's folder (printed on success only): the one the launcher made
        return self.launcher.returncode, self.runs / self.run, err.decode()

    def close(self) -> None:
        """Close the watching session (an open one hangs the interpreter at exit) and stop
        the launcher if a failed test left it running (it stops its services)."""
        self._stack.close()
        if self.launcher.poll() is None:
            self.launcher.send_signal(signal.SIGINT)
            try:
                self.launcher.communicate(timeout=30)
            except subprocess.TimeoutExpired:
                self.launcher.kill()
                self.launcher.communicate()


@pytest.fixture
def start_mission(tmp_path: Path, free_port: int) -> Iterator[Callable[[str], Mission]]:
    """Start missions through ``ddvi run``; whatever happens, close them after the test."""
    missions: list[Mission] = []

    def start(text: str) -> Mission:
        missions.append(Mission(tmp_path, text, free_port))
        return missions[-1]

    yield start
    for mission in missions:
        mission.close()


def test_killed_services_are_restarted_and_the_mission_completes(
    start_mission: Callable[[str], Mission],
) -> None:
    """`ddvi fault RUN kill` crashes a controller (mid-learning) and a navigation service; the
    launcher restarts each into the running mission as its policy says; the environment holds
    the controller's last command while it is away; the mission completes and summary.json
    counts the kills and restarts."""
    mission = start_mission(RESTARTED.replace("{restart}", RESTART_POLICY))
    mission.wait_for(600.0)
    r = mission.fault("kill", "ctrl-ddvi")
    assert r.returncode == 0 and "fault kill ctrl-ddvi: killed" in r.stdout, r.stdout + r.stderr
    killed_at = float(r.stdout.split("sent at t = ")[1].split()[0])
    mission.wait_for(killed_at + 3000.0)
    mission.kill("nav-lqr")
    rc, out, err = mission.finish()
    # completed, degraded: a command of the killed controller missing, or the LQR deputy on
    # the safe attitude while its navigation was away and its newest sample too old: status 3
    degraded = "missing" in err or "safe attitude flown by ctrl-lqr" in err
    assert rc == 3 and degraded, err[-3000:]
    summary = json.loads((out / "summary.json").read_text())
    assert summary["completed"] is True
    services = summary["messages"]["services"]
    assert services["launcher"]["kills"] == 2
    assert services["launcher"]["restarts.ctrl-ddvi"] == 1
    assert services["launcher"]["restarts.nav-lqr"] == 1
    assert summary["messages"]["totals"]["restarted"] == 2
    # lock-step paused for the restart (the deputy held its last command meanwhile; whether a
    # step's command went missing depends on when in the step the kill fell)
    env_log = (out / "logs" / "environment.log").read_text()
    assert "controller of ddvi went away" in env_log and "controller of ddvi is back" in env_log
    ctrl_log = (out / "logs" / "ctrl-ddvi.log").read_text()
    assert "restarted: learning starts over" in ctrl_log
    assert "restarted into the running mission" in (out / "logs" / "nav-lqr.log").read_text()
    recorded, complete = read_recording(out / "recording.mcap")
    assert complete
    cmds = {
        sc: sorted(
            r.data["body"]["for_t"]
            for r in recorded
            if r.schema == "ddvi.cmd" and r.data["body"]["sc"] == sc
        )
        for sc in ("lqr", "ddvi")
    }
    end = summary["sim_time_s"]
    for sc, times in cmds.items():
        assert times[-1] >= end - 60.0, sc  # both controllers fly to the end
    # the restarted controller's commands come from a new process (its seq starts again at 0)
    # from a step after the kill; whether a step went without one depends on where in the step
    # the kill fell, so no gap is required, but no step is commanded twice
    ddvi = sorted(
        (r.data["body"]["for_t"], r.data["seq"])
        for r in recorded
        if r.schema == "ddvi.cmd" and r.data["src"] == "ctrl-ddvi"
    )
    assert len({t for t, _ in ddvi}) == len(ddvi)
    restarts = [t for (_, s0), (t, s1) in itertools.pairwise(ddvi) if s1 < s0]
    assert len(restarts) == 1 and restarts[0] > killed_at
    assert min(np.diff(cmds["ddvi"])) >= 60.0 - 1e-6


def test_a_crash_without_restart_ends_the_run_with_the_recording_intact(
    start_mission: Callable[[str], Mission],
) -> None:
    """With no restart policy a crashed controller ends the run (exit 1, naming it); the
    monitor still closes a complete recording and writes a partial report."""
    mission = start_mission(RESTARTED.replace("{restart}", ""))
    mission.wait_for(300.0)
    r = mission.fault("kill", "ctrl-nobody")
    assert r.returncode == 1 and "'ctrl-nobody' is not alive" in r.stderr, r.stderr
    r = mission.fault("kill", "ctrl-lqr")
    assert r.returncode == 0, r.stdout + r.stderr
    rc, out, err = mission.finish()
    assert rc == 1 and "ctrl-lqr exited with status -9" in err, err[-3000:]
    summary = json.loads((out / "summary.json").read_text())
    assert summary["completed"] is False
    recorded, complete = read_recording(out / "recording.mcap")
    assert complete and len(recorded) == summary["messages"]["recorded"]
    last_cmd = max(r.data["t"] for r in recorded if r.data.get("src") == "ctrl-lqr")
    assert last_cmd >= 300.0  # what it sent before it died is there


FAULTED = RESTARTED.replace(
    "{restart}",
    """
[[fault]]                 # the lqr deputy's panel deploys only 70 %
at_orbits = 0.5
kind = "panel"
deputy = "lqr"
area_factor = 0.7
[[fault]]                 # the ddvi deputy's navigation jumps 100 m along-track
at_orbits = 0.5
kind = "bias"
deputy = "ddvi"
position_bias = [0.0, 100.0, 0.0]
""",
)


def _series(csv: Path, deputy: str) -> dict[str, np.ndarray]:
    import csv as csv_module

    with csv.open() as f:
        rows = [r for r in csv_module.DictReader(f) if r["deputy"] == deputy]
    return {k: np.array([float(r[k]) for r in rows]) for k in ("t", "y", "nav_y")}


def test_panel_and_bias_faults_scheduled_and_from_the_ground(
    start_mission: Callable[[str], Mission],
) -> None:
    """Scheduled [[fault]]s and `ddvi fault RUN panel|bias|outage` change the truth's panel
    area, a navigation bias and whether navigation measures at their times: the faulted
    deputy's truth leaves the unfaulted reference from the fault on (not before), the
    navigation error jumps by the bias, and summary.json counts every fault applied."""
    mission = start_mission(FAULTED)
    orbit = 5431.0
    mission.wait_for(0.6 * orbit)
    r = mission.fault("panel", "ddvi", "--area-factor", "1.2", "--stuck-angle", "40")
    assert r.returncode == 0, r.stdout + r.stderr
    assert "fault panel ddvi: panel area now 1.2 x nominal, normal stuck at 40 deg" in r.stdout
    r = mission.fault("bias", "lqr", "--position", "0", "0", "0")
    assert r.returncode == 0 and "fault bias lqr: navigation bias now" in r.stdout, r.stderr
    r = mission.fault("outage", "ddvi", "--orbits", "0.05")
    assert r.returncode == 0, r.stdout + r.stderr
    assert "fault outage ddvi: no measurement from t = " in r.stdout
    # reached by --hub alone, the run's deputies are those alive on its bus: nothing is sent
    r = mission.fault("panel", "nobody", "--area-factor", "1.2")
    said = f"ddvi fault panel: 'nobody' is not a deputy of run {mission.run!r}; its deputies: "
    assert r.returncode == 2 and r.stderr == said + "ddvi, lqr\n", r.stdout + r.stderr
    # the environment refuses such a fault put on the bus (counted in its bad_faults)
    mission.put_fault("panel", "nobody", {"area_factor": 1.2})
    rc, out, err = mission.finish()
    # 270 s without navigation, past the stale limit (120 s): the safe attitude, exit 3
    assert rc == 3 and "safe attitude flown by ctrl-ddvi" in err, err[-3000:]
    summary = json.loads((out / "summary.json").read_text())
    services = summary["messages"]["services"]
    assert services["environment"]["panel_faults"] == 2
    assert services["environment"]["bad_faults"] == 1
    assert services["nav-ddvi"]["bias_faults"] == 1 and services["nav-lqr"]["bias_faults"] == 1
    # 0.05 orbits of samples every 10 s: 27 or 28 not measured
    assert services["nav-ddvi"]["outages"] == 1
    assert 26 <= services["nav-ddvi"]["outage_samples"] <= 28
    assert services["nav-lqr"]["outages"] == 0
    # the same mission with no fault, in one process: the lqr deputy's truth is the same up
    # to its panel fault and departs from it after
    table = tomllib.loads(FAULTED.format(port=0))
    del table["fault"]
    reference = run_in_process(deployment_from_table(table))["lqr"]
    series = _series(out / "timeseries.csv", "lqr")
    ref_y = np.interp(series["t"], reference["t"], reference["x"][:, 1])  # navigation frame
    fault_t = 0.5 * orbit
    before = series["t"] <= fault_t
    assert np.max(np.abs(series["nav_y"][before] - ref_y[before])) < 1e-3
    assert np.abs(series["nav_y"][-1] - ref_y[-1]) > 10.0
    # the ddvi deputy's navigation error steps by the 100 m bias at its time
    ddvi = _series(out / "timeseries.csv", "ddvi")
    error = ddvi["nav_y"] - ddvi["y"]
    k = int(np.searchsorted(ddvi["t"], fault_t))
    assert abs(error[k + 1] - error[k - 2] - 100.0) < 5.0


def test_link_faults_from_the_ground(start_mission: Callable[[str], Mission]) -> None:
    """`ddvi fault RUN link` impairs a link of a running mission from then on: every command
    the lossy link drops is one the environment misses, and the delayed link holds samples."""
    # 40 orbits: the mission outlasts the four `ddvi fault` calls on a loaded machine
    mission = start_mission(
        RESTARTED.replace("{restart}", "").replace("orbits = 10.0", "orbits = 40.0")
    )
    mission.wait_for(600.0)
    r = mission.fault(
        "link", "--from", "ctrl-lqr", "--to", "environment", "--topic", "cmd/*/att", "--loss", "0.5"
    )
    assert r.returncode == 0, r.stdout + r.stderr
    assert "environment now receives cmd/*/att from ctrl-lqr with loss 0.5" in r.stdout
    # a glob reaches every controller: each one's answer is printed; reached by --hub alone,
    # the run's deployment is checked by the services, each of which refuses a link from no
    # service of it
    r = mission.fault("link", "--from", "nobody", "--to", "ctrl-*", "--delay", "0")
    assert r.returncode == 1, r.stdout + r.stderr
    for ctrl in ("ctrl-lqr", "ctrl-ddvi"):
        said = f"{ctrl}: fault link ctrl-*: refused at {ctrl} (link.publisher: 'nobody' "
        assert said in r.stdout, r.stdout
    r = mission.fault("link", "--from", "nav/ddvi", "--to", "ctrl/ddvi", "--delay", "120")
    assert r.returncode == 0 and "ctrl-ddvi now receives ** from nav-ddvi with delay 120" in (
        r.stdout
    ), r.stdout + r.stderr
    r = mission.fault("link", "--from", "ctrl-lqr", "--to", "environment", "--loss", "2")
    said = "ddvi fault: link.loss: expected a probability in [0, 1], got 2.0"
    assert r.returncode == 2 and said in r.stderr and not r.stdout, r.stdout + r.stderr
    rc, out, err = mission.finish()
    # completed, with the commands the faulted link dropped missing: exit status 3
    assert rc == 3 and "missing" in err, err[-3000:]
    summary = json.loads((out / "summary.json").read_text())
    env = summary["messages"]["services"]["environment"]
    assert env["dropped"] > 50
    # every dropped command is a missed step, except the one for the final time, which no step
    # flies (whether its drop is counted depends on it arriving before the final stats); the
    # last steps' commands may be lost too, on the way out
    assert -1 <= env["missing_commands"] - env["dropped"] <= 2
    assert summary["messages"]["services"]["ctrl-ddvi"]["delayed"] > 0
    assert summary["completed"] is True


SHORT_ORBITS = 12.0
"""The short mission's length: 65,160 s, which a 50,000 s link delay fits."""
SHORT_SECONDS = 65160


def _short_mission() -> str:
    """The default mission (its LQR and DDVI deputies) cut to SHORT_ORBITS, on an open bus the
    test's session joins: a Mission template (``{port}``)."""
    text = resolve("rendezvous").read_text()
    text = text.replace("orbits = 40.0", f"orbits = {SHORT_ORBITS}", 1)
    text = text.replace("{", "{{").replace("}", "}}")  # its inline tables, for str.format
    return text + "\n[bus]\nport = {port}\nsecurity = false\n"


ZERO = [0.0, 0.0, 0.0]


def test_a_link_fault_obeys_the_deployment_and_stale_navigation_flies_the_safe_attitude(
    start_mission: Callable[[str], Mission],
) -> None:
    """`ddvi fault RUN link` is checked as the run's deployment checks its [[link]]s: a delay
    longer than the mission is refused with the limit named, exit 2, and nothing sent.  A legal
    50,000 s delay on nav-lqr -> ctrl-lqr leaves the LQR controller's lock-step steps only
    ever older samples: past run.nav_stale_limit (two steps) it flies the safe attitude,
    logged, counted and reported, and the completed run exits 3.  The DDVI deputy flies
    exactly as in a clean run of the same deployment."""
    mission = start_mission(_short_mission())
    mission.wait_for(600.0)
    r = mission.fault_by_folder("link", "--from", "nav-lqr", "--to", "ctrl-lqr", "--delay", "1e300")
    said = (
        f"ddvi fault: link: delay + jitter = 1e+300 s is not shorter than the mission "
        f"({SHORT_SECONDS} s): every message on it would be lost; give a delay + jitter below "
        f"{SHORT_SECONDS} s"
    )
    assert r.returncode == 2 and r.stderr.strip() == said and not r.stdout, r.stdout + r.stderr
    r = mission.fault_by_folder("link", "--from", "nav-lqr", "--to", "ctrl-lqr", "--delay", "50000")
    applied = (
        "ctrl-lqr: fault link ctrl-lqr: ctrl-lqr now receives ** from nav-lqr with delay 50000"
    )
    assert r.returncode == 0 and applied in r.stdout, r.stdout + r.stderr
    rc, out, err = mission.finish()
    assert rc == 3 and "safe attitude flown by ctrl-lqr (" in err, err[-3000:]
    summary = json.loads((out / "summary.json").read_text())
    assert summary["completed"] is True
    safe = summary["outcome"]["health"]["safe_attitude_steps"]
    assert list(safe) == ["ctrl-lqr"] and safe["ctrl-lqr"] > 0, safe
    report = (out / "report.md").read_text()
    assert f"**safe attitude flown** (navigation too old): ctrl-lqr {safe['ctrl-lqr']} steps" in (
        report
    )
    log = (out / "logs" / "ctrl-lqr.log").read_text()
    assert "s old (limit 120 s): flying the safe attitude" in log, log[-3000:]
    records, complete = read_recording(out / "recording.mcap")
    assert complete
    # only the legal fault went out
    faults = [r.data["body"] for r in records if r.topic == topics.fault_topic("link")]
    assert [f["params"]["delay"] for f in faults] == [50000.0], faults
    # from its first safe step to the end, the LQR deputy flies the safe attitude
    flown = sorted(
        (r.data["body"]["for_t"], r.data["body"]["sigma"])
        for r in records
        if r.topic == "cmd/lqr/att"
    )
    first = next(t for t, sigma in flown if sigma == ZERO and t > 0.0)
    after = [sigma for t, sigma in flown if t >= first]
    assert all(sigma == ZERO for sigma in after) and len(after) <= safe["ctrl-lqr"]
    assert len(after) > safe["ctrl-lqr"] - 3  # the last commands may go out unrecorded

    clean = start_mission(_short_mission())
    rc, clean_out, err = clean.finish()
    assert rc == 0, err[-3000:]
    clean_summary = json.loads((clean_out / "summary.json").read_text())
    assert summary["deputies"]["ddvi"] == clean_summary["deputies"]["ddvi"]
    lqr, clean_lqr = summary["deputies"]["lqr"], clean_summary["deputies"]["lqr"]
    assert lqr["final_along_track_error_m"] != clean_lqr["final_along_track_error_m"]


REFUSED_FAULTS: list[tuple[list[str], str]] = [
    (
        ["link", "--from", "nav-lqr", "--to", "ctrl-lqr", "--delay", "60000", "--jitter", "6000"],
        f"link: delay + jitter = 66000 s is not shorter than the mission ({SHORT_SECONDS} s)",
    ),
    (
        ["link", "--from", "nobody", "--to", "ctrl-lqr"],
        "link.publisher: 'nobody' matches no service; services: monitor, nav-lqr, ctrl-lqr",
    ),
    (
        ["link", "--from", "ctrl-*", "--to", "ctrl-nobody"],
        "link.subscriber: 'ctrl-nobody' matches no service",
    ),
    (
        ["link", "--from", "environment", "--to", "nav-*"],
        "link: impairs the environment's truth to navigation",
    ),
    (
        ["link", "--from", "nav-lqr", "--to", "monitor"],
        "link.subscriber: the monitor records what is published, unimpaired",
    ),
    (
        ["link", "--from", "nav-lqr", "--to", "ctrl-lqr", "--loss", "1.5"],
        "link.loss: expected a probability in [0, 1], got 1.5",
    ),
    (
        ["link", "--from", "nav-lqr", "--to", "ctrl-lqr", "--jitter", "-1"],
        "link.jitter: expected a finite value >= 0, got -1.0",
    ),
    (
        ["kill", "ctrl-nobody"],
        "kill: 'ctrl-nobody' is not a service of this run; kill one of nav-lqr, ctrl-lqr, "
        "nav-ddvi, ctrl-ddvi",
    ),
    (["kill", "environment"], "kill: the environment is not killed by faults"),
    (
        ["panel", "nobody", "--area-factor", "0.8"],
        "panel.deputy: 'nobody' is not one of lqr, ddvi",
    ),
    (
        ["bias", "lqr", "--position", "2e7", "0", "0"],
        "bias.position_bias[0]: expected a finite number in [-1e+07, 1e+07], got 20000000.0",
    ),
    (
        ["bias", "ddvi", "--position", "0", "0", "0", "--velocity", "0", "-20000", "0"],
        "bias.velocity_bias[1]: expected a finite number in [-10000, 10000], got -20000.0",
    ),
    (
        ["bias", "lqr", "--position", "0", "0", "0", "--area-factor", "2"],
        "bias: area_factor and normal_angle belong to panel faults, not 'bias'",
    ),
    (["outage", "nobody", "--orbits", "0.1"], "outage.deputy: 'nobody' is not one of lqr, ddvi"),
    (
        ["bias", "nosuch", "--position", "1", "0", "0"],
        "bias.deputy: 'nosuch' is not one of lqr, ddvi",
    ),
]
"""A fault the short mission's deployment refuses, and what ``ddvi fault`` says of it."""


def _run_folder(tmp_path: Path, port: int) -> Path:
    """A run folder of the short mission, as the launcher writes it, whose hub nobody serves."""
    folder = tmp_path / "short"
    folder.mkdir()
    bus = {"run": "short", "hub": f"tcp/127.0.0.1:{port}", "security": False}
    (folder / "bus.json").write_text(json.dumps(bus))
    (folder / "deployment.toml").write_text(_short_mission().format(port=port))
    return folder


@pytest.mark.parametrize(("args", "said"), REFUSED_FAULTS)
def test_a_fault_the_runs_deployment_refuses_is_one_line_and_exit_2(
    args: list[str], said: str, tmp_path: Path, free_port: int, capsys: pytest.CaptureFixture
) -> None:
    """Every kind of `ddvi fault` is checked against the run's deployment, as its own [[link]],
    [[fault]] tables and services are, before anything is sent: one line naming the limit,
    exit 2 (a run folder whose hub nobody serves: a fault that passed would say so, exit 1)."""
    folder = _run_folder(tmp_path, free_port)
    assert ddvi(["fault", str(folder), *args, "--timeout", "1"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("ddvi fault: ") and said in err and len(err.splitlines()) == 1, err


def test_a_fault_the_runs_deployment_allows_goes_on_to_the_run(
    tmp_path: Path, free_port: int
) -> None:
    """The same checks pass a legal fault, which then looks for the run (none here: exit 1)."""
    folder = _run_folder(tmp_path, free_port)
    link = ["link", "--from", "nav-lqr", "--to", "ctrl-lqr", "--delay", "50000"]
    cmd = [sys.executable, "-m", "services.cli", "fault", str(folder), *link, "--timeout", "0.5"]
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=60)
    assert r.returncode == 1 and "no clock from run 'short'" in r.stderr, r.stderr


@pytest.mark.parametrize(
    ("args", "status", "text"),
    [
        (["link", "--to", "ctrl-a"], 2, "give --from PUBLISHER and --to SUBSCRIBER"),
        (["kill"], 2, "ddvi fault kill: name the target"),
        (["panel", "a"], 2, "give --area-factor F in (0, 100] and/or --stuck-angle DEG in (0, 90)"),
        (["panel", "a", "--stuck-angle", "95"], 2, "normal_angle must lie in (0, 90) deg"),
        (["bias", "a"], 2, "give --position X Y Z"),
        (["outage", "a", "--orbits", "0"], 2, "give --orbits N (> 0)"),
        (["kill", "ctrl-a", "--timeout", "0.5"], 1, "no clock from run 'norun'"),
    ],
)
def test_fault_command_errors(args: list[str], status: int, text: str, free_port: int) -> None:
    hub = f"tcp/127.0.0.1:{free_port}"
    cmd = [sys.executable, "-m", "services.cli", "fault", "norun", *args, "--hub", hub]
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=60)
    assert r.returncode == status and text in r.stderr, r.stderr


def test_a_fault_for_a_finished_run_says_it_is_over_at_once(
    tmp_path: Path, free_port: int, capsys: pytest.CaptureFixture
) -> None:
    """A run whose folder holds its report (the monitor writes summary.json as the run ends) is
    over: one line saying so and where its report is, exit 1, without waiting for a clock that
    will not come or naming the hub it flew on."""
    folder = _run_folder(tmp_path, free_port)
    (folder / "summary.json").write_text("{}")
    assert ddvi(["fault", str(folder), "kill", "ctrl-lqr", "--timeout", "600"]) == 1
    err = capsys.readouterr().err
    assert err == (
        f"ddvi fault: run 'short' is over (its report: {folder / 'report.md'}); a fault goes to "
        "a run while it flies\n"
    )


@pytest.fixture
def flying_hub(free_port: int) -> Iterator[tuple[str, queue.SimpleQueue]]:
    """An insecure run 'norun' on a hub the test serves (no run folder: ``ddvi fault --hub``):
    the environment's clock ticking and the liveliness of the LQR and DDVI deputies'
    navigation and controllers; yields the hub and what arrives on the fault topics."""
    endpoint = f"tcp/127.0.0.1:{free_port}"
    faults: queue.SimpleQueue = queue.SimpleQueue()
    stop = threading.Event()
    settings = BusSettings(mode="peer", listen=[endpoint], connect=[])
    with open_session(settings) as session:
        buses = [Bus(session, "norun", name) for name in ("environment", *SERVICES)]
        for bus in buses[1:]:
            bus.declare_alive()
        fault_sub = session.declare_subscriber("ddvi/norun/fault/*", faults.put)

        def tick() -> None:
            clock = {"step": 0, "dt": 10.0, "fsw": True, "mode": "lockstep", "final": False}
            for k in itertools.count():
                if stop.wait(0.05):
                    return
                buses[0].publish(topics.CLOCK, "clock", {**clock, "step": k}, 10.0 * k)

        ticker = threading.Thread(target=tick, daemon=True)
        ticker.start()
        try:
            yield endpoint, faults
        finally:
            stop.set()
            ticker.join()
            fault_sub.undeclare()
            for bus in buses:
                bus.close()


SERVICES = ("nav-lqr", "ctrl-lqr", "nav-ddvi", "ctrl-ddvi")


def test_a_fault_for_a_deputy_the_run_reached_by_hub_lacks_is_bad_input(
    flying_hub: tuple[str, queue.SimpleQueue],
) -> None:
    """A run reached by --hub alone has no deployment here to check the fault against: its
    deputies are those whose services are alive on its bus.  One not among them is one line
    naming them, exit 2, nothing sent; one among them is sent."""
    hub, faults = flying_hub
    cmd = [sys.executable, "-m", "services.cli", "fault", "norun", "bias"]
    bias = ["--position", "1", "0", "0", "--hub", hub, "--timeout", "1"]
    r = subprocess.run([*cmd, "nosuch", *bias], capture_output=True, text=True, timeout=60)
    said = "ddvi fault bias: 'nosuch' is not a deputy of run 'norun'; its deputies: ddvi, lqr\n"
    assert r.returncode == 2 and r.stderr == said, r.stderr
    # a deputy of the run: sent (nobody here answers for nav-lqr: exit 1)
    r = subprocess.run([*cmd, "lqr", *bias], capture_output=True, text=True, timeout=60)
    assert r.returncode == 1 and "no answer from nav-lqr" in r.stderr, r.stderr
    sent = faults.get(timeout=10)
    assert str(sent.key_expr) == "ddvi/norun/fault/bias"
    assert faults.empty()  # the refused fault never went out
