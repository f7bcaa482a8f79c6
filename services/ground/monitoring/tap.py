"""``ddvi monitor [KEYEXPR]``: a tap on the bus that prints every message, one line each.

    ddvi monitor --run RUN [TOPICS] [--output ROOT] [--count N] [--seconds S]
    ddvi monitor --run RUN 'ctrl/*/status'           # a topic pattern below the run's keys
    ddvi monitor --run RUN 'ddvi/<run>/ctrl/*/status'  # the same, as a full key expression
    ddvi monitor 'ctrl/*/status' --hub H [--count N] [--seconds S]

``--run`` finds a run by its folder (what ``ddvi run`` prints) or its name under ``--output``:
its hub from the folder's ``bus.json`` and, on a secure bus, the observer's credentials (a
subscribe-only user) from its ``security/`` folder; a folder that holds credentials while its
bus.json turns security off is refused (exit 2) unless ``--insecure`` says to connect without
authentication anyway (``services.ground.launch.credentials.find_run``); TOPICS (a topic pattern
such as ``ctrl/*/status``, or a full ``ddvi/<run>/...`` key expression) defaults to every topic; a
pattern that matches no topic of the topology is refused.
``--hub`` taps an insecure bus directly; ``--live`` serves the messages to Foxglove instead
(``services.ground.monitoring.live_tap``).  A sample that holds a batch prints one line per
message; one that does not decode prints why it is rejected.  The tap is a plain zenoh
subscriber: it records nothing and keeps no state.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import queue
import sys
import time
from collections.abc import Callable
from typing import Any

import numpy as np
import zenoh

from services.bus import EPHEMERAL_LOOPBACK, BusSettings, error_text, open_session
from services.bus.security import OBSERVER
from services.ground.launch import lifecycle
from services.ground.launch.credentials import RunNotFoundError, find_run
from services.ground.monitoring.live_address import LIVE_DEFAULT
from services.ground.monitoring.run_keys import run_keyexpr
from services.interface import MessageError, decode, unpack_batch


def add_monitor_arguments(p: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """The arguments of ``ddvi monitor``, for ``services.cli``."""
    p.add_argument(
        "keyexpr",
        nargs="?",
        metavar="TOPICS",
        help="a topic pattern such as 'ctrl/*/status' or 'nav/**' (or a full key expression "
        "'ddvi/<run>/ctrl/*/status'); default: every topic of the run",
    )
    p.add_argument("--run", help="the run folder ddvi run prints, or the run's name")
    p.add_argument("--output", default="runs", help="where run folders are (default: runs)")
    p.add_argument("--hub", help="an insecure bus's endpoint to connect to (instead of --run)")
    p.add_argument(
        "--insecure",
        action="store_true",
        help="connect without authentication although the run folder holds credentials and "
        "its bus.json turns security off (refused otherwise; docs/security.md)",
    )
    p.add_argument("--count", type=int, default=0, help="stop after N messages (0: no limit)")
    p.add_argument("--seconds", type=float, default=0.0, help="stop after S s (0: no limit)")
    p.add_argument(
        "--live",
        nargs="?",
        const=LIVE_DEFAULT,
        metavar="HOST:PORT",
        help=f"serve the messages to Foxglove instead of printing them (default {LIVE_DEFAULT}, "
        "or ws://HOST:PORT; needs --run and foxglove-sdk; docs/live.md)",
    )
    return p


def _compact(value: Any, width: int = 160) -> str:
    def short(v: Any) -> Any:
        if isinstance(v, np.ndarray):
            return np.round(v, 6).tolist()
        if isinstance(v, float):
            return float(f"{v:.6g}")
        if isinstance(v, dict):
            return {k: short(x) for k, x in v.items()}
        return v

    text = json.dumps(short(value), separators=(",", ":"), default=str)
    return text if len(text) <= width else text[: width - 3] + "..."


def format_sample(key: str, payload: bytes) -> list[str]:
    """One line per bus message of a zenoh sample (a batch holds several): key, schema, t,
    compact body (or why it is rejected)."""
    try:
        parts = unpack_batch(payload)
    except MessageError as err:
        return [f"{key} REJECTED {err.reason} ({len(payload)} B): {err}"]
    lines = []
    for part in parts or (payload,):
        try:
            msg = decode(part)
        except MessageError as err:
            lines.append(f"{key} REJECTED {err.reason} ({len(part)} B): {err}")
            continue
        body = _compact(msg.body)
        lines.append(f"{key} {msg.schema} t={msg.t:.3f} src={msg.src} seq={msg.seq} {body}")
    return lines


def _tap_settings(args: argparse.Namespace) -> tuple[BusSettings, str]:
    """The tap's session settings and key expression, from ``--run`` or ``--hub``; ValueError
    (one line) when neither names a bus."""
    if getattr(args, "run", None):
        try:
            bus = find_run(args.run, args.output, OBSERVER, getattr(args, "insecure", False))
        except RunNotFoundError as exc:
            raise ValueError(str(exc)) from exc
        return bus.settings(), run_keyexpr(bus.run, args.keyexpr)
    if not args.hub:
        raise ValueError("give --run RUN (the run folder ddvi run prints) or an insecure --hub")
    settings = BusSettings(mode="peer", listen=[EPHEMERAL_LOOPBACK], connect=[args.hub])
    return settings, run_keyexpr("*", args.keyexpr)


def _interrupt(_signum: int, _frame: Any) -> None:
    raise KeyboardInterrupt


def monitor_command(args: argparse.Namespace, out: Callable[[str], None] | None = None) -> int:
    """``ddvi monitor [KEYEXPR] {--run RUN | --hub H} [--count N] [--seconds S]``: print each
    message on the bus as one line until Ctrl-C, N messages or S seconds. Returns 0; 2 for no
    bus named, 1 for a bus that refuses or cannot be reached."""
    # Ctrl-C, SIGTERM and SIGHUP end a tap in order, as KeyboardInterrupt, also when it
    # inherited them ignored (``ddvi monitor ... &`` in a script)
    with lifecycle.handling(lifecycle.STOP_SIGNALS, _interrupt):
        return _monitor(args, out)


def _monitor(args: argparse.Namespace, out: Callable[[str], None] | None) -> int:
    """What ``monitor_command`` does, its stop signals taken."""
    if getattr(args, "live", None) is not None:
        from services.ground.monitoring.live_tap import serve_live

        return serve_live(args)
    emit = out or (lambda line: print(line, flush=True))
    try:
        settings, keyexpr = _tap_settings(args)
        zenoh.KeyExpr(keyexpr)
    except (ValueError, zenoh.ZError) as exc:
        print(f"ddvi monitor: {error_text(exc)}", file=sys.stderr)
        return 2
    with contextlib.ExitStack() as stack:
        try:
            session = stack.enter_context(open_session(settings))
        except zenoh.ZError as exc:
            print(
                f"ddvi monitor: cannot connect to {settings.connect[0]} ({error_text(exc)})",
                file=sys.stderr,
            )
            return 1
        _print_samples(session, keyexpr, emit, int(args.count or 0), float(args.seconds or 0.0))
    return 0


def _print_samples(
    session: zenoh.Session, keyexpr: str, emit: Callable[[str], None], count: int, seconds: float
) -> None:
    """Print what ``keyexpr`` hears, a line a message, until ``count`` lines (0: no limit),
    ``seconds`` s (0: no limit) or Ctrl-C."""
    inbox: queue.SimpleQueue[tuple[str, bytes]] = queue.SimpleQueue()
    shown = 0
    sub = session.declare_subscriber(
        keyexpr, lambda s: inbox.put((str(s.key_expr), s.payload.to_bytes()))
    )
    deadline = time.monotonic() + seconds if seconds > 0 else None
    try:
        while count <= 0 or shown < count:
            if deadline is not None and time.monotonic() >= deadline:
                break
            try:
                key, payload = inbox.get(timeout=0.1)
            except queue.Empty:
                continue
            for line in format_sample(key, payload):
                if count <= 0 or shown < count:
                    emit(line)
                    shown += 1
    except KeyboardInterrupt:
        pass
    finally:
        sub.undeclare()
