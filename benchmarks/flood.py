"""A flood from a stolen credential against a running mission, and what it costs the run.

    python -m benchmarks.flood                      # the default mission, 10 s floods
    python -m benchmarks.flood --seconds 3 --orbits 8

A clean run first, then one run per attack: nav-lqr's credential putting ``stats/nav-lqr``
(each message naming a new service) and ctrl-lqr's putting its own command topic, each one
message a put and 64 a put (``pack_batch``), as fast as one Python client goes, for
``--seconds`` wall seconds from the mission's first clock.  For each it prints the put rate,
the run's exit status and verdict line, the monitor's peak resident memory (VmHWM) against the
clean run's, whether the standard ``mcap`` reader reads the whole recording, and whether the
deputies the credential does not own fly bit-identical figures.  ``run_attack`` is what
``tests/ground/test_flood.py`` runs, shorter.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse
import json
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import psutil
import zenoh
from mcap.reader import make_reader

from services.bus import BusSettings, open_session
from services.bus.security import credentials_path, load_credentials
from services.interface import encode, pack_batch

DEPLOYMENT = Path(__file__).resolve().parents[1] / "deployments" / "rendezvous.toml"
ATTACKS = {"stats": "nav-lqr", "cmd": "ctrl-lqr"}
"""The topic an attack floods, by the credential (user) it stole."""


@dataclass
class Outcome:
    """One run: its status, verdict line, summary, the monitor's peak memory (bytes), the
    flood put (messages, puts, seconds), and whether the standard reader read the recording."""

    status: int
    said: str
    summary: dict[str, Any]
    monitor_peak: int
    readable: bool
    sent: dict[str, float] = field(default_factory=dict)


def deployment(tmp: Path, orbits: float | None) -> Path:
    """The default mission, shortened to ``orbits`` when given."""
    text = DEPLOYMENT.read_text()
    if orbits is not None:
        text = text.replace("orbits = 40.0", f"orbits = {orbits}", 1)
    path = tmp / "flood.toml"
    path.write_text(text)
    return path


def payloads(kind: str, run: str, batch: int, n: int = 4096) -> tuple[str, list[bytes]]:
    """The key and ``n`` ready payloads of one attack (each ``batch`` messages)."""
    if kind == "stats":
        key, user = f"ddvi/{run}/stats/nav-lqr", "nav-lqr"

        def make(i: int) -> bytes:
            body = {"service": f"forged-{i}", "counters": {"x": i}}
            return encode("stats", body, seq=i, t=60.0, src=user)
    else:
        key, user = f"ddvi/{run}/cmd/lqr/att", "ctrl-lqr"
        command = {"sc": "lqr", "sigma": np.array([0.0, 0.0, 0.5]), "for_t": 60.0}

        def make(i: int) -> bytes:
            return encode("cmd", command, seq=10**6 + i, t=60.0, src=user)

    msgs = [make(i) for i in range(n * batch)]
    if batch == 1:
        return key, msgs
    return key, [pack_batch(msgs[i : i + batch]) for i in range(0, len(msgs), batch)]


def _run_folder(root: Path, proc: subprocess.Popen, timeout: float = 60.0) -> Path:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline and proc.poll() is None:
        found = list(root.glob("*/security/ctrl-lqr.json"))
        if found and (found[0].parents[1] / "bus.json").is_file():
            return found[0].parents[1]
        time.sleep(0.05)
    raise RuntimeError(f"no run folder under {root}")


def _monitor_peak(launcher: int, stop: threading.Event, peak: list[int]) -> None:
    """The monitor's VmHWM (peak resident set, bytes), read until ``stop``."""
    while not stop.wait(0.1):
        try:
            for child in psutil.Process(launcher).children():
                if "services.ground.monitoring.monitor" in child.cmdline():
                    status = Path(f"/proc/{child.pid}/status").read_text()
                    line = next(x for x in status.splitlines() if x.startswith("VmHWM"))
                    peak[0] = max(peak[0], int(line.split()[1]) * 1024)
        except (psutil.Error, OSError, StopIteration):
            pass


def _flood(out: Path, kind: str, batch: int, seconds: float, proc: subprocess.Popen) -> dict:
    """Put the attack's payloads from its stolen credential for ``seconds`` from the first
    clock (or until the run ends)."""
    info = json.loads((out / "bus.json").read_text())
    cred = load_credentials(credentials_path(out, ATTACKS[kind]))
    settings = BusSettings(
        mode="client", listen=[], connect=[info["hub"]], user=cred.user, password=cred.password
    )
    key, ready = payloads(kind, info["run"], batch)
    started = threading.Event()
    sent = {"messages": 0.0, "puts": 0.0, "seconds": 0.0}
    deadline = time.monotonic() + 120.0
    while True:  # the router opens just after the run folder is written
        try:
            session_cm = open_session(settings)
            session = session_cm.__enter__()
            break
        except zenoh.ZError:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.05)
    try:
        sub = session.declare_subscriber(f"ddvi/{info['run']}/clock", lambda _s: started.set())
        while not started.wait(0.1):
            if proc.poll() is not None:
                return sent
        publisher = session.declare_publisher(key, congestion_control=zenoh.CongestionControl.DROP)
        t0 = time.monotonic()
        puts, n = 0, len(ready)
        while time.monotonic() - t0 < seconds and proc.poll() is None:
            for _ in range(256):
                publisher.put(ready[puts % n])
                puts += 1
        sent.update(messages=float(puts * batch), puts=float(puts), seconds=time.monotonic() - t0)
        publisher.undeclare()
        sub.undeclare()
    finally:
        session_cm.__exit__(None, None, None)
    return sent


def readable(path: Path) -> bool:
    """Whether the standard ``mcap`` reader reads every record of ``path``."""
    try:
        with path.open("rb") as f:
            reader = make_reader(f)
            for _ in reader.iter_messages():
                pass
            reader.get_summary()
        return True
    except Exception:
        return False


def run_attack(
    dep: Path, root: Path, kind: str | None, batch: int = 1, seconds: float = 10.0
) -> Outcome:
    """``ddvi run dep`` into ``root``, flooded by ``kind`` (None: clean)."""
    cmd = [sys.executable, "-m", "services.cli", "run", str(dep), "--output", str(root)]
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1"}
    root.mkdir(parents=True, exist_ok=True)
    with (root / "ddvi.log").open("w") as log:
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=log, env=env, text=True)
        stop, peak = threading.Event(), [0]
        watcher = threading.Thread(target=_monitor_peak, args=(proc.pid, stop, peak), daemon=True)
        watcher.start()
        try:
            out = _run_folder(root, proc)
            sent = _flood(out, kind, batch, seconds, proc) if kind else {}
            status = proc.wait(timeout=600)
        finally:
            if proc.poll() is None:
                proc.kill()
            stop.set()
            watcher.join()
    said = [x for x in (root / "ddvi.log").read_text().splitlines() if "mission" in x]
    summary = json.loads((out / "summary.json").read_text())
    return Outcome(
        status, said[-1] if said else "", summary, peak[0], readable(out / "recording.mcap"), sent
    )


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="benchmarks.flood", description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--orbits", type=float, default=None, help="default: the mission's 40")
    ap.add_argument("--out", default="/tmp/ddvi-flood")
    args = ap.parse_args(argv)
    root = Path(args.out)
    root.mkdir(parents=True, exist_ok=True)
    dep = deployment(root, args.orbits)
    clean = run_attack(dep, root / "clean", None)
    print(
        f"clean: status {clean.status}, monitor peak {clean.monitor_peak / 1e6:.0f} MB, "
        f"readable {clean.readable}"
    )
    for kind, user in ATTACKS.items():
        for batch in (1, 64):
            o = run_attack(dep, root / f"{kind}-{batch}", kind, batch, args.seconds)
            rate = o.sent.get("messages", 0) / max(o.sent.get("seconds", 0), 1e-9)
            others = [sc for sc in clean.summary["deputies"] if f"-{sc}" not in user]
            same = all(o.summary["deputies"][sc] == clean.summary["deputies"][sc] for sc in others)
            print(
                f"{user} on {kind}, batch {batch}: {rate:,.0f} messages/s for "
                f"{o.sent.get('seconds', 0):.1f} s; status {o.status} ({o.said}); monitor "
                f"peak {o.monitor_peak / 1e6:.0f} MB = {o.monitor_peak / clean.monitor_peak:.2f}"
                f" x clean; mcap readable {o.readable}; {', '.join(others)} identical {same}; "
                f"flooded {o.summary['outcome'].get('flooded')}"
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())
