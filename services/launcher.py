"""The launcher: ``ddvi run [DEPLOYMENT]``.

Reads a deployment, is the run's zenoh hub (the endpoint every service connects to), starts each
service as its own OS process, waits for their liveliness tokens, starts the environment (the
time master) last, waits for the mission to complete and the monitor to write its report, then
stops everything (SIGTERM, then SIGKILL after a grace period): no orphan, no hang.
"""

from __future__ import annotations

import datetime
import json
import os
import signal
import socket
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import IO

from services.bus import BusSettings, open_session, wait_for_alive
from services.deployment import Deployment
from services.mission import holding_margin

MODULES = {
    "environment": "services.environment",
    "monitor": "services.monitor",
    "nav": "services.navigation",
    "ctrl": "services.controller",
}


def module_of(service: str) -> str:
    return MODULES[service.split("-", 1)[0]]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@dataclass
class Process:
    name: str
    popen: subprocess.Popen
    log: IO[bytes]


class Launcher:
    def __init__(self, dep: Deployment, out_root: str | None = None, quiet: bool = False) -> None:
        self.dep = dep
        stamp = datetime.datetime.now().strftime("%Y%m%d-%H%M%S")
        self.run = f"{dep.run.name}-{stamp}-{os.getpid() % 10000}"
        self.out = Path(out_root or dep.run.output) / self.run
        self.port = dep.bus.port or free_port()
        self.hub = f"tcp/127.0.0.1:{self.port}"
        self.procs: dict[str, Process] = {}
        self.quiet = quiet

    def say(self, text: str) -> None:
        if not self.quiet:
            print(f"ddvi run: {text}", file=sys.stderr, flush=True)

    def start(self, name: str) -> None:
        logs = self.out / "logs"
        logs.mkdir(parents=True, exist_ok=True)
        log = open(logs / f"{name}.log", "wb")  # noqa: SIM115 - closed in stop_all
        cmd = [
            sys.executable,
            "-m",
            module_of(name),
            "--deployment",
            self.dep.path,
            "--run",
            self.run,
            "--hub",
            self.hub,
            "--name",
            name,
            "--out",
            str(self.out),
        ]
        env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "PYTHONUNBUFFERED": "1"}
        # the monitor keeps the terminal for its live status; the others log to files
        stderr = None if name == "monitor" and not self.quiet else log
        popen = subprocess.Popen(cmd, stdout=log, stderr=stderr, env=env, start_new_session=True)
        self.procs[name] = Process(name, popen, log)

    def stop_all(self, grace: float = 5.0) -> None:
        for p in self.procs.values():
            if p.popen.poll() is None:
                p.popen.send_signal(signal.SIGTERM)
        deadline = time.monotonic() + grace
        for p in self.procs.values():
            try:
                p.popen.wait(timeout=max(deadline - time.monotonic(), 0.1))
            except subprocess.TimeoutExpired:
                p.popen.kill()
                p.popen.wait()
            p.log.close()

    def execute(self) -> int:
        """Run the mission; the exit status is 0 only when it completed and was reported."""
        self.out.mkdir(parents=True, exist_ok=True)
        self.say(f"run {self.run}, output {self.out}")
        for d in self.dep.deputy:
            if (margin := holding_margin(self.dep, d)) < 0:
                self.say(
                    f"warning: deputy {d.name!r} cannot hold a slot: its largest drag (area "
                    f"factor {d.area_factor:g}, |sigma3| <= {d.attitude_limit:g}) is "
                    f"{-margin:.0%} below the chief's, so its along-track error will grow"
                )
        hub = BusSettings(mode="peer", listen=[self.hub], connect=list(self.dep.bus.connect))
        started = time.monotonic()
        try:
            with open_session(hub) as session:
                first = [s for s in self.dep.services if s != "environment"]
                # the monitor first, so that it records everything from the first message on
                self.start("monitor")
                if not wait_for_alive(session, self.run, ["monitor"], self.dep.run.startup_timeout):
                    self.say(f"the monitor did not come alive; see {self.out / 'logs'}")
                    return 1
                for name in first[1:]:
                    self.start(name)
                alive = wait_for_alive(session, self.run, first, self.dep.run.startup_timeout)
                if missing := sorted(set(first) - alive):
                    self.say(
                        f"not alive after {self.dep.run.startup_timeout} s: {missing}; "
                        f"see {self.out / 'logs'}"
                    )
                    return 1
                self.say(
                    f"{len(first)} services alive in {time.monotonic() - started:.1f} s; "
                    "starting the environment"
                )
                self.start("environment")
                return self._supervise(started)
        except KeyboardInterrupt:
            self.say("interrupted; stopping every service")
            return 130
        finally:
            self.stop_all()

    def _supervise(self, started: float) -> int:
        env, monitor = self.procs["environment"].popen, self.procs["monitor"].popen
        while env.poll() is None:
            for name, p in self.procs.items():
                rc = p.popen.poll()
                if rc not in (None, 0) and name != "environment":
                    self.say(
                        f"{name} exited with status {rc} before the mission ended; "
                        f"see {self.out / 'logs' / (name + '.log')}"
                    )
                    return 1
            time.sleep(0.2)
        if env.returncode != 0:
            self.say(f"environment exited with status {env.returncode}; see its log")
            return 1
        try:
            monitor.wait(timeout=60)
        except subprocess.TimeoutExpired:
            self.say("monitor did not finish its report within 60 s")
            return 1
        summary = self.out / "summary.json"
        if monitor.returncode != 0 or not summary.is_file():
            self.say(f"monitor exited with status {monitor.returncode}; no report")
            return 1
        completed = json.loads(summary.read_text()).get("completed", False)
        self.say(
            f"mission {'completed' if completed else 'INCOMPLETE'} in "
            f"{time.monotonic() - started:.1f} s; report in {self.out}"
        )
        print(self.out)
        return 0 if completed else 1
