"""The phases a deputy's controller flies in, and the one place it moves between them.

An LQR deputy stays in ``lqr``.  A learning deputy starts ``exploring`` (K0 and the
exploration, collecting for its learner), is ``learned`` once a gain is taken, and with
``learning.relearn`` goes ``relearning`` (K0 and the exploration again) when its change
detector sees the plant change; from there it is ``learned`` again, on the new gains or, when
re-learning fails too often, on the gains of before the detection.
"""

from __future__ import annotations

from enum import StrEnum


class Phase(StrEnum):
    """A controller's phase; its value is the word the status messages and reports carry."""

    LQR = "lqr"
    EXPLORING = "exploring"
    LEARNED = "learned"
    RELEARNING = "relearning"


TRANSITIONS: dict[tuple[Phase, Phase], str] = {
    (Phase.EXPLORING, Phase.LEARNED): "a learning attempt gave gains",
    (Phase.LEARNED, Phase.RELEARNING): "the change detector saw the plant change",
    (Phase.RELEARNING, Phase.LEARNED): "re-learning gave gains, or was abandoned",
}
"""Every move a controller may make, with what makes it; the LQR never moves."""


class PhaseTransitionError(RuntimeError):
    """A move the controller's phases do not allow: a bug in the controller, not bad input."""


class PhaseMachine:
    """The phase in force; :meth:`move` is the only way to change it."""

    def __init__(self, start: Phase) -> None:
        self.current = start

    def move(self, to: Phase) -> None:
        """Enter phase ``to``; raises PhaseTransitionError if TRANSITIONS has no such move."""
        if (self.current, to) not in TRANSITIONS:
            allowed = [str(b) for a, b in TRANSITIONS if a == self.current] or ["none"]
            raise PhaseTransitionError(
                f"controller phase {self.current!s} cannot move to {to!s} (from "
                f"{self.current!s} it may move to: {', '.join(allowed)})"
            )
        self.current = to

    @property
    def exploring(self) -> bool:
        """Flying K0 with the exploration and collecting for the learner: before the first
        learning or, after a detected change, before re-learning."""
        return self.current in (Phase.EXPLORING, Phase.RELEARNING)
