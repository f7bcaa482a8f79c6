"""Tests of ddvi_core.decay: the drag decay of a near-circular orbit against its closed form
and against the truth's own propagation, and its input checks."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ddvi_core.constants import MU_EARTH, R_EARTH
from ddvi_core.decay import drag_decay
from ddvi_core.orbit import elements_to_rv
from ddvi_core.truth import Atmosphere, Spacecraft, propagate

A0 = R_EARTH + 300e3
RHO0, H, B = 5e-11, 8e3, 0.0156  # kg/m^3 at A0, m, m^2/kg


def _held(a: float) -> float:
    """An exponential density times sqrt(A0 / a): with it rho B sqrt(mu a) is
    k exp(-(a - A0) / H), k = RHO0 B sqrt(mu A0), whose decay has a closed form."""
    return RHO0 * math.exp(-(a - A0) / H) * math.sqrt(A0 / a)


K = RHO0 * B * math.sqrt(MU_EARTH * A0)


def test_reentry_time_is_the_closed_form_of_the_exponential_case() -> None:
    # d/dt exp((a - A0)/H) = -k/H, so a reaches a1 at t = H/k (1 - exp((a1 - A0)/H))
    out = drag_decay(A0, B, lambda t, a: _held(a), 1e6, min_altitude=150e3, rtol=1e-9)
    expected = H / K * (1.0 - math.exp((R_EARTH + 150e3 - A0) / H))
    assert out.t_reentry == pytest.approx(expected, rel=1e-6)
    assert out.t_end == out.t_reentry and out.altitude_end == pytest.approx(150e3)


def test_altitude_at_the_horizon_is_the_closed_form() -> None:
    horizon = 0.5 * H / K
    out = drag_decay(A0, B, lambda t, a: _held(a), horizon, min_altitude=150e3, rtol=1e-9)
    assert out.t_reentry is None and out.t_end == horizon
    assert out.a_end == pytest.approx(A0 + H * math.log(1.0 - K * horizon / H), abs=0.01)
    assert out.altitude_end == pytest.approx(out.a_end - R_EARTH)


def test_prediction_matches_the_truth_propagation_with_big_drag() -> None:
    """A Hill-pointing craft, facet normal at 45 deg (exposure sin 45), no J2, twenty times
    the nominal density: the truth falls below 150 km within half an orbit after the
    prediction (the prediction's circular decay outruns the last, plunging orbit)."""
    craft = Spacecraft(mass=6.0, area=0.06, cd=2.2, normal_B=(math.sqrt(0.5), math.sqrt(0.5), 0))
    atm = Atmosphere(rho0=2.2e-11, h_ref=300e3, scale_height=8e3, density_factor=20.0)
    period = 2.0 * math.pi * math.sqrt(A0**3 / MU_EARTH)
    predicted = drag_decay(
        A0,
        craft.ballistic * math.sqrt(0.5),
        lambda t, a: float(atm.density(np.array([a, 0.0, 0.0]))),
        20 * period,
        min_altitude=150e3,
    ).t_reentry
    r, v = elements_to_rv(A0, 0.0, math.radians(45.0), 0.0, 0.0, 0.0)
    x, t, flown = np.concatenate((r, v))[None], 0.0, None
    while flown is None and t < 20 * period:
        times = t + np.arange(10.0, 601.0, 10.0)
        traj = propagate(x, t, t + 600.0, np.eye(3)[None], craft, atm, attitude_frame="hill",
                         j2=False, t_eval=times)  # fmt: skip
        low = np.linalg.norm(traj[:, 0, :3], axis=1) < R_EARTH + 150e3
        flown = times[np.argmax(low)] if low.any() else None
        x, t = traj[-1], t + 600.0
    assert predicted is not None and flown is not None
    assert 0.0 <= (flown - predicted) / period < 0.5
    assert 3.0 < predicted / period < 6.0  # a re-entry within a few orbits


def test_no_drag_and_an_orbit_at_the_floor() -> None:
    out = drag_decay(A0, 0.0, lambda t, a: 1.0, 1e5, min_altitude=150e3)
    assert out.t_reentry is None and out.a_end == A0 and out.evaluations == 0
    out = drag_decay(R_EARTH + 100e3, B, lambda t, a: 1.0, 1e5, min_altitude=150e3, t0=7.0)
    assert out.t_reentry == 7.0


@pytest.mark.parametrize(
    ("args", "kwargs", "match"),
    [
        ((R_EARTH - 1.0, B, _held, 1e5), {}, "a0 must exceed r_planet"),
        ((math.nan, B, _held, 1e5), {}, "a0 must be finite"),
        ((A0, -1.0, _held, 1e5), {}, "ballistic must be non-negative"),
        ((A0, B, "rho", 1e5), {}, "density must be a callable"),
        ((A0, B, _held, 0.0), {}, "horizon must be positive"),
        ((A0, B, _held, 1e5), {"min_altitude": -1.0}, "min_altitude must be non-negative"),
        ((A0, B, _held, 1e5), {"mu": 0.0}, "mu and r_planet must be positive"),
        ((A0, B, _held, 1e5), {"rtol": 1.0}, "rtol must be in"),
    ],
)
def test_bad_input_is_refused(args: tuple, kwargs: dict, match: str) -> None:
    kwargs = {"min_altitude": 150e3, **kwargs}
    with pytest.raises(ValueError, match=match):
        drag_decay(*args, **kwargs)


@pytest.mark.parametrize("rho", [-1e-12, math.nan, math.inf])
def test_a_density_that_is_negative_or_not_finite_is_refused(rho: float) -> None:
    with pytest.raises(ValueError, match="must be finite and non-negative"):
        drag_decay(A0, B, lambda t, a: rho, 1e5, min_altitude=150e3)
