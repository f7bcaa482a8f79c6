"""The live view's handoff: messages queued by the monitor's loop reach the server in bursts,
in the order they came, with the clock after them, and none is lost to another's error."""

from __future__ import annotations

import itertools
import threading
import time

from services.ground.monitoring.live_handoff import HANDOFF_S, Handoff
from tests.support import wait_until


class Channel:
    """A stand-in for ``foxglove.Channel``: what it was given, and when."""

    def __init__(self, topic: str, log: list[tuple[str, bytes, int, float]]) -> None:
        self.topic = topic
        self._log = log

    def log(self, data: bytes, *, log_time: int) -> None:
        if data == b"bad":
            raise ValueError("a message the server refuses")
        self._log.append((self.topic, data, log_time, time.monotonic()))


def test_queued_messages_go_over_together_in_order_with_the_clock_after() -> None:
    logged: list[tuple[str, bytes, int, float]] = []
    clocks: list[tuple[int, int]] = []  # (time ns, messages logged when it was moved)
    handoff = Handoff(lambda t: clocks.append((t, len(logged))))
    try:
        a, b = Channel("a", logged), Channel("b", logged)
        for k in range(200):
            handoff.put(a if k % 2 else b, str(k).encode(), k)
        handoff.time(199)
        assert wait_until(lambda: len(logged) == 200)
        assert [int(data) for _, data, _, _ in logged] == list(range(200))
        assert [t for _, _, t, _ in logged] == list(range(200))
        assert [topic for topic, *_ in logged] == ["b", "a"] * 100
        assert wait_until(lambda: clocks == [(199, 200)])
        time.sleep(3 * HANDOFF_S)  # the clock unmoved: not told again
        assert clocks == [(199, 200)]
    finally:
        handoff.close()


def test_messages_coming_one_by_one_go_over_in_bursts() -> None:
    logged: list[tuple[str, bytes, int, float]] = []
    handoff = Handoff(lambda t: None)
    try:
        channel = Channel("a", logged)
        start = time.monotonic()
        for k in range(100):
            handoff.put(channel, b"x", k)
            time.sleep(0.002)
        span = time.monotonic() - start
        assert wait_until(lambda: len(logged) == 100)
    finally:
        handoff.close()
    at = [when for *_, when in logged]
    gaps = [later - earlier for earlier, later in itertools.pairwise(at)]
    bursts = 1 + sum(gap > HANDOFF_S / 5 for gap in gaps)
    assert bursts <= span / HANDOFF_S + 2 and bursts < 25, (bursts, span)


def test_a_message_the_server_refuses_is_counted_and_the_rest_go() -> None:
    logged: list[tuple[str, bytes, int, float]] = []
    handoff = Handoff(lambda t: None)
    try:
        channel = Channel("a", logged)
        for data in (b"1", b"bad", b"2"):
            handoff.put(channel, data, 0)
        assert wait_until(lambda: len(logged) == 2)
        assert [data for _, data, _, _ in logged] == [b"1", b"2"]
        assert handoff.errors == 1
    finally:
        handoff.close()


def test_closing_hands_over_what_is_queued_and_stops_the_thread() -> None:
    logged: list[tuple[str, bytes, int, float]] = []
    clocks: list[int] = []
    before = set(threading.enumerate())
    handoff = Handoff(clocks.append)
    (thread,) = set(threading.enumerate()) - before
    assert thread.name == "live-handoff"
    channel = Channel("a", logged)
    for k in range(1000):
        handoff.put(channel, b"x", k)
        handoff.time(k)
    handoff.close()
    assert len(logged) == 1000 and clocks[-1] == 999
    assert not thread.is_alive()
    handoff.close()  # idempotent
    assert len(logged) == 1000
