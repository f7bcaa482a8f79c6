"""The bus endpoint: one typed ``Bus`` per service on a zenoh session (``services.bus.session``).

Keys are ``ddvi/<run>/<topic>``; the liveliness token ``ddvi/<run>/alive/<service>``
(``services.bus.liveliness`` watches them). Payloads are encoded and decoded only by
``services.interface.schema``.

Threading
---------
Zenoh calls subscriber callbacks on its own threads. ``Bus`` decodes, counts and link-models the
message on that thread, then calls the handler there too, so a handler must be quick and thread
safe: ``queue_handler(q)`` hands messages to the service's main loop through a
``queue.SimpleQueue``.
Counters and sequence numbers are guarded by locks; nothing raised in a callback reaches zenoh.
"""

from __future__ import annotations

import functools
import logging
import math
import queue
import threading
import time
import zlib
from collections.abc import Callable, Collection, Iterable, Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any

import zenoh

from services.bus.budget import Dropped, RateBudget
from services.bus.guards import ORIGIN_REASONS, SEQUENCE_REASONS, SequenceGuards, check_origin
from services.bus.links import CLOCKS, LinkModel, LinkRule, rule_latency, select_rule
from services.bus.session import check_name, key_prefix
from services.interface import (
    MAX_BATCH,
    MAX_PAYLOAD,
    REASONS,
    Message,
    MessageError,
    decode,
    encode,
    pack_batch,
    unpack_batch,
)
from services.interface.topics import CLOCK, alive_topic

log = logging.getLogger("ddvi.bus")

MSGPACK_ENCODING = "application/msgpack"
_LINK_COUNTERS = ("dropped", "duplicated", "reordered", "delayed")
_ORIGIN_TEXT = {
    "src": "not this topic's publisher",
    "identity": "its body names another than its topic does",
    "time": "a time outside the mission's window",
}
_SEQUENCE_TEXT = {"duplicate": "seen already", "stale": "older than its window"}

Handler = Callable[[str, Message], None]
"""A subscription handler: ``handler(topic, message)``, topic relative to ``ddvi/<run>/``."""


def queue_handler(q: queue.SimpleQueue[Any] | queue.Queue[Any]) -> Handler:
    """A handler that puts ``(topic, message)`` on ``q`` for the service's main loop.

    Use an unbounded queue, preferably a ``queue.SimpleQueue`` (in C: a put is a fraction of a
    ``queue.Queue``'s): a full bounded queue raises into the bus, which counts it as a handler
    error and loses the message.
    """

    def handler(topic: str, message: Message) -> None:
        q.put_nowait((topic, message))

    return handler


def _check_topic(topic: str) -> str:
    if (
        not isinstance(topic, str)
        or not topic
        or any(c in topic for c in "*$?#")
        or "//" in topic
        or topic[0] == "/"
        or topic[-1] == "/"
    ):
        raise ValueError(f"topic: expected a/b/c without wildcards, got {topic!r}")
    return topic


@dataclass
class _Route:
    """One subscription: its handler, schema filter, its link models (an explicit one for every
    message, or one per matching deployment rule, made on first use) and an observer."""

    handler: Handler
    expected: str | Collection[str] | None
    link: LinkModel | None
    observe: Handler | None = None
    index: int = 0  # the subscription's number on its bus (seeds its link models)
    models: dict[tuple[int, str], LinkModel] = field(default_factory=dict)
    guards: SequenceGuards = field(default_factory=SequenceGuards)
    # the same window on what comes off the wire, before the link and the observer: a replay
    # is refused before it can touch a lock-step wait (the one above refuses what the link
    # itself duplicates)
    wire: SequenceGuards = field(default_factory=SequenceGuards)
    # re-entrant: a handler may change the bus's link rules (a run-time link fault)
    lock: threading.RLock = field(default_factory=threading.RLock)
    subscriber: Any = None
    key: str | None = None  # the one key a subscription without wildcards hears
    lost: Dropped | None = None  # told of a key's messages its rate budget dropped
    lost_told: dict[str, float] = field(default_factory=dict)  # key -> sim time last told

    def all_models(self) -> list[LinkModel]:
        return ([self.link] if self.link is not None else []) + list(self.models.values())


class Bus:
    """One service's endpoint on one session: typed publish/subscribe, liveliness, counters.

    ``Bus(session, run, service)``; the session is owned by the caller (see ``open_session``),
    ``close()`` undeclares what this Bus declared. Usable as a context manager.  ``links`` are
    the deployment's link rules at this subscriber (``Deployment.links_for``): each received
    message goes through the model of the first rule matching its publisher and topic, on
    ``link_clock`` ("sim": the time given to ``pump``; "wall": ``time.monotonic()``), one model
    per publisher, seeded from ``seed``.  A received message whose ``src`` is not its topic's
    publisher per the topology, or whose time lies outside ``time_window`` (earliest, latest
    simulation time, s; None: not checked), is refused (``guards.check_origin``).  With a
    ``budget`` (``services.bus.budget``), a sample past its key's rate budget is dropped before
    it is decoded, and counted (``flooded``, ``flood.<publisher>``).
    """

    def __init__(
        self,
        session: zenoh.Session,
        run: str,
        service: str,
        links: Iterable[LinkRule] = (),
        link_clock: str = "sim",
        seed: int = 0,
        time_window: tuple[float, float] | None = None,
        budget: RateBudget | None = None,
    ) -> None:
        if link_clock not in CLOCKS:
            raise ValueError(f"link_clock: expected one of {CLOCKS}, got {link_clock!r}")
        self.session = session
        self.run = check_name("run", run)
        self.service = check_name("service", service)
        self.prefix = key_prefix(run)
        self._pub_lock = threading.RLock()  # seq counters and publishers
        self._count_lock = threading.Lock()  # counters only; never held while calling out
        self._publishers: dict[str, zenoh.Publisher] = {}
        self._seq: dict[str, int] = {}  # topic -> next seq (its keys: topics checked once)
        self._batching = 0  # depth of open ``batch()`` blocks
        self._held: dict[str, list[bytes]] = {}  # topic -> payloads of the open batch
        self._sent = 0  # under _pub_lock: publishing takes one lock a message
        self._routes: list[_Route] = []
        self._token: zenoh.LivelinessToken | None = None
        self._sim_time = 0.0
        self._closed = False
        self._counts: dict[str, int] = dict.fromkeys(
            ["sent", "received", "delivered", "rejected", "handler_errors"], 0
        )
        self._counts.update({f"rejected.{r}": 0 for r in sorted(REASONS)})
        self._counts.update({f"rejected.{r}": 0 for r in SEQUENCE_REASONS})
        self._counts.update({f"rejected.{r}": 0 for r in ORIGIN_REASONS})
        self.time_window = time_window
        self.budget = budget
        self._rules = list(links)
        self._link_clock, self._seed = link_clock, seed
        self._rule_cache: dict[tuple[str, str], int | None] = {}

    # -- counters ---------------------------------------------------------------------------

    def _count(self, key: str, n: int = 1) -> int:
        with self._count_lock:
            self._counts[key] += n
            return self._counts[key]

    @property
    def counters(self) -> dict[str, int]:
        """Snapshot: sent, received, delivered, rejected, rejected.<reason>, handler_errors, and
        the link-model totals dropped, duplicated, reordered, delayed. A flat str->int map, ready
        for a ``stats`` message."""
        with self._count_lock:
            out = dict(self._counts)
        with self._pub_lock:
            out["sent"] = self._sent
        out.update(dict.fromkeys(_LINK_COUNTERS, 0))
        if self.budget is not None:
            flood = self.budget.counters()
            out["flooded"] = sum(flood.values())
            out.update(flood)
        for route in list(self._routes):
            with route.lock:
                for model in route.all_models():
                    for key, value in model.counters.items():
                        out[key] += value
        return out

    def add_link_rule(self, rule: LinkRule) -> None:
        """A link fault at run time: ``rule`` takes precedence over every rule so far for the
        messages it matches from now on (what a link already holds keeps its due time)."""
        routes = list(self._routes)
        for route in routes:
            route.lock.acquire()
        try:
            self._rules.insert(0, rule)
            self._rule_cache.clear()
            for route in routes:
                route.models = {(i + 1, pub): m for (i, pub), m in route.models.items()}
        finally:
            for route in reversed(routes):
                route.lock.release()

    def latency(self, publisher: str, topic: str) -> float:
        """The largest delay (s: delay + jitter) of the deployment link from ``publisher`` on
        ``topic`` to this service; 0 when no link rule applies."""
        return rule_latency(self._rules, publisher, topic)

    # -- publishing -------------------------------------------------------------------------

    def publish(self, topic: str, schema: str, body: Mapping[str, Any], t: float) -> int:
        """Encode and put ``body`` on ``ddvi/<run>/<topic>``; return the seq used.

        ``seq`` counts per topic from 0. Raises MessageError if the body does not fit its
        schema (nothing is sent and the seq is not consumed).
        """
        if topic not in self._seq:
            _check_topic(topic)
        with self._pub_lock:
            if self._closed:
                raise RuntimeError(f"bus of {self.service} is closed")
            seq = self._seq.get(topic, 0)
            payload = encode(schema, body, seq=seq, t=t, src=self.service)
            self._seq[topic] = seq + 1
            if self._batching:
                held = self._held.setdefault(topic, [])
                size = sum(map(len, held)) + len(payload)
                if held and (len(held) >= MAX_BATCH or size > MAX_PAYLOAD // 2):  # packs in one
                    self._put(topic, held)
                    held.clear()
                held.append(payload)
            else:
                self._put(topic, [payload])
            self._sent += 1
        return seq

    @contextmanager
    def batch(self) -> Iterator[None]:
        """Hold what is published inside the block and put it out at its end as one zenoh
        sample per topic (``services.interface.schema.pack_batch``; a lone message goes out as
        itself).
        A lock-step publisher wraps one step's messages in it: receivers still see each
        message, with its own seq and time, but the bus carries a sample per topic and step.
        Blocks nest; the outermost one sends."""
        with self._pub_lock:
            self._batching += 1
        try:
            yield
        finally:
            with self._pub_lock:
                self._batching -= 1
                if not self._batching and not self._closed:
                    held, self._held = self._held, {}
                    for topic, payloads in held.items():
                        if payloads:
                            self._put(topic, payloads)

    def _put(self, topic: str, payloads: list[bytes]) -> None:
        """Put one message, or several as a batch, on ``topic`` (caller holds _pub_lock)."""
        publisher = self._publishers.get(topic)
        if publisher is None:
            publisher = self.session.declare_publisher(
                self.prefix + topic,
                encoding=zenoh.Encoding(MSGPACK_ENCODING),
                congestion_control=zenoh.CongestionControl.BLOCK,
            )
            self._publishers[topic] = publisher
        publisher.put(payloads[0] if len(payloads) == 1 else pack_batch(payloads))

    # -- subscribing ------------------------------------------------------------------------

    def subscribe(
        self,
        topic_pattern: str,
        handler: Handler,
        expected_schema: str | Collection[str] | None = None,
        link: LinkModel | None = None,
        observe: Handler | None = None,
        lost: Dropped | None = None,
    ) -> None:
        """Subscribe to ``ddvi/<run>/<topic_pattern>`` (zenoh wildcards allowed).

        A pattern without wildcards is the topic of all it hears: a raw put on a wildcard key
        that zenoh delivers to it (``ddvi/<run>/**``) counts as a message on that topic, under
        its link rule and its replay window (a replay cannot slip past them that way).

        Each sample is decoded and validated (rejects are counted by reason and logged), passed
        through ``link`` if given, else through the deployment's matching link rule, and what
        the link lets through now is handed to ``handler(topic, message)``; items held by a
        link are delivered by ``pump``.  Then ``observe(topic, message)``, if given, sees every
        accepted message, whatever the link did with it (delivered, held or dropped): a
        lock-step loop uses it to know that a message it waits for is accounted for.
        ``lost(topic)``, if given, is told (once a key per step of the receiver's clock) that
        the bus's rate budget dropped messages on ``topic`` unread: what a lock-step loop
        waits for may be among them.
        """
        if self._closed:
            raise RuntimeError(f"bus of {self.service} is closed")
        route = _Route(handler, expected_schema, link, observe, index=len(self._routes), lost=lost)
        if "*" not in topic_pattern:
            route.key = self.prefix + topic_pattern
        route.subscriber = self.session.declare_subscriber(
            self.prefix + topic_pattern, functools.partial(self._on_sample, route)
        )
        self._routes.append(route)

    def _now(self, link: LinkModel) -> float:
        return time.monotonic() if link.clock == "wall" else self._sim_time

    def _model(self, route: _Route, publisher: str, topic: str) -> LinkModel | None:
        """The link model a message from ``publisher`` on ``topic`` goes through (caller holds
        route.lock)."""
        if route.link is not None:
            return route.link
        if not self._rules:
            return None
        key = (publisher, topic)
        if key not in self._rule_cache:
            self._rule_cache[key] = select_rule(self._rules, publisher, topic)
        i = self._rule_cache[key]
        if i is None:
            return None
        model = route.models.get((i, publisher))
        if model is None:
            # one seeded stream per (subscriber, route, rule, publisher): what one publisher's
            # messages suffer does not depend on how they interleave with another's
            seed = zlib.crc32(f"{self._seed}/{self.service}/{route.index}/{i}/{publisher}".encode())
            model = LinkModel(self._rules[i].spec, seed, self._link_clock)
            route.models[(i, publisher)] = model
        return model

    def _on_sample(self, route: _Route, sample: zenoh.Sample) -> None:
        """Zenoh callback: must never raise.  A batch is taken apart: each of its messages is
        decoded, offered to its link and delivered as if it had come alone, in its order."""
        try:
            key = route.key or str(sample.key_expr)  # a string per sample costs
            payload = sample.payload.to_bytes()
            if self.budget is not None and not self.budget.take(key, payload):
                self._tell_lost(route, key)
                return
            try:
                parts = unpack_batch(payload)  # also refuses an oversized payload
            except MessageError as err:
                self._reject(key, err.reason, str(err))
                return
            self._on_messages(route, key, parts or (payload,))
        except Exception:
            self._count("handler_errors")
            log.exception("%s: error in bus callback", self.service)

    def _tell_lost(self, route: _Route, key: str) -> None:
        """Tell the route's ``lost`` of a budget's drop on ``key``, once a receiver's step."""
        if route.lost is None or route.lost_told.get(key, -math.inf) >= self._sim_time:
            return
        if len(route.lost_told) < 1024 or key in route.lost_told:  # bounded, as the budget
            route.lost_told[key] = self._sim_time
        topic = key[len(self.prefix) :] if key.startswith(self.prefix) else key
        try:
            route.lost(topic)
        except Exception:
            self._count("handler_errors")
            log.exception("%s: lost-message handler failed on %s", self.service, topic)

    def _on_messages(self, route: _Route, key: str, payloads: Iterable[bytes]) -> None:
        """Messages off the wire, one sample's: decode, link, deliver, observe (see
        ``subscribe``); the route's lock and the counters are taken once for them all."""
        topic = key[len(self.prefix) :] if key.startswith(self.prefix) else key
        messages = []
        for payload in payloads:  # one bad part costs that part only
            try:
                message = decode(payload, route.expected)
            except MessageError as err:
                self._reject(key, err.reason, str(err))
                continue
            except Exception:
                self._count("handler_errors")
                log.exception("%s: error decoding on %s", self.service, topic)
                continue
            if (why := check_origin(message, topic, self.time_window)) is not None:
                self._reject(key, why, f"seq {message.seq} from {message.src!r} at t = "
                             f"{message.t:g}: " + _ORIGIN_TEXT[why])  # fmt: skip
                continue
            messages.append(message)
            if self.budget is not None and topic == CLOCK:  # the time master's, checked above
                self.budget.advance(message.t)
        if not messages:
            return
        fresh: list[Message] = []  # what passes the wire's replay window: all that acts
        try:
            with route.lock:
                for message in messages:
                    if (why := route.wire.check(message, topic)) is None:
                        fresh.append(message)
                    else:
                        self._reject(key, why, f"seq {message.seq} from {message.src} at t = "
                                     f"{message.t:g}: " + _SEQUENCE_TEXT[why])  # fmt: skip
                messages = fresh
                items: list[tuple[str, Message]] = []
                direct = route.link is None and not self._rules  # no link to choose per message
                for message in messages:
                    try:
                        model = None if direct else self._model(route, message.src, topic)
                        if model is None or model.transparent:
                            items.append((topic, message))
                        else:
                            items += model.offer(
                                (topic, message),
                                self._now(model),
                                sent=message.t if model.clock == "sim" else None,
                            )
                    except Exception:
                        self._count("handler_errors")
                        log.exception("%s: error in bus callback", self.service)
                # delivered under the lock (handlers only queue), so that what one thread's
                # offer releases is queued before another thread's pump returns
                self._deliver(route, items, received=len(messages))
        finally:  # whatever happened above, each accepted message is accounted for
            if route.observe is not None:
                for message in fresh:
                    try:
                        route.observe(topic, message)
                    except Exception:
                        self._count("handler_errors")
                        log.exception("%s: observer failed on %s", self.service, topic)

    def _reject(self, key: str, reason: str, text: str) -> None:
        """Count a refused message by reason; log the first ten of each and every 1000th."""
        with self._count_lock:
            self._counts["rejected"] += 1
            self._counts[f"rejected.{reason}"] += 1
            n = self._counts[f"rejected.{reason}"]
        if n <= 10 or n % 1000 == 0:
            log.warning("%s: rejected %s (%s, #%d): %s", self.service, key, reason, n, text)

    def _deliver(
        self, route: _Route, items: Iterable[tuple[str, Message]], received: int = 0
    ) -> int:
        """Hand what a link lets through to the handler (caller holds route.lock), each
        (publisher, topic, seq) once: duplicates and replays are refused here, after the link,
        as a receiver behind a real network would.  ``received``: messages to count as
        received with the delivered ones (one counter update a message)."""
        delivered = 0
        for topic, message in items:
            if (why := route.guards.check(message, topic)) is not None:
                self._reject(
                    self.prefix + topic,
                    why,
                    f"seq {message.seq} from {message.src} at t = {message.t} "
                    + _SEQUENCE_TEXT[why],
                )
                continue
            try:
                route.handler(topic, message)
                delivered += 1
            except Exception:
                self._count("handler_errors")
                log.exception("%s: handler failed on %s", self.service, topic)
        with self._count_lock:
            self._counts["received"] += received
            self._counts["delivered"] += delivered
        return delivered

    def pump(self, sim_time: float | None = None) -> int:
        """Advance the receiver's simulation clock (if given) and deliver held items now due.

        Call from the main loop: sim-clock links release against the latest ``sim_time``,
        wall-clock links against ``time.monotonic()``. Returns how many items were delivered.
        """
        if sim_time is not None:
            self._sim_time = float(sim_time)
            if self.budget is not None:
                self.budget.advance(self._sim_time)
        if self._closed:
            return 0
        delivered = 0
        for route in list(self._routes):
            with route.lock:
                items = [
                    item for model in route.all_models() for item in model.release(self._now(model))
                ]
                if items:
                    delivered += self._deliver(route, items)
        return delivered

    @property
    def sim_time(self) -> float:
        """The receiver's simulation time as last given to ``pump``."""
        return self._sim_time

    # -- liveliness and teardown ------------------------------------------------------------

    def declare_alive(self) -> None:
        """Declare the liveliness token ``ddvi/<run>/alive/<service>`` (idempotent)."""
        if self._token is None:
            key = self.prefix + alive_topic(self.service)
            self._token = self.session.liveliness().declare_token(key)

    def withdraw(self) -> None:
        """Undeclare the liveliness token alone (idempotent): the service is done, and its
        publishers (their keys) stay declared for what it has put and zenoh has not yet sent.
        zenoh sends declarations ahead of queued data, so a key undeclared right after a put
        can reach the router first, which then drops the put it can no longer resolve."""
        with self._pub_lock:
            token, self._token = self._token, None
        if token is not None:
            token.undeclare()

    def close(self) -> None:
        """Undeclare subscribers, publishers and the liveliness token (idempotent)."""
        with self._pub_lock:
            if self._closed:
                return
            self._closed = True
            publishers, token = self._publishers, self._token
            self._publishers, self._token = {}, None
        # Undeclare outside the lock: a callback in flight may be publishing. Routes stay, so
        # their link counters remain readable after close.
        for route in self._routes:
            route.subscriber.undeclare()
        for publisher in publishers.values():
            publisher.undeclare()
        if token is not None:
            token.undeclare()

    def __enter__(self) -> Bus:
        return self

    def __exit__(self, *_exc: object) -> None:
        self.close()
