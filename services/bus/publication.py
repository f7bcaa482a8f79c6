"""What one service puts on the bus: its messages encoded with a sequence number per topic and
its bus's boot, one zenoh publisher per topic, and a lock-step step's messages batched into one
zenoh sample per topic (``services.interface.schema.pack_batch``).  ``services.bus.endpoint.Bus``
publishes through it."""

from __future__ import annotations

import secrets
import threading
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from typing import Any

import zenoh

from services.interface import MAX_BATCH, MAX_PAYLOAD, encode, pack_batch

MSGPACK_ENCODING = "application/msgpack"


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


class Publication:
    """One service's outgoing messages on ``session``, below the key ``prefix``.

    Thread safe: ``lock`` guards the sequence numbers, the publishers and the open batch (the
    bus also takes it to withdraw its token)."""

    def __init__(self, session: zenoh.Session, prefix: str, service: str) -> None:
        self.session, self.prefix, self.service = session, prefix, service
        self.lock = threading.RLock()
        self.publishers: dict[str, zenoh.Publisher] = {}
        self.seq: dict[str, int] = {}  # topic -> next seq (its keys: topics checked once)
        # drawn anew each time a bus opens: a receiver tells a restarted publisher, counting
        # from 0 again, by its new boot, not by how its sequence numbers look
        self.boot = secrets.randbits(63)
        self.batching = 0  # depth of open ``batch()`` blocks
        self.held: dict[str, list[bytes]] = {}  # topic -> payloads of the open batch
        self.sent = 0  # under the lock: publishing takes one lock a message
        self.closed = False

    def publish(self, topic: str, schema: str, body: Mapping[str, Any], t: float) -> int:
        """Encode and put ``body`` on ``ddvi/<run>/<topic>``; return the seq used.

        ``seq`` counts per topic from 0. Raises MessageError if the body does not fit its
        schema (nothing is sent and the seq is not consumed).
        """
        if topic not in self.seq:
            _check_topic(topic)
        with self.lock:
            if self.closed:
                raise RuntimeError(f"bus of {self.service} is closed")
            seq = self.seq.get(topic, 0)
            payload = encode(schema, body, seq=seq, t=t, src=self.service, boot=self.boot)
            self.seq[topic] = seq + 1
            if self.batching:
                held = self.held.setdefault(topic, [])
                size = sum(map(len, held)) + len(payload)
                if held and (len(held) >= MAX_BATCH or size > MAX_PAYLOAD // 2):  # packs in one
                    self._put(topic, held)
                    held.clear()
                held.append(payload)
            else:
                self._put(topic, [payload])
            self.sent += 1
        return seq

    @contextmanager
    def batch(self) -> Iterator[None]:
        """Hold what is published inside the block and put it out at its end as one zenoh
        sample per topic (``services.interface.schema.pack_batch``; a lone message goes out as
        itself).
        A lock-step publisher wraps one step's messages in it: receivers still see each
        message, with its own seq and time, but the bus carries a sample per topic and step.
        Blocks nest; the outermost one sends."""
        with self.lock:
            self.batching += 1
        try:
            yield
        finally:
            with self.lock:
                self.batching -= 1
                if not self.batching and not self.closed:
                    held, self.held = self.held, {}
                    for topic, payloads in held.items():
                        if payloads:
                            self._put(topic, payloads)

    def _put(self, topic: str, payloads: list[bytes]) -> None:
        """Put one message, or several as a batch, on ``topic`` (caller holds _pub_lock)."""
        publisher = self.publishers.get(topic)
        if publisher is None:
            publisher = self.session.declare_publisher(
                self.prefix + topic,
                encoding=zenoh.Encoding(MSGPACK_ENCODING),
                congestion_control=zenoh.CongestionControl.BLOCK,
            )
            self.publishers[topic] = publisher
        publisher.put(payloads[0] if len(payloads) == 1 else pack_batch(payloads))

    def close(self) -> list[zenoh.Publisher] | None:
        """Refuse any further message; the publishers to undeclare, or None when it was
        closed already."""
        with self.lock:
            if self.closed:
                return None
            self.closed = True
            publishers, self.publishers = list(self.publishers.values()), {}
            return publishers
