"""What every service process shares: its command line, its session, its bus, its shutdown.

A service is started by the launcher as ``python -m <module> --deployment FILE
--run RUN --hub ENDPOINT [--name NAME] [--out DIR] [--join]``; ``--join`` marks a restart into a
running mission (``ServiceContext.joining``): the service declares itself alive only once it can
do its job, so that nobody waits on it before.  ``run_service`` opens the zenoh session
(always closed, whatever happens), builds the Bus, turns SIGTERM/SIGINT into a stop request,
runs the service's main loop, publishes its final counters and returns an exit status.
SIGHUP stops it too, and so does the launcher's death (``stop_with_launcher``).
"""

from __future__ import annotations

import os

# BLAS threads would compete with the services for the cores
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse
import contextlib
import ctypes
import logging
import signal
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import zenoh

from services.bus import (
    LINK_PARAMETERS,
    SERVICE_ZENOH_RUNTIME,
    Bus,
    BusSettings,
    LinkRule,
    RateBudget,
    budget_for,
    open_session,
    router_answers,
    wait_for_alive,
    wait_for_gone,
)
from services.bus.security import Credentials, load_credentials
from services.config import (
    Deployment,
    DeploymentError,
    check_link_fault,
    link_from_params,
    load_deployment,
)
from services.flight.health import HANG_STATUS, HangError
from services.interface import Message, fault_topic, log_topic, stats_topic
from services.interface.keys import PatternError, key_matches
from services.model import duration

# zenoh reads it when a session opens: every service's, not the launcher's (SERVICE_ZENOH_RUNTIME)
os.environ.setdefault("ZENOH_RUNTIME", SERVICE_ZENOH_RUNTIME)

log = logging.getLogger("ddvi")

MONITOR_WAIT = 10.0
"""Wall seconds a service waits at start-up to see the monitor, at least (the run's
``startup_timeout`` if longer: the launcher starts the monitor and the services together), so
that what it publishes first is recorded: a message put before this session knows the
monitor's subscription goes nowhere."""
OUTLAST_MONITOR = 30.0
"""Wall seconds a finished service keeps its session for the monitor to close the recording
(the monitor's final wait, its own stats and its bounded drain of what is queued)."""


@dataclass
class ServiceContext:
    """Handed to a service's main function."""

    deployment: Deployment
    run: str
    name: str
    bus: Bus
    stop: threading.Event  # set by SIGTERM/SIGINT: finish the current step and return
    out: str  # the run's output folder
    joining: bool = False  # restarted into a running mission (the launcher's --join)

    def ready(self) -> None:
        """Declare the liveliness token: call once every subscription is declared, so that a
        service seen alive never misses a message addressed to it."""
        self.bus.declare_alive()

    def give_up(self, exc: HangError) -> int:
        """Lock-step gave up waiting (``exc``): log whom it blames and return ``HANG_STATUS``.
        The blame goes to the part that stopped talking: the awaited service, unless the
        run's router, which relays everything, does not answer either."""
        if not router_answers(self.bus.session, self.run, exc.service):
            exc = exc.router_silent()
        self.log("error", str(exc), exc.t)
        return HANG_STATUS

    def publish_stats(self, t: float, extra: dict[str, int] | None = None) -> None:
        counters = dict(self.bus.counters)
        counters.update(extra or {})
        self.bus.publish(
            stats_topic(self.name), "stats", {"service": self.name, "counters": counters}, t
        )

    def on_link_fault(self, _topic: str, msg: Message) -> None:
        """``fault/link`` (``ddvi fault RUN link``): when this service matches the fault's
        target (the subscriber pattern), impair what it receives from ``params.from`` (a
        publisher pattern) on ``params.topic`` from now on, as a deployment's [[link]] would;
        refused, as that [[link]] would be, unless the deployment allows it
        (``check_link_fault``)."""
        target, p = msg.body["target"], msg.body["params"]
        where = f"fault link {target}: "
        try:
            if self.name == "monitor" or not key_matches(target, self.name):
                return  # the monitor records what is published, unimpaired
        except PatternError as exc:
            self.log("warning", where + f"refused at {self.name} ({exc})", msg.t)
            return
        try:
            numbers = {k: p[k] for k in LINK_PARAMETERS if k in p}
            link = link_from_params(p.get("from", "*"), target, p.get("topic", "*"), numbers)
            check_link_fault(self.deployment, link)
        except DeploymentError as exc:
            self.log("warning", where + f"refused at {self.name} ({exc})", msg.t)
            return
        spec, publisher, topic = link.spec, link.publisher, link.topic
        self.bus.add_link_rule(LinkRule(publisher, topic, spec))
        impairments = (
            ", ".join(f"{k} {getattr(spec, k):g}" for k in LINK_PARAMETERS if getattr(spec, k))
            or "none"
        )
        self.log(
            "warning",
            where + f"{self.name} now receives {topic} from {publisher} with "
            f"{impairments} (from t = {msg.t:.0f} s)",
            msg.t,
        )

    def log(self, level: str, text: str, t: float = 0.0) -> None:
        getattr(log, level if level in ("info", "warning", "error") else "info")(text)
        try:
            self.bus.publish(
                log_topic(self.name),
                "log",
                {"service": self.name, "level": level, "text": text[:2000]},
                t,
            )
        except Exception:  # logging must never take a service down
            log.exception("could not publish a log message")


PR_SET_PDEATHSIG = 1  # linux/prctl.h


ORPHAN_GRACE = {"monitor": 60.0}
"""Wall seconds a service whose launcher died has to stop by itself before it is ended (the
monitor writes the run's report first); any other service: ``ORPHAN_GRACE_DEFAULT``."""
ORPHAN_GRACE_DEFAULT = 10.0


STOP_SIGNALS = (signal.SIGTERM, signal.SIGINT, signal.SIGHUP)
"""What asks a process of the run to stop: a service (``ServiceContext.stop``), ``ddvi run``."""


def stop_on_signals(stop: threading.Event, signals: tuple[int, ...] = STOP_SIGNALS) -> None:
    """Have ``signals`` set ``stop`` (main thread only).  Not from the handler itself: Python
    runs a handler in the main thread between any two bytecodes, also while that thread holds
    the Event's lock (inside ``Event.set`` when a second signal comes, as a launcher's death
    and the router's with it can send), and ``Event.set`` would then wait on that lock forever.
    The handler only writes a byte to a pipe; a thread that reads it sets ``stop``."""
    readable, writable = os.pipe()
    os.set_blocking(writable, False)

    def on_signal(_signum: int, _frame: Any) -> None:
        with contextlib.suppress(OSError):  # the pipe full: a stop is on its way already
            os.write(writable, b"\0")

    def relay() -> None:
        os.read(readable, 1)
        stop.set()

    threading.Thread(target=relay, name="stop-signals", daemon=True).start()
    for sig in signals:
        signal.signal(sig, on_signal)


def stop_with_launcher(name: str) -> None:
    """Linux: have the kernel send this process SIGTERM (a stop request) when the launcher
    that started it dies, even by SIGKILL (``prctl(PR_SET_PDEATHSIG)``); a launcher already
    gone stops it at once.  The launcher names itself in ``DDVI_LAUNCHER_PID``; without it
    (a service started by hand) nothing is done.

    A stop request is only seen between Python steps, and the launcher's death also takes the
    run's router: a service blocked in its session (opening, or closing one whose router is
    gone) would never return to see it.  A watchdog thread therefore ends the process once the
    launcher has been gone for the service's grace (``ORPHAN_GRACE``)."""
    parent = os.environ.get("DDVI_LAUNCHER_PID", "")
    if not parent.isdigit() or not sys.platform.startswith("linux"):
        return
    threading.Thread(
        target=_end_when_orphaned,
        args=(int(parent), ORPHAN_GRACE.get(name, ORPHAN_GRACE_DEFAULT)),
        name="orphan-watchdog",
        daemon=True,
    ).start()
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        if libc.prctl(PR_SET_PDEATHSIG, int(signal.SIGTERM), 0, 0, 0) != 0:
            log.warning("prctl(PR_SET_PDEATHSIG) failed (errno %d)", ctypes.get_errno())
            return
    except (OSError, AttributeError) as exc:
        log.warning("no parent-death signal (%s): this service outlives a killed launcher", exc)
        return
    if os.getppid() != int(parent):  # the launcher died before the prctl
        os.kill(os.getpid(), signal.SIGTERM)


def _end_when_orphaned(launcher: int, grace: float) -> None:
    while os.getppid() == launcher:
        time.sleep(0.5)
    time.sleep(grace)
    log.error("the launcher is gone and this service did not stop within %g s: ending it", grace)
    logging.shutdown()
    os._exit(128 + int(signal.SIGTERM))


def mission_window(dep: Deployment) -> tuple[float, float]:
    """The simulation times (s) a received message may carry: the mission's, with two
    flight-software steps of margin each side (``Bus(time_window=...)``)."""
    margin = 2.0 * max(dep.run.fsw_period, dep.run.nav_period)
    return -margin, duration(dep) + margin


def rate_budget(dep: Deployment, run: str) -> RateBudget:
    """What a service takes from each publisher of ``run`` (``services.bus.budget``)."""
    r = dep.run
    return budget_for(f"ddvi/{run}/", r.nav_period, r.fsw_period, r.status_every, dep.publisher_of)


def bus_settings(dep: Deployment, hub: str, credentials: Credentials | None = None) -> BusSettings:
    connect, lease = [hub, *dep.bus.connect], dep.session_lease_ms()
    if credentials is not None:  # a secure bus: the hub's client, listening on nothing
        return credentials.client(connect, lease)
    if dep.bus.mode == "client":
        return BusSettings(mode="client", listen=[], connect=connect, lease_ms=lease)
    return BusSettings(mode="peer", listen=["tcp/127.0.0.1:0"], connect=connect, lease_ms=lease)


def parse_args(argv: list[str] | None, default_name: str) -> argparse.Namespace:
    ap = argparse.ArgumentParser(prog=f"services.{default_name}")
    ap.add_argument("--deployment", required=True)
    ap.add_argument("--run", required=True)
    ap.add_argument("--hub", required=True, help="zenoh endpoint of the run's hub")
    ap.add_argument("--name", default=default_name, help="service name")
    ap.add_argument("--out", default=".", help="the run's output folder")
    ap.add_argument("--join", action="store_true", help="restarted into a running mission")
    ap.add_argument("--credentials", help="this service's bus credentials (a secure bus)")
    return ap.parse_args(argv)


def _see_monitor(session: Any, run: str, stop: threading.Event, wait: float) -> bool:
    """Wait up to ``wait`` s for the monitor's token, in slices: a stop request ends it."""
    deadline = time.monotonic() + wait
    while not stop.is_set() and time.monotonic() < deadline:
        if wait_for_alive(session, run, ["monitor"], min(0.5, deadline - time.monotonic())):
            return True
    return False


def run_service(
    main: Callable[[ServiceContext], int], default_name: str, argv: list[str] | None = None
) -> int:
    args = parse_args(argv, default_name)
    logging.basicConfig(
        level=logging.INFO,
        stream=sys.stderr,
        format=f"%(asctime)s {args.name} %(levelname)s %(message)s",
    )
    zenoh.init_log_from_env_or("warn")
    try:
        dep = load_deployment(args.deployment)
    except DeploymentError as exc:
        print(f"{args.name}: {exc}", file=sys.stderr)
        return 2
    stop = threading.Event()
    stop_on_signals(stop)
    stop_with_launcher(args.name)
    try:
        creds = load_credentials(args.credentials) if args.credentials else None
    except (OSError, ValueError) as exc:
        print(f"{args.name}: --credentials: {exc}", file=sys.stderr)
        return 2
    with open_session(bus_settings(dep, args.hub, creds)) as session:
        bus = Bus(
            session,
            args.run,
            args.name,
            links=dep.links_for(args.name),
            link_clock="sim" if dep.run.mode == "lockstep" else "wall",
            seed=dep.run.seed,
            time_window=mission_window(dep),
            budget=rate_budget(dep, args.run),
        )
        try:
            ctx = ServiceContext(dep, args.run, args.name, bus, stop, args.out, args.join)
            # the monitor subscribed before its token: seeing the token, this session knows
            # the subscription (the launcher starts the monitor with the others: a short wait)
            wait = max(MONITOR_WAIT, dep.run.startup_timeout)
            if args.name != "monitor" and not _see_monitor(session, args.run, stop, wait):
                log.warning(
                    "the monitor is not seen after %g s: what this service publishes "
                    "before it is may not be recorded",
                    wait,
                )
            bus.subscribe(fault_topic("link"), ctx.on_link_fault, expected_schema="fault")
            status = main(ctx)
            bus.declare_alive()  # no-op if the service declared itself ready
            bus.withdraw()  # done: the monitor and the launcher see its token go
            if status == 0 and args.name != "monitor" and not stop.is_set():
                # keep the keys of what it has put until the recording is closed (the
                # monitor's token goes then): see Bus.withdraw
                wait_for_gone(session, args.run, "monitor", OUTLAST_MONITOR)
            return status
        finally:
            bus.close()
