"""The lock-step floor: the distributed mission with nothing but its processes, messages and work.

The deployment's processes (the environment, a navigation and a controller service per deputy,
the monitor) exchange the lock-step mission's messages, and each spends, every step, the wall
time its share of the work takes in the one-process run
(``services.flight.inprocess.run_in_process(timing=...)``) as a busy spin.  Per
flight-software step:

    environment   spins its share (the truth); puts the step's samples of truth/<sc> for the
                  chief and each deputy and of exo/state, each topic's in one put (as
                  Bus.batch() sends them), and clock; waits for every deputy's cmd of the step
    nav-<d>       once it has the step's truth/chief and truth/<d>: spins, puts the step's
                  nav/<d>/state
    ctrl-<d>      once it has the step's nav/<d>/state and exo/state: spins, puts cmd/<d>/att
    monitor       counts every sample (plain zenoh, whatever the layer); on the routed
                  topology records every message to MCAP too, as the ground monitor does

Two layers carry the flight processes' messages:

- ``plain``: zenoh-python and msgpack, nothing else (no schema, link model, sequence guard);
- ``bus``: the project's ``services.bus.endpoint.Bus``: schema encode and validating decode,
  the link model, sequence guards, one handler call a message.

Two topologies connect them:

- ``peer``: peer sessions meshed through the driver's hub, no authentication;
- ``routed``: the mission's (``benchmarks.floor_topology``): every process an authenticated
  client of the driver's router, which enforces the run's access control, and a monitor that
  records every message to MCAP.

The processes are otherwise started and configured as the services are: one zenoh receive
worker (``services.bus.endpoint.SERVICE_ZENOH_RUNTIME``), a subscriber callback handing what
arrives to the main thread over a ``queue.SimpleQueue``, senders waiting for the monitor
before they put.  What the distributed mission's loop costs above the routed floor is the
services' own beyond the one-process run's work (the bus layer, the environment's attitudes,
stats and logs, bookkeeping, the monitor's report data).

    python -m benchmarks.floor --layer plain --steps 3620   # the floor, no work
    python -m benchmarks.floor --topology routed            # on the mission's topology
"""

from __future__ import annotations

import argparse
import json
import os
import queue
import resource
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import msgpack
import numpy as np
import zenoh

from benchmarks.floor_topology import TOPOLOGIES, FloorRecorder, client_settings, router_settings
from services.bus import SERVICE_ZENOH_RUNTIME, Bus, BusSettings, open_session, wait_for_alive
from services.ground.launch.launcher import free_port
from services.interface import SCHEMAS
from services.interface.topics import (
    CLOCK,
    EXOSTATE,
    alive_topic,
    command_topic,
    nav_state_topic,
    stats_topic,
    truth_topic,
)

RUN = "floor"
LAYERS = ("plain", "bus")
STOP = stats_topic("environment")  # the environment's last put: every process ends on it
START_TIMEOUT = 60.0  # s for every process to be up (2 + 2N interpreters start at once)
STEP_TIMEOUT = 30.0  # s a process waits for a step's message before giving up

# what arrives, as the main thread sees it: (topic, time of the first message, messages)
Arrival = tuple[str, float, int]


def _key(topic: str) -> str:
    return f"ddvi/{RUN}/{topic}"


def _spin(seconds: float) -> None:
    """Busy for ``seconds`` of this thread's CPU time: the work a process would do (time it
    spends preempted is not work done)."""
    end = time.thread_time() + seconds
    while time.thread_time() < end:
        pass


def _body(kind: str, sc: str, t: float, vector: Callable[[list[float]], Any]) -> dict[str, Any]:
    """A message body of the project's schema ``kind``, its vectors made by ``vector``
    (``list`` for msgpack, ``np.array`` for the Bus)."""
    if kind == "truth":
        r, v, s = vector([6.6e6, 1.0, 2.0]), vector([1.0, 7.7e3, 3.0]), vector([0.0, 0.0, 0.0])
        return {"sc": sc, "r_N": r, "v_N": v, "sigma_BN": s}
    if kind == "exo":
        return {"v": vector([1.0, 0.5, 0.5, 0.5, 0.5]), "phase": 0.0}  # exostate's (5,)
    if kind == "nav":
        cov = vector([[0.0] * 6] * 6)
        return {
            "sc": sc,
            "x_hill": vector([1.0] * 6),
            "z_hill": vector([1.0] * 6),
            "cov": cov,
            "altitude": 3e5,
            "valid": True,
        }
    if kind == "cmd":
        return {"sc": sc, "sigma": vector([0.0, 0.0, 0.1]), "for_t": t}
    return {"step": 0, "dt": 10.0, "fsw": True, "mode": "lockstep", "final": False}  # clock


class _Plain:
    """zenoh-python and msgpack: a topic's messages of a step in one put, as a list of maps
    (header and body); an arrival a sample."""

    def __init__(self, session: zenoh.Session, name: str) -> None:
        self.session, self.name = session, name
        self._pubs: dict[str, Any] = {}
        self._subs: list[Any] = []

    def publish(self, topic: str, kind: str, sc: str, times: list[float]) -> None:
        pub = self._pubs.get(topic)
        if pub is None:
            block = zenoh.CongestionControl.BLOCK
            pub = self._pubs[topic] = self.session.declare_publisher(
                _key(topic), congestion_control=block
            )
        header = {"schema": kind, "version": SCHEMAS[kind].version, "src": self.name}
        messages = [
            {**header, "seq": seq, "t": t, "body": _body(kind, sc, t, list)}
            for seq, t in enumerate(times)
        ]
        pub.put(msgpack.packb(messages))

    def subscribe(self, topic: str, kind: str, arrived: Callable[[Arrival], None]) -> None:
        def on_sample(sample: zenoh.Sample) -> None:
            messages = msgpack.unpackb(sample.payload.to_bytes())
            arrived((str(sample.key_expr)[len(_key("")) :], messages[0]["t"], len(messages)))

        self._subs.append(self.session.declare_subscriber(_key(topic), on_sample))

    def close(self) -> None:
        for s in self._subs:
            s.undeclare()
        for p in self._pubs.values():
            p.undeclare()


class _ProjectBus:
    """The project's Bus: a step's messages of a topic in one Bus.batch(); an arrival a
    message, as the Bus delivers them."""

    def __init__(self, session: zenoh.Session, name: str) -> None:
        self.bus = Bus(session, RUN, name)

    def publish(self, topic: str, kind: str, sc: str, times: list[float]) -> None:
        with self.bus.batch():
            for t in times:
                self.bus.publish(topic, kind, _body(kind, sc, t, np.array), t)

    def subscribe(self, topic: str, kind: str, arrived: Callable[[Arrival], None]) -> None:
        self.bus.subscribe(
            topic, lambda topic, msg: arrived((topic, msg.t, 1)), expected_schema=kind
        )

    def close(self) -> None:
        self.bus.close()


class _Step:
    """The step grid: step k has samples at k T + dt, ..., (k + 1) T with T = samples dt."""

    def __init__(self, samples: int, dt: float) -> None:
        self.samples, self.dt, self.period = samples, dt, samples * dt

    def times(self, k: int) -> list[float]:
        return [k * self.period + (i + 1) * self.dt for i in range(self.samples)]

    def of(self, t: float) -> int:
        """The step of a sample at ``t``."""
        return (round(t / self.dt) - 1) // self.samples


def _environment(
    wire: _Plain | _ProjectBus,
    session: zenoh.Session,
    deputies: list[str],
    steps: int,
    grid: _Step,
    spin: float,
) -> dict[str, Any]:
    inbox: queue.SimpleQueue[Arrival] = queue.SimpleQueue()
    wire.subscribe(command_topic("*"), "cmd", inbox.put)  # every deputy's
    stop = session.declare_publisher(_key(STOP), congestion_control=zenoh.CongestionControl.BLOCK)
    token = session.liveliness().declare_token(_key(alive_topic("environment")))  # subscribed
    others = ["monitor", *(f"{p}-{d}" for d in deputies for p in ("nav", "ctrl"))]
    try:
        if set(others) - wait_for_alive(session, RUN, others, START_TIMEOUT):
            raise RuntimeError(f"floor: not every process up after {START_TIMEOUT} s")
        t0 = time.perf_counter()
        for k in range(steps):
            _spin(spin)
            times = grid.times(k)
            for sc in ("chief", *deputies):
                wire.publish(truth_topic(sc), "truth", sc, times)
            wire.publish(EXOSTATE, "exo", "environment", times)
            wire.publish(CLOCK, "clock", "environment", times[-1:])
            done: set[str] = set()
            while len(done) < len(deputies):
                topic, t, _ = inbox.get(timeout=STEP_TIMEOUT)
                if abs(t - times[-1]) < 1e-6:
                    done.add(topic)
        loop = time.perf_counter() - t0
        stop.put(b"")
        return {"loop_s": loop, "steps": steps}
    finally:
        token.undeclare()
        stop.undeclare()


def _relay(
    wire: _Plain | _ProjectBus,
    session: zenoh.Session,
    name: str,
    inputs: list[tuple[str, str]],
    receiver: str,
    publish: Callable[[int], None],
    grid: _Step,
    spin: float,
) -> dict[str, Any]:
    """A navigation or controller process: once every input message of a step has come, spin
    and ``publish(step)``; clock messages are taken and ignored; end on the stop.  It declares
    itself alive once its ``receiver`` is (so that its first put reaches it), and the
    environment starts once everyone is."""
    inbox: queue.SimpleQueue[Arrival] = queue.SimpleQueue()
    for topic, kind in [*inputs, (CLOCK, "clock")]:
        wire.subscribe(topic, kind, inbox.put)
    stop = session.declare_subscriber(_key(STOP), lambda _: inbox.put((STOP, 0.0, 0)))
    have: dict[int, int] = {}
    need = len(inputs) * grid.samples
    try:
        if not wait_for_alive(session, RUN, [receiver], START_TIMEOUT):
            raise RuntimeError(f"floor: {name} does not see {receiver}")
        token = session.liveliness().declare_token(_key(alive_topic(name)))
        wait = 2 * START_TIMEOUT  # the others' start-up, then a step at most
        while True:
            topic, t, n = inbox.get(timeout=wait)
            wait = STEP_TIMEOUT
            if topic == STOP:
                break
            if topic == CLOCK:
                continue
            k = grid.of(t)
            have[k] = have.get(k, 0) + n
            if have[k] == need:
                del have[k]
                _spin(spin)
                publish(k)
        token.undeclare()
        return {"pending": len(have)}
    finally:
        stop.undeclare()


def _monitor(
    session: zenoh.Session, expected: int, recorder: FloorRecorder | None = None
) -> dict[str, Any]:
    """Count every sample (and with a ``recorder``, record every message) until the stop."""
    inbox: queue.SimpleQueue[str] = queue.SimpleQueue()
    if recorder is None:
        sub = session.declare_subscriber(_key("**"), lambda s: inbox.put(str(s.key_expr)))
        take = inbox.get
    else:
        sub = session.declare_subscriber(_key("**"), recorder.on_sample)
        take = recorder.take
    received = 0
    try:
        token = session.liveliness().declare_token(_key(alive_topic("monitor")))
        # after the stop, what other publishers put before it may still be on its way: wait
        # for all of it (and a little more, for any extra) or 2 s
        deadline = None
        wait = 3 * START_TIMEOUT  # the others' start-up, then a step at most
        while deadline is None or time.monotonic() < deadline:
            try:
                key = take(timeout=wait if deadline is None else 0.05)
            except queue.Empty:
                if deadline is None:
                    raise RuntimeError(f"floor: the monitor had nothing for {wait} s") from None
                continue
            wait = STEP_TIMEOUT
            received += 1
            if key == _key(STOP):
                deadline = time.monotonic() + 2.0
            if deadline is not None and received >= expected:
                deadline = min(deadline, time.monotonic() + 0.1)
        token.undeclare()
        return {"received": received, **(recorder.close() if recorder is not None else {})}
    finally:
        sub.undeclare()


def _expected(deputies: list[str], steps: int) -> int:
    """Samples the monitor sees: a step's truths, exo, clock, navs and cmds; the stop."""
    return steps * (len(deputies) + 3 + 2 * len(deputies)) + 1


def _role(args: argparse.Namespace) -> dict[str, Any]:
    deputies, steps, grid = args.deputies, args.steps, _Step(args.samples, args.dt)
    if args.folder is None:
        settings = BusSettings(mode="peer", listen=["tcp/127.0.0.1:0"], connect=[args.hub])
    else:
        settings = client_settings(Path(args.folder), args.role, args.hub)
    with open_session(settings) as session:
        if args.role == "monitor":
            recorder = None
            if args.folder is not None:
                recorder = FloorRecorder(Path(args.folder), args.layer, _key(""))
            return _monitor(session, _expected(deputies, steps), recorder)
        if args.role != "environment" and not wait_for_alive(
            session, RUN, ["monitor"], START_TIMEOUT
        ):
            raise RuntimeError("floor: the monitor is not up")
        wire = (_Plain if args.layer == "plain" else _ProjectBus)(session, args.role)
        try:
            if args.role == "environment":
                return _environment(wire, session, deputies, steps, grid, args.spin)
            kind, sc = args.role.split("-", 1)
            if kind == "nav":
                inputs, receiver = (
                    [(truth_topic("chief"), "truth"), (truth_topic(sc), "truth")],
                    f"ctrl-{sc}",
                )

                def publish(k: int) -> None:
                    wire.publish(nav_state_topic(sc), "nav", sc, grid.times(k))
            else:
                inputs, receiver = [(nav_state_topic(sc), "nav"), (EXOSTATE, "exo")], "environment"

                def publish(k: int) -> None:
                    wire.publish(command_topic(sc), "cmd", sc, grid.times(k)[-1:])

            return _relay(wire, session, args.role, inputs, receiver, publish, grid, args.spin)
        finally:
            wire.close()


def run_floor(
    deputies: list[str],
    steps: int,
    samples: int = 6,
    dt: float = 10.0,
    spins: dict[str, float] | None = None,
    layer: str = "plain",
    topology: str = "peer",
) -> dict[str, Any]:
    """The floor for ``deputies`` over ``steps`` flight-software steps of ``samples`` samples
    ``dt`` s apart, the flight processes' messages on ``layer`` (``plain`` or ``bus``), the
    processes connected as ``topology`` says (``peer`` or ``routed``);
    ``spins``: wall seconds of work a step by process name (``environment``, ``nav-<d>``,
    ``ctrl-<d>``; missing: none).  Returns ``loop_s`` (the environment's first put to the last
    step's last command), ``steps``, the monitor's ``received`` samples, all of them
    (RuntimeError otherwise), and ``cpu_s``: the CPU seconds of the floor's processes and
    its hub, start-up included (not inflated by a loaded machine, as its wall time is)."""
    if not deputies or steps < 1 or samples < 1:
        raise ValueError("run_floor needs at least one deputy, one step and one sample a step")
    if layer not in LAYERS:
        raise ValueError(f"run_floor: layer {layer!r} is not one of {LAYERS}")
    if topology not in TOPOLOGIES:
        raise ValueError(f"run_floor: topology {topology!r} is not one of {TOPOLOGIES}")
    cpu0 = _cpu()
    with tempfile.TemporaryDirectory(prefix="ddvi-floor-") as folder:
        floor = _run_floor(
            deputies,
            steps,
            samples,
            dt,
            spins or {},
            layer,
            Path(folder) if topology == "routed" else None,
        )
    return {**floor, "cpu_s": _cpu() - cpu0}


def _cpu() -> float:
    """CPU seconds of this process (the hub or router's threads) and of its children waited
    for (the floor's processes)."""
    return sum(
        u.ru_utime + u.ru_stime
        for u in (
            resource.getrusage(resource.RUSAGE_SELF),
            resource.getrusage(resource.RUSAGE_CHILDREN),
        )
    )


def _run_floor(
    deputies: list[str],
    steps: int,
    samples: int,
    dt: float,
    spins: dict[str, float],
    layer: str,
    folder: Path | None,
) -> dict[str, Any]:
    """``run_floor``; ``folder``: the routed topology's credentials and recording (None:
    peers)."""
    hub = f"tcp/127.0.0.1:{free_port()}"
    env = {"ZENOH_RUNTIME": SERVICE_ZENOH_RUNTIME, **os.environ, "OPENBLAS_NUM_THREADS": "1"}
    names = ["monitor", *(f"{p}-{d}" for d in deputies for p in ("nav", "ctrl")), "environment"]
    common = [
        "--hub",
        hub,
        "--layer",
        layer,
        "--deputies",
        *deputies,
        "--steps",
        str(steps),
        "--samples",
        str(samples),
        "--dt",
        str(dt),
    ]
    if folder is None:
        hub_settings = BusSettings(mode="peer", listen=[hub], connect=[])
    else:
        hub_settings = router_settings(folder, RUN, names, hub)
        common += ["--folder", str(folder)]
    with open_session(hub_settings):
        procs = {
            name: subprocess.Popen(
                [
                    sys.executable,
                    "-m",
                    "benchmarks.floor",
                    name,
                    *common,
                    "--spin",
                    repr(spins.get(name, 0.0)),
                ],
                env=env,
                stdout=subprocess.PIPE,
                text=True,
            )
            for name in names
        }
        results = {}
        try:
            # the first process to fail ends the floor (the others would wait for it)
            while len(results) < len(procs):
                for name, proc in procs.items():
                    if name in results or proc.poll() is None:
                        continue
                    out = proc.stdout.read() if proc.stdout else ""
                    if proc.returncode != 0 or not out.strip():
                        raise RuntimeError(f"floor: {name} failed ({proc.returncode})")
                    results[name] = json.loads(out.strip().splitlines()[-1])
                time.sleep(0.05)
        finally:
            for proc in procs.values():
                if proc.poll() is None:
                    proc.kill()
                    proc.wait()
    received, expected = results["monitor"]["received"], _expected(deputies, steps)
    if received != expected:  # congestion control BLOCK: nothing lost, nothing extra
        raise RuntimeError(f"floor: the monitor received {received} samples, not {expected}")
    if unfinished := [n for n, r in results.items() if r.get("pending")]:
        raise RuntimeError(f"floor: {unfinished} ended with steps half received")
    recorded = {k: v for k, v in results["monitor"].items() if k == "recorded"}
    return {**results["environment"], "received": received, **recorded}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        prog="python -m benchmarks.floor",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    ap.add_argument("role", nargs="?", help="(internal) the process to be; none: run the floor")
    ap.add_argument("--layer", choices=LAYERS, default="plain")
    ap.add_argument("--topology", choices=TOPOLOGIES, default="peer")
    ap.add_argument("--folder", help="(internal) the routed topology's credentials, recording")
    ap.add_argument("--hub", help="(internal) the driver's endpoint")
    ap.add_argument("--deputies", nargs="+", default=["lqr", "ddvi"])
    ap.add_argument("--steps", type=int, default=3620)
    ap.add_argument("--samples", type=int, default=6, help="samples a step")
    ap.add_argument("--dt", type=float, default=10.0, help="s between samples")
    ap.add_argument("--spin", type=float, default=0.0, help="(internal) s of work a step")
    args = ap.parse_args(argv)
    if args.role is None:
        floor = run_floor(
            args.deputies,
            args.steps,
            args.samples,
            args.dt,
            layer=args.layer,
            topology=args.topology,
        )
        print(json.dumps(floor))
    else:
        print(json.dumps(_role(args)), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
