"""The run's services as OS processes: how the launcher starts one (its command line, its
environment, its log), restarts it into a running mission, watches for one that has ended, and
stops them all in order (``ServiceProcesses``)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import IO

from services.config import Deployment
from services.ground.launch import credentials
from services.ground.launch.netns import hub_address

MODULES = {
    "environment": "services.flight.environment",
    "monitor": "services.ground.monitoring.monitor",
    "nav": "services.flight.navigation",
    "ctrl": "services.flight.controller",
    "ros2": "services.ros2.gateway.service",
}


def module_of(service: str) -> str:
    return MODULES[service.split("-", 1)[0]]


@dataclass
class Process:
    name: str
    popen: subprocess.Popen
    log: IO[bytes]


class ServiceProcesses:
    """The services of run ``run`` of ``dep``, each its own OS process in its own session,
    logging to ``out/logs/<name>.log``, connecting to ``hub`` (or, on another host, to the
    launcher's address there, on ``port``), the monitor serving the live view on ``live``
    when given, the environment flying lock-step at ``rate`` times real time at most (0: as
    fast as it goes)."""

    def __init__(
        self,
        dep: Deployment,
        run: str,
        out: Path,
        hub: str,
        port: int,
        quiet: bool,
        live: str | None = None,
        rate: float = 0.0,
    ) -> None:
        self.dep, self.run, self.out = dep, run, out
        self.hub, self.port, self.quiet, self.live = hub, port, quiet, live
        self.rate = rate
        self.procs: dict[str, Process] = {}

    def __getitem__(self, name: str) -> Process:
        return self.procs[name]

    def get(self, name: str) -> Process | None:
        return self.procs.get(name)

    def __iter__(self) -> Iterator[Process]:
        return iter(list(self.procs.values()))

    def start(self, name: str, join: bool = False) -> None:
        """Start one service; ``join``: a restart into the running mission (its log goes on)."""
        logs = self.out / "logs"
        log = open(logs / f"{name}.log", "ab" if join else "wb")  # noqa: SIM115 - see stop_all
        host = self.dep.host_of(name)
        hub = (
            self.hub
            if host is None
            else credentials.host_endpoint(self.dep, hub_address(host), self.port)
        )
        # a service on another host runs in its network namespace (ip netns exec execs it,
        # so the pid and the signals are the service's own)
        prefix = [] if host is None else ["ip", "netns", "exec", self.dep.host[host].netns]
        cmd = [
            *prefix,
            sys.executable,
            "-m",
            module_of(name),
            "--deployment",
            self.dep.path,
            "--run",
            self.run,
            "--hub",
            hub,
            "--name",
            name,
            "--out",
            str(self.out),
            *(["--join"] if join else []),
            *(["--live", self.live] if name == "monitor" and self.live else []),
            *(["--rate", repr(self.rate)] if name == "environment" and self.rate else []),
            *credentials.service_arguments(self.dep, self.out, name),
        ]
        env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "PYTHONUNBUFFERED": "1"}
        # a service stops by itself when the launcher dies (services.flight.runtime)
        env["DDVI_LAUNCHER_PID"] = str(os.getpid())
        # the monitor keeps the terminal for its live status (and logs to its file too:
        # services.ground.monitoring.monitor); the others log to files
        stderr = None if name == "monitor" and not self.quiet else log
        popen = subprocess.Popen(cmd, stdout=log, stderr=stderr, env=env, start_new_session=True)
        if (old := self.procs.get(name)) is not None:
            old.log.close()
        self.procs[name] = Process(name, popen, log)

    def exited(self) -> tuple[str, int] | None:
        """A started service that has ended (name, status), or None."""
        for p in self:
            if (rc := p.popen.poll()) is not None:
                return p.name, rc
        return None

    def stop_all(self, grace: float = 5.0, report_grace: float = 60.0) -> None:
        """SIGTERM the flight services (SIGKILL after ``grace`` s), then the monitor, which
        closes its recording and writes a (partial) report: it gets ``report_grace`` s."""
        flight = [p for p in self if p.name != "monitor"]
        monitor = [p for p in self if p.name == "monitor"]
        for group, wait in ((flight, grace), (monitor, report_grace)):
            for p in group:
                if p.popen.poll() is None:
                    p.popen.send_signal(signal.SIGTERM)
            deadline = time.monotonic() + wait
            for p in group:
                try:
                    p.popen.wait(timeout=max(deadline - time.monotonic(), 0.1))
                except subprocess.TimeoutExpired:
                    p.popen.kill()
                    p.popen.wait()
                p.log.close()
