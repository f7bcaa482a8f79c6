"""What navigation and the controller both do with their input streams: pair the messages of
two topics measured at the same time, hold faults until they are due, and end the run a grace
period after the final clock if the last messages never come.
"""

from __future__ import annotations

import time
from collections.abc import Hashable
from typing import Any, Generic, NamedTuple, TypeVar

from services.interface import Message

END_GRACE = 2.0
"""Wall seconds a service waits, after the final clock, for a message its link may have lost."""

T = TypeVar("T")


class SamplePairs:
    """Messages of several parts (topics) held by measurement time until every part of that
    time has arrived.

    Parameters
    ----------
    parts : the keys a complete sample has, e.g. ``("chief", "lqr")`` or ``("nav", "exo")``.
    """

    def __init__(self, parts: tuple[Hashable, ...]) -> None:
        self.parts = parts
        self.pending: dict[float, dict[Hashable, Any]] = {}

    def add(self, t: float, part: Hashable, value: Any) -> dict[Hashable, Any] | None:
        """Hold ``value`` as ``part`` of the sample measured at ``t`` (a repeat replaces it);
        return the sample, ``{part: value}``, once it is complete, and forget it."""
        slot = self.pending.setdefault(t, {})
        slot[part] = value
        if all(p in slot for p in self.parts):
            del self.pending[t]
            return slot
        return None

    def forget_before(self, t: float) -> list[dict[Hashable, Any]]:
        """Drop the incomplete samples measured before ``t`` (their partner was lost, or they
        repeat one already used) and return them, oldest held first."""
        stale = [s for s in self.pending if s < t]
        return [self.pending.pop(s) for s in stale]


class Fault(NamedTuple, Generic[T]):
    """A fault waiting to be applied: its time (s; ``-inf``: at the next step), what it sets,
    and where it came from, for the log ("scheduled", "from <service>")."""

    t: float
    value: T
    origin: str


class FaultQueue(Generic[T]):
    """The faults a service has still to apply: the deployment's, at their times, and the
    ground's, at the next step."""

    def __init__(self, scheduled: list[tuple[float, T]]) -> None:
        self.waiting: list[Fault[T]] = [Fault(t, value, "scheduled") for t, value in scheduled]

    def from_ground(self, value: T, src: str) -> None:
        """A fault the ground sent (from service ``src``): applied at the next step."""
        self.waiting.append(Fault(-float("inf"), value, f"from {src}"))

    def pop_due(self, t: float) -> list[Fault[T]]:
        """Remove and return the faults due at ``t``, in the order they were queued."""
        due = [f for f in self.waiting if f.t <= t + 1e-6]
        self.waiting = [f for f in self.waiting if f.t > t + 1e-6]
        return due


class FinalClock:
    """The final clock message, once seen, and the grace period after it: a service whose last
    inputs were lost on their links stops ``END_GRACE`` wall seconds after it."""

    def __init__(self) -> None:
        self.t: float | None = None  # simulation time of the final clock
        self.seen = 0.0  # wall time (monotonic s) it arrived

    def on_clock(self, msg: Message) -> None:
        if msg.body["final"]:
            self.t, self.seen = msg.t, time.monotonic()

    def grace_over(self) -> bool:
        return self.t is not None and time.monotonic() - self.seen > END_GRACE
