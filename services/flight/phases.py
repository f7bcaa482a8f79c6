"""The phases a deputy's controller flies in, and the one place it moves between them.

An LQR deputy stays in ``lqr``.  A learning deputy starts ``exploring`` (K0 and the
exploration, collecting for its learner), is ``learned`` once a gain is taken, and with
``learning.relearn`` goes ``relearning`` (K0 and the exploration again) when its change
detector sees the plant change; from there it is ``learned`` again, on the new gains or, when
re-learning fails too often, on the gains of before the detection.  Where no gain validates
(no first gain by ``learning.learn_until_orbits``, or an attempt at it on data whose input was
at the attitude limit; re-learning failed with ``learning.fallback = "lqr"``) it flies its
``fallback``, the nominal model's LQR gains: never K0's exploration, which holds no slot.  A
fallback taken on saturated data goes ``exploring-on-fallback`` (the fallback's gains and the
exploration) once its command leaves the limit with time left to learn, and from there is
``learned`` or back on the ``fallback`` to the end.  The phase in force holds
what it flies and when it learns: its gains (``Gains``: K, L and their source), an exploring
phase its ``Schedule`` (data from when, the next attempt when), re-learning what flew before
the detection (``Relearning``); so that no move changes one without the others.

The safe attitude is not a phase of the controller: it is what a step flies when navigation
is stale (``services.flight.control_loop.StaleNavigation``), whatever the phase, which goes
on (a learner explores on, and collects nothing it does not measure).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from enum import StrEnum

import numpy as np
from numpy.typing import NDArray

from services.flight.relearning import Relearning


class Phase(StrEnum):
    """A controller's phase; its value is the word the status messages and reports carry."""

    LQR = "lqr"
    EXPLORING = "exploring"
    LEARNED = "learned"
    RELEARNING = "relearning"
    FALLBACK = "fallback"
    EXPLORING_ON_FALLBACK = "exploring-on-fallback"


TRANSITIONS: dict[tuple[Phase, Phase], str] = {
    (Phase.EXPLORING, Phase.LEARNED): "a learning attempt gave gains",
    (Phase.EXPLORING, Phase.FALLBACK): (
        "no gain validated by learning.learn_until_orbits, or an attempt at the first gain "
        "failed on data whose input was at the attitude limit (learning.saturated_fraction)"
    ),
    (Phase.LEARNED, Phase.RELEARNING): "the change detector saw the plant change",
    (Phase.RELEARNING, Phase.LEARNED): "re-learning gave gains, or was abandoned",
    (Phase.RELEARNING, Phase.FALLBACK): 're-learning was abandoned with learning.fallback = "lqr"',
    (Phase.FALLBACK, Phase.EXPLORING_ON_FALLBACK): (
        "the fallback, taken on saturated data, has held its command off the attitude limit "
        "for an orbit, with twice learning.resume_window_orbits left"
    ),
    (Phase.EXPLORING_ON_FALLBACK, Phase.LEARNED): "a learning attempt on the fallback gave gains",
    (Phase.EXPLORING_ON_FALLBACK, Phase.FALLBACK): (
        "no gain validated on the fallback while one would still fly "
        "learning.resume_window_orbits before the end"
    ),
}
"""Every move a controller may make, with what makes it; the LQR never moves."""


SOURCES: dict[Phase, str] = {
    Phase.LQR: "lqr",
    Phase.EXPLORING: "initial",
    Phase.RELEARNING: "initial",
    Phase.FALLBACK: "lqr",
    Phase.EXPLORING_ON_FALLBACK: "lqr",
}
"""The source of the gains each phase but ``learned`` flies; ``learned`` flies any other (a
learner's name, or "fallback")."""


EXPLORING_PHASES = (Phase.EXPLORING, Phase.RELEARNING, Phase.EXPLORING_ON_FALLBACK)
"""The phases that fly the exploration on K0 (on the fallback's gains: exploring-on-fallback)
and collect for the learner: they have a ``Schedule``."""


class PhaseTransitionError(RuntimeError):
    """A move the controller's phases do not allow: a bug in the controller, not bad input."""


@dataclass(frozen=True)
class Gains:
    """What a phase flies, u = -K x + L v: K (1, n), L (1, q), and where they came from (a
    ``gains`` message's source: "lqr", "initial" for K0 while exploring, the learner's name,
    or "fallback" for the gains of before a re-learning that failed)."""

    K: NDArray[np.float64]
    L: NDArray[np.float64]
    source: str


@dataclass(frozen=True)
class Schedule:
    """When an exploring phase learns: the learner takes the samples from ``collect_from`` on
    and attempts at ``next_attempt`` (s; inf: no more attempts)."""

    collect_from: float
    next_attempt: float


class PhaseMachine:
    """The phase in force, the gains it flies, an exploring phase's schedule and, while
    re-learning, what flew before; :meth:`move` is the only way to change the phase, and it
    changes them all.  Whether the gains are converged follows from the phase."""

    def __init__(self, start: Phase, gains: Gains, schedule: Schedule | None = None) -> None:
        self._enter(start, gains, schedule, None)

    def move(
        self,
        to: Phase,
        gains: Gains,
        schedule: Schedule | None = None,
        before: Relearning | None = None,
    ) -> None:
        """Enter phase ``to`` flying ``gains``, with the ``schedule`` an exploring phase has
        and, into ``relearning``, what flew ``before``; raises PhaseTransitionError if
        TRANSITIONS has no such move or the phase does not fly gains of that source."""
        if (self.current, to) not in TRANSITIONS:
            allowed = [str(b) for a, b in TRANSITIONS if a == self.current] or ["none"]
            raise PhaseTransitionError(
                f"controller phase {self.current!s} cannot move to {to!s} (from "
                f"{self.current!s} it may move to: {', '.join(allowed)})"
            )
        self._enter(to, gains, schedule, before)

    def _enter(
        self, to: Phase, gains: Gains, schedule: Schedule | None, before: Relearning | None
    ) -> None:
        if (to in EXPLORING_PHASES) != (schedule is not None):
            needs = "needs a" if to in EXPLORING_PHASES else "has no"
            raise PhaseTransitionError(f"controller phase {to!s} {needs} learning schedule")
        if (to is Phase.RELEARNING) != (before is not None):
            raise PhaseTransitionError(
                "re-learning, and only re-learning, keeps the gains flown before the detection"
            )
        self.gains = self._checked(to, gains)
        self.current, self.schedule, self.before = to, schedule, before

    def reschedule(self, **changes: float) -> None:
        """An exploring phase's schedule changed (``collect_from``, ``next_attempt``): a
        retry, or a restart into a running mission; the phase and its gains unchanged."""
        if self.schedule is None:
            raise PhaseTransitionError(f"controller phase {self.current!s} has no schedule")
        self.schedule = dataclasses.replace(self.schedule, **changes)

    def trim(self, L: NDArray[np.float64]) -> None:
        """The feedforward gain trimmed on station: the phase, K and the source unchanged."""
        self.gains = dataclasses.replace(self.gains, L=L)

    @staticmethod
    def _checked(phase: Phase, gains: Gains) -> Gains:
        own = SOURCES.get(phase)
        theirs = gains.source == own if own is not None else gains.source not in SOURCES.values()
        if not theirs:
            raise PhaseTransitionError(
                f"controller phase {phase!s} cannot fly {gains.source!r} gains"
            )
        return gains

    @property
    def converged(self) -> bool:
        """Flying gains that are not explored on: the LQR's, learned ones or the fallback."""
        return self.current in (Phase.LQR, Phase.LEARNED, Phase.FALLBACK)

    @property
    def exploring(self) -> bool:
        """Flying the exploration and collecting for the learner: on K0 before the first
        learning or, after a detected change, before re-learning; on the fallback's gains once
        a fallback taken on saturated data is off the limit."""
        return self.current in EXPLORING_PHASES
