"""The bus endpoint: one typed ``Bus`` per service on a zenoh session (``services.bus.session``).

Keys are ``ddvi/<run>/<topic>``; the liveliness token ``ddvi/<run>/alive/<service>``
(``services.bus.liveliness`` watches them). Payloads are encoded and decoded only by
``services.interface.schema``.

Threading
---------
Zenoh calls subscriber callbacks on its own threads. Each subscription's ``Route``
(``services.bus.reception``) decodes, counts and link-models the message on that thread, then
calls the handler there too, so a handler must be quick and thread
safe: ``queue_handler(q)`` hands messages to the service's main loop through a
``queue.SimpleQueue``.
Counters and sequence numbers are guarded by locks; nothing raised in a callback reaches zenoh.
"""

from __future__ import annotations

import queue
from collections.abc import Collection, Iterable, Mapping
from contextlib import AbstractContextManager
from typing import Any

import zenoh

from services.bus.budget import Dropped, RateBudget
from services.bus.links import CLOCKS, LinkModel
from services.bus.publication import Publication
from services.bus.reception import Handler, Reception, Route
from services.bus.session import check_name, key_prefix
from services.interface import Message
from services.interface.links import LinkRule, rule_latency
from services.interface.topics import alive_topic

_LINK_COUNTERS = ("dropped", "duplicated", "reordered", "delayed")


def queue_handler(q: queue.SimpleQueue[Any] | queue.Queue[Any]) -> Handler:
    """A handler that puts ``(topic, message)`` on ``q`` for the service's main loop.

    Use an unbounded queue, preferably a ``queue.SimpleQueue`` (in C: a put is a fraction of a
    ``queue.Queue``'s): a full bounded queue raises into the bus, which counts it as a handler
    error and loses the message.
    """

    def handler(topic: str, message: Message) -> None:
        q.put_nowait((topic, message))

    return handler


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
        self._out = Publication(session, self.prefix, self.service)
        self._routes: list[Route] = []
        self._token: zenoh.LivelinessToken | None = None
        self._rx = Reception(
            self.service, self.prefix, links, link_clock, seed, time_window, budget
        )

    @property
    def budget(self) -> RateBudget | None:
        """The rate budget its subscriptions take samples against (None: none)."""
        return self._rx.budget

    # -- counters ---------------------------------------------------------------------------

    @property
    def counters(self) -> dict[str, int]:
        """Snapshot: sent, received, delivered, rejected, rejected.<reason>, handler_errors, and
        the link-model totals dropped, duplicated, reordered, delayed. A flat str->int map, ready
        for a ``stats`` message."""
        with self._rx.count_lock:
            out = dict(self._rx.counts)
        out["sent"] = self._out.sent
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
            self._rx.rules.insert(0, rule)
            self._rx.rule_cache.clear()
            for route in routes:
                route.models = {(i + 1, pub): m for (i, pub), m in route.models.items()}
        finally:
            for route in reversed(routes):
                route.lock.release()

    def latency(self, publisher: str, topic: str) -> float:
        """The largest delay (s: delay + jitter) of the deployment link from ``publisher`` on
        ``topic`` to this service; 0 when no link rule applies."""
        return rule_latency(self._rx.rules, publisher, topic)

    # -- publishing -------------------------------------------------------------------------

    @property
    def boot(self) -> int:
        """This bus's boot number (``Publication.boot``)."""
        return self._out.boot

    def publish(self, topic: str, schema: str, body: Mapping[str, Any], t: float) -> int:
        """Encode and put ``body`` on ``ddvi/<run>/<topic>`` (``Publication.publish``); return
        the seq used."""
        return self._out.publish(topic, schema, body, t)

    def batch(self) -> AbstractContextManager[None]:
        """Hold what is published inside the block and put it out at its end as one zenoh
        sample per topic (``Publication.batch``)."""
        return self._out.batch()

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
        message from its topic's publisher, whatever the link did with it (delivered, held or
        dropped), and also one its sequence window refused: a lock-step loop uses it to know
        that a message it waits for is accounted for.  A sequence number proves nothing of who
        sent it (a stolen credential can take the genuine message's number first), so a
        refusal by number must not make a lock-step wait for a message that has come.
        ``lost(topic)``, if given, is told (once a key per step of the receiver's clock) that
        the bus's rate budget dropped messages on ``topic`` unread: what a lock-step loop
        waits for may be among them.
        """
        if self._out.closed:
            raise RuntimeError(f"bus of {self.service} is closed")
        route = Route(
            self._rx, handler, expected_schema, link, observe, pattern=topic_pattern, lost=lost
        )
        if "*" not in topic_pattern:
            route.key = self.prefix + topic_pattern
        route.subscriber = self.session.declare_subscriber(
            self.prefix + topic_pattern, route.on_sample
        )
        self._routes.append(route)

    def pump(self, sim_time: float | None = None) -> int:
        """Advance the receiver's simulation clock (if given) and deliver held items now due.

        Call from the main loop: sim-clock links release against the latest ``sim_time``,
        wall-clock links against ``time.monotonic()``. Returns how many items were delivered.
        """
        if sim_time is not None:
            self._rx.sim_time = float(sim_time)
            if self.budget is not None:
                self.budget.advance(self._rx.sim_time)
        if self._out.closed:
            return 0
        return sum(route.release() for route in list(self._routes))

    @property
    def sim_time(self) -> float:
        """The receiver's simulation time as last given to ``pump``."""
        return self._rx.sim_time

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
        with self._out.lock:
            token, self._token = self._token, None
        if token is not None:
            token.undeclare()

    def close(self) -> None:
        """Undeclare subscribers, publishers and the liveliness token (idempotent)."""
        with self._out.lock:
            publishers = self._out.close()
            if publishers is None:
                return
            token, self._token = self._token, None
        # Undeclare outside the lock: a callback in flight may be publishing. Routes stay, so
        # their link counters remain readable after close.
        for route in self._routes:
            route.subscriber.undeclare()
        for publisher in publishers:
            publisher.undeclare()
        if token is not None:
            token.undeclare()

    def __enter__(self) -> Bus:
        return self

    def __exit__(self, *_exc: object) -> None:
        self.close()
