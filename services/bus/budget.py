"""Rate budgets: what a receiver takes from each key before it decodes anything.

A receiver gives every key (``ddvi/<run>/<topic>``, whose one publisher the topology and the
router's access control fix) a token bucket in messages, refilled as the receiver's
*simulated* time goes on at ``BUDGET_SLACK`` times the topic's rate in the topology
(``services.interface.topics.budget_period``), and holding at most ``BUDGET_BURST`` messages: the
start, the end and a receiver's clock a few steps behind its inputs fit in it.  Simulated time,
not wall time: in lock-step a mission flies as fast as the machine lets it, so a wall-clock rate
would be either too tight for a fast machine or too loose to stop a flood.  A message past its
key's budget is dropped and counted against the key's publisher (``flood.<publisher>``) without
being decoded, which is what keeps a flooded receiver on time and its memory bounded.
Buckets are kept for at most ``MAX_KEYS`` keys; keys past that share one bucket.
"""

from __future__ import annotations

import threading
from collections.abc import Callable

from services.interface import MAX_BATCH
from services.interface.topics import budget_period, publisher_of

BUDGET_SLACK = 4.0
"""How many times its topology rate a key may send, sustained."""
BUDGET_BURST = 512.0
"""Messages a key may send at once (its bucket's size)."""
MAX_KEYS = 512
"""Keys with their own bucket; any further key shares ``OTHER``'s."""
OTHER = "<other>"
"""The shared bucket's key, and the publisher its drops are counted against."""


def message_count(payload: bytes) -> int:
    """Messages in a payload, read from its first bytes only: a batch's (a msgpack array,
    ``services.interface.pack_batch``) length, else 1."""
    if not payload:
        return 1
    first = payload[0]
    if 0x90 <= first <= 0x9F:
        n = first & 0x0F
    elif first == 0xDC and len(payload) >= 3:
        n = int.from_bytes(payload[1:3], "big")
    elif first == 0xDD and len(payload) >= 5:
        n = int.from_bytes(payload[1:5], "big")
    else:
        return 1
    return min(max(n, 1), MAX_BATCH)  # a longer array is refused whole when unpacked


class RateBudget:
    """Token buckets by key, refilled by simulated time (``advance``); thread safe.

    ``periods`` maps a period name of the topology (``"nav"``, ``"fsw"``, ``"status"``) to
    simulated seconds; a topic outside the topology gets the shortest of them.  ``owner``
    names a topic's publisher, whom its drops are counted against: the topology's by default;
    a run's own (``Deployment.publisher_of``) knows who commands a deputy flown from ROS 2.
    """

    def __init__(
        self,
        prefix: str,
        periods: dict[str, float],
        slack: float = BUDGET_SLACK,
        burst: float = BUDGET_BURST,
        max_keys: int = MAX_KEYS,
        owner: Callable[[str], str | None] = publisher_of,
    ) -> None:
        if not periods or min(periods.values()) <= 0:
            raise ValueError(f"RateBudget.periods: expected positive periods, got {periods}")
        self.prefix = prefix
        self.periods, self.slack, self.burst, self.max_keys = dict(periods), slack, burst, max_keys
        self.sim_t = 0.0
        self.dropped: dict[str, int] = {}  # publisher -> messages dropped
        self._buckets: dict[str, list[float]] = {}  # key -> [tokens, rate, sim time of tokens]
        self._owner: dict[str, str] = {}  # key -> its publisher, for the counts
        self._owner_of = owner
        self._lock = threading.Lock()

    def advance(self, sim_t: float) -> None:
        """The receiver's simulated time is now ``sim_t`` s (it never goes back)."""
        if sim_t > self.sim_t:
            self.sim_t = sim_t

    def _bucket(self, key: str) -> tuple[str, list[float]]:
        bucket = self._buckets.get(key)
        if bucket is not None:
            return key, bucket
        if len(self._buckets) >= self.max_keys:
            key = OTHER
            bucket = self._buckets.get(key)
            if bucket is not None:
                return key, bucket
        topic = key[len(self.prefix) :] if key.startswith(self.prefix) else key
        period = self.periods.get(budget_period(topic) or "", min(self.periods.values()))
        bucket = self._buckets[key] = [self.burst, self.slack / period, self.sim_t]
        self._owner[key] = OTHER if key == OTHER else (self._owner_of(topic) or OTHER)
        return key, bucket

    def take(self, key: str, payload: bytes) -> bool:
        """Whether the messages of ``payload`` on ``key`` are within its budget (they are then
        taken from it); if not, they are counted as dropped against the key's publisher."""
        n = message_count(payload)
        with self._lock:
            key, bucket = self._bucket(key)
            tokens, rate, since = bucket
            now = self.sim_t
            if now > since:
                tokens = min(self.burst, tokens + rate * (now - since))
                bucket[2] = now
            if tokens >= n:
                bucket[0] = tokens - n
                return True
            bucket[0] = tokens
            owner = self._owner[key]
            self.dropped[owner] = self.dropped.get(owner, 0) + n
            return False

    def dropped_from(self, publisher: str) -> int:
        """Messages of ``publisher`` dropped so far: how far its sequence numbers may have run
        ahead of what the receiver saw."""
        return self.dropped.get(publisher, 0)

    def counters(self) -> dict[str, int]:
        """``flood.<publisher>``: the messages dropped from each publisher so far."""
        with self._lock:
            return {f"flood.{owner}": n for owner, n in self.dropped.items()}


def budget_for(
    prefix: str,
    nav_period: float,
    fsw_period: float,
    status_every: int,
    owner: Callable[[str], str | None] = publisher_of,
) -> RateBudget:
    """A run's budget: its periods from the deployment's (``Deployment.run``, and the shortest
    navigation period of its deputies as ``nav_period``), its topics' publishers ``owner``'s."""
    return RateBudget(
        prefix,
        {"nav": nav_period, "fsw": fsw_period, "status": fsw_period * max(status_every, 1)},
        owner=owner,
    )


Dropped = Callable[[str], None]
"""Told the topic of messages a budget dropped (a lock-step loop counts them as lost)."""
