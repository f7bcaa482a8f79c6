"""The re-entry predicted before flight (``services.model.reentry_warnings``): the chief's
drag decay under the truth's atmosphere, warned of when it falls below
environment.min_altitude before the mission ends.  No flight: the flown orbits they are
checked against are in docs/atmosphere.md."""

from __future__ import annotations

import re

import pytest

from services.config import deployment_from_table, read_table
from services.model import chief_decay, orbit_period, reentry_problems, reentry_warnings


def _mismatched(name: str | None, factor: float, orbits: float, **environment):
    """``name`` as ``ddvi sweep noise --mismatch factor --orbits orbits`` flies it: the truth's
    density_factor and every deputy's area_factor times ``factor``."""
    table = read_table(name)
    env = table.setdefault("environment", {})
    env["density_factor"] = env.get("density_factor", 1.0) * factor
    env.update(environment)
    for d in table["deputy"]:
        d["area_factor"] = d.get("area_factor", 1.0) * factor
    table["run"]["orbits"] = orbits
    return deployment_from_table(table, "test")


def test_the_2_5x_mission_of_30_orbits_is_warned_of() -> None:
    """realistic-nav-2x at 1.25x (the truth's density 2.5x nominal) re-enters at orbit 27.2
    when flown; the prediction says about 26.6, of the mission's 30."""
    dep = _mismatched("realistic-nav-2x", 1.25, 30.0)
    ((craft, text),) = reentry_problems(dep)
    assert craft == "chief"
    orbit = float(re.search(r"at about orbit (\d+\.\d) of the mission's 30,", text)[1])
    assert 26.0 <= orbit <= 27.2
    assert "environment.min_altitude = 150 km" in text
    assert f"shorten run.orbits to at most {int(orbit)}" in text
    assert reentry_warnings(dep) == [text]


@pytest.mark.parametrize(
    ("name", "factor", "orbits"), [("realistic-nav-2x", 1.0, 30.0), (None, 1.0, 40.0)]
)
def test_missions_that_stay_up_are_not_warned_of(name: str | None, factor, orbits) -> None:
    dep = _mismatched(name, factor, orbits)
    assert reentry_warnings(dep) == []
    assert chief_decay(dep).altitude_end > 270e3


def test_a_mission_ending_before_the_predicted_reentry_is_not_warned_of() -> None:
    assert reentry_warnings(_mismatched("realistic-nav-2x", 1.25, 26.0)) == []


def test_no_drag_no_decay() -> None:
    dep = _mismatched("realistic-nav-2x", 1.25, 30.0, drag=False)
    assert chief_decay(dep) is None and reentry_warnings(dep) == []


def test_j2_brings_the_reentry_forward() -> None:
    """J2 holds the mean radius of an orbit started circular below its initial one: without it
    the same mission is predicted to re-enter about seven orbits later (flown: 27.3 with J2,
    33.8 without, the chief alone)."""
    with_j2 = chief_decay(_mismatched("realistic-nav-2x", 1.25, 40.0)).t_reentry
    without = chief_decay(_mismatched("realistic-nav-2x", 1.25, 40.0, j2=False)).t_reentry
    assert 5.0 < (without - with_j2) / orbit_period(_mismatched(None, 1.0, 40.0)) < 8.0


def test_nrlmsis_truth_is_predicted_from_its_own_density() -> None:
    """NRLMSIS at 15x: flown, the formation re-enters at orbit 28.2."""
    table = read_table(None)
    table["atmosphere"] = {"model": "nrlmsis"}
    table["environment"]["density_factor"] = 15.0
    dep = deployment_from_table(table, "test")
    orbit = chief_decay(dep).t_reentry / orbit_period(dep)
    assert 27.5 < orbit <= 28.2
    (text,) = reentry_warnings(dep)
    assert f"at about orbit {orbit:.1f} of the mission's 40" in text
