"""The live view's messages handed to the SDK's server in bursts, from a thread of their own.

Each ``Channel.log`` wakes the server's worker when it sleeps.  Woken once a message, at the
pace a mission flies (thousands of messages a wall second), the worker costs about twice the
CPU it costs woken once a burst (``benchmarks.live_floor``).  So the live view's messages are
queued as they come (the monitor's loop pays one append) and handed over together every
``HANDOFF_S`` s, in the order they came, with the server's newest clock after them: a delay
no one watching sees.
"""

from __future__ import annotations

import logging
import threading
from collections import deque
from collections.abc import Callable
from typing import Any

from services.bus import worth_saying

log = logging.getLogger("ddvi.live")

HANDOFF_S = 0.05
"""Wall seconds between two handovers: the most a message waits in the queue."""


class Handoff:
    """A queue of (channel, bytes, log time ns) handed to the server every ``HANDOFF_S`` s.

    Parameters
    ----------
    broadcast_time : how the server's clock is moved (``WebSocketServer.broadcast_time``), with
        the newest time given to ``time`` since the last handover.
    """

    def __init__(self, broadcast_time: Callable[[int], None]) -> None:
        self._broadcast_time = broadcast_time
        self._queue: deque[tuple[Any, bytes, int]] = deque()  # appends and pops: thread-safe
        self._time = -1  # the newest clock (ns), and the one the server was last given
        self._told = -1
        self._closed = threading.Event()
        self.errors = 0
        self._thread = threading.Thread(target=self._run, name="live-handoff", daemon=True)
        self._thread.start()

    def put(self, channel: Any, data: bytes, log_ns: int) -> None:
        """Queue ``data`` for ``channel`` (a ``foxglove.Channel``) at ``log_ns``."""
        self._queue.append((channel, data, log_ns))

    def time(self, log_ns: int) -> None:
        """The server's clock, moved to ``log_ns`` at the next handover."""
        self._time = log_ns

    def _run(self) -> None:
        while not self._closed.wait(HANDOFF_S):
            self._hand_over()

    def _hand_over(self) -> None:
        """Every queued message to the server, oldest first, then the clock (this thread only,
        or the closing one once this has ended: one consumer keeps each channel's order)."""
        queue = self._queue
        while queue:
            channel, data, log_ns = queue.popleft()
            try:
                channel.log(data, log_time=log_ns)
            except Exception:  # one message lost must not lose the rest
                self._failed(channel.topic)
        if self._time != self._told:
            self._told = self._time
            try:
                self._broadcast_time(self._told)
            except Exception:
                self._failed("the clock")

    def _failed(self, what: str) -> None:
        self.errors += 1
        if worth_saying(self.errors):
            log.exception("live view: could not hand over %s (#%d)", what, self.errors)

    def close(self) -> None:
        """Hand over what is queued and stop; idempotent."""
        self._closed.set()
        self._thread.join(timeout=5.0)
        if not self._thread.is_alive():
            self._hand_over()
