"""A learner whose input is held at the attitude limit: the actuation counts the steps at the
limit, a first attempt on such data flies the fallback at once, and the fallback explores on
its own gains and learns once its command is off the limit with time left to fly a gain."""

from __future__ import annotations

import numpy as np
import pytest

from services.config import DeploymentError, deployment_from_table, read_table
from services.flight.actuation import Actuation
from services.flight.control import Controller
from services.flight.inprocess import run_in_process
from services.model import lqr_gains


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


def _on_saturated_fallback(orbits: float = 40.0, **learning) -> tuple[Controller, float]:
    """A model-fit controller flying the fallback it took on saturated data at orbit 6 (s),
    its commands at the limit to then."""
    ctrl = Controller(_realistic(orbits, **learning), "fit")
    for k in range(int(6 * ctrl.orbit // 60) + 1):
        ctrl.actuation.allocate(60.0 * k, 5.0, ctrl.actuation.h_model)
    t_fallback = 60.0 * k
    ctrl.learning.saturated_fallback = True
    ctrl.learning.fall_back(t_fallback, "no gain")
    return ctrl, t_fallback


def _fly_off_the_limit(ctrl: Controller, start: float, end: float) -> None:
    for t in np.arange(start, end + 1.0, 60.0):
        ctrl.actuation.allocate(float(t), 0.01, ctrl.actuation.h_model)


def test_the_fallback_explores_on_its_own_gains_once_off_the_limit_for_an_orbit() -> None:
    ctrl, t0 = _on_saturated_fallback()
    orbit, fallback = ctrl.orbit, ctrl.phases.gains
    t = t0 + 60.0 * round(1.5 * orbit / 60.0)
    _fly_off_the_limit(ctrl, t0 + 60.0, t)
    assert ctrl.actuation.steps[-1][0] == t
    assert ctrl.learning.resume_on_fallback(t0 + 0.5 * orbit) is None  # an orbit after, not before
    ctrl.actuation.at_limit[-10] = True  # a step at the limit in the last orbit
    assert ctrl.learning.resume_on_fallback(t) is None
    ctrl.actuation.at_limit[-10] = False
    explored = ctrl.learner.store
    ctrl.watch.record(60.0, np.zeros(4), 0.2, np.zeros(ctrl.exosystem[1].shape[0]))  # K0's
    log = ctrl.learning.resume_on_fallback(t)
    assert log is not None and "exploring on the fallback" in log
    assert ctrl.phase == "exploring-on-fallback" and ctrl.exploring
    assert ctrl.phases.gains is fallback and ctrl.source == "lqr"
    assert ctrl.phases.schedule.next_attempt == pytest.approx(t + 3.0 * orbit)
    assert ctrl.learning.resume_until == pytest.approx(40.0 * orbit - 3.0 * orbit)
    assert ctrl.learner.store is not explored  # the data from K0's exploration are not kept
    assert not ctrl.watch.samples  # nor are its samples, for the change detector
    assert ctrl.learning.resumed_at == [t]


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
