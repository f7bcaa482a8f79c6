"""``ddvi monitor [KEYEXPR]``: a tap on the bus that prints every message, one line each.

    ddvi monitor 'ddvi/<run>/**' [--hub H] [--count N] [--seconds S]

A sample that holds a batch prints one line per message; one that does not decode prints why
it is rejected.  The tap is a plain zenoh subscriber: it records nothing and keeps no state.
"""

from __future__ import annotations

import argparse
import json
import queue
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from services.bus import DEFAULT_HUB, EPHEMERAL_LOOPBACK, BusSettings, open_session
from services.interface import MessageError, decode, unpack_batch


def add_monitor_arguments(p: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """The arguments of ``ddvi monitor``, for ``services.cli``."""
    p.add_argument("keyexpr", nargs="?", default="ddvi/**", help="zenoh key expression")
    p.add_argument("--hub", default=DEFAULT_HUB, help="zenoh endpoint to connect to")
    p.add_argument("--count", type=int, default=0, help="stop after N messages (0: no limit)")
    p.add_argument("--seconds", type=float, default=0.0, help="stop after S s (0: no limit)")
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


def monitor_command(args: argparse.Namespace, out: Callable[[str], None] | None = None) -> int:
    """``ddvi monitor [KEYEXPR] [--hub H] [--count N] [--seconds S]``: print each message on
    the bus as one line until Ctrl-C, N messages or S seconds. Returns 0."""
    emit = out or (lambda line: print(line, flush=True))
    settings = BusSettings(mode="peer", listen=[EPHEMERAL_LOOPBACK], connect=[args.hub])
    inbox: queue.SimpleQueue[tuple[str, bytes]] = queue.SimpleQueue()
    count, seconds = int(args.count or 0), float(args.seconds or 0.0)
    shown = 0
    with open_session(settings) as session:
        sub = session.declare_subscriber(
            args.keyexpr, lambda s: inbox.put((str(s.key_expr), s.payload.to_bytes()))
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
    return 0
