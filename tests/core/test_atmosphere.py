"""Tests of ddvi_core.atmosphere (the per-call density track) and ddvi_core.earth (frames)."""

from __future__ import annotations

import math
from datetime import datetime

import numpy as np
import pytest

from ddvi_core.atmosphere import DensityTrack, inverse_scale_height, predict_positions
from ddvi_core.earth import WGS84_A, WGS84_F, geodetic, gmst, inertial_to_geodetic
from ddvi_core.truth import Atmosphere, propagate, rendezvous_initial_states


def _track(n: int = 2) -> DensityTrack:
    return DensityTrack(
        t0=100.0,
        t1=160.0,
        radius=np.tile([6.7e6, 6.701e6], (n, 1)),
        log_rho=np.tile([math.log(2e-11), math.log(3e-11)], (n, 1)),
        inv_scale_height=np.tile([1 / 50e3, 1 / 60e3], (n, 1)),
    )


def test_track_is_the_anchor_density_at_the_anchors_and_exponential_off_them() -> None:
    tr = _track()
    r0 = np.array([[6.7e6, 0.0, 0.0]] * 2)
    assert tr.density(100.0, r0) == pytest.approx([2e-11] * 2, rel=1e-12)
    r1 = np.array([[0.0, 6.701e6, 0.0]] * 2)
    assert tr.density(160.0, r1) == pytest.approx([3e-11] * 2, rel=1e-12)
    # 1 km above the start anchor: one local scale height's worth lower
    up = np.array([[6.701e6, 0.0, 0.0]] * 2)
    assert tr.density(100.0, up) == pytest.approx(2e-11 * math.exp(-1e3 / 50e3), rel=1e-12)
    # half way: the log density, radius and 1/H halfway between the anchors
    mid = np.array([[0.0, 0.0, 6.7005e6]] * 2)
    assert tr.density(130.0, mid) == pytest.approx(math.sqrt(2e-11 * 3e-11), rel=1e-12)


def test_track_refuses_bad_input() -> None:
    with pytest.raises(ValueError, match="t1 > t0"):
        DensityTrack(1.0, 1.0, np.ones((1, 2)), np.ones((1, 2)), np.ones((1, 2)))
    with pytest.raises(ValueError, match="log_rho must be finite"):
        DensityTrack(0.0, 1.0, np.ones((1, 2)), np.array([[np.nan, 1.0]]), np.ones((1, 2)))
    with pytest.raises(ValueError, match="inv_scale_height must be positive"):
        DensityTrack(0.0, 1.0, np.ones((1, 2)), np.ones((1, 2)), -np.ones((1, 2)))
    with pytest.raises(ValueError, match="densities must be positive"):
        inverse_scale_height([1e-11], [0.0], 2e3)


def test_propagation_with_a_track_equal_to_the_exponential_matches_it() -> None:
    """A track whose anchors lie on the exponential profile flies the exponential's drag."""
    atm = Atmosphere()
    x0 = rendezvous_initial_states()
    att = np.stack([np.eye(3)] * 2)
    ref = propagate(x0, 0.0, 60.0, att, atmosphere=atm, attitude_frame="hill")
    radius = np.tile(np.linalg.norm(x0[:, :3], axis=1)[:, None], (1, 2))
    log_rho = np.log(atm.density(x0[:, :3]))[:, None].repeat(2, axis=1)
    track = DensityTrack(0.0, 60.0, radius, log_rho, np.full((2, 2), 1 / atm.scale_height))
    got = propagate(x0, 0.0, 60.0, att, atmosphere=track, attitude_frame="hill")
    assert np.max(np.abs(got[:, :3] - ref[:, :3])) < 1e-6
    # and the drag the two agree on is there: without it the craft end elsewhere
    nodrag = propagate(x0, 0.0, 60.0, att, drag=False, attitude_frame="hill")
    assert np.max(np.abs(nodrag[:, :3] - ref[:, :3])) > 1e-4


def test_predicted_positions_against_the_integrator() -> None:
    x0 = rendezvous_initial_states()
    att = np.stack([np.eye(3)] * 2)
    for dt, bound in ((60.0, 10.0), (360.0, 12e3)):
        truth = propagate(x0, 0.0, dt, att, j2=False, drag=False)
        err = np.linalg.norm(predict_positions(x0, [dt])[0] - truth[:, :3], axis=1)
        assert np.all(err < bound)


def test_geodetic_on_the_ellipsoid_and_above_the_pole() -> None:
    b = WGS84_A * (1 - WGS84_F)
    lat, lon, alt = geodetic(np.array([[WGS84_A + 400e3, 0.0, 0.0], [0.0, 0.0, b + 400e3]]))
    assert np.degrees(lat) == pytest.approx([0.0, 90.0], abs=1e-9)
    assert alt == pytest.approx([400e3, 400e3], abs=1e-6)
    assert np.degrees(lon[0]) == pytest.approx(0.0)
    # a point 400 km along the ellipsoid normal at 40 deg geodetic latitude, 30 deg east
    phi, lam, h = math.radians(40.0), math.radians(30.0), 400e3
    e2 = WGS84_F * (2 - WGS84_F)
    n = WGS84_A / math.sqrt(1 - e2 * math.sin(phi) ** 2)
    r = [
        (n + h) * math.cos(phi) * math.cos(lam),
        (n + h) * math.cos(phi) * math.sin(lam),
        (n * (1 - e2) + h) * math.sin(phi),
    ]
    lat, lon, alt = geodetic(np.array([r]))
    assert math.degrees(lat[0]) == pytest.approx(40.0, abs=1e-10)
    assert math.degrees(lon[0]) == pytest.approx(30.0, abs=1e-10)
    assert alt[0] == pytest.approx(h, abs=1e-5)


def test_sidereal_time_turns_the_earth_under_the_inertial_frame() -> None:
    # GMST at J2000.0 is 280.46 deg; a sidereal day later it is back
    assert math.degrees(gmst(0.0)) == pytest.approx(280.46061837, abs=1e-8)
    sidereal_day = 0.99726956634
    assert math.degrees(gmst(sidereal_day)) == pytest.approx(280.46061837, abs=1e-4)
    # a point on the inertial x axis is at longitude -GMST
    _, lon, _ = inertial_to_geodetic(np.array([[7e6, 0.0, 0.0]]), np.array([0.0]))
    assert lon[0] == pytest.approx(360.0 - 280.46061837, abs=1e-8)
    with pytest.raises(ValueError, match="r_N must have shape"):
        inertial_to_geodetic(np.zeros((2, 3)), np.zeros(3))


def test_the_equinox_sun_direction_is_over_greenwich_at_noon_utc() -> None:
    """At the March equinox the Sun lies along inertial +x; at 12:00 UTC it stands over
    longitude 0 within the equation of time (under 2 deg in March)."""
    days = (datetime(2024, 3, 20, 12) - datetime(2000, 1, 1, 12)).total_seconds() / 86400.0
    _, lon, _ = inertial_to_geodetic(np.array([[7e6, 0.0, 0.0]]), np.array([days]))
    assert abs(lon[0]) < 3.0
