"""The service host: what runs one flight component on the bus, for every flight service alike.

A hosted component declares what it takes (``Listen``, ``Watch``: each checked against the
topology access control is made from, ``services.flight.inputs``) and says what it does with
each message; the host subscribes, declares the service alive, runs the main loop, gives up
with the exit status that names the silent service when lock-step hangs (``HangError``), and
publishes the final counters, whatever ends the run.

Two kinds of component are hosted:

- a ``Reactive`` one acts on what arrives (navigation, a controller): the host reads the inbox
  in order, hands each entry to ``take`` and, once the inbox is empty, lets it run what can run
  now (``settle``); it ends when the component is ``done`` with the mission's final clock, when
  a stop is requested, or ``END_GRACE`` wall seconds after the final clock if the last inputs
  were lost on their links;
- a ``Driver`` sets the pace itself (the environment, the time master): the host hands it the
  inbox and it flies to the end.

    def main(ctx: ServiceContext) -> int:
        return ServiceHost(ctx).react(NavigationService(ctx))
"""

from __future__ import annotations

import contextlib
import queue
from dataclasses import dataclass
from typing import Any, Protocol

from services.flight.health import HangError
from services.flight.inputs import PRESENCE, Inputs
from services.flight.runtime import ServiceContext
from services.flight.streams import FinalClock


@dataclass(frozen=True)
class Listen:
    """A subscription: ``topic`` (a pattern) for messages of ``schema``; ``accounted``: also
    what its link has delivered, held or dropped, and the rate budget's drops (a lock-step
    wait counts them); ``tag``: the inbox entry's tag instead of the topic (``Inputs.listen``)."""

    topic: str
    schema: str
    accounted: bool = False
    tag: str = ""


@dataclass(frozen=True)
class Watch:
    """The liveliness of the services ``pattern`` names, as ``(tag, (service, up))`` entries."""

    pattern: str
    tag: str = PRESENCE


class Hosted(Protocol):
    """What every hosted component declares."""

    inputs: tuple[Listen | Watch, ...]
    ready_at_start: bool  # alive once subscribed; False: it declares itself alive later

    def finish(self) -> tuple[float, dict[str, int]]:
        """Publish what closes the run for it; return the time and the counters of its final
        stats."""
        ...


class Reactive(Hosted, Protocol):
    """A component that acts on what arrives."""

    batched: bool  # what one pass over the inbox publishes leaves as one zenoh sample a topic

    def poll(self) -> float:
        """Wall seconds to wait for an entry before ``settle`` runs anyway (a wait may end by
        time alone: a service's absence, a step's deadline)."""
        ...

    def start(self) -> None:
        """Publish what opens the run, once subscribed."""
        ...

    def take(self, kind: str, msg: Any) -> None:
        """One inbox entry: ``(topic, message)`` or ``(tag, payload)``."""
        ...

    def settle(self, final_t: float | None) -> None:
        """The inbox is empty: run what can run now (``final_t``: the final clock's time, once
        seen)."""
        ...

    def done(self, final_t: float | None) -> bool:
        """Whether the component has done the mission up to its final clock."""
        ...


class Driver(Hosted, Protocol):
    """A component that sets the pace itself."""

    def fly(self, inbox: queue.SimpleQueue) -> int:
        """Fly the mission, reading ``inbox``; return the exit status."""
        ...


class ServiceHost:
    """Runs one component on the bus of ``ctx``: its inputs, liveliness, main loop, hang and
    final stats.

    Parameters
    ----------
    ctx : the service's context (its bus, deployment, stop request, log).
    """

    def __init__(self, ctx: ServiceContext) -> None:
        self.ctx = ctx
        self.final = FinalClock()

    def react(self, component: Reactive) -> int:
        """Run a reactive component until its mission is done; returns its exit status."""
        return self._host(component, lambda inbox: self._react(component, inbox))

    def drive(self, component: Driver) -> int:
        """Run a driver until it has flown; returns its exit status."""
        return self._host(component, component.fly)

    def _host(self, component: Hosted, body: Any) -> int:
        inputs = Inputs(self.ctx)
        try:
            for entry in component.inputs:
                if isinstance(entry, Watch):
                    inputs.watch(entry.pattern, entry.tag)
                else:
                    inputs.listen(
                        entry.topic, entry.schema, accounted=entry.accounted, tag=entry.tag
                    )
            if component.ready_at_start:
                self.ctx.ready()
            try:
                status = body(inputs.inbox)
            except HangError as exc:
                status = self.ctx.give_up(exc)
            t, counters = component.finish()
            self.ctx.publish_stats(t, counters)
            return status
        finally:
            inputs.close()

    def _react(self, component: Reactive, inbox: queue.SimpleQueue) -> int:
        ctx, final = self.ctx, self.final
        component.start()
        while not ctx.stop.is_set():
            try:
                kind, msg = inbox.get(timeout=component.poll())
            except queue.Empty:
                if final.grace_over():
                    break  # the last inputs were lost on their links: nothing more will come
                component.settle(final.t)
                if component.done(final.t):
                    break
                continue
            with ctx.bus.batch() if component.batched else contextlib.nullcontext():
                while True:
                    if getattr(msg, "schema", None) == "clock":
                        final.on_clock(msg)
                    component.take(kind, msg)
                    try:
                        kind, msg = inbox.get_nowait()
                    except queue.Empty:
                        break
                component.settle(final.t)
            if component.done(final.t):
                break
        return 0
