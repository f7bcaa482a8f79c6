"""The launcher: ``ddvi run [DEPLOYMENT]``.

Reads a deployment, is the run's zenoh hub (the endpoint every service connects to), starts each
service as its own OS process, waits for their liveliness tokens, starts the environment (the
time master) last, waits for the mission to complete and the monitor to write its report, then
stops everything (SIGTERM, then SIGKILL after a grace period): no orphan, no hang.

Supervision: a service that dies before the mission ends is started again, into the running
mission (``--join``), when its [[restart]] policy says so, up to its ``max_restarts``; else the
run ends with status 1.  Inputs: ``fault/kill`` (fault messages, ``ddvi fault RUN kill
SERVICE``): the named service is killed with SIGKILL, a crash.  Outputs: ``stats/launcher``
(restarts, restarts.<service>, kills) after every restart or kill; ``log/launcher``.
"""

from __future__ import annotations

import datetime
import json
import os
import queue
import signal
import socket
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import IO

from services.bus import Bus, BusSettings, open_session, queue_handler, wait_for_alive
from services.config import Deployment
from services.ground.netns import exists as netns_exists
from services.ground.netns import hub_address
from services.interface.topics import fault_topic, log_topic, stats_topic
from services.model import holding_warnings

MODULES = {
    "environment": "services.flight.environment",
    "monitor": "services.ground.monitor",
    "nav": "services.flight.navigation",
    "ctrl": "services.flight.controller",
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
        self.restarts: dict[str, int] = {}
        self.kills = 0

    def say(self, text: str, error: bool = False) -> None:
        """Progress on stderr (not with --quiet); an error is always said."""
        if error or not self.quiet:
            print(f"ddvi run: {text}", file=sys.stderr, flush=True)

    def start(self, name: str, join: bool = False) -> None:
        """Start one service; ``join``: a restart into the running mission (its log goes on)."""
        logs = self.out / "logs"
        logs.mkdir(parents=True, exist_ok=True)
        log = open(logs / f"{name}.log", "ab" if join else "wb")  # noqa: SIM115 - see stop_all
        host = self.dep.host_of(name)
        hub = self.hub if host is None else f"tcp/{hub_address(host)}:{self.port}"
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
        ]
        env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "PYTHONUNBUFFERED": "1"}
        # the monitor keeps the terminal for its live status; the others log to files
        stderr = None if name == "monitor" and not self.quiet else log
        popen = subprocess.Popen(cmd, stdout=log, stderr=stderr, env=env, start_new_session=True)
        if (old := self.procs.get(name)) is not None:
            old.log.close()
        self.procs[name] = Process(name, popen, log)

    def stop_all(self, grace: float = 5.0, report_grace: float = 60.0) -> None:
        """SIGTERM the flight services (SIGKILL after ``grace`` s), then the monitor, which
        closes its recording and writes a (partial) report: it gets ``report_grace`` s."""
        flight = [p for name, p in self.procs.items() if name != "monitor"]
        monitor = [p for name, p in self.procs.items() if name == "monitor"]
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

    def execute(self) -> int:
        """Run the mission; the exit status is 0 only when it completed and was reported."""
        self.out.mkdir(parents=True, exist_ok=True)
        self.say(f"run {self.run}, output {self.out}, hub {self.hub}")
        for warning in holding_warnings(self.dep):
            self.say(f"warning: {warning}")
        if missing := [h.netns for h in self.dep.host if not netns_exists(h.netns)]:
            self.say(f"network namespaces {missing} do not exist: run `ddvi netns up "
                     f"{self.dep.path}` first (as root)", error=True)  # fmt: skip
            return 1
        started = time.monotonic()
        try:
            with open_session(self._hub_settings()) as session:
                first = [s for s in self.dep.services if s != "environment"]
                # the monitor first, so that it records everything from the first message on
                self.start("monitor")
                if not wait_for_alive(session, self.run, ["monitor"], self.dep.run.startup_timeout):
                    self.say(f"the monitor did not come alive; see {self.out / 'logs'}", error=True)
                    return 1
                for name in first[1:]:
                    self.start(name)
                alive = wait_for_alive(session, self.run, first, self.dep.run.startup_timeout)
                if missing := sorted(set(first) - alive):
                    self.say(
                        f"not alive after {self.dep.run.startup_timeout} s: {missing}; "
                        f"see {self.out / 'logs'}",
                        error=True,
                    )
                    return 1
                self.say(
                    f"{len(first)} services alive in {time.monotonic() - started:.1f} s; "
                    "starting the environment"
                )
                with Bus(session, self.run, "launcher") as bus:
                    faults: queue.SimpleQueue = queue.SimpleQueue()
                    bus.subscribe(
                        fault_topic("kill"), queue_handler(faults), expected_schema="fault"
                    )
                    self.start("environment")
                    return self._supervise(started, bus, faults)
        except KeyboardInterrupt:
            self.say("interrupted; stopping every service")
            return 130
        finally:
            self.stop_all()

    def _hub_settings(self) -> BusSettings:
        """The hub's session: client-mode services need a router to relay between them; it
        listens on loopback and on the launcher's side of every other host's link."""
        hosts = range(len(self.dep.host))
        listen = [self.hub] + [f"tcp/{hub_address(k)}:{self.port}" for k in hosts]
        mode = "router" if self.dep.bus.mode == "client" else "peer"
        return BusSettings(mode=mode, listen=listen, connect=list(self.dep.bus.connect))

    def _event(self, bus: Bus, level: str, text: str, t: float) -> None:
        """Say it, log it on the bus, and publish the launcher's counters."""
        self.say(text)
        counters = {"restarts": sum(self.restarts.values()), "kills": self.kills}
        counters.update({f"restarts.{k}": v for k, v in self.restarts.items()})
        try:
            log = {"service": "launcher", "level": level, "text": text}
            bus.publish(log_topic("launcher"), "log", log, t)
            stats = {"service": "launcher", "counters": counters}
            bus.publish(stats_topic("launcher"), "stats", stats, t)
        except Exception as exc:  # the bus is a report channel here, never a reason to stop
            self.say(f"could not publish: {exc}")

    def _kill(self, bus: Bus, target: str, t: float) -> None:
        """A ``kill`` fault: SIGKILL the named service, as a crash would."""
        p = self.procs.get(target)
        if p is None:
            why = "no such service"
        elif target in ("environment", "monitor"):
            why = "the environment and the monitor are not killed by faults (they end the run)"
        elif p.popen.poll() is not None:
            why = "it is not running"
        else:
            why = ""
        if why:
            self._event(bus, "warning", f"fault kill {target}: ignored ({why})", t)
            return
        p.popen.kill()
        self.kills += 1
        self._event(bus, "warning", f"fault kill {target}: killed (SIGKILL) at t = {t:.0f} s", t)

    def _supervise(self, started: float, bus: Bus, faults: queue.SimpleQueue) -> int:
        env, monitor = self.procs["environment"].popen, self.procs["monitor"].popen
        sim_t = 0.0
        while env.poll() is None:
            while not faults.empty():
                _, msg = faults.get_nowait()
                sim_t = max(sim_t, msg.t)
                if msg.body["kind"] == "kill":
                    self._kill(bus, msg.body["target"], msg.t)
            for name, p in list(self.procs.items()):
                rc = p.popen.poll()
                if rc in (None, 0) or name == "environment":
                    continue
                policy = self.dep.restart_policy(name)
                done = self.restarts.get(name, 0)
                if policy.policy == "on-failure" and done < policy.max_restarts:
                    self.restarts[name] = done + 1
                    self.start(name, join=True)
                    self._event(bus, "warning", f"{name} exited with status {rc}; restarted "
                                f"({done + 1} of {policy.max_restarts})", sim_t)  # fmt: skip
                    continue
                self.say(
                    f"{name} exited with status {rc} before the mission ended; "
                    f"see {self.out / 'logs' / (name + '.log')}",
                    error=True,
                )
                return 1
            time.sleep(0.2)
        if env.returncode != 0:
            self.say(f"environment exited with status {env.returncode}; see its log", error=True)
            return 1
        try:
            monitor.wait(timeout=60)
        except subprocess.TimeoutExpired:
            self.say("monitor did not finish its report within 60 s", error=True)
            return 1
        summary = self.out / "summary.json"
        if monitor.returncode != 0 or not summary.is_file():
            self.say(f"monitor exited with status {monitor.returncode}; no report", error=True)
            return 1
        completed = json.loads(summary.read_text()).get("completed", False)
        self.say(
            f"mission {'completed' if completed else 'INCOMPLETE'} in "
            f"{time.monotonic() - started:.1f} s; report in {self.out}"
        )
        print(self.out)
        return 0 if completed else 1
