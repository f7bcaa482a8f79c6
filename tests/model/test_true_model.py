"""The truth's own linear model and its optimal gains (``true_problem``, ``true_lqr_gains``):
the reference a learned gain is scored against."""

from __future__ import annotations

import numpy as np
import pytest

from services.config import deployment_from_table, load_deployment, read_table
from services.model import (
    lqr_gains,
    nominal_problem,
    orbit_mean_density,
    true_lqr_gains,
    true_problem,
)

# K* of the truth's linear model of deployments/mismatch-2x.toml (truth density and the
# deputies' facet area 2x the nominal): the Riccati gain at 4x the nominal B.
MISMATCH_2X_K = np.array([-0.0118, 3.7e-4, -1.167, -5.33])


def test_true_gains_equal_the_nominal_lqr_gains_when_the_truth_is_nominal() -> None:
    dep = load_deployment("rendezvous")
    for deputy in dep.deputy:
        K, L = lqr_gains(dep, deputy)
        K_true, L_true = true_lqr_gains(dep, deputy)
        np.testing.assert_allclose(K_true, K, rtol=1e-12)
        np.testing.assert_allclose(L_true, L, rtol=1e-12, atol=1e-15)


def test_mismatch_2x_true_gain_is_the_truth_models_not_the_nominal() -> None:
    dep = load_deployment("mismatch-2x")
    deputy = dep.deputy[0]
    K_true, _ = true_lqr_gains(dep, deputy)
    np.testing.assert_allclose(K_true[0], MISMATCH_2X_K, rtol=0.02)
    K_nominal, _ = lqr_gains(dep, deputy)
    gap = np.linalg.norm(K_nominal - K_true) / np.linalg.norm(K_true)
    assert gap == pytest.approx(0.68, abs=0.02)  # a perfect learner scored against nominal


def test_true_model_scales_the_input_by_density_and_area_and_carries_the_drag_offset() -> None:
    dep = load_deployment("mismatch-2x")
    deputy = dep.deputy[0]
    pr, pr0 = true_problem(dep, deputy), nominal_problem(dep, deputy)
    assert pr.B[3, 0] == pytest.approx(4.0 * pr0.B[3, 0], rel=1e-12)
    # twice the deputy's area at twice the density: the deputy's extra drag, as much as the
    # chief's whole drag at the truth's density, pulls it back along track
    assert pr.D[3, 0] < 0 and np.count_nonzero(pr.D) == 1
    # the feedforward turns the facet away to cancel it: sigma3 = -(1 - 1/2) tan(45 deg) / 4
    _, L_true = true_lqr_gains(dep, deputy)
    assert L_true[0, 0] == pytest.approx(-0.125, rel=1e-6)


def test_no_drag_in_the_truth_has_no_optimal_gain() -> None:
    table = read_table(None)
    table["environment"]["drag"] = False
    dep = deployment_from_table(table, "test")
    with pytest.raises(ValueError, match="no drag"):
        true_lqr_gains(dep, dep.deputy[0])


def test_under_nrlmsis_the_true_model_takes_the_orbit_mean_density_and_its_scale_height() -> None:
    from ddvi_core.constants import R_EARTH
    from services.model.msis import MsisDensity

    dep = load_deployment("msis")
    deputy = dep.deputy[0]
    rho, H = orbit_mean_density(dep)
    # NRLMSIS's own density at 16 points around the chief's orbit plane at time 0
    angles = np.linspace(0.0, 2 * np.pi, 16, endpoint=False)
    raan, inc = np.radians(dep.chief.raan), np.radians(dep.chief.i)
    u = angles + np.radians(dep.chief.argp)
    r = dep.chief.a * np.column_stack(
        (
            np.cos(raan) * np.cos(u) - np.sin(raan) * np.sin(u) * np.cos(inc),
            np.sin(raan) * np.cos(u) + np.cos(raan) * np.sin(u) * np.cos(inc),
            np.sin(u) * np.sin(inc),
        )
    )
    direct = MsisDensity.from_deployment(dep).density(np.zeros(16), r).mean()
    assert rho == pytest.approx(direct, rel=1e-9)
    assert 30e3 < H < 80e3  # NRLMSIS at 300 km, not the nominal model's 8 km
    pr, pr0 = true_problem(dep, deputy), nominal_problem(dep, deputy)
    ratio = rho / dep.atmosphere.rho0 * np.exp((dep.chief.a - R_EARTH - 300e3) / 8e3)
    assert pr.B[3, 0] == pytest.approx(ratio * pr0.B[3, 0], rel=1e-9)  # the input: the density
    assert pr.A[3, 0] != pytest.approx(pr0.A[3, 0], rel=0.1)  # the gradient: its scale height
    K_true, _ = true_lqr_gains(dep, deputy)
    K, _ = lqr_gains(dep, deputy)
    assert not np.allclose(K_true, K, rtol=1e-3)
    # the exponential truth is untouched by it: K* of a nominal truth is the LQR's
    exp = deployment_from_table({**read_table("msis"), "atmosphere": {}})
    np.testing.assert_allclose(
        true_lqr_gains(exp, exp.deputy[0])[0], lqr_gains(exp, exp.deputy[0])[0]
    )
