"""``ddvi monitor --run RUN --live [HOST:PORT]``: a running mission served to Foxglove live.

A tap on the run's bus (as the observer, a subscribe-only user, on a secure bus) that serves
every message it hears through ``services.ground.monitoring.live.LiveServer``: the channels of the
run's deployment (attached to its recording) advertised at once, each message at its simulation
time, the formation's 3D scene made from them (``services.ground.monitoring.scene``) and each
service's liveliness (``alive/<service>``: the tokens there when it starts, then each change).
It runs until Ctrl-C, ``--count`` messages or ``--seconds`` s; the flight never waits for it
(the subscribers' callbacks only queue).
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import queue
import sys
import time
import tomllib
from pathlib import Path
from typing import Any

import zenoh
from mcap.exceptions import McapError
from mcap.records import Attachment, Chunk
from mcap.records import Message as McapMessage
from mcap.stream_reader import StreamReader

from services.bus import error_text, open_session, watch_alive
from services.bus.security import OBSERVER
from services.config import Deployment, DeploymentError, deployment_from_table
from services.ground.launch.credentials import RunNotFoundError, find_run, run_folder
from services.ground.monitoring.live import LiveServer, live_server
from services.ground.monitoring.live_address import LiveError, check_live, exposure_warning
from services.ground.monitoring.run_keys import run_keyexpr
from services.ground.monitoring.scene import Scene, open_scene
from services.ground.storage.recording import RECORDING
from services.interface import Message, MessageError, decode, schema_for_topic, unpack_batch

log = logging.getLogger("ddvi.live")

POLL = 0.1  # s between looks at the clock and the limits when nothing arrives
# s to wait for the recording's deployment: a run just started may not have made it yet
DEPLOYMENT_WAIT = 30.0


def wait_for_deployment(path: Path, wait: float = DEPLOYMENT_WAIT) -> Deployment | None:
    """The deployment attached to the recording at ``path``, waiting up to ``wait`` s for the
    monitor to start it; None after that."""
    deadline = time.monotonic() + wait
    while (dep := attached_deployment(path)) is None and time.monotonic() < deadline:
        time.sleep(0.2)
    if dep is None:
        log.warning("no deployment in %s: topics advertised as they come, no K*", path)
    return dep


def attached_deployment(path: Path) -> Deployment | None:
    """The deployment attached to a recording (the monitor writes it first, before any
    message), or None when there is none (yet) or it does not read."""
    if not path.is_file():
        return None
    try:
        with path.open("rb") as f:
            for record in StreamReader(f, skip_magic=False).records:
                if isinstance(record, Attachment) and record.media_type == "application/toml":
                    return deployment_from_table(tomllib.loads(record.data.decode()), record.name)
                if isinstance(record, Chunk | McapMessage):
                    return None
    except (OSError, ValueError, DeploymentError, EOFError, McapError):
        pass  # not written whole yet
    return None


def serve_live(args: argparse.Namespace) -> int:
    """Serve the run ``args.run`` names on ``args.live`` until Ctrl-C, ``args.count`` messages
    or ``args.seconds`` s.  0; 2 for bad input (no run, the package missing, the port taken);
    1 for a bus that refuses or cannot be reached."""
    try:
        if not args.run:
            raise LiveError("--live needs --run RUN (the run folder ddvi run prints)")
        address = check_live(args.live)
        bus = find_run(args.run, args.output, OBSERVER, getattr(args, "insecure", False))
        folder = run_folder(args.run, args.output)
        keyexpr = run_keyexpr(bus.run, args.keyexpr)
    except (LiveError, RunNotFoundError, ValueError) as exc:
        print(f"ddvi monitor: {exc}", file=sys.stderr)
        return 2
    if warning := exposure_warning(address):
        print(f"ddvi monitor: warning: {warning}", file=sys.stderr)
    dep = wait_for_deployment(folder / RECORDING)
    with contextlib.ExitStack() as stack:
        try:
            session = stack.enter_context(open_session(bus.settings()))
        except zenoh.ZError as exc:
            print(f"ddvi monitor: cannot connect to {bus.hub} ({error_text(exc)})", file=sys.stderr)
            return 1
        scene = open_scene(dep)
        if dep is not None:
            channels = scene.channels() if scene is not None else []
            server = live_server(address, dep, bus.run, scene=channels)
        else:  # the topics are advertised as they come, and K* is not known
            server = LiveServer(address, f"ddvi {bus.run}", {}, {})
        stack.callback(server.close)
        print(
            f"ddvi monitor: live view of {bus.run} on {address.url} (Foxglove: Open "
            "connection, Foxglove WebSocket; docs/live.md); Ctrl-C to stop",
            file=sys.stderr,
            flush=True,
        )
        limits = (int(args.count or 0), float(args.seconds or 0.0))
        _serve(session, keyexpr, bus.run, server, scene, *limits)
    return 0


def _serve(
    session: zenoh.Session,
    keyexpr: str,
    run: str,
    server: LiveServer,
    scene: Scene | None,
    count: int,
    seconds: float,
) -> None:
    """Serve what ``keyexpr`` hears of ``run``, the ``scene`` made from it and the run's
    liveliness, until ``count`` messages (0: no limit), ``seconds`` s (0: no limit) or
    Ctrl-C."""
    inbox: queue.SimpleQueue[tuple[str | None, Any]] = queue.SimpleQueue()
    sub = session.declare_subscriber(
        keyexpr, lambda s: inbox.put((str(s.key_expr), s.payload.to_bytes()))
    )
    # a liveliness change is queued as (None, (service, up))
    alive = watch_alive(session, run, "*", lambda name, up: inbox.put((None, (name, up))))
    prefix = f"ddvi/{run}/"
    deadline = time.monotonic() + seconds if seconds > 0 else None
    served, sim_t = 0, 0.0
    try:
        while count <= 0 or served < count:
            if deadline is not None and time.monotonic() >= deadline:
                break
            try:
                key, payload = inbox.get(timeout=POLL)
            except queue.Empty:
                continue
            if key is None:
                server.alive(*payload, sim_t)
                continue
            topic = key.removeprefix(prefix)
            try:
                parts = unpack_batch(payload) or (payload,)
            except MessageError as err:
                server.rejected(topic, key, payload, err, sim_t)
                continue
            for part in parts:
                try:
                    msg = decode(part, schema_for_topic(topic))
                except MessageError as err:
                    server.rejected(topic, key, part, err, sim_t)
                    continue
                sim_t = max(sim_t, msg.t)
                server.message(topic, msg)
                served += 1
                if scene is not None:
                    _draw(scene, server, topic, msg)
    except KeyboardInterrupt:
        pass
    finally:
        alive.undeclare()
        sub.undeclare()


def _draw(scene: Scene, server: LiveServer, topic: str, msg: Message) -> None:
    """Serve the scene messages ``msg`` completes; an error is logged, the tap goes on."""
    try:
        for m in scene.message(topic, msg):
            server.scene(m)
    except Exception:
        log.exception("could not draw the scene at t = %s", msg.t)
