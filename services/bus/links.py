"""Link model: delay, jitter, loss, duplication and reordering of one publisher->subscriber link.

Pure logic, no I/O and no zenoh: the bus feeds received items in and delivers what comes out.
Fully deterministic for a given seed and sequence of calls.

Inputs/outputs:
    LinkSpec, LinkRule               a link's parameters and where they apply, as a deployment
                                     declares them (``services.interface.links``)
    LinkModel(spec, seed, clock)
        offer(item, now) -> list     admit one item, return everything deliverable at ``now``
        release(now) -> list         return held items due at ``now``, in due order
    link_seed(...)                   the seed of one subscription's link from one publisher
        counters -> dict             dropped, duplicated, reordered, delayed

Semantics, per offered item (random draws in this fixed order):
    1. lost with probability ``loss`` (counted ``dropped``; nothing else happens);
    2. one extra copy with probability ``duplicate`` (counted ``duplicated``);
    3. with probability ``reorder`` the item swaps places with the next item offered on the link
       (pairwise: that successor does not swap again): it is held until the successor is due and
       delivered right after it (counted ``reordered`` when the pair forms; until a successor
       arrives it stays held);
    4. each copy gets latency ``delay + U(0, jitter)``; a copy with positive latency is held
       until ``sent + latency`` (``sent`` defaults to ``now``; counted ``delayed``).
Items due at the same time come out in the order they were offered (swaps aside).

``clock`` says which time ``now`` is: ``"sim"``, simulation time as the receiver knows it
(lock-step runs), or ``"wall"``, ``time.monotonic()`` (real-time runs). The model only compares
the numbers it is given. Not thread safe: the caller serialises calls.
"""

from __future__ import annotations

import heapq
import random
import zlib
from typing import Any

from services.interface.links import LinkSpec

CLOCKS = ("sim", "wall")


def link_seed(seed: int, subscriber: str, subscription: str, rule: int, publisher: str) -> int:
    """The seed of the link model one subscriber's ``subscription`` (its topic pattern) gives
    the messages of ``publisher`` under link rule number ``rule``: one stream per (subscriber,
    subscription, rule, publisher), so that what one publisher's messages suffer does not
    depend on how they interleave with another's, and a one-process executor can draw what
    the services draw."""
    return zlib.crc32(f"{seed}/{subscriber}/{subscription}/{rule}/{publisher}".encode())


class LinkModel:
    """Applies a LinkSpec to a stream of items; see the module docstring for the semantics."""

    def __init__(self, spec: LinkSpec, seed: int, clock: str = "sim") -> None:
        if clock not in CLOCKS:
            raise ValueError(f"LinkModel.clock: expected one of {CLOCKS}, got {clock!r}")
        self.spec = spec
        self.clock = clock
        self._rng = random.Random(seed)
        self._held: list[tuple[float, float, int, Any]] = []  # heap of (due, rank, tiebreak, item)
        self._waiting: tuple[float, Any] | None = None  # (due, item) waiting for its successor
        self._rank = 0
        self._tiebreak = 0
        self._counters = {"dropped": 0, "duplicated": 0, "reordered": 0, "delayed": 0}
        self._perfect = spec == LinkSpec()

    @property
    def counters(self) -> dict[str, int]:
        """Snapshot of dropped, duplicated, reordered, delayed."""
        return dict(self._counters)

    @property
    def held(self) -> int:
        """Number of items currently held (delayed or waiting for a swap)."""
        return len(self._held) + (self._waiting is not None)

    @property
    def transparent(self) -> bool:
        """A perfect link holding nothing: ``offer`` would hand the item straight back."""
        return self._perfect and not self._held and self._waiting is None

    def _push(self, due: float, rank: float, item: Any) -> None:
        self._tiebreak += 1
        heapq.heappush(self._held, (due, rank, self._tiebreak, item))

    def offer(self, item: Any, now: float, sent: float | None = None) -> list[Any]:
        """Admit ``item`` at time ``now``; return every item deliverable at ``now``.

        ``sent``: when the item left its publisher, if not ``now`` (a lock-step receiver's clock
        need not be the sender's: the latency then runs from the message's own time)."""
        if self.transparent:
            return [item]  # no draw can change anything
        spec, rng = self.spec, self._rng
        if rng.random() < spec.loss:
            self._counters["dropped"] += 1
            return self.release(now)
        copies = 1
        if rng.random() < spec.duplicate:
            copies = 2
            self._counters["duplicated"] += 1
        swap = rng.random() < spec.reorder
        dues = []
        for _ in range(copies):
            latency = spec.delay + (rng.uniform(0.0, spec.jitter) if spec.jitter > 0 else 0.0)
            if latency > 0:
                self._counters["delayed"] += 1
            dues.append((now if sent is None else sent) + latency)
        self._rank += 1
        rank = float(self._rank)
        if self._waiting is not None:
            # This item completes a swap: the waiting item follows it; it cannot swap again.
            due, waiting = self._waiting
            self._waiting = None
            self._counters["reordered"] += 1
            self._push(dues[0], rank, item)
            self._push(max(due, dues[0]), rank + 0.5, waiting)
        elif swap:
            self._waiting = (dues[0], item)
        else:
            self._push(dues[0], rank, item)
        if copies == 2:
            self._push(dues[1], rank, item)
        return self.release(now)

    def release(self, now: float) -> list[Any]:
        """Return the held items due at or before ``now``, in due order."""
        out = []
        while self._held and self._held[0][0] <= now:
            out.append(heapq.heappop(self._held)[3])
        return out
