"""State for a client that joins late: the live view's last message of each state-like channel
(``LATCHED``: liveliness, status, gains and K*, stats, the deployment, the scene), sent again
when a client subscribes to it (``services.ground.monitoring.live``).

The server tells of a subscription (its ``on_subscribe``) before it routes the channel's
messages to that client, so the message is sent ``LATCH_DELAY`` s later, from a thread of its
own: the monitor's loop never waits for it.  The SDK sends a channel's message to every client
subscribed to it, so one that was there already gets the same state again, with its own time.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable

log = logging.getLogger("ddvi.live")

LATCHED = frozenset({"alive", "status", "gains", "stats", "live_gains", "deployment", "scene"})
"""The kinds of channel whose last message a late client is sent (``schema_kind``)."""
LATCH_DELAY = 0.25
"""Wall seconds between a subscription and its latched message: the server has routed the
channel to the client long before (it does so right after telling)."""

Payload = bytes | Callable[[], bytes]
"""A message's bytes, or how to make them when it is sent (the live gains take the K* known
then; a message nobody subscribes to is never encoded)."""


def payload_bytes(payload: Payload) -> bytes:
    """``payload``'s bytes, made now if they are made on demand."""
    return payload if isinstance(payload, bytes) else payload()


def schema_kind(schema_name: str) -> str:
    """A channel's kind, from its schema name: ``ddvi.status`` -> ``status``; Foxglove's own
    (``foxglove.SceneUpdate``, ``foxglove.FrameTransforms``) -> ``scene``."""
    family, _, kind = schema_name.partition(".")
    return "scene" if family == "foxglove" else kind


class Latch:
    """The last message of each latched channel, and the subscriptions it is owed to.

    Parameters
    ----------
    send : how a latched message goes out: ``send(topic, payload bytes, log_time ns)``.
    """

    def __init__(self, send: Callable[[str, bytes, int], None]) -> None:
        self._send = send
        self._last: dict[str, tuple[Payload, int]] = {}  # topic -> (its bytes, its time ns)
        self._due: dict[str, float] = {}  # topic -> when its message is owed (monotonic s)
        self._lock = threading.Lock()
        self._wake = threading.Event()
        self._closed = False
        self.sent = 0
        self._thread = threading.Thread(target=self._run, name="live-latch", daemon=True)
        self._thread.start()

    def keep(self, topic: str, payload: Payload, log_ns: int) -> None:
        """``topic``'s newest message (a dict assignment: the monitor's loop pays no more)."""
        self._last[topic] = (payload, log_ns)

    def subscribed(self, topic: str) -> None:
        """A client subscribed to ``topic`` (called on the server's thread): its last message
        is owed in ``LATCH_DELAY`` s."""
        with self._lock:
            self._due.setdefault(topic, time.monotonic() + LATCH_DELAY)
        self._wake.set()

    def _run(self) -> None:
        while not self._closed:
            with self._lock:
                now = time.monotonic()
                ready = [t for t, at in self._due.items() if at <= now]
                for topic in ready:
                    del self._due[topic]
                later = min(self._due.values(), default=None)
            for topic in ready:
                self._resend(topic)
            self._wake.wait(None if later is None else max(later - time.monotonic(), 0.0))
            self._wake.clear()

    def _resend(self, topic: str) -> None:
        kept = self._last.get(topic)
        if kept is None:
            return  # nothing said on it yet: its first message will come as any other
        payload, log_ns = kept
        try:
            self._send(topic, payload_bytes(payload), log_ns)
            self.sent += 1
        except Exception:  # a latched message lost must not end the thread
            log.exception("live view: could not send %s's last message again", topic)

    def close(self) -> None:
        self._closed = True
        self._wake.set()
        self._thread.join(timeout=2.0)
