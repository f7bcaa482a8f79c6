"""What a ``Bus`` does with what it hears (``services.bus.endpoint``): each subscription is a
``Route`` that decodes and validates a sample's messages, refuses a forged origin, a replay or a
duplicate, passes each through its link model and hands what the link lets through to the
subscription's handler; ``Reception`` is what a bus's routes share (its link rules, its clock,
its rate budget, its counters).

Threading: zenoh calls ``Route.on_sample`` on its own threads; a route's lock serialises its
link models and windows, the counters have their own lock, and nothing raised reaches zenoh.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable, Collection, Iterable
from dataclasses import dataclass, field
from typing import Any

import zenoh

from services.bus.budget import Dropped, RateBudget
from services.bus.guards import ORIGIN_REASONS, SEQUENCE_REASONS, SequenceGuards, check_origin
from services.bus.links import LinkModel, link_seed
from services.interface import REASONS, Message, MessageError, decode, unpack_batch
from services.interface.links import LinkRule, select_rule
from services.interface.topics import CLOCK

log = logging.getLogger("ddvi.bus")

Handler = Callable[[str, Message], None]
"""A subscription handler: ``handler(topic, message)``, topic relative to ``ddvi/<run>/``."""

_ORIGIN_TEXT = {
    "src": "not this topic's publisher",
    "identity": "its body names another than its topic does",
    "time": "a time outside the mission's window",
}
_SEQUENCE_TEXT = {
    "duplicate": "seen already",
    "stale": "older than its window",
    "jump": "past any number its publisher has reached",
}


class Reception:
    """What a bus's subscriptions share: the service's name and key prefix, the deployment's
    link rules (first match wins; ``rule_of`` caches the match), the link models' clock and
    seed, the origin check's time window, the rate budget, the receiver's simulation time (as
    last given to ``Bus.pump``) and the counters of what was received."""

    def __init__(
        self,
        service: str,
        prefix: str,
        rules: Iterable[LinkRule],
        link_clock: str,
        seed: int,
        time_window: tuple[float, float] | None,
        budget: RateBudget | None,
    ) -> None:
        self.service, self.prefix = service, prefix
        self.rules = list(rules)
        self.rule_cache: dict[tuple[str, str], int | None] = {}
        self.link_clock, self.seed = link_clock, seed
        self.time_window, self.budget = time_window, budget
        self.sim_time = 0.0
        self.count_lock = threading.Lock()  # counters only; never held while calling out
        self.counts: dict[str, int] = dict.fromkeys(
            ["sent", "received", "delivered", "rejected", "handler_errors"], 0
        )
        self.counts.update({f"rejected.{r}": 0 for r in sorted(REASONS)})
        self.counts.update({f"rejected.{r}": 0 for r in SEQUENCE_REASONS})
        self.counts.update({f"rejected.{r}": 0 for r in ORIGIN_REASONS})

    def count(self, key: str, n: int = 1) -> int:
        with self.count_lock:
            self.counts[key] += n
            return self.counts[key]

    def reject(self, key: str, reason: str, text: str) -> None:
        """Count a refused message by reason; log the first ten of each and every 1000th."""
        with self.count_lock:
            self.counts["rejected"] += 1
            self.counts[f"rejected.{reason}"] += 1
            n = self.counts[f"rejected.{reason}"]
        if worth_saying(n):
            log.warning("%s: rejected %s (%s, #%d): %s", self.service, key, reason, n, text)

    def now(self, link: LinkModel) -> float:
        return time.monotonic() if link.clock == "wall" else self.sim_time

    def rule_of(self, publisher: str, topic: str) -> int | None:
        """The index of the first link rule matching ``publisher`` and ``topic``, or None."""
        key = (publisher, topic)
        if key not in self.rule_cache:
            self.rule_cache[key] = select_rule(self.rules, publisher, topic)
        return self.rule_cache[key]


def worth_saying(n: int) -> bool:
    """Whether the ``n``-th of a kind of refusal or error is logged: the first ten, then every
    1000th (a flood must not flood the log)."""
    return n <= 10 or n % 1000 == 0


@dataclass
class Route:
    """One subscription: its handler, schema filter, its link models (an explicit one for every
    message, or one per matching deployment rule, made on first use) and an observer."""

    reception: Reception
    handler: Handler
    expected: str | Collection[str] | None
    link: LinkModel | None
    observe: Handler | None = None
    pattern: str = ""  # the subscription's topic pattern (seeds its link models)
    models: dict[tuple[int, str], LinkModel] = field(default_factory=dict)
    # what the link lets through, each once: its own losses may skip any number ahead
    guards: SequenceGuards = field(default_factory=lambda: SequenceGuards(ahead=None))
    # the window on what comes off the wire, before the link: a replay, or a number past what
    # its publisher has reached, never reaches the handler (the observer still accounts for it)
    wire: SequenceGuards = field(default_factory=SequenceGuards)
    # re-entrant: a handler may change the bus's link rules (a run-time link fault)
    lock: threading.RLock = field(default_factory=threading.RLock)
    subscriber: Any = None
    key: str | None = None  # the one key a subscription without wildcards hears
    lost: Dropped | None = None  # told of a key's messages its rate budget dropped
    lost_told: dict[str, float] = field(default_factory=dict)  # key -> sim time last told

    def all_models(self) -> list[LinkModel]:
        return ([self.link] if self.link is not None else []) + list(self.models.values())

    def model(self, publisher: str, topic: str) -> LinkModel | None:
        """The link model a message from ``publisher`` on ``topic`` goes through (caller holds
        the lock)."""
        if self.link is not None:
            return self.link
        rx = self.reception
        if not rx.rules:
            return None
        i = rx.rule_of(publisher, topic)
        if i is None:
            return None
        model = self.models.get((i, publisher))
        if model is None:
            seed = link_seed(rx.seed, rx.service, self.pattern, i, publisher)
            model = LinkModel(rx.rules[i].spec, seed, rx.link_clock)
            self.models[(i, publisher)] = model
        return model

    def on_sample(self, sample: zenoh.Sample) -> None:
        """Zenoh callback: must never raise.  A batch is taken apart: each of its messages is
        decoded, offered to its link and delivered as if it had come alone, in its order."""
        rx = self.reception
        try:
            key = self.key or str(sample.key_expr)  # a string per sample costs
            payload = sample.payload.to_bytes()
            if rx.budget is not None and not rx.budget.take(key, payload):
                self.tell_lost(key)
                return
            try:
                parts = unpack_batch(payload)  # also refuses an oversized payload
            except MessageError as err:
                rx.reject(key, err.reason, str(err))
                return
            self.on_messages(key, parts or (payload,))
        except Exception:
            rx.count("handler_errors")
            log.exception("%s: error in bus callback", rx.service)

    def tell_lost(self, key: str) -> None:
        """Tell ``lost`` of a budget's drop on ``key``, once a receiver's step."""
        rx = self.reception
        if self.lost is None or self.lost_told.get(key, -math.inf) >= rx.sim_time:
            return
        if len(self.lost_told) < 1024 or key in self.lost_told:  # bounded, as the budget
            self.lost_told[key] = rx.sim_time
        topic = key[len(rx.prefix) :] if key.startswith(rx.prefix) else key
        try:
            self.lost(topic)
        except Exception:
            rx.count("handler_errors")
            log.exception("%s: lost-message handler failed on %s", rx.service, topic)

    def on_messages(self, key: str, payloads: Iterable[bytes]) -> None:
        """Messages off the wire, one sample's: decode, link, deliver, observe (see
        ``Bus.subscribe``); the lock and the counters are taken once for them all."""
        rx = self.reception
        topic = key[len(rx.prefix) :] if key.startswith(rx.prefix) else key
        messages = []
        for payload in payloads:  # one bad part costs that part only
            try:
                message = decode(payload, self.expected)
            except MessageError as err:
                rx.reject(key, err.reason, str(err))
                continue
            except Exception:
                rx.count("handler_errors")
                log.exception("%s: error decoding on %s", rx.service, topic)
                continue
            if (why := check_origin(message, topic, rx.time_window)) is not None:
                rx.reject(
                    key,
                    why,
                    f"seq {message.seq} from {message.src!r} at t = "
                    f"{message.t:g}: " + _ORIGIN_TEXT[why],
                )
                continue
            messages.append(message)
            if rx.budget is not None and topic == CLOCK:  # the time master's, checked above
                rx.budget.advance(message.t)
        if not messages:
            return
        fresh: list[Message] = []  # what passes the wire's replay window: all that is handled
        try:
            missed = rx.budget.dropped_from if rx.budget is not None else None
            with self.lock:
                for message in messages:
                    if (why := self.wire.check(message, topic, missed)) is None:
                        fresh.append(message)
                    else:
                        rx.reject(
                            key,
                            why,
                            f"seq {message.seq} from {message.src} at t = "
                            f"{message.t:g}: " + _SEQUENCE_TEXT[why],
                        )
                items: list[tuple[str, Message]] = []
                direct = self.link is None and not rx.rules  # no link to choose per message
                for message in fresh:
                    try:
                        model = None if direct else self.model(message.src, topic)
                        if model is None or model.transparent:
                            items.append((topic, message))
                        else:
                            items += model.offer(
                                (topic, message),
                                rx.now(model),
                                sent=message.t if model.clock == "sim" else None,
                            )
                    except Exception:
                        rx.count("handler_errors")
                        log.exception("%s: error in bus callback", rx.service)
                # delivered under the lock (handlers only queue), so that what one thread's
                # offer releases is queued before another thread's pump returns
                self.deliver(items, received=len(fresh))
        finally:  # whatever happened above, each message from its publisher is accounted for
            if self.observe is not None:
                for message in messages:
                    try:
                        self.observe(topic, message)
                    except Exception:
                        rx.count("handler_errors")
                        log.exception("%s: observer failed on %s", rx.service, topic)

    def deliver(self, items: Iterable[tuple[str, Message]], received: int = 0) -> int:
        """Hand what a link lets through to the handler (caller holds the lock), each
        (publisher, topic, seq) once: duplicates and replays are refused here, after the link,
        as a receiver behind a real network would.  ``received``: messages to count as
        received with the delivered ones (one counter update a message)."""
        rx = self.reception
        delivered = 0
        for topic, message in items:
            if (why := self.guards.check(message, topic)) is not None:
                rx.reject(
                    rx.prefix + topic,
                    why,
                    f"seq {message.seq} from {message.src} at t = {message.t} "
                    + _SEQUENCE_TEXT[why],
                )
                continue
            try:
                self.handler(topic, message)
                delivered += 1
            except Exception:
                rx.count("handler_errors")
                log.exception("%s: handler failed on %s", rx.service, topic)
        with rx.count_lock:
            rx.counts["received"] += received
            rx.counts["delivered"] += delivered
        return delivered

    def release(self) -> int:
        """Deliver what this route's link models hold and is now due; how many."""
        with self.lock:
            items = [
                item
                for model in self.all_models()
                for item in model.release(self.reception.now(model))
            ]
            return self.deliver(items) if items else 0
