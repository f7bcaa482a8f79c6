"""The monitor's intake: the raw subscriber of every topic of a run and the subscriber of its
liveliness tokens, queueing what they receive, stamped with its receive time, for the
monitor's main loop (``services.ground.monitoring.monitor``).  A sample past its key's rate
budget (``services.bus.budget``) is dropped in the callback, unread and unqueued: a flood
neither grows the queue nor delays the recording."""

from __future__ import annotations

import logging
import queue
import time
from typing import Any

import zenoh

from services.bus import RateBudget
from services.ground.analysis.outcome import TIME_MASTER
from services.interface import MessageError, decode, topics, unpack_batch

log = logging.getLogger("ddvi.monitor")

DATA, ALIVE = 0, 1
Item = tuple[int, str, Any, int]
"""A queued sample: (DATA or ALIVE, key, payload bytes or alive flag, receive time ns)."""
Inbox = queue.SimpleQueue[Item]


def _advance(budget: RateBudget, payload: bytes) -> None:
    """The budget's simulated time from a clock payload (the time master's only)."""
    try:
        for part in unpack_batch(payload) or (payload,):
            msg = decode(part, "clock")
            if msg.src == TIME_MASTER:
                budget.advance(msg.t)
    except MessageError:
        pass  # recorded and refused by the main loop


def subscribe(
    session: zenoh.Session, run: str, inbox: Inbox, budget: RateBudget | None = None
) -> tuple[Any, Any]:
    """The raw data subscriber and the liveliness subscriber, feeding ``inbox``; with a
    ``budget``, a sample past its key's is dropped here, unread and unqueued (counted in the
    budget): a flood neither grows the queue nor delays the recording."""
    clock_key = f"ddvi/{run}/{topics.CLOCK}"

    def on_data(sample: zenoh.Sample) -> None:
        try:
            key, payload = str(sample.key_expr), sample.payload.to_bytes()
            if budget is not None:
                if key == clock_key:
                    _advance(budget, payload)
                if not budget.take(key, payload):
                    return
            inbox.put((DATA, key, payload, time.time_ns()))
        except Exception:  # a zenoh callback must never raise
            log.exception("monitor: could not queue a sample")

    def on_alive(sample: zenoh.Sample) -> None:
        try:
            up = sample.kind == zenoh.SampleKind.PUT
            inbox.put((ALIVE, str(sample.key_expr), up, time.time_ns()))
        except Exception:
            log.exception("monitor: could not queue a liveliness change")

    prefix = f"ddvi/{run}/"
    data_sub = session.declare_subscriber(prefix + "**", on_data)
    alive_sub = session.liveliness().declare_subscriber(
        prefix + topics.alive_topic("*"), on_alive, history=True
    )
    return data_sub, alive_sub
