"""A learner whose input is held at the attitude limit: the actuation counts the steps at the
limit, a first attempt on such data flies the fallback at once, and the fallback explores on
its own gains and learns once its command is off the limit with time left to fly a gain."""

from __future__ import annotations

import numpy as np
import pytest

from services.config import DeploymentError, deployment_from_table, read_table
from services.flight import learners
from services.flight.actuation import Actuation
from services.flight.control import Controller
from services.flight.inprocess import run_in_process
from services.flight.phases import Gains, Phase, Schedule
from services.flight.relearning import Relearning
from services.model import duration, lqr_gains


def _realistic(orbits: float, factor: float = 1.0, **learning) -> object:
    """``realistic-nav``'s LQR and model-fit deputies, the truth's density and every deputy's
    facet ``factor`` times the model's."""
    table = read_table("realistic-nav")
    table["run"]["orbits"] = orbits
    table["environment"]["density_factor"] = factor
    table["deputy"] = [d for d in table["deputy"] if d["name"] in ("lqr", "fit")]
    for d in table["deputy"]:
        d["area_factor"] = factor
    table["deputy"][1]["learning"].update(learning)
    return deployment_from_table(table, "realistic-nav")


def test_the_actuation_counts_the_steps_whose_input_is_out_of_reach() -> None:
    dep = _realistic(1.0)
    act = Actuation(dep, "fit")
    h = dep.chief.a - 6378137.0
    for k, u in enumerate([0.0, 0.05, 5.0, -5.0, 0.05]):
        act.allocate(60.0 * k, u, h)
    assert act.at_limit == [False, False, True, True, False]
    assert act.fraction_at_limit(0.0, 240.0) == pytest.approx(0.4)
    assert act.fraction_at_limit(120.0, 180.0) == 1.0  # both ends included
    assert act.fraction_at_limit(240.0, 240.0) == 0.0
    assert act.fraction_at_limit(300.0, 900.0) == 0.0  # no step


@pytest.mark.integration  # a 6.2-orbit mission
def test_a_first_attempt_on_data_at_the_attitude_limit_flies_the_fallback_at_once() -> None:
    """At 0.82x K0's command asks for more drag than the facet makes through the whole
    exploration: the attempt at orbit 6 fails and the fallback flies from that step, not
    after retries on K0 to learn_until_orbits (12)."""
    dep = _realistic(6.2, 0.82)
    out = run_in_process(dep)
    ctrl = out["fit"]["controller"]
    assert ctrl.learning.learn_attempts == 1 and not ctrl.learning.learned_at
    assert ctrl.phase == "fallback" and ctrl.learning.saturated_fallback
    assert ctrl.learning.fallback_at[0] / ctrl.orbit == pytest.approx(6.0, abs=0.02)
    np.testing.assert_array_equal(ctrl.K, lqr_gains(dep, ctrl.deputy)[0])
    log = out["fit"]["log"][0]
    assert "the attitude was at its limit in 100% of the steps it learned from" in log, log
    assert "flying the fallback" in log


@pytest.mark.integration  # the same, where the fraction asked is above what the data show
def test_below_the_saturated_fraction_a_failed_attempt_explores_on() -> None:
    dep = _realistic(6.2, 1.0, fit_tolerance=1e-6)
    out = run_in_process(dep)
    ctrl = out["fit"]["controller"]
    assert ctrl.phase == "exploring" and not ctrl.learning.fallback_at
    assert out["fit"]["log"][0].endswith("exploring on"), out["fit"]["log"][0]
    start = ctrl.learning.learning_window(6.0 * ctrl.orbit)
    assert ctrl.actuation.fraction_at_limit(start, 6.0 * ctrl.orbit) < 0.9


def _exploring_at_the_limit(
    orbits: float = 40.0, off: int = 0, **learning
) -> tuple[Controller, float]:
    """A model-fit controller that has explored to orbit 6 (s) with every command out of reach
    but its last ``off``, due to attempt then."""
    ctrl = Controller(_realistic(orbits, **learning), "fit")
    steps = int(6 * ctrl.orbit // 60) + 1
    for k in range(steps):
        ctrl.actuation.allocate(60.0 * k, 5.0 if k < steps - off else 0.01, ctrl.actuation.h_model)
    return ctrl, 60.0 * (steps - 1)


def _on_saturated_fallback(orbits: float = 40.0, **learning) -> tuple[Controller, float]:
    """The same, on the fallback its failed attempt at orbit 6 (s) took."""
    ctrl, t = _exploring_at_the_limit(orbits, **learning)
    ctrl.learning.learning_failed(t, "no gain")
    assert ctrl.phase == "fallback" and ctrl.learning.saturated_fallback
    return ctrl, t


def _fly_off_the_limit(ctrl: Controller, start: float, end: float) -> None:
    for t in np.arange(start, end + 1.0, 60.0):
        ctrl.actuation.allocate(float(t), 0.01, ctrl.actuation.h_model)


@pytest.mark.parametrize(("off", "phase"), [(0, "fallback"), (1, "exploring")])
def test_a_failed_attempt_falls_back_at_once_from_the_saturated_fraction_on(
    off: int, phase: str
) -> None:
    """At saturated_fraction = 1: every step at the limit is enough, one step off is not."""
    ctrl, t = _exploring_at_the_limit(off=off, saturated_fraction=1.0)
    log = ctrl.learning.learning_failed(t, "no gain")
    assert ctrl.phase == phase and ctrl.learning.saturated_fallback is (off == 0)
    if off == 0:
        assert "at its limit in 100% of the steps it learned from" in log, log
        assert ctrl.learning.fallback_at == [t] and ctrl.source == "lqr"
    else:
        assert log.endswith("exploring on") and ctrl.next_attempt > t


def test_a_failed_re_learning_does_not_take_the_saturated_fallback() -> None:
    ctrl, t = _exploring_at_the_limit()
    phases = ctrl.phases
    phases.move(Phase.LEARNED, Gains(ctrl.K, ctrl.L, "model-fit"))
    before = Relearning(ctrl.K, ctrl.L, ctrl.exosystem, 0.0, None, (20, 20), 0.0, ctrl.orbit)
    phases.move(Phase.RELEARNING, Gains(ctrl.K, ctrl.L, "initial"), Schedule(0.0, t), before)
    log = ctrl.learning.learning_failed(t, "no gain")
    assert ctrl.phase == "relearning" and before.failures == 1 and not ctrl.learning.fallback_at
    assert log.endswith("exploring on")


def test_the_fallback_explores_on_its_own_gains_once_off_the_limit_for_an_orbit() -> None:
    ctrl, t0 = _on_saturated_fallback()
    orbit, fallback = ctrl.orbit, ctrl.phases.gains
    t = t0 + 60.0 * round(1.5 * orbit / 60.0)
    _fly_off_the_limit(ctrl, t0 + 60.0, t)
    assert ctrl.actuation.steps[-1][0] == t
    ctrl.actuation.at_limit[:] = [False] * len(ctrl.actuation.at_limit)
    assert ctrl.learning.resume_on_fallback(t0 + 0.5 * orbit) is None  # an orbit after, not before
    ctrl.actuation.at_limit[-10] = True  # a step at the limit in the last orbit
    assert ctrl.learning.resume_on_fallback(t) is None
    ctrl.actuation.at_limit[-10] = False
    explored = ctrl.learner.store
    ctrl.watch.record(60.0, np.zeros(4), 0.2, np.zeros(ctrl.exosystem[1].shape[0]))  # K0's
    v = np.array([1.0, 1.0, 0.0, 1.0, 0.0])
    log = ctrl.tick(t, np.zeros(4), v, ctrl.actuation.h_model)
    assert log is not None and "exploring on the fallback" in log
    assert ctrl.phase == "exploring-on-fallback" and ctrl.exploring
    assert ctrl.phases.gains is fallback and ctrl.source == "lqr"
    assert ctrl.collect_from == ctrl.actuation.first_acting_step(t)
    assert ctrl.next_attempt == pytest.approx(t + 3.0 * orbit)
    assert ctrl.learning.resume_until == pytest.approx(duration(ctrl.dep) - 3.0 * orbit)
    assert ctrl.learner.store is not explored  # the data from K0's exploration are not kept
    assert not ctrl.watch.samples  # nor are its samples, for the change detector
    assert ctrl.learning.resumed_at == [t]


def test_a_failed_attempt_on_the_fallback_retries_while_a_gain_would_fly_then_falls_back() -> None:
    ctrl, t0 = _on_saturated_fallback()
    orbit, cycle = ctrl.orbit, ctrl.learning
    t = t0 + 60.0 * round(1.5 * orbit / 60.0)
    _fly_off_the_limit(ctrl, t0 + 60.0, t)
    assert cycle.resume_on_fallback(t) is not None
    first = ctrl.next_attempt
    log = cycle.learning_failed(first, "no gain")
    assert log.endswith("exploring on the fallback") and ctrl.phase == "exploring-on-fallback"
    assert ctrl.next_attempt == pytest.approx(first + 0.5 * orbit)  # retry_orbits
    last = cycle.resume_until - 0.25 * orbit  # its retry would come past resume_until
    log = cycle.learning_failed(last, "no gain")
    assert "no gain validated on the fallback" in log and ctrl.phase == "fallback"
    assert cycle.fallback_at == [t0, last]


def test_the_fallback_explores_once_only() -> None:
    """A retry past the end (retry_orbits = 30) falls back at the first failed attempt, with
    time left to explore again: it does not."""
    ctrl, t0 = _on_saturated_fallback(retry_orbits=30.0)
    orbit, cycle = ctrl.orbit, ctrl.learning
    t = t0 + 60.0 * round(1.5 * orbit / 60.0)
    _fly_off_the_limit(ctrl, t0 + 60.0, t)
    assert cycle.resume_on_fallback(t) is not None
    cycle.learning_failed(ctrl.next_attempt, "no gain")
    assert ctrl.phase == "fallback" and len(cycle.fallback_at) == 2
    later = cycle.fallback_at[-1] + 2 * orbit
    _fly_off_the_limit(ctrl, cycle.fallback_at[-1] + 60.0, later)
    assert later + 6 * orbit <= duration(ctrl.dep)  # time enough, off the limit: only once
    assert ctrl.actuation.fraction_at_limit(later - orbit, later) == 0.0
    assert cycle.resume_on_fallback(later) is None and ctrl.phase == "fallback"


@pytest.mark.parametrize(("on_fallback", "tolerance"), [(False, 0.15), (True, 0.4)])
def test_an_attempt_on_the_fallback_takes_its_own_tolerance(
    monkeypatch: pytest.MonkeyPatch, on_fallback: bool, tolerance: float
) -> None:
    ctrl = Controller(_realistic(40.0, resume_fit_tolerance=0.4), "fit")
    taken: list[float] = []

    def fit_attempt(data, lrn, problem, exosystem, translation, tol, holdout):
        taken.append(tol)
        return None, {"rank": 1, "needed": 2}, "refused"

    monkeypatch.setattr(learners, "fit_attempt", fit_attempt)
    attempt = ctrl.learner.learn(None, ctrl.exosystem, 6 * ctrl.orbit, on_fallback)
    assert taken == [tolerance] and attempt.refused == "did not converge (refused)"


@pytest.mark.parametrize(
    ("why", "learning", "saturated"),
    [
        ("too late: twice the window ends past the mission", {"resume_window_orbits": 18}, True),
        ("never with a window of 0", {"resume_window_orbits": 0}, True),
        ("not after a fallback on data that varied", {}, False),
    ],
)
def test_the_fallback_does_not_explore(why: str, learning: dict, saturated: bool) -> None:
    ctrl, t0 = _on_saturated_fallback(**learning)
    ctrl.learning.saturated_fallback = saturated
    t = t0 + 2 * ctrl.orbit
    _fly_off_the_limit(ctrl, t0 + 60.0, t)
    assert ctrl.learning.resume_on_fallback(t) is None, why
    assert ctrl.phase == "fallback"


@pytest.mark.parametrize(
    ("key", "value", "message"),
    [
        ("saturated_fraction", 0.0, r"saturated_fraction: must lie in \(0, 1\]"),
        ("saturated_fraction", 1.5, r"saturated_fraction: must lie in \(0, 1\]"),
        ("resume_window_orbits", -1.0, "resume_window_orbits: must be >= 0"),
    ],
)
def test_bad_fallback_keys_name_the_key(key: str, value: float, message: str) -> None:
    with pytest.raises(DeploymentError, match=message):
        _realistic(6.0, **{key: value})


@pytest.mark.integration  # a 40-orbit mission, two deputies: about 8 s
def test_through_the_storm_the_fallback_learns_on_station_and_ends_closer_than_the_lqr() -> None:
    """`storm`: K0 is at the limit to orbit 6 (the chief's drag is 1.25x the model's), so the
    learner flies its fallback from there, which holds the LQR's 640 m offset; once on station
    it explores on the fallback, learns the drag the model lacks and ends closer."""
    table = read_table("storm")
    table["deputy"] = [d for d in table["deputy"] if d["name"] in ("lqr", "fit")]
    out = run_in_process(deployment_from_table(table, "storm"))
    ctrl = out["fit"]["controller"]
    cycle, orbit = ctrl.learning, ctrl.orbit
    assert cycle.fallback_at[0] / orbit == pytest.approx(6.0, abs=0.02)
    (resumed,) = cycle.resumed_at
    assert resumed >= cycle.fallback_at[0] + orbit and resumed + 6 * orbit <= 40 * orbit
    assert ctrl.actuation.fraction_at_limit(resumed - orbit, resumed) == 0.0
    assert ctrl.phase == "learned" and ctrl.source == "model-fit"
    assert resumed + 3 * orbit - 60.0 <= cycle.learned_at[0] <= 37 * orbit
    assert any("exploring on the fallback from" in line for line in out["fit"]["log"])
    fit, lqr = abs(out["fit"]["x"][-1][1]), abs(out["lqr"]["x"][-1][1])
    assert fit < 0.5 * lqr, (fit, lqr)
