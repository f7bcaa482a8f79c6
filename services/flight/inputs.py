"""What a flight service takes in from the bus: its inputs, declared against the topology, and
the liveliness it watches, all delivered to one inbox its main loop reads in order.  The
service host (``services.flight.host``) builds it from a component's declared ``Listen`` and
``Watch`` entries:

    inputs = Inputs(ctx)
    inputs.listen(nav_state_topic(sc), "nav", accounted=True)   # + (OBSERVED, msg), (LOST, topic)
    inputs.listen(RECORDED, "recorded", tag=RECORDED_TAG)        # (RECORDED_TAG, msg)
    inputs.watch(f"nav-{sc}", PRESENCE)                          # (PRESENCE, (service, up))
    ... inputs.inbox.get() ...
    inputs.close()

An entry is ``(topic, message)`` for a message delivered on ``topic``, or ``(tag, payload)``:
``OBSERVED`` (a message its link has delivered, held or dropped: what a lock-step wait counts
as accounted for), ``LOST`` (the topic whose messages the bus's rate budget dropped unread),
or the tag given to ``listen`` or ``watch``.  A service may listen only to what the topology
(``services.interface.topics``) says it subscribes, the table its access control is made from:
a listen outside it is a bug, raised at start-up.
"""

from __future__ import annotations

import queue
from collections.abc import Callable
from typing import Any

from services.bus import queue_handler, watch_alive
from services.flight.runtime import ServiceContext
from services.interface import Message
from services.interface.keys import key_matches
from services.interface.topics import topics_subscribed_by

OBSERVED = "observed"
"""Inbox tag: a message its link has delivered, held or dropped (``Bus.subscribe``'s observe)."""
LOST = "lost"
"""Inbox tag: messages on a topic the bus's rate budget dropped unread (a flood)."""
PRESENCE = "presence"
"""Inbox tag of a watched service's liveliness: ``(service, up)``."""


class Inputs:
    """One service's subscriptions and liveliness watches, delivered to ``inbox``.

    Parameters
    ----------
    ctx : the service's context (its bus and name).
    """

    def __init__(self, ctx: ServiceContext) -> None:
        self.ctx = ctx
        self.inbox: queue.SimpleQueue[tuple[str, Any]] = queue.SimpleQueue()
        self.declared = topics_subscribed_by(ctx.name)
        self.watches: list[Any] = []

    def listen(self, topic: str, schema: str, *, accounted: bool = False, tag: str = "") -> None:
        """Subscribe ``topic`` (a pattern) for messages of ``schema``: each delivered one as
        ``(topic, message)``, or ``(tag, message)`` with a ``tag``; ``accounted``: also every
        one its link has delivered, held or dropped (``OBSERVED``) and the rate budget's drops
        (``LOST``), what a lock-step wait needs."""
        if not any(key_matches(own, topic) for own in self.declared):
            raise ValueError(
                f"{self.ctx.name} listens to {topic!r}, which the topology does not give it "
                f"(it subscribes {', '.join(self.declared)}): add it to services.interface.topics"
            )
        inbox = self.inbox
        handler = queue_handler(inbox) if not tag else _tagged(inbox, tag)
        observe = _tagged(inbox, OBSERVED) if accounted else None
        lost: Callable[[str], None] | None = None
        if accounted:

            def lost(lost_topic: str) -> None:
                inbox.put((LOST, lost_topic))

        self.ctx.bus.subscribe(topic, handler, expected_schema=schema, observe=observe, lost=lost)

    def watch(self, pattern: str, tag: str = PRESENCE) -> None:
        """Watch the liveliness of the services ``pattern`` names: ``(tag, (service, up))``
        for each that is there now, comes or goes."""
        inbox = self.inbox

        def on_change(service: str, up: bool) -> None:
            inbox.put((tag, (service, up)))

        self.watches.append(watch_alive(self.ctx.bus.session, self.ctx.run, pattern, on_change))

    def close(self) -> None:
        """Undeclare the liveliness watches (the bus closes the subscriptions)."""
        for watch in self.watches:
            watch.undeclare()
        self.watches.clear()


def _tagged(inbox: queue.SimpleQueue, tag: str) -> Callable[[str, Message], None]:
    def handler(_topic: str, message: Message) -> None:
        inbox.put((tag, message))

    return handler
