"""The ground monitor as a real process on a real zenoh hub: recording, report, stop paths;
and ``ddvi monitor`` (the tap) on that hub."""

from __future__ import annotations

import argparse
import csv
import json
import math
import os
import queue
import signal
import subprocess
import sys
import threading
import time
from collections import Counter
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import msgpack
import numpy as np
import pytest
import zenoh
from mcap.reader import make_reader

from ddvi_core.constants import MU_EARTH
from ddvi_core.orbit import rv_to_hill
from services.bus import Bus, BusSettings, open_session, wait_for_alive
from services.config import load_deployment
from services.ground.monitoring.tap import add_monitor_arguments, format_sample, monitor_command
from services.ground.storage.recording import read_recording
from services.interface import topics
from services.model import lqr_gains, orbit_period
from tests.support import json_messages, wait_until

ROOT = Path(__file__).resolve().parents[2]
TIMEOUT = 10.0
A = 6678136.0
INC = math.radians(45.0)

DEPLOYMENT = """
[run]
name = "montest"
orbits = 0.5
nav_period = 10.0
fsw_period = 60.0

[[deputy]]
name = "alpha"
controller = "lqr"
y_ref = 0.0

[[deputy]]
name = "beta"
controller = "ddvi"
y_ref = -20.0
"""


# every test here runs on a zenoh hub, most with the monitor as a process
pytestmark = pytest.mark.integration


@pytest.fixture
def hub(free_port: int) -> Iterator[tuple[zenoh.Session, str]]:
    endpoint = f"tcp/127.0.0.1:{free_port}"
    with open_session(BusSettings(mode="peer", listen=[endpoint], connect=[])) as session:
        yield session, endpoint


def circular(theta: float, a: float = A) -> tuple[np.ndarray, np.ndarray]:
    c, s = math.cos(theta), math.sin(theta)
    r = a * np.array([c, s * math.cos(INC), s * math.sin(INC)])
    v = math.sqrt(MU_EARTH / a) * np.array([-s, c * math.cos(INC), c * math.sin(INC)])
    return r, v


class Monitor:
    """The monitor subprocess of one test."""

    def __init__(self, tmp: Path, hub: tuple[zenoh.Session, str], run: str) -> None:
        self.session, endpoint = hub
        self.run = run
        self.out = tmp / "out"
        self.dep_path = tmp / "deployment.toml"
        self.dep_path.write_text(DEPLOYMENT)
        self.dep = load_deployment(str(self.dep_path))
        self.log_path = tmp / "monitor.log"
        env = dict(os.environ, PYTHONPATH=str(ROOT), OPENBLAS_NUM_THREADS="1")
        args = ["--deployment", str(self.dep_path), "--run", run, "--hub", endpoint]
        with self.log_path.open("w") as log:
            self.proc = subprocess.Popen(
                [
                    sys.executable,
                    "-m",
                    "services.ground.monitoring.monitor",
                    *args,
                    "--out",
                    str(self.out),
                ],
                cwd=ROOT,
                env=env,
                stdout=log,
                stderr=subprocess.STDOUT,
            )
        alive = wait_for_alive(self.session, run, ["monitor"], TIMEOUT)
        assert alive == {"monitor"}, self.log()
        # The subscriber is declared right after the token: wait until it matches here.
        probe = self.session.declare_publisher(f"ddvi/{run}/probe")
        try:
            assert wait_until(lambda: probe.matching_status.matching, TIMEOUT), self.log()
        finally:
            probe.undeclare()

    def log(self) -> str:
        return self.log_path.read_text()

    def wait(self, timeout: float = 20.0) -> int:
        try:
            return self.proc.wait(timeout)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
            pytest.fail(f"monitor did not exit:\n{self.log()}")

    def close(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()


@pytest.fixture
def monitor(tmp_path: Path, hub: tuple[zenoh.Session, str], run_name: str) -> Iterator[Monitor]:
    m = Monitor(tmp_path, hub, run_name)
    try:
        yield m
    finally:
        m.close()


class Mission:
    """A synthetic mission published by fake services; counts what it publishes by topic."""

    SERVICES = ("environment", "nav-alpha", "ctrl-alpha", "nav-beta", "ctrl-beta")

    def __init__(self, session: zenoh.Session, run: str, dep: Any) -> None:
        self.session, self.run, self.dep = session, run, dep
        self.period = orbit_period(dep)
        self.n = 2 * math.pi / self.period
        self.buses = {s: Bus(session, run, s) for s in self.SERVICES}
        self.sent: Counter[str] = Counter()
        self.K_lqr = {d.name: np.asarray(lqr_gains(dep, d)[0]) for d in dep.deputy}
        self.K_beta = self.K_lqr["beta"] * 1.01  # the "learned" gain: 1 % off LQR
        self.t_learn = 1200.0
        self.t_detect, self.t_relearn = 1800.0, 2400.0  # K0 again, then the same K re-learned
        self.last_truth: dict[str, tuple[np.ndarray, np.ndarray]] = {}

    def pub(self, service: str, topic: str, schema: str, body: dict[str, Any], t: float) -> None:
        self.buses[service].publish(topic, schema, body, t)
        self.sent[topic] += 1

    def offset(self, name: str, t: float) -> float:
        """Along-track angle of a deputy behind the chief (decays for beta)."""
        return 3e-5 if name == "alpha" else 1e-4 * math.exp(-t / 1000.0)

    def step(self, k: int, last: int) -> None:
        t = 10.0 * k
        fsw = k % 6 == 0
        clock = {"step": k, "dt": 10.0, "fsw": fsw, "mode": "lockstep", "final": k == last}
        self.pub("environment", topics.CLOCK, "clock", clock, t)
        theta = self.n * t
        for sc in ("chief", "alpha", "beta"):
            r, v = circular(theta - (0.0 if sc == "chief" else self.offset(sc, t)))
            self.last_truth[sc] = (r, v)
            body = {"sc": sc, "r_N": r, "v_N": v, "sigma_BN": np.zeros(3)}
            self.pub("environment", topics.truth_topic(sc), "truth", body, t)
        u = theta
        v5 = [1.0, math.cos(u), math.sin(u), math.cos(2 * u), math.sin(2 * u)]
        self.pub("environment", topics.EXOSTATE, "exo", {"v": v5, "phase": u}, t)
        for sc in ("alpha", "beta"):
            rc, vc = self.last_truth["chief"]
            rd, vd = self.last_truth[sc]
            nav = {
                "sc": sc,
                "x_hill": rv_to_hill(rc, vc, rd, vd) + 0.01,
                "z_hill": rv_to_hill(rc, vc, rd, vd) + 0.02,
                "cov": np.eye(6) * 1e-4,
                "altitude": 300e3,
                "valid": True,
            }
            self.pub(f"nav-{sc}", topics.nav_state_topic(sc), "nav", nav, t)
        if fsw:
            for sc in ("alpha", "beta"):
                sigma = [0.0, 0.0, 0.1 * math.sin(t / 300.0)]
                cmd = {"sc": sc, "sigma": sigma, "for_t": t}
                self.pub(f"ctrl-{sc}", topics.command_topic(sc), "cmd", cmd, t)
            if k == 0:
                self.gains("alpha", self.K_lqr["alpha"], "lqr", t)
            if t < self.t_learn or self.t_detect <= t < self.t_relearn:
                self.gains("beta", np.zeros((1, 4)), "initial", t)
            elif t in (self.t_learn, self.t_relearn):
                self.gains("beta", self.K_beta, "ddvi", t)
            if k % 30 == 0:
                for sc, mode in (("alpha", "lqr"), ("beta", "ddvi")):
                    phase = (
                        "lqr" if mode == "lqr" else ("exploring" if t < self.t_learn else "learned")
                    )
                    status = {
                        "sc": sc,
                        "mode": mode,
                        "phase": phase,
                        "samples": k,
                        "intervals": k // 60,
                        "rank": 0,
                        "rank_needed": 34,
                        "counters": {"iterations": 3},
                    }
                    self.pub(f"ctrl-{sc}", topics.status_topic(sc), "status", status, t)
                self.stats(t)

    def gains(self, sc: str, K: np.ndarray, source: str, t: float) -> None:
        body = {
            "sc": sc,
            "K": K,
            "L": np.zeros((1, 5)),
            "source": source,
            "iteration": 7,
            "converged": source != "initial",
        }
        self.pub(f"ctrl-{sc}", topics.gains_topic(sc), "gains", body, t)

    def stats(self, t: float, only: tuple[str, ...] | None = None) -> None:
        for s in only or self.SERVICES:
            counters = dict(self.buses[s].counters)
            if s == "environment":
                counters.update(late_commands=2, missing_commands=0)
            self.pub(s, topics.stats_topic(s), "stats", {"service": s, "counters": counters}, t)

    def garbage(self) -> None:
        self.session.put(f"ddvi/{self.run}/garbage", b"\xc1 definitely not msgpack")

    def close(self) -> None:
        for bus in self.buses.values():
            bus.close()


def samples(dep: Any) -> int:
    from services.model import duration

    return int(duration(dep) // dep.run.nav_period) + 1


def recorded_topics(path: Path) -> tuple[Counter[str], list[Any], bool]:
    messages, complete = read_recording(path)
    data = Counter(
        m.topic
        for m in messages
        if not m.topic.startswith(("alive/", "rejected/"))
        and m.topic not in ("stats/monitor", "recorded")  # the monitor's own
    )
    return data, messages, complete


# ---- the full path --------------------------------------------------------------------------


def test_monitor_records_and_reports_a_mission(monitor: Monitor) -> None:
    start = time.monotonic()
    mission = Mission(monitor.session, monitor.run, monitor.dep)
    last = samples(monitor.dep) - 1
    try:
        for k in range(last + 1):
            mission.step(k, last)
            if k == 50:
                mission.garbage()
        mission.stats(10.0 * last)  # the final stats, after the final clock
    finally:
        mission.close()
    assert monitor.wait() == 0, monitor.log()
    elapsed = time.monotonic() - start
    assert "no final stats" not in monitor.log()  # it did not wait out FINAL_WAIT
    out = monitor.out

    # -- the recording: every message published, plus the rejected one
    with (out / "recording.mcap").open("rb") as f:
        reader = make_reader(f)
        summary_rec = reader.get_summary()
        assert summary_rec is not None and summary_rec.statistics is not None
        n_stat = json_messages(summary_rec)
        first = next(iter(reader.iter_messages(topics=["truth/beta"])))
    data, messages, complete = recorded_topics(out / "recording.mcap")
    assert complete and n_stat == len(messages)
    assert data == mission.sent
    rejected = [m for m in messages if m.topic.startswith("rejected/")]
    assert [(m.topic, m.data["reason"]) for m in rejected] == [("rejected/garbage", "malformed")]
    assert any(m.topic == "alive/monitor" and m.data["alive"] for m in messages)
    schema, channel, message = first
    assert schema.encoding == "jsonschema" and channel.message_encoding == "json"
    assert json.loads(schema.data)["title"] == "ddvi.truth"
    body = json.loads(message.data)
    assert body["schema"] == "truth" and body["src"] == "environment" and len(body["body"]["r_N"])
    assert message.log_time == 0 and message.publish_time > 1.6e18  # sim t = 0, wall clock

    # -- summary.json
    summary = json.loads((out / "summary.json").read_text())
    assert summary["completed"] is True and summary["run"] == monitor.run
    assert summary["sim_time_s"] == 10.0 * last
    assert summary["orbits"] == pytest.approx(10.0 * last / mission.period)
    assert 0 < summary["wall_s"] < elapsed
    assert set(summary["deputies"]) == {"alpha", "beta"}
    rc, vc = mission.last_truth["chief"]
    for name, y_ref in (("alpha", 0.0), ("beta", -20.0)):
        d = summary["deputies"][name]
        rd, vd = mission.last_truth[name]
        h = rv_to_hill(rc, vc, rd, vd)
        assert d["final_along_track_error_m"] == pytest.approx(abs(h[1] - y_ref), rel=1e-9)
        assert d["final_radial_m"] == pytest.approx(abs(h[0]), rel=1e-6)
        assert d["max_along_track_error_last_orbit_m"] >= d["final_along_track_error_m"]
        assert d["samples"] == last + 1
    alpha, beta = summary["deputies"]["alpha"], summary["deputies"]["beta"]
    assert alpha["final_along_track_error_m"] == pytest.approx(A * math.sin(3e-5) - 0, rel=1e-6)
    assert alpha["gain_error_vs_lqr"] is None and alpha["learned_at_orbits"] is None
    assert alpha["gains"]["source"] == "lqr" and alpha["phase"] == "lqr"
    assert beta["gain_error_vs_lqr"] == pytest.approx(0.01, rel=1e-6)
    assert beta["learned_at_orbits"] == pytest.approx(mission.t_learn / mission.period)
    assert beta["relearned_at_orbits"] == [pytest.approx(mission.t_relearn / mission.period)]
    assert alpha["relearned_at_orbits"] == []
    assert np.allclose(beta["gains"]["K"], mission.K_beta) and beta["phase"] == "learned"
    msgs = summary["messages"]
    assert msgs["rejected"] == 1 and msgs["rejected_by_reason"] == {"malformed": 1}
    assert msgs["recorded"] == len(messages)
    assert set(msgs["services"]) == {*Mission.SERVICES, "monitor"}
    assert msgs["totals"]["late"] == 2
    sent_before_final = sum(mission.buses[s].counters["sent"] for s in Mission.SERVICES)
    assert sent_before_final - len(Mission.SERVICES) <= msgs["totals"]["sent"]
    _check_files(out, summary, last)


def _check_files(out: Path, summary: dict[str, Any], last: int) -> None:
    """The figures, the CSV and report.md of the synthetic mission ending at step ``last``."""
    for name in summary["figures"]:
        assert (out / name).stat().st_size > 5000
    assert {
        "hill_x.png",
        "hill_y.png",
        "hill_xy.png",
        "hill_xdot.png",
        "hill_ydot.png",
        "sigma3.png",
        "gains.png",
    } <= set(summary["figures"])
    with (out / "timeseries.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 2 * (last + 1) == summary["csv_rows"]
    row = rows[-1]
    assert row["deputy"] == "beta" and float(row["t"]) == 10.0 * last
    assert float(row["nav_y"]) == pytest.approx(float(row["y"]) + 0.01, abs=1e-6)
    assert float(row["sigma3"]) == pytest.approx(0.1 * math.sin(10.0 * last // 60 * 60 / 300))
    assert row["phase"] == "learned"
    report = (out / "report.md").read_text()
    assert "| beta | ddvi |" in report and "gains.png" in report


# ---- stop paths -----------------------------------------------------------------------------


def _publish_part(monitor: Monitor, steps: int) -> Mission:
    mission = Mission(monitor.session, monitor.run, monitor.dep)
    last = samples(monitor.dep) - 1
    try:
        for k in range(steps):
            mission.step(k, last)
    finally:
        mission.close()
    return mission


def test_sigterm_mid_run_gives_a_closed_recording_and_a_partial_report(monitor: Monitor) -> None:
    mission = _publish_part(monitor, 60)
    # a marker behind the mission on the same session: once the monitor says it refused it,
    # it has taken in every message before it (recorded, not necessarily flushed yet)
    key = f"ddvi/{monitor.run}/marker"
    block = zenoh.CongestionControl.BLOCK
    monitor.session.put(key, b"\xc1 after the mission", congestion_control=block)
    assert wait_until(lambda: f"rejected {key} (malformed" in monitor.log(), TIMEOUT), monitor.log()
    monitor.proc.send_signal(signal.SIGTERM)
    assert monitor.wait() == 0, monitor.log()
    data, _, complete = recorded_topics(monitor.out / "recording.mcap")
    assert complete, "the writer must be closed (footer written) on SIGTERM"
    assert data == mission.sent
    summary = json.loads((monitor.out / "summary.json").read_text())
    assert summary["completed"] is False
    assert summary["sim_time_s"] == 590.0
    assert summary["deputies"]["beta"]["samples"] == 60


def test_kill_9_loses_at_most_the_last_flush_period(monitor: Monitor) -> None:
    mission = _publish_part(monitor, 40)
    path = monitor.out / "recording.mcap"
    # within a flush period of the last message, all of it is in the file...
    assert wait_until(lambda: recorded_topics(path)[0] == mission.sent), recorded_topics(path)[0]
    monitor.proc.kill()  # ... and a kill -9 takes none of it away
    monitor.proc.wait()
    data, _, complete = recorded_topics(monitor.out / "recording.mcap")
    assert not complete
    assert data == mission.sent


# ---- any client can read the bus ------------------------------------------------------------


def test_a_plain_zenoh_subscriber_decodes_bus_messages_with_msgpack_alone(
    hub: tuple[zenoh.Session, str], run_name: str
) -> None:
    session, endpoint = hub
    config = zenoh.Config()  # a client that knows nothing of services.bus.endpoint
    config.insert_json5("mode", '"peer"')
    config.insert_json5("connect/endpoints", json.dumps([endpoint]))
    config.insert_json5("scouting/multicast/enabled", "false")
    received: queue.Queue[tuple[str, bytes]] = queue.Queue()
    client = zenoh.open(config)
    try:
        sub = client.declare_subscriber(
            f"ddvi/{run_name}/**", lambda s: received.put((str(s.key_expr), s.payload.to_bytes()))
        )
        with Bus(session, run_name, "nav-alpha") as bus:
            body = {
                "sc": "alpha",
                "x_hill": [1.0, 2.0, 3.0, 0.1, 0.2, 0.3],
                "z_hill": [1.1, 2.1, 3.1, 0.1, 0.2, 0.3],
                "cov": np.eye(6).tolist(),
                "altitude": 300e3,
                "valid": True,
            }
            assert wait_until(
                lambda: (
                    bus.publish("nav/alpha/state", "nav", body, 12.5) >= 0 and not received.empty()
                ),
                TIMEOUT,
            )
            # one more behind the probes: take every probe out up to it, keep the first
            last = bus.publish("nav/alpha/state", "nav", body, 12.5)
            first = received.get(timeout=TIMEOUT)
            taken = first
            while msgpack.unpackb(taken[1])["seq"] != last:
                taken = received.get(timeout=TIMEOUT)
            assert received.empty()
            received.put(first)
            with bus.batch():
                for t in (20.0, 30.0, 40.0):
                    bus.publish("nav/alpha/state", "nav", body, t)
            assert wait_until(lambda: received.qsize() == 2, TIMEOUT)
        sub.undeclare()
    finally:
        client.close()
    key, payload = received.get_nowait()
    batches = [received.get_nowait()[1]]
    msg = msgpack.unpackb(payload)
    assert key == f"ddvi/{run_name}/nav/alpha/state"
    assert set(msg) == {"schema", "version", "seq", "t", "src", "boot", "body"}
    assert (msg["schema"], msg["t"], msg["src"]) == ("nav", 12.5, "nav-alpha")
    assert msg["body"] == body
    # a batch (one step's messages of a topic in one sample) is a msgpack array of payloads
    (batch,) = batches
    parts = msgpack.unpackb(batch)
    assert isinstance(parts, list) and len(parts) == 3
    assert [msgpack.unpackb(p)["t"] for p in parts] == [20.0, 30.0, 40.0]
    assert all(msgpack.unpackb(p)["body"] == body for p in parts)


# ---- ddvi monitor and helpers ---------------------------------------------------------------


def test_monitor_command_prints_one_line_per_message(
    hub: tuple[zenoh.Session, str], run_name: str
) -> None:
    session, endpoint = hub
    args = add_monitor_arguments(argparse.ArgumentParser()).parse_args(
        [f"ddvi/{run_name}/**", "--hub", endpoint, "--count", "3", "--seconds", "10"]
    )
    lines: list[str] = []
    result: list[int] = []
    thread = threading.Thread(target=lambda: result.append(monitor_command(args, lines.append)))
    thread.start()
    with Bus(session, run_name, "environment") as bus:
        clock = {"step": 1, "dt": 10.0, "fsw": True, "mode": "lockstep", "final": False}

        def published_until_heard() -> bool:  # until it has printed its 3 lines and returned
            bus.publish("clock", "clock", clock, 10.0)
            session.put(f"ddvi/{run_name}/junk", b"\x00\x01")
            return not thread.is_alive()

        assert wait_until(published_until_heard, 3 * TIMEOUT)
    thread.join(TIMEOUT)
    assert result == [0] and len(lines) == 3
    assert any(f"ddvi/{run_name}/clock clock t=10.000 src=environment" in ln for ln in lines)
    assert "REJECTED malformed" in format_sample("k", b"\x00\x01")[0]
