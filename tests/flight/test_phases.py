"""The controller's phases: the moves the transition table allows, the gains each phase may
fly, the schedule an exploring phase has and what re-learning keeps, and an error naming the
phases for any other."""

from __future__ import annotations

import numpy as np
import pytest

from services.config import load_deployment
from services.flight.control import Controller
from services.flight.phases import (
    EXPLORING_PHASES,
    Gains,
    Phase,
    PhaseMachine,
    PhaseTransitionError,
    Schedule,
)
from services.flight.relearning import Relearning

K0 = Gains(np.zeros((1, 4)), np.zeros((1, 2)), "initial")
LEARNED = Gains(np.ones((1, 4)), np.ones((1, 2)), "ddvi")
LQR = Gains(K0.K, K0.L, "lqr")
FLOWN = {
    Phase.LQR: LQR,
    Phase.EXPLORING: K0,
    Phase.RELEARNING: K0,
    Phase.FALLBACK: LQR,
    Phase.EXPLORING_ON_FALLBACK: LQR,
}
SCHEDULE = Schedule(collect_from=0.0, next_attempt=1000.0)
BEFORE = Relearning(LEARNED.K, LEARNED.L, (), 500.0, None, (20, 20), 600.0, 400.0)


def _args(phase: Phase) -> tuple:
    """What entering ``phase`` takes: its gains, an exploring phase's schedule, and what
    re-learning keeps of before."""
    schedule = SCHEDULE if phase in EXPLORING_PHASES else None
    before = BEFORE if phase is Phase.RELEARNING else None
    return FLOWN.get(phase, LEARNED), schedule, before


def _machine(start: Phase) -> PhaseMachine:
    gains, schedule, _ = _args(start)
    if start is not Phase.RELEARNING:
        return PhaseMachine(start, gains, schedule)
    phases = PhaseMachine(Phase.EXPLORING, K0, SCHEDULE)
    phases.move(Phase.LEARNED, LEARNED)
    phases.move(Phase.RELEARNING, *_args(Phase.RELEARNING))
    return phases


def test_a_learner_explores_learns_relearns_and_learns_again() -> None:
    phases = PhaseMachine(Phase.EXPLORING, K0, SCHEDULE)
    assert phases.exploring and not phases.converged and phases.schedule is SCHEDULE
    for to, exploring in ((Phase.LEARNED, False), (Phase.RELEARNING, True), (Phase.LEARNED, False)):
        gains, schedule, before = _args(to)
        phases.move(to, gains, schedule, before)
        assert phases.current is to and phases.exploring is exploring
        assert phases.gains is gains and phases.converged is not exploring
        assert phases.schedule is schedule and phases.before is before


@pytest.mark.parametrize("start", [Phase.EXPLORING, Phase.RELEARNING])
def test_a_learner_with_no_gain_validated_falls_back_to_the_lqr_gains_and_explores_only_on_them(
    start: Phase,
) -> None:
    phases = _machine(start)
    phases.move(Phase.FALLBACK, LQR)
    assert phases.current is Phase.FALLBACK and phases.gains is LQR
    assert phases.converged and not phases.exploring and phases.schedule is None
    for to in set(Phase) - {Phase.EXPLORING_ON_FALLBACK}:  # K0 again only after a restart
        with pytest.raises(
            PhaseTransitionError, match="from fallback it may move to: exploring-on-fallback"
        ):
            phases.move(to, *_args(to))


@pytest.mark.parametrize("outcome", [Phase.LEARNED, Phase.FALLBACK])
def test_a_fallback_explores_on_its_own_gains_and_learns_or_falls_back_again(
    outcome: Phase,
) -> None:
    phases = _machine(Phase.FALLBACK)
    phases.move(Phase.EXPLORING_ON_FALLBACK, LQR, SCHEDULE)
    assert phases.exploring and not phases.converged
    assert phases.gains is LQR and phases.schedule is SCHEDULE and phases.before is None
    phases.move(outcome, *_args(outcome))
    assert phases.current is outcome and phases.gains is FLOWN.get(outcome, LEARNED)
    assert phases.converged and phases.schedule is None


def test_an_exploring_phase_has_a_schedule_and_only_re_learning_keeps_what_flew_before() -> None:
    with pytest.raises(PhaseTransitionError, match="phase exploring needs a learning schedule"):
        PhaseMachine(Phase.EXPLORING, K0)
    with pytest.raises(PhaseTransitionError, match="phase lqr has no learning schedule"):
        PhaseMachine(Phase.LQR, FLOWN[Phase.LQR], SCHEDULE)
    phases = PhaseMachine(Phase.EXPLORING, K0, SCHEDULE)
    phases.reschedule(next_attempt=2000.0)  # a retry: the phase and its gains unchanged
    assert phases.schedule == Schedule(0.0, 2000.0) and phases.gains is K0
    phases.move(Phase.LEARNED, LEARNED)
    with pytest.raises(PhaseTransitionError, match="phase learned has no schedule"):
        phases.reschedule(next_attempt=3000.0)
    with pytest.raises(PhaseTransitionError, match="only re-learning, keeps the gains"):
        phases.move(Phase.RELEARNING, K0, SCHEDULE)  # without what flew before
    assert phases.current is Phase.LEARNED


@pytest.mark.parametrize(
    ("start", "to"),
    [
        (Phase.LQR, Phase.LEARNED),
        (Phase.EXPLORING, Phase.RELEARNING),
        (Phase.LEARNED, Phase.EXPLORING),
        (Phase.LEARNED, Phase.LEARNED),
        (Phase.RELEARNING, Phase.EXPLORING),
        (Phase.FALLBACK, Phase.EXPLORING),
        (Phase.FALLBACK, Phase.LEARNED),
        (Phase.LEARNED, Phase.FALLBACK),
        (Phase.EXPLORING, Phase.EXPLORING_ON_FALLBACK),
        (Phase.LEARNED, Phase.EXPLORING_ON_FALLBACK),
        (Phase.EXPLORING_ON_FALLBACK, Phase.EXPLORING),
        (Phase.EXPLORING_ON_FALLBACK, Phase.RELEARNING),
    ],
)
def test_an_illegal_move_raises_and_leaves_the_phase(start: Phase, to: Phase) -> None:
    phases = _machine(start)
    with pytest.raises(PhaseTransitionError, match=f"phase {start} cannot move to {to}"):
        phases.move(to, *_args(to))
    assert phases.current is start


@pytest.mark.parametrize(
    ("phase", "source"),
    [
        (Phase.LQR, "ddvi"),
        (Phase.EXPLORING, "lqr"),
        (Phase.LEARNED, "initial"),
        (Phase.FALLBACK, "ddvi"),
        (Phase.FALLBACK, "initial"),
        (Phase.EXPLORING_ON_FALLBACK, "initial"),
    ],
)
def test_a_phase_flies_only_gains_of_its_own_source(phase: Phase, source: str) -> None:
    with pytest.raises(PhaseTransitionError, match=f"phase {phase} cannot fly '{source}' gains"):
        PhaseMachine(phase, Gains(K0.K, K0.L, source), _args(phase)[1])


def test_a_trim_changes_the_feedforward_gain_alone() -> None:
    phases = PhaseMachine(Phase.EXPLORING, K0, SCHEDULE)
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
