"""The controller's phases: the moves the transition table allows, and an error naming the
phases for any other."""

from __future__ import annotations

import pytest

from services.config import load_deployment
from services.flight.control import Controller
from services.flight.phases import Phase, PhaseMachine, PhaseTransitionError


def test_a_learner_explores_learns_relearns_and_learns_again() -> None:
    phases = PhaseMachine(Phase.EXPLORING)
    assert phases.exploring
    for to, exploring in ((Phase.LEARNED, False), (Phase.RELEARNING, True), (Phase.LEARNED, False)):
        phases.move(to)
        assert phases.current is to and phases.exploring is exploring


@pytest.mark.parametrize(
    ("start", "to"),
    [
        (Phase.LQR, Phase.LEARNED),
        (Phase.EXPLORING, Phase.RELEARNING),
        (Phase.LEARNED, Phase.EXPLORING),
        (Phase.LEARNED, Phase.LEARNED),
        (Phase.RELEARNING, Phase.EXPLORING),
    ],
)
def test_an_illegal_move_raises_and_leaves_the_phase(start: Phase, to: Phase) -> None:
    phases = PhaseMachine(start)
    with pytest.raises(PhaseTransitionError, match=f"phase {start} cannot move to {to}"):
        phases.move(to)
    assert phases.current is start


def test_the_controller_reports_its_phase_as_a_word() -> None:
    """Status messages and reports carry the phase as a plain string."""
    dep = load_deployment(None)
    lqr, ddvi = Controller(dep, "lqr"), Controller(dep, "ddvi")
    assert type(lqr.phase) is str and lqr.phase == "lqr" and not lqr.exploring
    assert type(ddvi.phase) is str and ddvi.phase == "exploring" and ddvi.exploring
    with pytest.raises(PhaseTransitionError, match="from lqr it may move to: none"):
        lqr.phases.move(Phase.LEARNED)
    assert lqr.collector is None and ddvi.collector is ddvi.learner.store
