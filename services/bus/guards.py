"""Receiver guards: the anti-replay window a subscriber keeps per (publisher, topic), so each
message is delivered once whatever the link or an attacker repeats; and the origin check
(``check_origin``), so that a message is taken only from its topic's owner, only when its body
names what its topic names, and only for a time inside the mission's window."""

from __future__ import annotations

import math

from services.interface import Message
from services.interface.topics import identity_mismatch, may_publish

REPLAY_WINDOW = 256
"""Sequence numbers a subscriber remembers per (publisher, topic) to reject duplicates."""
SEQUENCE_REASONS = ("duplicate", "stale")
"""Why a well-formed message is refused by its sequence number (see ``SequenceGuard``)."""
ORIGIN_REASONS = ("src", "identity", "time")
"""Why a well-formed message is refused by its origin (see ``check_origin``)."""
TIME_FIELDS = ("for_t",)
"""Body fields that are simulation times, checked against the time window as ``t`` is."""


def check_origin(
    message: Message, topic: str, window: tuple[float, float] | None = None
) -> str | None:
    """None (accept) or why ``message`` on ``topic`` is refused: ``"src"`` when its header
    ``src`` is not the topic's publisher per the topology (``may_publish``; a topic outside the
    topology has no owner to check), ``"identity"`` when an identity field of its body (a
    command's ``sc``, a stats message's ``service``) is not what its topic names
    (``topics.identity_mismatch``): a publisher speaks only for what its topic owns; ``"time"``
    when its ``t`` or a body time (``TIME_FIELDS``, e.g. a command's ``for_t``) lies outside
    ``window = (earliest, latest)`` s: a message "for" a time the mission never reaches must
    not make the genuine traffic look stale."""
    if may_publish(message.src, topic) is False:
        return "src"
    if identity_mismatch(topic, message.body) is not None:
        return "identity"
    if window is not None:
        lo, hi = window
        if not lo <= message.t <= hi:
            return "time"
        for key in TIME_FIELDS:
            value = message.body.get(key)
            if value is not None and not lo <= value <= hi:
                return "time"
    return None


class SequenceGuard:
    """Anti-replay window of one subscriber for one (publisher, topic): like a CCSDS or IPsec
    receiver, it accepts each sequence number once, in any order within ``window`` of the
    highest seen.  ``check(seq, t)`` returns None (accept) or why not: ``"duplicate"`` (seen
    already: a replay, or a copy the link duplicated), ``"stale"`` (older than the window: a
    replay of old traffic).  A publisher's time never goes back as its seq goes up, so a seq
    at or below the highest with a time after the newest is a restarted publisher counting
    from 0 again: the window starts over."""

    def __init__(self, window: int = REPLAY_WINDOW) -> None:
        if window < 1:
            raise ValueError(f"SequenceGuard.window: expected >= 1, got {window}")
        self.window = window
        self.highest = -1
        self.newest_t = -math.inf
        self._seen = 0  # bit k: highest - k was accepted (k < window), as RFC 4303's bitmap
        self._mask = (1 << window) - 1

    def check(self, seq: int, t: float) -> str | None:
        highest = self.highest
        if seq <= highest and t > self.newest_t:
            highest = self.highest = -1  # the publisher restarted
            self._seen = 0
        elif seq <= highest - self.window:
            return "stale"
        if seq > highest:
            ahead = seq - highest
            self._seen = ((self._seen << ahead) | 1) & self._mask if ahead < self.window else 1
            self.highest = seq
        else:
            bit = 1 << (highest - seq)
            if self._seen & bit:
                return "duplicate"
            self._seen |= bit
        if t > self.newest_t:
            self.newest_t = t
        return None


class SequenceGuards:
    """One ``SequenceGuard`` per (publisher, topic), made on first use."""

    def __init__(self) -> None:
        self._guards: dict[tuple[str, str], SequenceGuard] = {}

    def check(self, message: Message, topic: str) -> str | None:
        """``SequenceGuard.check`` of the message's publisher on ``topic``."""
        guard = self._guards.get((message.src, topic))
        if guard is None:
            guard = self._guards[(message.src, topic)] = SequenceGuard()
        return guard.check(message.seq, message.t)
