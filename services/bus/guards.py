"""Receiver guards: the anti-replay window a subscriber keeps per (publisher, topic, boot), so
each message is delivered once whatever the link or an attacker repeats, and no one message can
move the window past the genuine traffic; and the origin check
(``check_origin``), so that a message is taken only from its topic's owner, only when its body
names what its topic names, and only for a time inside the mission's window."""

from __future__ import annotations

from collections.abc import Callable

from services.interface import Message
from services.interface.topics import identity_mismatch, may_publish

REPLAY_WINDOW = 256
"""Sequence numbers a subscriber remembers per (publisher, topic) to reject duplicates."""
SEQUENCE_REASONS = ("duplicate", "stale", "jump")
"""Why a well-formed message is refused by its sequence number (see ``SequenceGuard``)."""
JUMP_CONFIRM = 3
"""Consecutive sequence numbers past a window's reach that move the window there: a publisher
whose messages a receiver really missed goes on counting from where it is, one message that
claims a far sequence number does not."""
BOOTS_KEPT = 16
"""Boots a receiver keeps a window for per (publisher, topic), the least recently heard out."""
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
    """Anti-replay window of one subscriber for one (publisher, topic, boot): like a CCSDS or
    IPsec receiver, it accepts each sequence number once, in any order within ``window`` of the
    highest seen.  ``check(seq)`` returns None (accept) or why not: ``"duplicate"`` (seen
    already: a replay, or a copy the link duplicated), ``"stale"`` (older than the window: a
    replay of old traffic), ``"jump"`` (more than ``ahead + slack`` past the highest: a number
    no publisher of this boot has reached; it never becomes the new mark, so one message
    cannot make the genuine traffic look stale).  ``slack`` is what the receiver knows it
    missed from the publisher (its rate budget's drops); ``JUMP_CONFIRM`` consecutive numbers
    past the reach move the window there.  ``ahead=None`` takes any step ahead (behind a link
    model, whose losses are the receiver's own)."""

    def __init__(self, window: int = REPLAY_WINDOW, ahead: int | None = REPLAY_WINDOW) -> None:
        if window < 1:
            raise ValueError(f"SequenceGuard.window: expected >= 1, got {window}")
        if ahead is not None and ahead < 1:
            raise ValueError(f"SequenceGuard.ahead: expected >= 1 or None, got {ahead}")
        self.window, self.ahead = window, ahead
        self.highest = -1
        self._seen = 0  # bit k: highest - k was accepted (k < window), as RFC 4303's bitmap
        self._mask = (1 << window) - 1
        self._beyond: tuple[int, int] | None = None  # (last, how many) consecutive jumps

    def past_reach(self, seq: int, slack: int = 0) -> bool:
        """Whether ``seq`` lies more than ``ahead + slack`` past the highest number seen."""
        ahead = self.ahead
        return ahead is not None and self.highest >= 0 and seq - self.highest > ahead + slack

    def check(self, seq: int, slack: int = 0) -> str | None:
        highest = self.highest
        if self.past_reach(seq, slack):
            if not self._confirmed(seq):
                return "jump"
            highest = self.highest = seq - 1  # the publisher is there: the window follows
            self._seen = 0
        self._beyond = None  # any number within reach, a stale one too, ends a run of jumps
        if seq <= highest - self.window:
            return "stale"
        if seq > highest:
            ahead = seq - highest
            self._seen = ((self._seen << ahead) | 1) & self._mask if ahead < self.window else 1
            self.highest = seq
            return None
        bit = 1 << (highest - seq)
        if self._seen & bit:
            return "duplicate"
        self._seen |= bit
        return None

    def _confirmed(self, seq: int) -> bool:
        """Whether ``seq``, past the window's reach, ends ``JUMP_CONFIRM`` consecutive ones."""
        last, run = self._beyond or (seq - 1, 0)
        run = run + 1 if seq == last + 1 else 1
        self._beyond = (seq, run)
        return run >= JUMP_CONFIRM


class SequenceGuards:
    """The ``SequenceGuard`` of each (publisher, topic, boot), made on first use; at most
    ``BOOTS_KEPT`` boots per (publisher, topic), the least recently heard forgotten first.  A
    restarted publisher counts from 0 again under a new boot: it gets a window of its own, and
    a message that claims a new boot cannot touch the window of the one in flight."""

    def __init__(self, ahead: int | None = REPLAY_WINDOW) -> None:
        self.ahead = ahead
        self._boots: dict[tuple[str, str], dict[int, SequenceGuard]] = {}

    def check(
        self, message: Message, topic: str, missed: Callable[[str], int] | None = None
    ) -> str | None:
        """``SequenceGuard.check`` of the message's publisher, topic and boot; ``missed``: what
        the receiver knows it missed from a publisher (its slack), asked only of a number past
        the window's reach."""
        boots = self._boots.get((message.src, topic))
        if boots is None:
            boots = self._boots[(message.src, topic)] = {}
        boot = message.boot
        guard = boots.get(boot)
        if guard is None:
            guard = boots[boot] = SequenceGuard(ahead=self.ahead)
            if len(boots) > BOOTS_KEPT:
                del boots[next(iter(boots))]
        elif len(boots) > 1:  # the most recently heard is last
            boots[boot] = boots.pop(boot)
        seq = message.seq
        if missed is not None and guard.past_reach(seq):
            return guard.check(seq, missed(message.src))
        return guard.check(seq)
