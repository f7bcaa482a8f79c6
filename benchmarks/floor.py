"""The lock-step floor: the distributed mission with a bus layer that costs nothing.

The deployment's processes (the environment, a navigation and a controller service per deputy,
the monitor) exchange the lock-step mission's messages in plain zenoh-python and msgpack: no
schema, link model, sequence guard, recording or report.  Each spends, every step, the wall
time its share of the work takes in the one-process run
(``services.inprocess.run_in_process(timing=...)``), as a busy spin.  Per flight-software step:

    environment   spins its share (the truth); puts truth/<sc> for the chief and each deputy
                  and exo/state, the step's samples packed in one put each (as Bus.batch()
                  sends them), and clock; waits for every deputy's cmd of the step
    nav-<d>       once it has truth/chief and truth/<d> of the step: spins, puts nav/<d>/state
    ctrl-<d>      once it has nav/<d>/state and exo/state of the step: spins, puts cmd/<d>/att
    monitor       takes every sample

The processes are started and configured as the services are: peer sessions meshed through
the driver's hub, one zenoh receive worker (``services.service.SERVICE_ZENOH_RUNTIME``), a
subscriber callback handing samples to the main thread over a ``queue.SimpleQueue``, senders
waiting for the monitor before they put.  What the distributed mission's loop costs above this
floor is the project's own: its bus layer, the services' work beyond the one-process run's
(the environment's attitudes, stats and logs), the monitor's recording.

    python -m benchmarks.floor --deputies lqr ddvi --steps 3620   # the floor, no work
"""

from __future__ import annotations

import argparse
import json
import os
import queue
import subprocess
import sys
import time
from typing import Any

import msgpack
import zenoh

from services.bus import SERVICE_ZENOH_RUNTIME, BusSettings, open_session, wait_for_alive
from services.launcher import free_port

RUN = "floor"
STOP = "floor/stop"  # the environment's last put: every process ends on it
START_TIMEOUT = 60.0  # s for every process to be up (2 cores, 2 + 2N interpreters starting)
STEP_TIMEOUT = 30.0  # s a process waits for a step's message before giving up


def _key(topic: str) -> str:
    return f"ddvi/{RUN}/{topic}"


def _spin(seconds: float) -> None:
    """Busy for ``seconds`` of wall time: the work a process would do, holding its core."""
    end = time.perf_counter() + seconds
    while time.perf_counter() < end:
        pass


def _samples(kind: str, sc: str, t: float, n: int, dt: float) -> bytes:
    """A step's ``n`` samples of one topic, packed; each a header and a body of the size the
    project's schema gives it (three 3-vectors of truth, a 6-vector of navigation...)."""
    bodies = {
        "truth": lambda: {"sc": sc, "r_N": [6.6e6, 1.0, 2.0], "v_N": [1.0, 7.7e3, 3.0],
                          "sigma_BN": [0.0, 0.0, 0.1]},
        "exo": lambda: {"v": [1.0, 0.0], "phase": 0.0},
        "nav": lambda: {"sc": sc, "x_hill": [1.0] * 6, "altitude": 3e5, "valid": True},
    }  # fmt: skip
    return msgpack.packb(
        [
            {
                "schema": kind,
                "version": 1,
                "seq": i,
                "t": t + (i + 1) * dt,
                "src": sc,
                "body": bodies[kind](),
            }
            for i in range(n)
        ]
    )


def _environment(
    session: zenoh.Session, deputies: list[str], steps: int, samples: int, dt: float,
    spin: float,
) -> dict[str, Any]:  # fmt: skip
    inbox: queue.SimpleQueue[bytes] = queue.SimpleQueue()
    block = zenoh.CongestionControl.BLOCK
    topics = [*(f"truth/{sc}" for sc in ("chief", *deputies)), "exo/state", "clock", STOP]
    pubs = {t: session.declare_publisher(_key(t), congestion_control=block) for t in topics}
    sub = session.declare_subscriber(_key("cmd/*/att"), lambda s: inbox.put(s.payload.to_bytes()))
    others = ["monitor", *(f"{p}-{d}" for d in deputies for p in ("nav", "ctrl"))]
    try:
        if set(others) - wait_for_alive(session, RUN, others, START_TIMEOUT):
            raise RuntimeError(f"floor: not every process up after {START_TIMEOUT} s")
        t0 = time.perf_counter()
        for step in range(steps):
            t = step * samples * dt
            _spin(spin)
            for sc in ("chief", *deputies):
                pubs[f"truth/{sc}"].put(_samples("truth", sc, t, samples, dt))
            pubs["exo/state"].put(_samples("exo", "environment", t, samples, dt))
            pubs["clock"].put(msgpack.packb({"t": t, "step": step}))
            done: set[str] = set()
            while len(done) < len(deputies):
                cmd = msgpack.unpackb(inbox.get(timeout=STEP_TIMEOUT))
                if abs(cmd["for_t"] - t) < 1e-6:
                    done.add(cmd["sc"])
        loop = time.perf_counter() - t0
        pubs[STOP].put(b"")
        return {"loop_s": loop, "steps": steps}
    finally:
        sub.undeclare()
        for p in pubs.values():
            p.undeclare()


def _relay(
    session: zenoh.Session, name: str, inputs: list[str], output: str, payload: Any,
    spin: float,
) -> dict[str, Any]:  # fmt: skip
    """A navigation or controller process: once every input of a step has come, spin and put
    the output for it (``payload(t)``, t the step's first sample time); end on the stop."""
    inbox: queue.SimpleQueue[tuple[str, bytes]] = queue.SimpleQueue()
    pub = session.declare_publisher(_key(output), congestion_control=zenoh.CongestionControl.BLOCK)
    subs = [
        session.declare_subscriber(
            _key(topic), lambda s, topic=topic: inbox.put((topic, s.payload.to_bytes()))
        )
        for topic in [*inputs, STOP]
    ]
    have: dict[float, set[str]] = {}
    try:
        token = session.liveliness().declare_token(_key(f"alive/{name}"))
        while True:
            topic, data = inbox.get(timeout=STEP_TIMEOUT)
            if topic == STOP:
                break
            t = msgpack.unpackb(data)[0]["t"]
            got = have.setdefault(t, set())
            got.add(topic)
            if len(got) == len(inputs):
                del have[t]
                _spin(spin)
                pub.put(payload(t))
        token.undeclare()
        return {"pending": len(have)}
    finally:
        for s in subs:
            s.undeclare()
        pub.undeclare()


def _monitor(session: zenoh.Session, expected: int) -> dict[str, Any]:
    inbox: queue.SimpleQueue[str] = queue.SimpleQueue()
    sub = session.declare_subscriber(_key("**"), lambda s: inbox.put(str(s.key_expr)))
    received = 0
    try:
        token = session.liveliness().declare_token(_key("alive/monitor"))
        deadline = None  # after the stop, what other publishers sent may still be on its way
        while received < expected and (deadline is None or time.monotonic() < deadline):
            try:
                key = inbox.get(timeout=STEP_TIMEOUT if deadline is None else 0.1)
            except queue.Empty:
                continue
            received += 1
            if key == _key(STOP):
                deadline = time.monotonic() + 2.0
        token.undeclare()
        return {"received": received}
    finally:
        sub.undeclare()


def _role(args: argparse.Namespace) -> dict[str, Any]:
    deputies, steps, samples, dt = args.deputies, args.steps, args.samples, args.dt
    settings = BusSettings(mode="peer", listen=["tcp/127.0.0.1:0"], connect=[args.hub])
    with open_session(settings) as session:
        if args.role == "monitor":
            per_step = len(deputies) + 3 + 2 * len(deputies)  # truth, exo, clock; nav, cmd
            return _monitor(session, steps * per_step + 1)
        if args.role != "environment" and not wait_for_alive(
            session, RUN, ["monitor"], START_TIMEOUT
        ):
            raise RuntimeError("floor: the monitor is not up")
        if args.role == "environment":
            return _environment(session, deputies, steps, samples, dt, args.spin)
        kind, sc = args.role.split("-", 1)
        if kind == "nav":
            inputs, output = ["truth/chief", f"truth/{sc}"], f"nav/{sc}/state"

            def payload(t: float) -> bytes:
                return _samples("nav", sc, t - dt, samples, dt)
        else:
            inputs, output = [f"nav/{sc}/state", "exo/state"], f"cmd/{sc}/att"

            def payload(t: float) -> bytes:
                return msgpack.packb({"sc": sc, "for_t": t - dt, "sigma": [0.0, 0.0, 0.1]})

        return _relay(session, args.role, inputs, output, payload, args.spin)


def run_floor(
    deputies: list[str], steps: int, samples: int = 6, dt: float = 10.0,
    spins: dict[str, float] | None = None,
) -> dict[str, Any]:  # fmt: skip
    """The floor for ``deputies`` over ``steps`` flight-software steps of ``samples`` samples
    ``dt`` s apart; ``spins``: wall seconds of work a step by process name (``environment``,
    ``nav-<d>``, ``ctrl-<d>``; missing: none).  Returns ``loop_s`` (the environment's first put
    to the last step's last command), ``steps``, and the monitor's ``received`` against
    ``expected`` samples."""
    if not deputies or steps < 1 or samples < 1:
        raise ValueError("run_floor needs at least one deputy, one step and one sample a step")
    spins = spins or {}
    hub = f"tcp/127.0.0.1:{free_port()}"
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "ZENOH_RUNTIME": SERVICE_ZENOH_RUNTIME}
    names = ["monitor", *(f"{p}-{d}" for d in deputies for p in ("nav", "ctrl")), "environment"]
    common = ["--hub", hub, "--deputies", *deputies, "--steps", str(steps),
              "--samples", str(samples), "--dt", str(dt)]  # fmt: skip
    with open_session(BusSettings(mode="peer", listen=[hub], connect=[])):
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
            for name, proc in procs.items():
                out, _ = proc.communicate(timeout=START_TIMEOUT + steps * STEP_TIMEOUT)
                if proc.returncode != 0:
                    raise RuntimeError(f"floor: {name} failed ({proc.returncode})")
                results[name] = json.loads(out.strip().splitlines()[-1])
        finally:
            for proc in procs.values():
                if proc.poll() is None:
                    proc.kill()
                    proc.wait()
    per_step = len(deputies) + 3 + 2 * len(deputies)
    received, expected = results["monitor"]["received"], steps * per_step + 1
    if received != expected:  # plain zenoh with congestion control BLOCK loses nothing
        raise RuntimeError(f"floor: the monitor received {received} of {expected} samples")
    return {**results["environment"], "received": received, "expected": expected}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.floor", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    ap.add_argument("role", nargs="?", help="(internal) the process to be; none: run the floor")
    ap.add_argument("--hub", help="(internal) the driver's endpoint")
    ap.add_argument("--deputies", nargs="+", default=["lqr", "ddvi"])
    ap.add_argument("--steps", type=int, default=3620)
    ap.add_argument("--samples", type=int, default=6, help="samples a step")
    ap.add_argument("--dt", type=float, default=10.0, help="s between samples")
    ap.add_argument("--spin", type=float, default=0.0, help="(internal) s of work a step")
    args = ap.parse_args(argv)
    if args.role is None:
        print(json.dumps(run_floor(args.deputies, args.steps, args.samples, args.dt)))
    else:
        print(json.dumps(_role(args)), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
