"""The service host (services.flight.host): what it subscribes, the order it hands entries to a
component, and how every run ends (done, a hang, the final clock's grace, a stop) with the
component's final counters published."""

from __future__ import annotations

import contextlib
import threading
from typing import Any

import pytest

from services.flight import streams
from services.flight.health import HANG_STATUS, HangError
from services.flight.host import Listen, ServiceHost
from services.interface import CLOCK, Message, nav_state_topic


class FakeBus:
    """What the host and its inputs use of a Bus: subscriptions and batches, recorded."""

    def __init__(self) -> None:
        self.handlers: dict[str, Any] = {}
        self.batches = 0
        self.subscribed = threading.Event()

    def subscribe(self, topic: str, handler: Any, **_: Any) -> None:
        self.handlers[topic] = handler
        self.subscribed.set()

    @contextlib.contextmanager
    def batch(self):
        self.batches += 1
        yield


class FakeContext:
    """A service's context without a session: what it was asked to do, recorded."""

    def __init__(self, name: str) -> None:
        self.name, self.run = name, "test"
        self.bus = FakeBus()
        self.stop = threading.Event()
        self.alive = 0
        self.stats: list[tuple[float, dict[str, int]]] = []
        self.gave_up: list[HangError] = []

    def ready(self) -> None:
        self.alive += 1

    def give_up(self, exc: HangError) -> int:
        self.gave_up.append(exc)
        return HANG_STATUS

    def publish_stats(self, t: float, counters: dict[str, int]) -> None:
        self.stats.append((t, dict(counters)))


def clock(t: float, final: bool = False) -> Message:
    return Message("clock", 1, 0, t, "environment", {"final": final})


class Recording:
    """A reactive component that records what the host hands it, done at ``done_at``."""

    ready_at_start = True
    batched = True

    def __init__(self, ctx: FakeContext, done_at: float = 30.0, hang_at: float | None = None):
        self.ctx, self.done_at, self.hang_at = ctx, done_at, hang_at
        self.inputs = (Listen(CLOCK, "clock"),)
        self.events: list[Any] = []
        self.newest = -1.0
        self.counters = {"taken": 0}

    def poll(self) -> float:
        return 0.05

    def start(self) -> None:
        self.events.append("start")

    def take(self, kind: str, msg: Any) -> None:
        self.events.append(("take", msg.t))
        self.counters["taken"] += 1
        self.newest = max(self.newest, msg.t)

    def settle(self, final_t: float | None) -> None:
        self.events.append(("settle", final_t))
        if self.hang_at is not None and self.newest >= self.hang_at:
            raise HangError("nav-lqr", "navigation sample", self.newest, 5.0)

    def done(self, final_t: float | None) -> bool:
        return self.newest >= self.done_at

    def finish(self) -> tuple[float, dict[str, int]]:
        return self.newest, self.counters


def deliver(ctx: FakeContext, *messages: Message) -> None:
    for msg in messages:
        ctx.bus.handlers[CLOCK](CLOCK, msg)


def serve_in_thread(ctx: FakeContext, component: Recording) -> tuple[threading.Thread, list]:
    status: list[int] = []
    thread = threading.Thread(target=lambda: status.append(ServiceHost(ctx).react(component)))
    thread.start()
    return thread, status


def wait_subscribed(ctx: FakeContext) -> None:
    assert ctx.bus.subscribed.wait(timeout=10), "the host never subscribed"


def test_the_host_subscribes_hands_entries_in_order_and_publishes_the_final_counters() -> None:
    ctx = FakeContext("ctrl-lqr")
    component = Recording(ctx, done_at=120.0)
    thread, status = serve_in_thread(ctx, component)
    wait_subscribed(ctx)
    deliver(ctx, clock(0.0), clock(60.0), clock(120.0))
    thread.join(timeout=10)
    assert not thread.is_alive() and status == [0]
    assert ctx.alive == 1  # alive once subscribed
    assert component.events[0] == "start"
    takes = [e[1] for e in component.events if e[0] == "take"]
    assert takes == [0.0, 60.0, 120.0]
    assert ("settle", None) in component.events  # settled once the inbox was empty
    assert ctx.stats == [(120.0, {"taken": 3})]
    assert ctx.bus.batches >= 1  # a batched component's pass publishes as one


def test_a_hang_gives_up_with_the_hang_status_and_still_publishes_the_counters() -> None:
    ctx = FakeContext("ctrl-lqr")
    thread, status = serve_in_thread(ctx, Recording(ctx, done_at=1e9, hang_at=60.0))
    wait_subscribed(ctx)
    deliver(ctx, clock(0.0), clock(60.0))
    thread.join(timeout=10)
    assert status == [HANG_STATUS]
    assert [exc.service for exc in ctx.gave_up] == ["nav-lqr"]
    assert ctx.stats == [(60.0, {"taken": 2})]


def test_after_the_final_clock_the_run_ends_when_the_last_inputs_never_come(monkeypatch) -> None:
    monkeypatch.setattr(streams, "END_GRACE", 0.05)
    ctx = FakeContext("nav-lqr")
    component = Recording(ctx, done_at=1e9)  # waits for a sample its link lost
    thread, status = serve_in_thread(ctx, component)
    wait_subscribed(ctx)
    deliver(ctx, clock(0.0), clock(60.0, final=True))
    thread.join(timeout=10)
    assert status == [0]
    assert ("settle", 60.0) in component.events  # the component was told the final time
    assert ctx.stats == [(60.0, {"taken": 2})]


def test_a_stop_request_ends_the_loop_with_the_counters_published() -> None:
    ctx = FakeContext("nav-lqr")
    thread, status = serve_in_thread(ctx, Recording(ctx, done_at=1e9))
    wait_subscribed(ctx)
    deliver(ctx, clock(0.0))
    ctx.stop.set()
    thread.join(timeout=10)
    assert status == [0] and ctx.stats[-1][1]["taken"] in (0, 1)


def test_an_input_the_topology_does_not_give_the_service_is_refused_at_start() -> None:
    ctx = FakeContext("ctrl-lqr")
    component = Recording(ctx)
    component.inputs = (Listen(nav_state_topic("other"), "nav"),)
    with pytest.raises(ValueError, match="topology does not give it"):
        ServiceHost(ctx).react(component)
    assert ctx.alive == 0  # never declared alive
