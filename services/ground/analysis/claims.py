"""What a service says of itself, checked: its ``stats/<service>`` counters against what the
ground received from it and against what is possible.

A service's stats message is its own word on its counters (``sent``, ``steps``, ...); the report
sums them over the service's processes.  The ground believes a claim only when it can be true:

- counters are counts: never below zero, and never lower than the same process said before.  A
  process is its bus's boot (``Message.boot``): a restarted one has a new boot and counts from
  0 again.  In a recording without boots (every boot 0), a ``sent`` lower than before
  starts a new process;
- ``sent`` is at most what the service's topics' rate budgets (``services.bus.budget``: each key
  ``BUDGET_BURST`` messages at once and ``BUDGET_SLACK`` times its topology rate, sustained)
  let through in the simulated time flown, plus what the ground dropped from it unread;
- ``sent`` is at most what the ground received from that process, plus what it dropped from it
  unread, plus one batch in flight (``MAX_BATCH``, for all the service's processes together).
  A stats message counts what its process put before it, goes out on the same session and is
  never batched: on a reliable bus what it counts is there before it (docs/health.md);
- a counter of flight-software steps (``STEP_COUNTERS``) is at most the steps flown.

A claim that is not possible is never believed: the service's figures stay what its last
possible stats said (a report never shows the claim as a figure, nor a loss made of it), and
the claim is counted by publisher, counter and reason (``impossible``: summary.json's
``outcome.impossible``, report.md's outcome, and ``ddvi run`` exits 3 for a completed mission).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

from services.config import Deployment
from services.flight.runtime import rate_budget
from services.interface import MAX_BATCH, Message
from services.interface.topics import budget_period, stats_topic

log = logging.getLogger("ddvi.monitor")

IN_FLIGHT = MAX_BATCH
"""Messages a service's stats may count that have not reached the ground yet: one batch."""
STEP_COUNTERS = {"steps": 1, "paused_steps": 1, "safe_attitude_steps": 1}
"""Counters that grow by at most this many a flight-software step (``controller_away_steps``:
one a deputy, see ``step_limit``)."""
STEP_MARGIN = 2  # steps a service may be ahead of the clock the ground has seen
LAUNCHER = "launcher"  # publishes stats too, from the router's session
MAX_KINDS = 64  # (publisher, counter, reason) kinds listed; more are counted together
MAX_SESSIONS = 64  # processes a service may have had; a claim of one more is impossible
MAX_NAME = 80  # characters of a counter's name kept for the report
OTHERS = "(others)"

REASONS = {
    "negative": "a count below zero",
    "decreased": "lower than the {limit:,} the same process said before (counters never go down)",
    "budget": "more than its topics' rate budgets let through in the {flown:,.0f} s flown "
    "({limit:,} at most)",
    "unseen": "{unseen:,} more than the ground received from it and it can have lost "
    "({limit:,} at most in flight or dropped unread)",
    "steps": "more than the {limit:,} flight-software steps flown",
    "unknown": "from a service this run does not have",
    "sessions": f"from more than {MAX_SESSIONS} processes",
}
"""Why a claim is impossible, in words (``limit``, ``flown``, ``unseen`` filled in)."""


@dataclass
class Impossible:
    """One kind of impossible claim: who claimed what, the largest figure, the limit it broke,
    how many times and when first."""

    src: str
    counter: str
    reason: str
    claimed: int
    limit: int
    received: int  # messages the ground had received from ``src`` then
    count: int
    first_t: float
    text: str


@dataclass(frozen=True)
class Finding:
    """An impossible figure: the counter, why (a key of ``REASONS``), the figure claimed (for
    ``sent``, summed over the service's processes) and the limit it broke."""

    counter: str
    reason: str
    claimed: int
    limit: int
    flown: float = 0.0  # simulated seconds flown, for "budget"
    unseen: int = 0  # messages the claim would make lost, for "unseen"

    @property
    def text(self) -> str:
        return REASONS[self.reason].format(limit=self.limit, flown=self.flown, unseen=self.unseen)


def _no_drops(_publisher: str) -> int:
    return 0


class Claims:
    """Every service's stats, each believed only when possible (see the module's docstring).

    Parameters
    ----------
    dep : the deployment (its services, topics, periods and deputies).
    run : the run's name.
    dropped : messages the ground's rate budget has dropped unread from a publisher so far
        (None: none).
    """

    def __init__(
        self, dep: Deployment, run: str, dropped: Callable[[str], int] | None = None
    ) -> None:
        self.dropped = dropped or _no_drops
        self.fsw = dep.run.fsw_period
        self.deputies = len(dep.deputy)
        budget = rate_budget(dep, run)
        shortest = min(budget.periods.values())
        # per service: (messages its keys may send at once, messages a simulated second),
        # each key as the receivers' RateBudget buckets it
        self.budgets: dict[str, tuple[float, float]] = {}
        for topic in dep.topics():  # the run's topics, as the live view's
            owner = dep.publisher_of(topic)
            if owner is None:
                continue
            period = budget.periods.get(budget_period(topic) or "", shortest)
            burst, rate = self.budgets.get(owner, (0.0, 0.0))
            self.budgets[owner] = (burst + budget.burst, rate + budget.slack / period)
        self.known = {*dep.services, LAUNCHER}
        self.stats: dict[str, dict[str, int]] = {}  # service -> counters, all its processes
        self.stats_t: dict[str, float] = {}  # service -> latest t of its believed stats
        # service -> process -> its last believed counters; a process is (boot, n): n counts
        # the processes of a recording without boots (all boot 0)
        self.sessions: dict[str, dict[tuple[int, int], dict[str, int]]] = {}
        self.received: dict[tuple[str, int], int] = {}  # (publisher, boot) -> received
        self._boots: dict[str, int] = {}  # publisher -> its boots counted apart
        self.kinds: dict[tuple[str, str, str], Impossible] = {}

    # -- what was received --------------------------------------------------------------------

    def seen(self, msg: Message) -> None:
        """A message the ground received (and decoded) from ``msg.src``'s process ``msg.boot``,
        believed or not: a stats message, before its claim.  Counted for the run's services
        and their first ``MAX_SESSIONS`` boots each (a table no flood of invented names or
        boots grows); the rest together."""
        key = (msg.src, msg.boot)
        if (n := self.received.get(key)) is not None:  # a known publisher's counted boot
            self.received[key] = n + 1
            return
        if msg.src not in self.known:
            key = (OTHERS, 0)
        if key not in self.received:
            boots = self._boots.get(key[0], 0)
            if boots >= MAX_SESSIONS:
                key = (key[0], -1)
            else:
                self._boots[key[0]] = boots + 1
        self.received[key] = self.received.get(key, 0) + 1

    def received_from(self, service: str) -> int:
        return sum(n for (src, _), n in self.received.items() if src == service)

    # -- a claim ------------------------------------------------------------------------------

    def claim(self, msg: Message, sim_t: float) -> bool:
        """Take ``msg`` (a stats message its topic lets its publisher send, ``seen`` already)
        at the ground's simulated time ``sim_t``; whether it is believed (else it is counted as
        impossible and nothing of it is used)."""
        service, counters = str(msg.body["service"]), dict(msg.body["counters"])
        sessions = self.sessions.setdefault(service, {})
        process = self._process(sessions, msg.boot, counters)
        previous = sessions.get(process, {})
        if (found := self._impossible(service, process, previous, counters, sim_t)) is not None:
            self._count(msg, found)
            if not sessions:
                del self.sessions[service]
            return False
        sessions[process] = counters
        total: dict[str, int] = {}
        for said in sessions.values():
            for k, v in said.items():
                total[k] = total.get(k, 0) + v
        self.stats[service] = total
        self.stats_t[service] = max(msg.t, self.stats_t.get(service, -math.inf))
        return True

    def _process(
        self,
        sessions: Mapping[tuple[int, int], dict[str, int]],
        boot: int,
        counters: Mapping[str, int],
    ) -> tuple[int, int]:
        """The process ``counters`` come from: its boot, and (boot 0: a recording without
        boots) a new process when ``sent`` went down."""
        if boot != 0:
            return boot, 0
        n = max((k for b, k in sessions if b == 0), default=0)
        last = sessions.get((0, n))
        if last is not None and counters.get("sent", 0) < last.get("sent", 0):
            return 0, n + 1
        return 0, n

    def _impossible(
        self,
        service: str,
        process: tuple[int, int],
        previous: Mapping[str, int],
        counters: Mapping[str, int],
        sim_t: float,
    ) -> Finding | None:
        """The first impossible figure of ``counters``, or None."""
        if service not in self.known:
            return Finding("service", "unknown", 0, 0)
        if not previous and len(self.sessions.get(service, {})) >= MAX_SESSIONS:
            return Finding("service", "sessions", len(self.sessions[service]) + 1, MAX_SESSIONS)
        for name, value in counters.items():
            if value < 0:
                return Finding(name, "negative", value, 0)
        for name, before in previous.items():
            if counters.get(name, 0) < before:
                return Finding(name, "decreased", counters.get(name, 0), before)
        return self._sent_impossible(service, process, counters, sim_t) or self._steps_impossible(
            service, process, counters, sim_t
        )

    def _others(self, service: str, process: tuple[int, int], key: str) -> int:
        """``key`` summed over the service's other processes."""
        return sum(c.get(key, 0) for p, c in self.sessions.get(service, {}).items() if p != process)

    def _sent_impossible(
        self, service: str, process: tuple[int, int], counters: Mapping[str, int], sim_t: float
    ) -> Finding | None:
        sent = int(counters.get("sent", 0))
        if sent == 0:
            return None
        dropped = self.dropped(service)
        total = sent + self._others(service, process, "sent")
        burst, rate = self.budgets.get(service, (0.0, 0.0))
        most = math.floor(burst + rate * (max(sim_t, 0.0) + STEP_MARGIN * self.fsw)) + dropped
        if total > most:
            return Finding("sent", "budget", total, most, flown=max(sim_t, 0.0))
        allowed = IN_FLIGHT + dropped
        if (unseen := self._unrecorded(service, process, sent)) > allowed:
            return Finding("sent", "unseen", total, allowed, unseen=unseen)
        return None

    def _steps_impossible(
        self, service: str, process: tuple[int, int], counters: Mapping[str, int], sim_t: float
    ) -> Finding | None:
        steps = math.floor(max(sim_t, 0.0) / self.fsw + 1e-9) + STEP_MARGIN
        for name, value in counters.items():
            if (limit := step_limit(name, steps, self.deputies)) is None:
                continue
            if (total := value + self._others(service, process, name)) > limit:
                return Finding(name, "steps", total, limit)
        return None

    def _unrecorded(self, service: str, process: tuple[int, int], sent: int) -> int:
        """What the service's stats would say it sent and the ground never received, with
        ``sent`` the claim of ``process``."""
        said = {p: c.get("sent", 0) + 1 for p, c in self.sessions.get(service, {}).items()}
        said[process] = sent + 1  # and the stats message that claims it
        return sum(self._lost(service, said).values())

    def _lost(self, service: str, said: Mapping[tuple[int, int], int]) -> dict[int, int]:
        """Boot -> messages the processes of that boot said they sent, beyond those received
        (none below zero: a process killed before its final stats sent more than they say)."""
        by_boot: dict[int, int] = {}
        for (boot, _), n in said.items():
            by_boot[boot] = by_boot.get(boot, 0) + n
        return {
            boot: lost
            for boot, n in by_boot.items()
            if (lost := n - self.received.get((service, boot), 0)) > 0
        }

    def unrecorded(self) -> dict[str, int]:
        """Messages each service published that never reached the ground: what each process's
        last believed stats say it sent (its stats message not included, hence + 1) against
        what arrived from it.  A process killed before its final stats sent more than they
        say: this can hide a loss, never invent one."""
        lost = {}
        for service, sessions in self.sessions.items():
            said = {p: c.get("sent", 0) + 1 for p, c in sessions.items()}
            if n := sum(self._lost(service, said).values()):
                lost[service] = n
        return lost

    # -- the impossible -----------------------------------------------------------------------

    def _count(self, msg: Message, found: Finding) -> None:
        src, counter = msg.src[:MAX_NAME], found.counter[:MAX_NAME]
        key = (src, counter, found.reason)
        kind = self.kinds.get(key)
        if kind is None and len(self.kinds) >= MAX_KINDS:
            key = (OTHERS, OTHERS, found.reason)
            kind = self.kinds.get(key)
        received = self.received_from(msg.src)
        if kind is None:
            kind = self.kinds[key] = Impossible(
                *key, found.claimed, found.limit, received, 0, msg.t, found.text
            )
        elif found.claimed > kind.claimed:
            kind.claimed, kind.limit, kind.received = found.claimed, found.limit, received
            kind.text = found.text
        kind.count += 1
        if kind.count <= 10 or kind.count % 1000 == 0:
            said = f"{counter} = {found.claimed}, {found.text}"
            log.warning("impossible %s from %s: %s (#%d)", stats_topic(src), src, said, kind.count)

    def impossible(self) -> list[dict[str, Any]]:
        """Every kind of impossible claim, most frequent first, as summary.json holds them."""
        kinds = sorted(self.kinds.values(), key=lambda k: (-k.count, k.src, k.counter))
        return [vars(k).copy() for k in kinds]


def step_limit(counter: str, steps: int, deputies: int) -> int | None:
    """The most ``counter`` can be after ``steps`` flight-software steps, None when it is not a
    count of steps."""
    if counter == "controller_away_steps":
        return steps * max(deputies, 1)
    per_step = STEP_COUNTERS.get(counter)
    return None if per_step is None else steps * per_step
