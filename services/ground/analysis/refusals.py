"""What the ground refuses to believe: a message whose publisher does not own its topic, or
whose body names another deputy or service than its topic does (``services.bus.check_origin``).

The monitor and ``ddvi report`` record such a message but build nothing of the report from
it: a service's counters come only from that service, a deputy's gains only from its
controller.  ``Refusals`` counts them by (publisher, topic, reason) for the report, which says
what was refused and from whom.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Any

from services.bus.guards import check_origin
from services.interface import Message
from services.interface.topics import identity_mismatch, may_publish

log = logging.getLogger("ddvi.monitor")

MAX_KINDS = 64
"""(publisher, topic, reason) kinds listed one by one; more are counted together (memory stays
bounded whatever names a flood invents)."""
MAX_NAME = 80  # characters of a publisher's or a topic's name kept for the report
OTHERS = "(others)"


@dataclass
class Refused:
    """One kind of refused message: how many, when first, and what its body claimed."""

    src: str
    topic: str
    reason: str
    count: int
    first_t: float
    claimed: str


class Refusals:
    """The ground's origin check and its tally (see the module's docstring)."""

    def __init__(self) -> None:
        self.kinds: dict[tuple[str, str, str], Refused] = {}

    def accepts(self, topic: str, msg: Message) -> bool:
        """Whether the report may use ``msg`` (on ``topic``); a refused one is counted."""
        owner = may_publish(msg.src, topic)
        if owner is None:
            why = "topic"
        elif (why := check_origin(msg, topic)) is None:
            return True
        claimed = ""
        if why == "identity":
            field = identity_mismatch(topic, msg.body) or ""
            claimed = f"{field} = {str(msg.body.get(field))[:MAX_NAME]!r}"
        self._count(msg.src[:MAX_NAME], topic[:MAX_NAME], why, msg.t, claimed)
        return False

    def _count(self, src: str, topic: str, reason: str, t: float, claimed: str) -> None:
        key = (src, topic, reason)
        kind = self.kinds.get(key)
        if kind is None and len(self.kinds) >= MAX_KINDS:
            key = (OTHERS, OTHERS, reason)
            kind = self.kinds.get(key)
        if kind is None:
            kind = self.kinds[key] = Refused(*key, 0, t, claimed)
        kind.count += 1
        if kind.count <= 10 or kind.count % 1000 == 0:
            log.warning("refused %s from %r (%s, #%d)", topic, src, reason, kind.count)

    @property
    def total(self) -> int:
        return sum(k.count for k in self.kinds.values())

    def summary(self) -> list[dict[str, Any]]:
        """Every kind, most frequent first, as summary.json holds them."""
        kinds = sorted(self.kinds.values(), key=lambda k: (-k.count, k.topic, k.src))
        return [vars(k).copy() for k in kinds]
