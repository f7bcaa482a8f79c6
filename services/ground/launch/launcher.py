"""The launcher: ``ddvi run [DEPLOYMENT]``.

Reads a deployment, is the run's zenoh hub (the endpoint every service connects to), starts each
service as its own OS process, all at once (the environment, the time master, flies once it
sees every other service alive), waits for their liveliness tokens, watches them while the
mission flies (``services.ground.launch.supervisor``: kill faults, restarts by policy), waits for
the monitor to write its report, then stops everything (SIGTERM, then SIGKILL after a grace
period): no orphan, no hang.

Inputs: ``fault/kill`` (fault messages, ``ddvi fault RUN kill SERVICE``).  Outputs:
``stats/launcher`` (restarts, restarts.<service>, kills) after every restart or kill;
``log/launcher``.
"""

from __future__ import annotations

import contextlib
import dataclasses
import datetime
import os
import queue
import shutil
import signal
import socket
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import tomli_w
import zenoh

from services.bus import Bus, BusSettings, error_text, open_session, queue_handler
from services.bus.security import write_private
from services.config import Deployment
from services.ground.launch import credentials, lifecycle
from services.ground.launch.netns import exists as netns_exists
from services.ground.launch.netns import hub_address
from services.ground.launch.processes import ServiceProcesses
from services.ground.launch.report import await_report, recover_report, report_wait
from services.ground.launch.runfolder import DEPLOYMENT_FILE, FOLDER_MODE, make_run_folder
from services.ground.launch.supervisor import Supervisor
from services.ground.monitoring.live_address import CLIENT_JOINED, parse_address
from services.interface.topics import ROS2_GATEWAY, fault_topic, log_topic
from services.model import holding_warnings, reentry_warnings


def _live_view(
    bus: Bus, live: str | None, wait: bool, say: Callable[[str], None]
) -> tuple[str, threading.Event]:
    """Say where the live view serves (``live``, HOST:PORT); its URL, and the event set when
    the monitor says on its log that the live view has its first client (listened to when
    the first step ``wait``s for it)."""
    watched = threading.Event()
    if not live:
        return "", watched
    url = parse_address(live).url
    say(f"live view on {url} (Foxglove: Open connection, Foxglove WebSocket; docs/live.md)")

    def on_log(_topic: str, msg: Any) -> None:
        if msg.body["text"].startswith(CLIENT_JOINED):
            watched.set()

    if wait:
        bus.subscribe(log_topic("monitor"), on_log, expected_schema="log")
    return url, watched


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@dataclasses.dataclass(frozen=True)
class Viewing:
    """How a person watches the run (``ddvi run --live --rate --wait-for-client``)."""

    live: str | None = None  # HOST:PORT the monitor serves the live view on, or none
    rate: float = 0.0  # lock-step's simulated seconds per wall second at most; 0: no pace
    wait_for_client: bool = False  # with ``live``: the first step waits for its first client


class Launcher:
    def __init__(
        self,
        dep: Deployment,
        out_root: str | None = None,
        quiet: bool = False,
        folder_mode: int | None = None,
        viewing: Viewing | None = None,
        table: dict[str, Any] | None = None,
    ) -> None:
        self.dep = dep
        self.viewing = view = viewing or Viewing()
        # the deployment's table when a command-line option changed it from its file's
        # (--ros2): the run folder keeps it as the deployment the run flies, and the services
        # read it there
        self.table = table
        stamp = datetime.datetime.now().strftime("%Y%m%d-%H%M%S")
        self.run = f"{dep.run.name}-{stamp}-{os.getpid() % 10000}"  # another if it exists
        self.root = Path(out_root or dep.run.output)
        self.out = self.root / self.run
        self.folder_mode = FOLDER_MODE if folder_mode is None else folder_mode
        self.port = dep.bus.port or free_port()
        self.hub = f"tcp/127.0.0.1:{self.port}"
        self.services = ServiceProcesses(
            dep, self.run, self.out, self.hub, self.port, quiet, view.live, view.rate
        )
        self.quiet = quiet
        self.signals = lifecycle.StopSignals()
        self.supervisor = Supervisor(
            dep, self.services, self.say, lambda: self.signals.received is not None, view.rate
        )

    def say(self, text: str, error: bool = False) -> None:
        """Progress on stderr (not with --quiet); an error is always said."""
        if error or not self.quiet:
            print(f"ddvi run: {text}", file=sys.stderr, flush=True)

    def execute(self) -> int:
        """Run the mission; the exit status (``services.ground.launch.lifecycle``): 0 completed, 1
        failed or ended early, 2 bad input, 3 completed with commands refused, stale or
        missing, 128 + N stopped by signal N (every service stopped, the partial report
        written)."""
        warnings, refused = lifecycle.resource_problems(self.dep)
        if refused is not None:
            self.say(refused, error=True)
            return lifecycle.EXIT_USAGE
        # before the folder: a run that cannot start leaves no credentials behind
        if missing := [h.netns for h in self.dep.host if not netns_exists(h.netns)]:
            self.say(
                f"network namespaces {missing} do not exist: run `ddvi netns up "
                f"{self.dep.path}` first (as root)",
                error=True,
            )
            return 1
        if (status := self._make_folder()) is not None:
            return status
        for warning in warnings:
            self.say(f"warning: {warning}")
        for warning in holding_warnings(self.dep) + reentry_warnings(self.dep):
            self.say(f"warning: {warning}")
        self.signals.install()
        try:
            status = self._open_and_fly()
        finally:
            try:
                self.services.stop_all(report_grace=report_wait(self.dep))
            finally:
                self.signals.restore()
        if self.supervisor.monitor_died:
            recover_report(self.out, self.say)
        return self._after_stop(status)

    def _make_folder(self) -> int | None:
        """Make the run folder exclusively (``runfolder.make_run_folder``: a name that exists
        is never reused) with its credentials and a copy of the deployment; None, or
        (one line said, no run folder left) status 2."""
        made = False
        try:
            self.run, self.out = make_run_folder(self.root, self.run, self.folder_mode)
            self.services.run, self.services.out = self.run, self.out  # a new name if taken
            made = True
            (self.out / "logs").mkdir()
            self._hub_settings()  # the credentials, each a new file
            if self.table is not None:
                text = tomli_w.dumps(self.table)
                write_private(self.out / DEPLOYMENT_FILE, text, mode=0o644)
                self.dep = dataclasses.replace(self.dep, path=str(self.out / DEPLOYMENT_FILE))
                self.services.dep = self.supervisor.dep = self.dep
            elif self.dep.path:  # what `ddvi fault` checks a fault against
                text = Path(self.dep.path).read_text()
                write_private(self.out / DEPLOYMENT_FILE, text, mode=0o644)
        except OSError as exc:
            if made:
                shutil.rmtree(self.out, ignore_errors=True)
            why = f"{exc.filename}: {exc.strerror}" if exc.filename and exc.strerror else exc
            self.say(
                f"cannot create the run folder {self.out} ({why}); choose "
                "another with --output or run.output",
                error=True,
            )
            return lifecycle.EXIT_USAGE
        return None

    def _open_and_fly(self) -> int:
        """Open the hub's session (failing: one line, status 2, and no run folder left), then
        fly the mission."""
        started = time.monotonic()
        zenoh.init_log_from_env_or("warn")  # the router's own warnings (a dropped sample, a link)
        with contextlib.ExitStack() as stack:
            try:
                session = stack.enter_context(open_session(self._hub_settings()))
            except Exception as exc:  # zenoh.ZError: a port in use, an endpoint unreachable
                first = error_text(exc)
                # nothing ran: leave no run folder behind
                shutil.rmtree(self.out, ignore_errors=True)
                self.say(
                    f"cannot open the bus (port {self.port}, connect "
                    f"{self.dep.bus.connect}): {first}; is bus.port in use, or a "
                    "bus.connect endpoint wrong?",
                    error=True,
                )
                return lifecycle.EXIT_USAGE
            if (status := self._write_bus_file()) is not None:
                return status
            # said once the run can be found: a command started on this line connects
            self.say(f"run {self.run}, output {self.out}, hub {self.hub}")
            return self._fly(session, started)
        return lifecycle.EXIT_FAILED  # not reached (mypy: ExitStack may swallow)

    def _await(self, session: Any, names: list[str]) -> int | None:
        """Wait for the services' liveliness, watching them: None when all are alive, else
        the exit status (a crash is said at once, with the service's last log lines)."""
        how, what = lifecycle.await_alive(
            session,
            self.run,
            names,
            self.dep.run.startup_timeout,
            self.services.exited,
            lambda: self.signals.received is not None,
        )
        return self._awaited(how, what, "starting")

    def _awaited(self, how: str, what: Any, doing: str) -> int | None:
        """None when the wait ended as it should, else the exit status, said (``lifecycle``'s
        ``await_alive`` and ``await_client``)."""
        if how in ("alive", "watched"):
            return None
        if how == "stopped":
            return lifecycle.EXIT_FAILED  # _after_stop makes it 128 + N
        if how == "exited":
            name, rc = what
            log = self.out / "logs" / f"{name}.log"
            tail = "".join(f"\n    {line}" for line in lifecycle.last_lines(log))
            self.say(
                f"{name} exited with status {rc} while {doing}; last lines of {log}:"
                f"{tail or ' (empty)'}",
                error=True,
            )
            return lifecycle.EXIT_FAILED
        self.say(
            f"not alive after {self.dep.run.startup_timeout} s: {what}; see {self.out / 'logs'}",
            error=True,
        )
        return lifecycle.EXIT_FAILED

    def _write_bus_file(self) -> int | None:
        """Say where the run's hub listens (``bus.json``), now that it does; None, or (one
        line said, no run folder left) status 2."""
        try:
            hub = self._hub_settings()  # made with the folder
            credentials.write_bus_file(self.out, self.run, hub, self.dep.bus.security)
        except OSError as exc:
            shutil.rmtree(self.out, ignore_errors=True)
            self.say(f"cannot write the run's bus.json in {self.out} ({exc})", error=True)
            return lifecycle.EXIT_USAGE
        return None

    def _fly(self, session: Any, started: float) -> int:
        """Start every service at once, the environment included, and supervise."""
        first = [s for s in self.dep.services if s != "environment"]
        # all at once: a service declares itself alive, and publishes, only once it sees the
        # monitor (services.flight.runtime), so that the recording has everything from the
        # first message on, and the environment flies once it sees every other service alive
        if (ros2 := self.dep.ros2).enabled:
            self.say(
                f"ROS 2 on {ros2.endpoint}, domain {ros2.domain_id}: {ROS2_GATEWAY} joins the "
                "Zenoh router there, or serves it (docs/ros2.md)"
            )
        with Bus(session, self.run, "launcher") as bus:
            faults: queue.SimpleQueue = queue.SimpleQueue()
            bus.subscribe(fault_topic("kill"), queue_handler(faults), expected_schema="fault")
            wait = self.viewing.wait_for_client
            url, watched = _live_view(bus, self.viewing.live, wait, self.say)
            for name in first if wait else [*first, "environment"]:
                self.services.start(name)
            if (status := self._await(session, first)) is not None:
                return status
            self.say(f"{len(first)} services alive in {time.monotonic() - started:.1f} s")
            if wait:
                self.say(f"waiting for a client of {url}: the mission flies once one subscribes")
                stopping = lambda: self.signals.received is not None  # noqa: E731
                how, what = lifecycle.await_client(watched, self.services.exited, stopping)
                if (status := self._awaited(how, what, "waiting for a client")) is not None:
                    return status
                self.say("a client is watching: the mission flies")
                self.services.start("environment")
            status = self.supervisor.watch(bus, faults)
            if status is not None:
                return status
            monitor = self.services["monitor"].popen
            return await_report(monitor, self.out, report_wait(self.dep), started, self.say)

    def _after_stop(self, status: int) -> int:
        """Once every service is stopped: a stop signal's status (and whether the partial
        report is there), or ``status``."""
        if (signum := self.signals.received) is None:
            return status
        report = self.out / "report.md"
        where = (
            f"partial report in {self.out}"
            if report.is_file()
            else (f"no report; see {self.out / 'logs' / 'monitor.log'}")
        )
        code = lifecycle.exit_for_signal(signum)
        self.say(
            f"stopped by {signal.Signals(signum).name}: every service stopped; {where} "
            f"(exit status {code})",
            error=True,
        )
        return code

    def _hub_settings(self) -> BusSettings:
        """The hub's session: client-mode services need a router to relay between them; it
        listens on loopback and on the launcher's side of every other host's link."""
        if (made := getattr(self, "_hub", None)) is not None:
            return made
        hosts = range(len(self.dep.host))
        listen = [self.hub] + [f"tcp/{hub_address(k)}:{self.port}" for k in hosts]
        # on a secure bus, every participant's credentials in the run folder
        self._hub: BusSettings = dataclasses.replace(
            credentials.hub_settings(self.dep, self.run, self.out, listen, self.dep.services),
            lease_ms=self.dep.session_lease_ms(),  # a frozen client keeps its hub (docs/health.md)
        )
        if not self.dep.bus.security:
            self.say(  # said even with --quiet: an open bus is never silent
                "warning: bus.security = false: the bus is open, unauthenticated and "
                "without access control; any local process can command the deputies",
                error=True,
            )
        return self._hub
