"""The ROS 2 bridge: its delay in the loop and its cost to the mission.

The delay: a deputy flown by the example ROS 2 node (docs/examples/ros2_lqr_node.py,
zenoh-ros2-sdk in a process of its own) beside the built-in LQR deputy, in lock-step and in
real time.  Per flight-software step T, the monitor's receive wall time (the recording's
publish_time) of the command for T (``cmd/<sc>/att``) less that of the navigation sample
measured at T (``nav/<sc>/state``).  For the ROS 2 deputy the interval holds the bus to the
gateway, its translation to CDR, the ROS 2 side's router, the node's decoding, control law and
publication, the gateway's checks and its put of the command on the bus; for the built-in
deputy (the baseline, same run) the bus to its controller, the law and the put.  Both ends are
received by the same monitor, so its own delivery delay cancels to within its jitter; the
environment, which acts on the command, receives it as the monitor does.

The cost: the default mission (``--quick``: 4 orbits) with ``--ros2`` and one subscriber of
every ROS 2 topic (a process of its own: a Zenoh router on the ROS 2 endpoint, what a user's
``rmw_zenohd`` is, and a zenoh-ros2-sdk subscription to each topic the gateway publishes)
against the same mission without ``--ros2``, and with ``--ros2`` and the router but no
subscriber (the gateway then receives every bus message it would carry and converts and puts
none: the floor under carrying them), in alternated rounds (three with ``--quick``, five
otherwise).  The wall time of ``ddvi run``, the CPU of its processes (launcher, router,
services, the gateway among them) and the CPU of every process: those and the ROS 2 side's,
from its start (imports included) to its end.

    python -m benchmarks.ros2 [--quick] [--json]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.live import alternated_row, print_rows
from benchmarks.live import missing as packages_missing
from benchmarks.mission import _row, skipped_row
from services.config import read_table, write_deployment
from services.ground.launch.launcher import free_port
from services.ground.storage.recording import RECORDING, read_recording

ROOT = Path(__file__).resolve().parents[1]
NODE = ROOT / "docs" / "examples" / "ros2_lqr_node.py"
TARGET = "<= 1.10"
DOMAIN = 0
NEEDS = {
    "zenoh_ros2_sdk": "zenoh-ros2-sdk (the ROS 2 node and subscriber)",
    "rosbags": "rosbags (the gateway's ROS 2 types)",
    "xxhash": "xxhash (the gateway's entity GIDs)",
}
"""The modules the ROS 2 benchmark needs beyond a plain installation: the test extra's."""

FLOWN = "rosd"
BUILT_IN = "lqr"
REALTIME_RATE = 300.0
"""Simulated seconds per wall second of the real-time delay run: a step every 0.2 s of wall
time, a navigation sample every 33 ms."""


def missing() -> str | None:
    """Why the ROS 2 benchmark cannot run here (what is not installed), or None."""
    return packages_missing(NEEDS)


def _children_cpu() -> float:
    """CPU seconds (user and system) of this process's waited-for descendants so far."""
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def _env() -> dict[str, str]:
    path = os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])
    return {**os.environ, "PYTHONPATH": path, "OPENBLAS_NUM_THREADS": "1"}


@contextmanager
def ros_side(
    port: int, folder: Path, deployment: Path | None = None
) -> Iterator[subprocess.Popen[str]]:
    """This module's ``--ros-side`` process: a Zenoh router on 127.0.0.1:``port`` (and, given
    a ``deployment``, a subscriber of every ROS 2 topic its gateway publishes), once it says it
    is ready; stopped with SIGTERM and waited for on leaving (its counts on its stdout)."""
    definitions = folder / "msg"
    write_msg_definitions(definitions)
    cmd = [sys.executable, "-m", "benchmarks.ros2", "--ros-side", str(port), str(definitions)]
    cmd += [str(deployment)] if deployment is not None else []
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, text=True, env=_env())
    try:
        assert proc.stdout is not None
        line = proc.stdout.readline()
        if line.strip() != "ready":
            raise RuntimeError(f"the ROS 2 side did not start ({proc.wait(timeout=30)})")
        yield proc
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout=60)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def write_msg_definitions(folder: Path) -> None:
    """The ``.msg`` files of every type the gateway exposes, for zenoh-ros2-sdk (no download)."""
    from services.ros2 import messages

    for ros_type in messages.EXPOSED_TYPES:
        for name, text in messages.message_definitions(ros_type).items():
            path = folder / (name + ".msg")
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_text(text)


def serve_ros_side(port: int, definitions: str, deployment: str | None) -> int:
    """The ``--ros-side`` process: the router, and a subscription to every topic of
    ``deployment``'s gateway; ``ready`` on stdout, then on SIGTERM the messages received per
    topic as JSON."""
    import zenoh
    from zenoh_ros2_sdk import ROS2Subscriber, ZenohSession, get_registry

    from services.config import load_deployment
    from services.ros2.gateway.exposure import ros_topics

    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    config = zenoh.Config()
    config.insert_json5("mode", json.dumps("router"))
    config.insert_json5("listen/endpoints", json.dumps([f"tcp/127.0.0.1:{port}"]))
    config.insert_json5("connect/endpoints", "[]")
    config.insert_json5("scouting/multicast/enabled", "false")
    counts: dict[str, int] = {}
    subscriptions: list[Any] = []
    with zenoh.open(config):
        try:
            if deployment is not None:
                get_registry(definitions)
                dep = load_deployment(deployment)
                optimal = {d.name: True for d in dep.deputy}
                where = {"node_name": "ddvi_bench", "domain_id": dep.ros2.domain_id}
                where |= {"router_ip": "127.0.0.1", "router_port": port}
                for topic in ros_topics(dep, optimal):
                    counts[topic.name] = 0

                    def count(_msg: Any, name: str = topic.name) -> None:
                        counts[name] += 1

                    subscriptions.append(
                        ROS2Subscriber(
                            topic=topic.name, msg_type=topic.ros_type, callback=count, **where
                        )
                    )
            print("ready", flush=True)
            stop.wait()
        finally:
            for subscription in subscriptions:
                subscription.close()
            if ZenohSession._instance is not None:
                ZenohSession._instance.close()
    print(json.dumps(counts), flush=True)
    return 0


def _announced(port: int, domain: int) -> set[tuple[str, str]]:
    """(topic, kind) of every ROS 2 endpoint announced on the router at ``port``."""
    from services.bus import BusSettings, open_session
    from services.ros2 import keys

    settings = BusSettings(mode="client", listen=[], connect=[f"tcp/127.0.0.1:{port}"])
    with open_session(settings) as session:
        replies = session.liveliness().get(keys.liveliness_pattern(domain), timeout=1.0)
        found = [keys.parse_token(str(r.ok.key_expr)) for r in replies if r.ok is not None]
    return {(e.topic, str(e.kind)) for e in found if isinstance(e, keys.Endpoint)}


def _wait_for_node(port: int, node: subprocess.Popen[str], timeout: float = 60.0) -> None:
    """Until the node's subscriptions and publisher are announced on the router (the gateway
    carries nothing to a topic no one reads yet)."""
    from services.ros2.keys import EntityKind

    wanted = {
        ("/clock", str(EntityKind.SUBSCRIPTION)),
        (f"/{FLOWN}/odom", str(EntityKind.SUBSCRIPTION)),
        (f"/{FLOWN}/altitude", str(EntityKind.SUBSCRIPTION)),
        (f"/{FLOWN}/cmd_attitude", str(EntityKind.PUBLISHER)),
    }
    end = time.monotonic() + timeout
    while not wanted <= _announced(port, DOMAIN):
        if node.poll() is not None or time.monotonic() > end:
            raise RuntimeError(f"the example node did not come up ({node.poll()})")
        time.sleep(0.2)


def _ddvi_run(
    path: Path, out: Path, options: list[str], ok: tuple[int, ...] = (0,)
) -> tuple[float, float, Path]:
    """``ddvi run path --quiet`` with ``options``, its exit status one of ``ok``: its wall
    time, the CPU of its processes (the launcher waits for every service) and its run
    folder."""
    cmd = [sys.executable, "-m", "services.cli", "run", str(path), "--quiet", "--output", str(out)]
    t0, cpu0 = time.perf_counter(), _children_cpu()
    proc = subprocess.run(cmd + options, capture_output=True, text=True, env=_env(), check=False)
    wall, cpu = time.perf_counter() - t0, _children_cpu() - cpu0
    if proc.returncode not in ok:
        raise RuntimeError(f"ddvi run {path} failed ({proc.returncode}): {proc.stderr[-2000:]}")
    return wall, cpu, Path(proc.stdout.strip().splitlines()[-1])


def flown_table(orbits: float, mode: str) -> dict[str, Any]:
    """The default mission's table with the deputy ``lqr`` and the deputy ``rosd`` flown from
    ROS 2, ``orbits`` long, in ``mode`` (real time at ``REALTIME_RATE``)."""
    table = read_table(None)
    table["run"].update(name="ros2bench", orbits=orbits, mode=mode)
    if mode == "realtime":
        table["run"]["rate"] = REALTIME_RATE
    table["ros2"] = {"enabled": True, "domain_id": DOMAIN}
    table["deputy"] = [
        {"name": BUILT_IN, "controller": "lqr"},
        {"name": FLOWN, "controller": "ros2"},
    ]
    return table


def step_delays(recording: Path, sc: str) -> np.ndarray:
    """Per step the deputy ``sc`` was commanded for, the monitor's receive wall time of the
    command less that of the navigation sample of the same step (s)."""
    nav: dict[float, int] = {}
    cmd: dict[float, int] = {}
    for item in read_recording(recording)[0]:
        if item.topic == f"nav/{sc}/state":
            nav[float(item.data["t"])] = item.publish_time
        elif item.topic == f"cmd/{sc}/att":
            cmd[float(item.data["body"]["for_t"])] = item.publish_time
    steps = sorted(set(nav) & set(cmd))
    return np.array([(cmd[t] - nav[t]) / 1e9 for t in steps])


def delay_run(
    folder: Path, orbits: float, mode: str
) -> tuple[dict[str, np.ndarray], dict[str, int]]:
    """One run of ``flown_table`` with the example node flying ``rosd``: each deputy's step
    delays, and the environment's counts of commands refused, stale, missing and late (a
    completed mission with some, exit status 3, is measured as well)."""
    port = free_port()
    path = write_deployment(flown_table(orbits, mode), folder, f"flown-{mode}")
    with ros_side(port, folder):
        cmd = [sys.executable, str(NODE), str(path), "--deputy", FLOWN]
        cmd += ["--router", f"127.0.0.1:{port}", "--messages", str(folder / "msg")]
        node = subprocess.Popen(cmd, stderr=subprocess.PIPE, text=True, env=_env())
        try:
            _wait_for_node(port, node)
            endpoint = f"tcp/127.0.0.1:{port}"
            options = ["--ros2", endpoint]
            _, _, out = _ddvi_run(path, folder / f"runs-{mode}", options, ok=(0, 3))
            node.communicate(timeout=60)
        finally:
            if node.poll() is None:
                node.send_signal(signal.SIGTERM)
                node.communicate(timeout=30)
    summary = json.loads((out / "summary.json").read_text())
    delays = {sc: step_delays(out / RECORDING, sc) for sc in (FLOWN, BUILT_IN)}
    return delays, summary["outcome"]["commands"]


def delay_rows(
    mode: str, delays: dict[str, np.ndarray], commands: dict[str, int]
) -> list[dict[str, Any]]:
    """p50, p95 and max of the ROS 2 deputy's step delays against the built-in deputy's, in
    ms; the environment's late commands (of both deputies) said in the rows."""
    flown, built_in = delays[FLOWN], delays[BUILT_IN]
    what = "lock-step" if mode == "lockstep" else f"real time ×{REALTIME_RATE:g}"
    late = f"; {commands.get('late', 0)} commands late" if mode == "realtime" else ""
    rows = []
    for name, q in (("p50", 50.0), ("p95", 95.0), ("max", 100.0)):
        project = float(np.percentile(flown, q)) * 1e3
        baseline = float(np.percentile(built_in, q)) * 1e3
        rows.append(
            _row(
                f"{what}: navigation sample to command on the bus, {name}, "
                f"the ROS 2 node ({len(flown)} steps{late})",
                "ms",
                project,
                baseline,
                "the built-in LQR deputy, same run",
                project / baseline,
                bench="ros2",
            )
        )
    return rows


WITH = "with"
"""A cost run with ``--ros2`` and the subscriber of every topic."""
UNREAD = "unread"
"""A cost run with ``--ros2`` and its ROS 2 side's router, no subscriber: the gateway receives
every message it would carry and converts and puts none (what it costs when no ROS 2 tool
listens, and the floor under carrying them: the bus side alone)."""
WITHOUT = "without"


def cost_run(path: Path, folder: Path, variant: str) -> dict[str, Any]:
    """``ddvi run path`` as ``variant`` has it (``WITH``, ``UNREAD`` or ``WITHOUT`` --ros2):
    the run's wall time and CPU, the CPU of every process (the run's and the ROS 2 side's,
    from its start to its end) and the messages the subscriber received."""
    if variant == WITHOUT:
        wall, cpu, out = _ddvi_run(path, folder / "runs", [])
        return {"wall_s": wall, "run_cpu_s": cpu, "cpu_s": cpu, "received": 0, "out": out}
    port = free_port()
    cpu0 = _children_cpu()
    with ros_side(port, folder, path if variant == WITH else None) as side:
        wall, run_cpu, out = _ddvi_run(path, folder / "runs", ["--ros2", f"tcp/127.0.0.1:{port}"])
    cpu = _children_cpu() - cpu0
    counts = json.loads(side.stdout.read() if side.stdout is not None else "{}")
    received = sum(counts.values())
    return {"wall_s": wall, "run_cpu_s": run_cpu, "cpu_s": cpu, "received": received, "out": out}


COST_FIGURES = {
    "wall_s": "whole run (ddvi run)",
    "run_cpu_s": "CPU of the run's processes",
    "cpu_s": "CPU of every process (the run's, the router's and the subscriber's)",
}


def _cost_row(
    orbits: float, key: str, what: str, runs: list[dict[str, Any]], without: list[dict[str, Any]]
) -> dict[str, Any]:
    figure = f"{orbits:g}-orbit mission, {COST_FIGURES[key]}, {what}"
    return alternated_row(figure, key, runs, without, "without --ros2", TARGET, "ros2")


def cost_rows(orbits: float, runs: dict[str, list[dict[str, Any]]]) -> list[dict[str, Any]]:
    """The mean of each cost figure with ``--ros2`` and the subscriber against without, each
    run's figure said; the wall time and the run's CPU with ``--ros2`` and no subscriber (the
    floor: every message received, none carried); the messages the subscriber received against
    those the run recorded."""
    rows = [
        _cost_row(orbits, key, "--ros2 and a subscriber of every topic", runs[WITH], runs[WITHOUT])
        for key in COST_FIGURES
    ]
    rows += [
        _cost_row(
            orbits,
            key,
            "--ros2 and no subscriber (the floor: every message received, none converted)",
            runs[UNREAD],
            runs[WITHOUT],
        )
        for key in ("wall_s", "run_cpu_s")
    ]
    last = runs[WITH][-1]
    recorded = json.loads((last["out"] / "summary.json").read_text())["messages"]["recorded"]
    rows.append(
        _row(
            "ROS 2 messages the subscriber received",
            "count",
            last["received"],
            recorded,
            "bus messages recorded",
            last["received"] / recorded,
            bench="ros2",
        )
    )
    return rows


def bench_ros2(
    quick: bool = False,
    *,
    delay_orbits: float | None = None,
    cost_orbits: float | None = None,
    pairs: int | None = None,
) -> list[dict[str, Any]]:
    """The bridge's delay in lock-step and real time (runs of ``delay_orbits``: 1 with
    ``quick``, else 4), and its cost to the default mission (``cost_orbits``: 4 with
    ``quick``, else the mission's own; ``pairs``: alternated rounds of its three runs, 3 with
    ``quick``, else 5);
    a skipped row when zenoh-ros2-sdk or rosbags is not installed."""
    if (why := missing()) is not None:
        return [skipped_row("ros2", why)]
    rows: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory(prefix="ddvi-bench-ros2-") as tmp:
        for mode in ("lockstep", "realtime"):
            folder = Path(tmp) / mode
            folder.mkdir()
            orbits = delay_orbits or (1.0 if quick else 4.0)
            rows += delay_rows(mode, *delay_run(folder, orbits, mode))
        table = read_table(None)
        if cost_orbits is not None or quick:
            table["run"]["orbits"] = cost_orbits or 4.0
        path = write_deployment(table, Path(tmp), "mission")
        runs: dict[str, list[dict[str, Any]]] = {WITHOUT: [], WITH: [], UNREAD: []}
        for k in range(pairs or (3 if quick else 5)):
            order = list(runs) if k % 2 == 0 else list(reversed(runs))
            for variant in order:
                folder = Path(tmp) / f"cost-{k}-{variant}"
                folder.mkdir()
                runs[variant].append(cost_run(path, folder, variant))
        rows += cost_rows(table["run"]["orbits"], runs)
    return rows


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.ros2", description=__doc__)
    parser.add_argument("--quick", action="store_true", help="short runs, three rounds")
    parser.add_argument("--json", action="store_true", help="the rows as JSON on stdout")
    parser.add_argument(
        "--ros-side", nargs="+", metavar="ARG", help=argparse.SUPPRESS
    )  # PORT DEFINITIONS [DEPLOYMENT]: the benchmark's own ROS 2 side
    args = parser.parse_args(argv)
    if args.ros_side:
        port, definitions, *deployment = args.ros_side
        return serve_ros_side(int(port), definitions, deployment[0] if deployment else None)
    rows = bench_ros2(args.quick)
    print_rows(rows, args.json)
    return 0


if __name__ == "__main__":
    sys.exit(main())
