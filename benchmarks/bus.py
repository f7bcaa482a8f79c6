"""Bus benchmark: the project's bus layer against plain zenoh-python with plain msgpack.

Two OS processes on loopback (peer mode, explicit endpoints, no scouting): this one pings, an
echo process (``python -m benchmarks.bus echo``) answers.  Measured for each layer:

- round trip: one navigation-sized message out, the echo's reply back, one at a time (median
  and p99);
- one-way throughput: a burst of messages, timed from the first put to the echo's report that
  it has received them all, the median of three bursts; for the project's layer also with the
  burst put out in ``Bus.batch()`` blocks of six, as a lock-step step sends them (against the
  same plain figure: plain zenoh puts each message).

``project``: ``services.bus.endpoint.Bus`` on both sides: schema encode with the header, decode with
validation (type, shape, finiteness), the replay window, a zero-delay link model on the
receiving route (a perfect link holding nothing: checked, and the message passes), the
handler.  ``plain``: ``session.put(msgpack.packb(...))`` and ``msgpack.unpackb`` in a zenoh
callback, the same dictionary (header and body) on the wire.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import queue
import statistics
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from typing import Any

import msgpack
import numpy as np
import zenoh

from services.bus import Bus, BusSettings, LinkModel, LinkSpec, open_session
from services.ground.launch.launcher import free_port
from services.interface import SCHEMAS

RUN = "bench"
STEP_BATCH = 6  # messages of a topic in one lock-step step (six 10 s samples a 60 s step)
BURSTS = 3  # bursts timed for each throughput figure, the median reported (one is noisy)
ECHO_READY = "ready"
BODY = {
    "sc": "deputy1",
    "x_hill": np.array([12.5, -33000.25, 0.5, 0.0031, -0.0079, 0.0004]),
    "z_hill": np.array([13.1, -33000.9, 0.2, 0.0042, -0.0065, 0.0011]),
    "cov": np.diag([0.02, 0.02, 0.02, 4e-8, 4e-8, 4e-8]),
    "altitude": 300e3,
    "valid": True,
}


def _plain_body() -> dict[str, Any]:
    plain = {k: BODY[k].tolist() for k in ("x_hill", "z_hill", "cov")}
    return {**BODY, **plain}


class _Side:
    """One process's end of one layer: send(kind, t), and a callback on(kind, t) on receipt."""

    def __init__(self, session: zenoh.Session, layer: str, me: str, peer: str) -> None:
        self.layer, self.session, self.me, self.peer = layer, session, me, peer
        self.handlers: dict[str, Callable[[float], None]] = {}
        self._seq = 0
        if layer == "project":
            self.bus = Bus(session, RUN, me)
            for kind in ("data", "ctl"):
                self.bus.subscribe(
                    f"{peer}/{kind}",
                    lambda _topic, msg, k=kind: self.handlers[k](msg.t),
                    expected_schema="nav",
                    link=LinkModel(LinkSpec(), seed=0, clock="wall"),
                )
        else:
            self.pubs = {
                kind: session.declare_publisher(
                    f"ddvi/{RUN}/{me}/{kind}", congestion_control=zenoh.CongestionControl.BLOCK
                )
                for kind in ("data", "ctl")
            }
            self.subs = [
                session.declare_subscriber(
                    f"ddvi/{RUN}/{peer}/{kind}",
                    lambda sample, k=kind: self.handlers[k](
                        msgpack.unpackb(sample.payload.to_bytes())["t"]
                    ),
                )
                for kind in ("data", "ctl")
            ]

    def send(self, kind: str, t: float) -> None:
        if self.layer == "project":
            self.bus.publish(f"{self.me}/{kind}", "nav", BODY, t)
            return
        self._seq += 1
        header = {
            "schema": "nav",
            "version": SCHEMAS["nav"].version,
            "seq": self._seq,
            "t": t,
            "src": self.me,
        }
        self.pubs[kind].put(msgpack.packb({**header, "body": _plain_body()}))

    def close(self) -> None:
        if self.layer == "project":
            self.bus.close()
        else:
            for s in self.subs:
                s.undeclare()
            for p in self.pubs.values():
                p.undeclare()


def echo(layer: str, connect: str) -> int:
    """The echo process: answers every ``data`` message with one of its own; on a ``ctl``
    message with t = N > 0 counts the next N data messages without answering and reports on
    ``ctl`` when it has them all; ctl with t = -1 ends it."""
    settings = BusSettings(mode="peer", listen=["tcp/127.0.0.1:0"], connect=[connect])
    done = threading.Event()
    with open_session(settings) as session:
        side = _Side(session, layer, "echo", "ping")
        state = {"expect": 0, "count": 0}
        lock = threading.Lock()

        def on_data(t: float) -> None:
            with lock:
                if state["expect"]:
                    state["count"] += 1
                    if state["count"] == state["expect"]:
                        state["expect"] = 0
                        side.send("ctl", float(state["count"]))
                    return
            side.send("data", t)

        greeted = threading.Event()

        def on_ctl(t: float) -> None:
            greeted.set()
            if t < 0:
                done.set()
                return
            with lock:
                state["expect"], state["count"] = int(t), 0
            side.send("ctl", 0.0)  # armed

        side.handlers.update(data=on_data, ctl=on_ctl)
        try:
            # say hello until the pinger answers (its route to us may not exist yet)
            while not greeted.wait(0.2):
                side.send("ctl", -2.0)
            done.wait()
        finally:
            side.close()
    return 0


def _measure(layer: str, pings: int, burst: int) -> dict[str, float]:
    port = free_port()
    hub = f"tcp/127.0.0.1:{port}"
    settings = BusSettings(mode="peer", listen=[hub], connect=[])
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1"}
    replies: queue.Queue[float] = queue.Queue()
    ctl: queue.Queue[float] = queue.Queue()
    with open_session(settings) as session:
        side = _Side(session, layer, "ping", "echo")
        side.handlers.update(data=replies.put, ctl=ctl.put)
        proc = subprocess.Popen(
            [sys.executable, "-m", "benchmarks.bus", "echo", "--layer", layer, "--connect", hub],
            env=env,
        )
        try:
            while ctl.get(timeout=30) != -2.0:
                pass
            side.send("ctl", 0.0)  # any ctl tells the echo it was heard
            time.sleep(0.3)
            while not ctl.empty():
                ctl.get_nowait()
            rtts = []
            for i in range(pings + pings // 10):  # the first tenth warms up
                t0 = time.perf_counter()
                side.send("data", float(i))
                while replies.get(timeout=10) != float(i):
                    pass
                if i >= pings // 10:
                    rtts.append(time.perf_counter() - t0)
            walls: dict[int, list[float]] = {}
            # one message a put; then (the project's layer only) lock-step batches of six
            for batch in (1, STEP_BATCH) if layer == "project" else (1,):
                for _ in range(BURSTS):
                    side.send("ctl", float(burst))
                    while ctl.get(timeout=10) != 0.0:
                        pass
                    t0 = time.perf_counter()
                    for i in range(0, burst, batch):
                        with side.bus.batch() if batch > 1 else contextlib.nullcontext():
                            for j in range(i, min(i + batch, burst)):
                                side.send("data", float(j))
                    while ctl.get(timeout=60) != float(burst):
                        pass
                    walls.setdefault(batch, []).append(time.perf_counter() - t0)
            side.send("ctl", -1.0)
            proc.wait(timeout=10)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
            side.close()
    rtts.sort()
    out = {
        "rtt_median_us": 1e6 * statistics.median(rtts),
        "rtt_p99_us": 1e6 * rtts[min(len(rtts) - 1, int(0.99 * len(rtts)))],
        "throughput_msg_s": burst / statistics.median(walls[1]),
    }
    if STEP_BATCH in walls:
        out["throughput_batched_msg_s"] = burst / statistics.median(walls[STEP_BATCH])
    return out


def bench_bus(quick: bool = False) -> list[dict[str, Any]]:
    """Rows for the bus benchmark: project layer against plain zenoh + msgpack."""
    pings, burst = (500, 5_000) if quick else (3_000, 50_000)
    project = _measure("project", pings, burst)
    plain = _measure("plain", pings, burst)
    plain["throughput_batched_msg_s"] = plain["throughput_msg_s"]  # plain zenoh: a put each
    rows = []
    for key, label, unit, lower_better in (
        ("rtt_median_us", "round trip, median", "us", True),
        ("rtt_p99_us", "round trip, p99", "us", True),
        ("throughput_msg_s", "one-way throughput", "msg/s", False),
        (
            "throughput_batched_msg_s",
            f"one-way throughput, Bus.batch() of {STEP_BATCH} (a lock-step step)",
            "msg/s",
            False,
        ),
    ):
        # ratio as cost: >1 means the project's layer is slower
        ratio = project[key] / plain[key] if lower_better else plain[key] / project[key]
        rows.append(
            {
                "benchmark": "bus",
                "metric": label,
                "unit": unit,
                "project": project[key],
                "baseline": plain[key],
                "baseline_name": "plain zenoh + msgpack",
                "cost_ratio": ratio,
                "target": "<= 1.3",
            }
        )
    return rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    sub = ap.add_subparsers(dest="role", required=True)
    e = sub.add_parser("echo")
    e.add_argument("--layer", choices=("project", "plain"), required=True)
    e.add_argument("--connect", required=True)
    args = ap.parse_args(argv)
    return echo(args.layer, args.connect)


if __name__ == "__main__":
    sys.exit(main())
