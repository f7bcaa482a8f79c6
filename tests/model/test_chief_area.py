"""A chief whose ballistic coefficient differs from the model's (``chief.area_factor``, a
non-cooperative object): the truth flies it in the truth's craft, the truth's linear model,
the holding margin and the re-entry prediction; the controllers' nominal model never knows it."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ddvi_core.constants import MU_EARTH
from ddvi_core.models import drag_sensitivity
from services.config import DeploymentError, deployment_from_table, load_deployment, read_table
from services.model import (
    chief_decay,
    holding_margin,
    holding_warnings,
    lqr_gains,
    nominal_problem,
    open_truth,
    true_problem,
    truth_craft,
)

FACTOR = 1.3


def _with_chief(factor: float | None, name: str | None = None, **environment):
    """``name`` (default: the default deployment) with the chief's area_factor ``factor``
    (None: the key left out)."""
    table = read_table(name)
    if factor is not None:
        table.setdefault("chief", {})["area_factor"] = factor
    table.setdefault("environment", {}).update(environment)
    return deployment_from_table(table, "test")


def test_the_default_chief_is_the_nominal_design() -> None:
    dep = load_deployment("rendezvous")
    assert dep.chief.area_factor == 1.0
    assert truth_craft(dep)[0].area == dep.spacecraft.area
    assert _with_chief(None) == _with_chief(1.0)


def test_the_truths_chief_flies_its_true_area() -> None:
    dep = _with_chief(FACTOR)
    craft = truth_craft(dep)
    assert craft[0].area == pytest.approx(FACTOR * dep.spacecraft.area, rel=1e-15)
    assert [c.area for c in craft[1:]] == [dep.spacecraft.area] * len(dep.deputy)


def test_the_truths_model_carries_the_chiefs_extra_drag_in_d() -> None:
    """The chief's extra drag pulls it back along track, the deputy relatively forward:
    D[3, 0] = +1/2 rho v^2 (f_c - 1) beta, beta the nominal ballistic coefficient; the rest of
    the truth's model and the nominal model as with a nominal chief."""
    dep, dep0 = _with_chief(FACTOR), _with_chief(1.0)
    deputy = dep.deputy[0]
    pr, pr0 = true_problem(dep, deputy), true_problem(dep0, dep0.deputy[0])
    sc = dep.spacecraft
    beta, _ = drag_sensitivity(sc.mass, sc.area, sc.cd, math.radians(sc.normal_angle))
    rho = dep.atmosphere.rho0 * math.exp(-(dep.chief.a - 6378137.0 - dep.atmosphere.h_ref) / 8e3)
    v = math.sqrt(MU_EARTH / dep.chief.a**3) * dep.chief.a
    expected = 0.5 * rho * v**2 * (FACTOR - 1.0) * beta
    shift = pr.D - pr0.D
    assert shift[3, 0] > 0 and np.count_nonzero(shift) == 1
    assert shift[3, 0] == pytest.approx(expected, rel=0.02)  # rho at the model's own altitude
    np.testing.assert_array_equal(pr.A, pr0.A)
    np.testing.assert_array_equal(pr.B, pr0.B)
    # the controllers are never told
    np.testing.assert_array_equal(nominal_problem(dep, deputy).D, nominal_problem(dep0, deputy).D)
    np.testing.assert_array_equal(lqr_gains(dep, deputy)[1], lqr_gains(dep0, deputy)[1])


def test_the_holding_margin_falls_by_the_chiefs_factor() -> None:
    dep, dep0 = _with_chief(FACTOR), _with_chief(1.0)
    for d, d0 in zip(dep.deputy, dep0.deputy, strict=True):
        assert 1.0 + holding_margin(dep, d) == pytest.approx(
            (1.0 + holding_margin(dep0, d0)) / FACTOR, rel=1e-12
        )


def _chief_energy_lost(factor: float, steps: int = 10) -> float:
    """The chief's specific orbital energy lost over ``steps`` flight-software steps of the
    built-in truth, two-body and drag (no J2: the two-body energy is drag's alone)."""
    dep = _with_chief(factor, j2=False, density_factor=10.0)
    truth = open_truth(dep)
    try:
        sigma = np.zeros((len(dep.deputy), 3))

        def energy(rv: np.ndarray) -> float:
            return 0.5 * float(rv[3:] @ rv[3:]) - MU_EARTH / float(np.linalg.norm(rv[:3]))

        start = energy(truth.state[0])
        for k in range(steps):
            truth.step(k * dep.run.fsw_period, sigma)
        return start - energy(truth.state[0])
    finally:
        truth.close()


def test_the_truths_chief_decays_faster_by_its_factor() -> None:
    lost, lost0 = _chief_energy_lost(FACTOR), _chief_energy_lost(1.0)
    assert lost0 > 0
    assert lost / lost0 == pytest.approx(FACTOR, rel=1e-3)


def test_the_reentry_prediction_takes_the_chiefs_true_area() -> None:
    """At 20x the density the default chief re-enters in the 40 orbits; 1.3x its area brings
    the re-entry earlier, about as 1.3x the density would."""
    t = chief_decay(_with_chief(1.0, density_factor=20.0)).t_reentry
    t_area = chief_decay(_with_chief(FACTOR, density_factor=20.0)).t_reentry
    t_density = chief_decay(_with_chief(1.0, density_factor=20.0 * FACTOR)).t_reentry
    assert t_area < t
    assert t_area == pytest.approx(t_density, rel=1e-3)


@pytest.mark.parametrize("bad", [0.0, -1.0, math.nan, math.inf, 1e9])
def test_a_chief_area_factor_out_of_range_is_refused_naming_the_key(bad: float) -> None:
    with pytest.raises(DeploymentError, match=r"^chief\.area_factor: .*"):
        _with_chief(bad)


def test_a_deputys_orbit_has_no_area_factor() -> None:
    table = read_table(None)
    table["deputy"][0]["orbit"] = {"area_factor": 1.3}
    with pytest.raises(DeploymentError, match=r"deputy\[0\]\.orbit\.area_factor: unknown key"):
        deployment_from_table(table, "test")


def test_a_chief_with_more_drag_than_any_deputy_can_match_is_warned_of() -> None:
    """At 1.5x the chief's area the deputies' largest drag (their facet broadside within the
    attitude limit: 1/sin 45 deg of the nominal exposure) falls short of it."""
    warnings = holding_warnings(_with_chief(1.5))
    assert len(warnings) == 2
    assert all("chief's (its area factor 1.5)" in w and "6% below" in w for w in warnings)
    assert holding_warnings(_with_chief(FACTOR)) == []
