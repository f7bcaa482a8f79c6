"""A navigation outage, the worked example of a fault added in one component: declared and
checked in the deployment, flown by navigation (no measurement, no noise drawn, the filter's
prediction, not valid) and by the control loop (no command and no learning on a sample that
is not valid; the safe attitude past the stale limit)."""

from __future__ import annotations

import re
import tomllib
from types import SimpleNamespace

import numpy as np
import pytest

from services.config import DeploymentError, deployment_from_table
from services.flight.control import Controller
from services.flight.control_loop import ControlLoop, Step
from services.flight.relative_navigation import RelativeNavigation
from services.model import initial_states, orbit_period

SHORT = """
[run]
orbits = 2.0
[[deputy]]
name = "lqr"
controller = "lqr"
navigation = {position_noise = 1.0, velocity_noise = 1e-3}
"""


def _deployment(**fault: object):
    table = tomllib.loads(SHORT)
    if fault:
        table["fault"] = [{"kind": "outage", "deputy": "lqr", **fault}]
    return deployment_from_table(table)


@pytest.mark.parametrize(
    ("fault", "said"),
    [
        ({"at_orbits": 0.5, "duration_orbits": 0.0}, "fault[0].duration_orbits: an outage lasts"),
        ({"at_orbits": 0.5, "duration_orbits": float("nan")}, "must be finite, got nan"),
        ({"at_orbits": 0.0, "duration_orbits": 0.1}, "an outage starts after the first"),
        ({"at_orbits": 0.5, "duration_orbits": 0.1, "deputy": "x"}, "'x' is not one of lqr"),
    ],
)
def test_a_bad_outage_is_refused_in_one_line(fault: dict, said: str) -> None:
    with pytest.raises(DeploymentError, match=re.escape(said)):
        _deployment(**fault)


def test_duration_belongs_to_outages_only() -> None:
    table = tomllib.loads(SHORT)
    table["fault"] = [{"kind": "bias", "deputy": "lqr", "at_orbits": 0.5, "duration_orbits": 1}]
    with pytest.raises(DeploymentError, match="duration_orbits belongs to outage faults"):
        deployment_from_table(table)


def _measure(dep, times: np.ndarray) -> list:
    """Navigation's samples at ``times`` of the craft held at their initial states (what is
    measured does not matter here, only whether and how)."""
    nav = RelativeNavigation(dep, dep.deputy[0])
    chief, deputy = initial_states(dep)[:2]
    return [nav.measure(float(t), chief, deputy) for t in times]


def test_navigation_measures_nothing_during_an_outage() -> None:
    """Samples in [start, end) are not valid, carry the filter's prediction with a growing
    covariance, and draw no noise: the first measurement after the outage is the draw the
    first sample of the outage would have had."""
    period = orbit_period(_deployment())
    start, end = 0.5 * period, 0.6 * period
    dep = _deployment(at_orbits=0.5, duration_orbits=0.1)
    times = np.arange(0.0, 0.7 * period, 10.0)
    faulted, clean = _measure(dep, times), _measure(_deployment(), times)
    valid = np.array([s.valid for s in faulted])
    assert np.array_equal(~valid, (times >= start) & (times < end))
    out = np.flatnonzero(~valid)
    cov = [np.trace(faulted[k].cov) for k in out]
    assert np.all(np.diff(cov) > 0) and cov[0] > np.trace(faulted[out[0] - 1].cov)
    assert faulted[out[0]].outage is not None and faulted[out[0]].outage.value == pytest.approx(end)
    for k in out:
        assert np.array_equal(faulted[k].z, faulted[k].x)  # nothing measured: the estimate
    first_after = out[-1] + 1
    noise_after = faulted[first_after].z - faulted[first_after].truth
    noise_at_start = clean[out[0]].z - clean[out[0]].truth
    assert np.allclose(noise_after, noise_at_start, rtol=0, atol=1e-9)


def _loop(**run: float) -> ControlLoop:
    dep = _deployment()
    settings = {"fsw_period": 60.0, "nav_stale_limit": 0.0, **run}
    return ControlLoop(Controller(dep, "lqr"), SimpleNamespace(**settings), delay=0.0)


def _feed(loop: ControlLoop, t: float, valid: bool, y: float = -100.0) -> list:
    x = np.array([0.0, y, 0.0, 0.0])
    loop.nav(t, x, 300e3, x, valid)
    loop.exo(t, np.array([1.0, 0.0, 0.0, 0.0, 0.0]))
    return list(loop.advance(lambda T: t + 1e-6 >= T, None))


def test_the_control_loop_flies_on_valid_samples_only_and_safe_past_the_stale_limit() -> None:
    loop = _loop()
    steps = [s for t in range(0, 130, 10) for s in _feed(loop, float(t), True)]
    flown = [s for s in steps if isinstance(s, Step)]
    assert [s.T for s in flown] == [0.0, 60.0, 120.0] and not any(s.safe for s in flown)
    # the outage: from 130 s nothing valid; a prediction of a far-off state must not be flown
    out = [s for t in range(130, 310, 10) for s in _feed(loop, float(t), False, y=5e4)]
    flown = [s for s in out if isinstance(s, Step)]
    assert [(s.T, s.safe) for s in flown] == [(180.0, False), (240.0, False), (300.0, True)]
    assert flown[0].sigma == flown[1].sigma  # both on the sample of 120 s
    said = [s.text for s in out if not isinstance(s, Step)]
    assert said == [
        "ctrl-lqr at t = 300 s: navigation 180 s old (limit 120 s): flying the safe attitude"
    ]
    assert loop.counters["invalid_samples"] == 18 and loop.counters["safe_attitude_steps"] == 1
    back = [s for s in _feed(loop, 310.0, True) + _feed(loop, 360.0, True) if isinstance(s, Step)]
    assert [(s.T, s.safe) for s in back] == [(360.0, False)]


def test_a_restarted_loop_waits_for_its_first_sample_then_flies_from_the_step_it_can() -> None:
    """Restarted into a running mission, the loop has no step until a sample comes: advancing
    before it flies nothing (and raises nothing); the first sample sets the first step."""
    dep = _deployment()
    run = SimpleNamespace(fsw_period=60.0, nav_stale_limit=0.0)
    loop = ControlLoop(Controller(dep, "lqr"), run, delay=0.0, joining=True)
    assert list(loop.advance(lambda T: True, None)) == []
    out = _feed(loop, 610.0, True)
    assert [s.T for s in out if isinstance(s, Step)] == []  # the step at 660 s is its first
    assert loop.next_tick == 660.0 and out[0].text.startswith("restarted: flying the LQR gains")
    assert [s.T for s in _feed(loop, 660.0, True) if isinstance(s, Step)] == [660.0]
