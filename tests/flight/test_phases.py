"""The controller's phases: the moves the transition table allows, the gains each phase may
fly, and an error naming the phases for any other."""

from __future__ import annotations

import numpy as np
import pytest

from services.config import load_deployment
from services.flight.control import Controller
from services.flight.phases import Gains, Phase, PhaseMachine, PhaseTransitionError

K0 = Gains(np.zeros((1, 4)), np.zeros((1, 2)), "initial")
LEARNED = Gains(np.ones((1, 4)), np.ones((1, 2)), "ddvi")
FLOWN = {Phase.LQR: Gains(K0.K, K0.L, "lqr"), Phase.EXPLORING: K0, Phase.RELEARNING: K0}


def test_a_learner_explores_learns_relearns_and_learns_again() -> None:
    phases = PhaseMachine(Phase.EXPLORING, K0)
    assert phases.exploring and not phases.converged
    for to, exploring in ((Phase.LEARNED, False), (Phase.RELEARNING, True), (Phase.LEARNED, False)):
        gains = FLOWN.get(to, LEARNED)
        phases.move(to, gains)
        assert phases.current is to and phases.exploring is exploring
        assert phases.gains is gains and phases.converged is not exploring


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
    phases = PhaseMachine(start, FLOWN.get(start, LEARNED))
    with pytest.raises(PhaseTransitionError, match=f"phase {start} cannot move to {to}"):
        phases.move(to, FLOWN.get(to, LEARNED))
    assert phases.current is start


@pytest.mark.parametrize(
    ("phase", "source"),
    [(Phase.LQR, "ddvi"), (Phase.EXPLORING, "lqr"), (Phase.LEARNED, "initial")],
)
def test_a_phase_flies_only_gains_of_its_own_source(phase: Phase, source: str) -> None:
    with pytest.raises(PhaseTransitionError, match=f"phase {phase} cannot fly '{source}' gains"):
        PhaseMachine(phase, Gains(K0.K, K0.L, source))


def test_a_trim_changes_the_feedforward_gain_alone() -> None:
    phases = PhaseMachine(Phase.EXPLORING, K0)
    phases.move(Phase.LEARNED, LEARNED)
    phases.trim(np.full((1, 2), 0.5))
    assert phases.current is Phase.LEARNED and phases.gains.source == "ddvi"
    assert phases.gains.K is LEARNED.K and np.array_equal(phases.gains.L, [[0.5, 0.5]])


def test_the_controller_reports_its_phase_as_a_word() -> None:
    """Status messages and reports carry the phase as a plain string."""
    dep = load_deployment(None)
    lqr, ddvi = Controller(dep, "lqr"), Controller(dep, "ddvi")
    assert type(lqr.phase) is str and lqr.phase == "lqr" and not lqr.exploring
    assert type(ddvi.phase) is str and ddvi.phase == "exploring" and ddvi.exploring
    assert (lqr.source, lqr.converged, ddvi.source, ddvi.converged) == (
        "lqr",
        True,
        "initial",
        False,
    )
    with pytest.raises(PhaseTransitionError, match="from lqr it may move to: none"):
        lqr.phases.move(Phase.LEARNED, LEARNED)
    assert lqr.collector is None and ddvi.collector is ddvi.learner.store
