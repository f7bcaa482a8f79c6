"""``ddvi fault RUN KIND ...``: inject a fault into a running deployment from the ground.

A fault is a message on ``ddvi/<run>/fault/<kind>`` (schema ``fault``: kind, target, params)
that the service responsible acts on, stamped with the run's simulation time (read from its
clock, which also proves the run is there).  The kinds:

    kill SERVICE                    the launcher kills the service with SIGKILL, as a crash
                                    would; its [[restart]] policy decides what follows
    panel DEPUTY {--area-factor F | --stuck-angle DEG | both}
                                    the environment makes the deputy's true drag-panel area F
                                    times the nominal and/or sticks its hinge with the facet
                                    normal at DEG in (0, 90) in the body x-y plane (the
                                    controllers are not told)
    bias DEPUTY --position X Y Z [--velocity X Y Z]
                                    the deputy's navigation bias becomes this (m, m/s)
    outage DEPUTY --orbits N        the deputy's navigation measures nothing for N chief
                                    orbits: its filter propagates, its samples are not valid
    link --from PUB --to SUB [--topic T] [--delay S] [--jitter S] [--loss P] [--duplicate P]
         [--reorder P]              every service matching SUB impairs what it receives from
                                    PUB (service-name patterns; nav/deputy1 means nav-deputy1)
                                    from now on, ahead of the deployment's [[link]]s

RUN is the run folder ``ddvi run`` prints, or the run's name under ``--output`` (default
``runs``): the command reads the run's hub from its ``bus.json`` and, on a secure bus, connects
with the operator's credentials from its ``security/`` folder (the only ones allowed to put
faults).  ``--hub`` names the hub of an insecure run that has no run folder here.

Before it sends anything the command checks the fault as the run's deployment would check the
same fault, link or kill in its file (``services.config.validation``: a link's delay + jitter
shorter than the mission, patterns naming its services, a deputy of the run, values in range),
against the copy in the run folder (``deployment.toml``); a run reached by ``--hub`` alone is
checked by its services on receipt, with the same checks, but for the deputy a panel, bias or
outage fault names, which must be one whose services are alive on the run's bus.  A run whose
folder holds its report (summary.json, written as it ends) is over: said at once, exit 1.

The service that acts logs ``fault <kind> <target>: ...``; the command waits for that line,
prints it, and exits 0, or 1 when the run, the service or that answer is not there (or the run
is over), or the service refused the fault; 2, with nothing sent, for a command line that does
not describe a fault or a run, or a fault the run's deployment (or its deputies) refuses.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import queue
import sys
import time
from typing import TYPE_CHECKING, Any

import zenoh

from services.bus import (
    LINK_PARAMETERS,
    Bus,
    BusSettings,
    alive_services,
    check_name,
    error_text,
    open_session,
    queue_handler,
    wait_for_alive,
)
from services.bus.security import OPERATOR
from services.config import (
    Deployment,
    DeploymentError,
    Fault,
    check_fault,
    check_kill,
    check_link_fault,
    check_panel,
    link_from_params,
    load_deployment,
)
from services.config.ranges import check_bias
from services.ground.launch.runfolder import DEPLOYMENT_FILE
from services.interface import decode, topics
from services.interface.keys import key_matches

if TYPE_CHECKING:
    from services.config.deployment import Link
    from services.ground.launch.credentials import RunBus

KINDS = ("kill", "panel", "bias", "outage", "link")


def add_fault_arguments(p: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """The arguments of ``ddvi fault``, for ``services.cli``."""
    p.add_argument("run", help="the run folder ddvi run prints, or the run's name under --output")
    p.add_argument("kind", choices=KINDS, help="what to inject")
    p.add_argument(
        "target",
        nargs="?",
        help="kill: a service (ctrl-<deputy>, nav-<deputy>); panel, bias, outage: a deputy; "
        "link: see --to",
    )
    p.add_argument("--from", dest="publisher", help="link: publishing service(s), a pattern")
    p.add_argument("--to", dest="subscriber", help="link: subscribing service(s), a pattern")
    p.add_argument(
        "--topic",
        default="**",
        help="link: topic pattern, a key expression (default: every topic but the clock)",
    )
    for key in LINK_PARAMETERS:
        unit = "s" if key in ("delay", "jitter") else "probability"
        p.add_argument(f"--{key}", type=float, default=0.0, help=f"link: {key} ({unit})")
    p.add_argument("--area-factor", type=float, help="panel: true area / nominal")
    p.add_argument(
        "--stuck-angle",
        type=float,
        metavar="DEG",
        help="panel: facet normal stuck at DEG (0-90) in body x-y",
    )
    p.add_argument(
        "--position",
        type=float,
        nargs=3,
        metavar=("X", "Y", "Z"),
        help="bias: Hill position bias, m",
    )
    p.add_argument(
        "--velocity",
        type=float,
        nargs=3,
        metavar=("X", "Y", "Z"),
        default=[0.0, 0.0, 0.0],
        help="bias: Hill velocity bias, m/s",
    )
    p.add_argument(
        "--orbits",
        type=float,
        metavar="N",
        help="outage: how long navigation measures nothing, chief orbits (> 0)",
    )
    p.add_argument("--output", default="runs", help="where run folders are (default: runs)")
    p.add_argument("--hub", help="an insecure run's hub, when its run folder is not here")
    p.add_argument(
        "--insecure",
        action="store_true",
        help="connect without authentication although the run folder holds credentials and "
        "its bus.json turns security off (refused otherwise; docs/security.md)",
    )
    # a lock-step run sends no clock while a controller learns (seconds, more on a busy host)
    p.add_argument("--timeout", type=float, default=30.0, help="s to wait for the run's answer")
    return p


def _clock(session: zenoh.Session, run: str, timeout: float) -> float | None:
    """The run's simulation time, from its next clock message (None: none within timeout)."""
    inbox: queue.SimpleQueue[bytes] = queue.SimpleQueue()
    key = f"ddvi/{run}/{topics.CLOCK}"
    sub = session.declare_subscriber(key, lambda s: inbox.put(s.payload.to_bytes()))
    try:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            try:
                return decode(inbox.get(timeout=0.1), "clock").t
            except queue.Empty:
                continue
            except Exception:
                continue  # not a clock we can read: wait for the next
        return None
    finally:
        sub.undeclare()


class UsageError(Exception):
    """A fault the command line does not describe fully; the message says what is missing."""


def locate_run(run: str, output: str, hub: str | None, user: str, insecure: bool = False) -> RunBus:
    """The run's bus: from its run folder (``find_run``; ``hub`` overrides its endpoint), or,
    with no run folder here, the insecure hub ``hub``.  Raises UsageError saying what is
    missing, or that the folder's bus.json turns security off while it holds credentials
    (unless ``insecure``: ``--hub`` does not get round that)."""
    # imported here: `ddvi fault` parses its arguments with the fewest modules (a running
    # mission waits for nobody)
    from services.ground.launch.credentials import (
        InsecureRunError,
        RunBus,
        RunNotFoundError,
        find_run,
    )

    try:
        found = find_run(run, output, user, insecure)
    except InsecureRunError as exc:
        raise UsageError(f"ddvi fault: {exc}") from exc
    except RunNotFoundError as exc:
        if hub is None:
            raise UsageError(f"ddvi fault: {exc}; or give an insecure run's --hub") from exc
        try:
            check_name("run", run)
            BusSettings(mode="client", listen=[], connect=[hub])
        except ValueError as err:
            raise UsageError(f"ddvi fault: {err}") from err
        return RunBus(run, hub, None)
    return RunBus(found.run, hub, found.credentials) if hub else found


def _target(args: argparse.Namespace) -> tuple[str, str]:
    """The run and the fault's target, checked (a link's target: its subscriber pattern)."""
    if args.kind == "link":
        if not args.publisher or not args.subscriber:
            raise UsageError("ddvi fault link: give --from PUBLISHER and --to SUBSCRIBER")
        args.target = args.subscriber.replace("/", "-")
    elif not args.target:
        raise UsageError(f"ddvi fault {args.kind}: name the target")
    try:
        run = check_name("run", args.run_name)
        target = args.target if args.kind == "link" else check_name("target", args.target)
    except ValueError as exc:
        raise UsageError(f"ddvi fault: {exc}") from exc
    return run, target


def _link(args: argparse.Namespace) -> Link:
    """The link a link fault impairs, its numbers checked as a [[link]]'s (UsageError)."""
    numbers = {k: getattr(args, k) for k in LINK_PARAMETERS}
    try:
        return link_from_params(args.publisher.replace("/", "-"), args.target, args.topic, numbers)
    except DeploymentError as exc:
        raise UsageError(f"ddvi fault: {exc}") from None


def _params(args: argparse.Namespace, target: str) -> tuple[dict[str, Any], str | None]:
    """The fault's params, each checked as far as it can be without the run's deployment, and
    the service that acts on it (None: every service a link's pattern matches answers)."""
    if args.kind == "panel":
        try:
            check_panel(args.area_factor, args.stuck_angle)
        except ValueError as exc:
            said = f"give --area-factor F in (0, 100] and/or --stuck-angle DEG in (0, 90) ({exc})"
            raise UsageError(f"ddvi fault panel: {said}") from exc
        params = {"area_factor": args.area_factor, "normal_angle": args.stuck_angle}
        return {k: v for k, v in params.items() if v is not None}, "environment"
    if args.kind == "bias":
        if args.position is None:
            raise UsageError("ddvi fault bias: give --position X Y Z (m)")
        try:
            check_bias("bias", args.position, args.velocity)
        except DeploymentError as exc:
            raise UsageError(f"ddvi fault: {exc}") from None
        values = [*args.position, *args.velocity]
        return dict(zip(("px", "py", "pz", "vx", "vy", "vz"), values, strict=True)), f"nav-{target}"
    if args.kind == "outage":
        if args.orbits is None or not args.orbits > 0:
            raise UsageError("ddvi fault outage: give --orbits N (> 0), how long it lasts")
        return {"duration_orbits": args.orbits}, f"nav-{target}"
    if args.kind == "link":
        link = _link(args)
        params = {"from": link.publisher, "topic": link.topic}
        params.update({k: getattr(link, k) for k in LINK_PARAMETERS})
        return params, None
    return {}, target


def run_deployment(run: str, output: str) -> Deployment | None:
    """The deployment the run flies, from the copy in its folder (``deployment.toml``); None
    when no run folder is here (a run reached by --hub) or it holds no copy."""
    from services.ground.launch.credentials import RunNotFoundError, run_folder

    try:
        path = run_folder(run, output) / DEPLOYMENT_FILE
    except RunNotFoundError:
        return None
    if not path.is_file():
        return None
    try:
        return load_deployment(str(path))
    except DeploymentError as exc:
        raise UsageError(f"ddvi fault: the run's deployment {path}: {exc}") from None


def check_against(dep: Deployment, args: argparse.Namespace, target: str) -> None:
    """Raise UsageError unless the fault is one the run's deployment ``dep`` allows: what its
    own [[link]], [[fault]] tables and services allow (``services.config.validation``)."""
    try:
        if args.kind == "kill":
            check_kill(dep, target)
        elif args.kind == "link":
            check_link_fault(dep, _link(args))
        else:
            fault = Fault(
                kind=args.kind,
                deputy=target,
                area_factor=args.area_factor,
                normal_angle=args.stuck_angle,
                position_bias=list(args.position or [0.0, 0.0, 0.0]),
                velocity_bias=list(args.velocity),
                duration_orbits=args.orbits if args.kind == "outage" else 0.0,
            )
            check_fault(dep, args.kind, fault)
    except DeploymentError as exc:
        raise UsageError(f"ddvi fault: {exc}") from None


def _link_answerers(session: zenoh.Session, run: str, target: str) -> set[str]:
    """The running services a link fault for ``target`` (a subscriber pattern) reaches, each of
    which answers: those alive that match it, but the monitor (it records unimpaired)."""
    alive = alive_services(session, run)
    return {n for n in alive if key_matches(target, n) and n not in ("monitor", "launcher")}


def run_deputies(alive: set[str]) -> list[str]:
    """The deputies whose navigation or controller is among the ``alive`` services."""
    return sorted({name.split("-", 1)[1] for name in alive if name.startswith(("nav-", "ctrl-"))})


def unknown_deputy(session: zenoh.Session, run: str, args: argparse.Namespace) -> str | None:
    """Why a panel, bias or outage fault names no deputy of the run reached by ``--hub`` alone
    (no deployment here to check it against), from the services alive on its bus: one line, or
    None (a deputy of the run, another kind, or no deputy's service alive to tell)."""
    if args.kind not in ("panel", "bias", "outage"):
        return None
    deputies = run_deputies(alive_services(session, run))
    if not deputies or args.target in deputies:
        return None
    return (
        f"ddvi fault {args.kind}: {args.target!r} is not a deputy of run {run!r}; its "
        f"deputies: {', '.join(deputies)}"
    )


def finished(run: str, output: str) -> str | None:
    """One line saying the run is over, when its folder holds the report its monitor writes
    as the run ends (summary.json), or None: a fault goes only to a run that flies."""
    from services.ground.launch.credentials import RunNotFoundError, run_folder

    try:
        folder = run_folder(run, output)
    except RunNotFoundError:
        return None
    if not (folder / "summary.json").is_file():
        return None
    return (
        f"ddvi fault: run {folder.name!r} is over (its report: {folder / 'report.md'}); a fault "
        "goes to a run while it flies"
    )


def _publish_and_wait(
    session: zenoh.Session,
    args: argparse.Namespace,
    run: str,
    target: str,
    params: dict[str, Any],
    t: float,
) -> int | None:
    """Publish the fault at simulation time ``t`` and print the answer of every service that
    acts on it (a link fault: each one its pattern matches); its exit status (1 when one ignored
    or refused it, or did not answer), or None when no answer came within ``args.timeout``."""
    expected = _link_answerers(session, run, target) if args.kind == "link" else set()
    answers: queue.SimpleQueue = queue.SimpleQueue()
    answered: dict[str, bool] = {}  # service -> whether it acted
    with Bus(session, run, f"ground-{os.getpid()}") as bus:
        bus.subscribe(topics.log_topic("*"), queue_handler(answers), expected_schema="log")
        time.sleep(0.2)  # let the subscription reach the service before it answers
        body = {"kind": args.kind, "target": target, "params": params}
        bus.publish(topics.fault_topic(args.kind), "fault", body, t)
        print(f"ddvi fault: {args.kind} {target} sent at t = {t:.0f} s")
        deadline = time.monotonic() + args.timeout
        while time.monotonic() < deadline and not (answered and expected <= set(answered)):
            try:
                _, msg = answers.get(timeout=0.1)
            except queue.Empty:
                continue
            text, service = msg.body["text"], msg.body["service"]
            if text.startswith(f"fault {args.kind} {target}:") and service not in answered:
                print(f"{service}: {text}")
                answered[service] = ": ignored" not in text and ": refused" not in text
    if not answered:
        return None
    if missing := sorted(expected - set(answered)):
        print(
            f"ddvi fault: no answer from {', '.join(missing)} within {args.timeout:g} s",
            file=sys.stderr,
        )
        return 1
    return 0 if all(answered.values()) else 1


def _connect(stack: contextlib.ExitStack, bus: RunBus) -> zenoh.Session | None:
    """The run's session (closed with ``stack``), or None, said in one line, when the hub
    refuses these credentials or cannot be reached."""
    try:
        return stack.enter_context(open_session(bus.settings()))
    except Exception as exc:  # zenoh.ZError: refused (credentials) or unreachable
        print(
            f"ddvi fault: cannot connect to {bus.hub} ({error_text(exc)}); is run {bus.run!r} "
            "running?",
            file=sys.stderr,
        )
        return None


def fault_command(args: argparse.Namespace) -> int:
    """Publish one fault and wait for the launcher's account of it; 0 when it was acted on."""
    try:
        bus = locate_run(args.run, args.output, args.hub, OPERATOR, args.insecure)
        args.run_name = bus.run
        run, target = _target(args)
        params, acting = _params(args, target)
        if (dep := run_deployment(args.run, args.output)) is not None:
            check_against(dep, args, target)
    except UsageError as exc:
        print(exc, file=sys.stderr)
        return 2
    if (over := finished(args.run, args.output)) is not None:
        print(over, file=sys.stderr)
        return 1
    with contextlib.ExitStack() as stack:
        if (session := _connect(stack, bus)) is None:
            return 1
        t = _clock(session, run, args.timeout)
        if t is None:
            # the run may have ended while the command waited
            said = finished(args.run, args.output) or (
                f"ddvi fault: no clock from run {run!r} on {bus.hub} within {args.timeout:g} s; "
                "is it running? (ddvi run prints 'run <name>, output <dir>, hub <endpoint>')"
            )
            print(said, file=sys.stderr)
            return 1
        if dep is None and (why := unknown_deputy(session, run, args)) is not None:
            print(why, file=sys.stderr)
            return 2
        if acting is not None and not wait_for_alive(session, run, [acting], 2.0):
            print(f"ddvi fault: service {acting!r} is not alive in run {run!r}", file=sys.stderr)
            return 1
        status = _publish_and_wait(session, args, run, target, params, t)
        if status is not None:
            return status
    who = acting or f"a service matching {target!r}"
    print(f"ddvi fault: no answer from {who} within {args.timeout:g} s", file=sys.stderr)
    return 1
