"""Relative navigation frames: the chief's path against the curvilinear Hill frame."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ddvi_core.constants import MU_EARTH
from ddvi_core.orbit import elements_to_rv
from ddvi_core.relnav import path_relative_state, propagate_gravity, relative_state

A_CHIEF = 6678.136e3
N_RATE = math.sqrt(MU_EARTH / A_CHIEF**3)
V_REF = N_RATE * A_CHIEF


def _chief_track(seconds: int) -> np.ndarray:
    """The chief's two-body + J2 trajectory, one state (6,) a second, from the mission's
    initial elements (circular osculating, so J2's short-period terms are all there)."""
    r, v = elements_to_rv(
        A_CHIEF, 0.0, math.radians(45), math.radians(20), math.radians(30), math.radians(20)
    )
    out = [np.concatenate([r, v])]
    for _ in range(seconds):
        r, v = propagate_gravity(r, v, 1.0, max_step=1.0)
        out.append(np.concatenate([r, v]))
    return np.array(out)


@pytest.fixture(scope="module")
def track() -> np.ndarray:
    return _chief_track(5500)


def test_a_deputy_on_the_chief_path_is_still(track) -> None:
    """A deputy flying the chief's own path 5 s (about 38 km) behind: in the path frame it
    sits still at y = -v_ref 5 s; in the curvilinear frame J2's short-period terms make its
    x and rates oscillate with amplitudes proportional to the separation."""
    lag = 5
    path, curv = [], []
    for k in range(lag, 5500, 60):
        chief, deputy = track[k], track[k - lag]
        path.append(relative_state("path", chief, deputy, v_ref=V_REF))
        curv.append(relative_state("curvilinear", chief, deputy, v_ref=V_REF))
    path, curv = np.array(path), np.array(curv)
    assert np.max(np.abs(path[:, 0])) < 0.01  # x, m
    assert np.max(np.abs(path[:, 2])) < 0.01  # z
    assert np.max(np.abs(path[:, 3:])) < 1e-5  # rates, m/s
    np.testing.assert_allclose(path[:, 1], -V_REF * lag, rtol=1e-9)
    # the same craft in the curvilinear frame: metres of x, cm/s of rates, over one orbit
    assert np.ptp(curv[:, 0]) > 5.0
    assert np.ptp(curv[:, 3]) > 0.01 and np.ptp(curv[:, 4]) > 0.01


def test_frames_agree_near_the_chief(track) -> None:
    chief = track[100]
    r, v = chief[:3], chief[3:]
    h = np.cross(r, v)
    radial, normal = r / np.linalg.norm(r), h / np.linalg.norm(h)
    along = np.cross(normal, radial)
    # 50 m above and 100 m behind, closing at 5 cm/s
    deputy = np.concatenate([r + 50 * radial - 100 * along, v + 0.05 * along])
    p = relative_state("path", chief, deputy, v_ref=V_REF)
    c = relative_state("curvilinear", chief, deputy, v_ref=V_REF)
    np.testing.assert_allclose(p[:3], c[:3], atol=0.05)
    np.testing.assert_allclose(p[3:], c[3:], atol=2e-4)


def test_drift_rate_follows_altitude(track) -> None:
    """A deputy 200 m higher drifts back at ydot = -3/2 n x, in the path frame as in HCW."""
    chief = track[0]
    r, v = chief[:3], chief[3:]
    rn = np.linalg.norm(r)
    up = r / rn
    deputy_r = r * (rn + 200.0) / rn
    deputy_v = v * math.sqrt(rn / (rn + 200.0))  # circular speed at the higher radius
    p = relative_state("path", chief, np.concatenate([deputy_r, deputy_v]), v_ref=V_REF)
    assert p[0] == pytest.approx(200.0, abs=0.5)
    assert p[4] == pytest.approx(-1.5 * N_RATE * 200.0, rel=0.05)
    assert abs(p[1]) < 1.0 and float(up @ up) == pytest.approx(1.0)


def test_propagate_gravity_round_trip(track) -> None:
    r, v = track[0][:3], track[0][3:]
    r2, v2 = propagate_gravity(*propagate_gravity(r, v, 9.0), -9.0)
    np.testing.assert_allclose(r2, r, atol=1e-6)
    np.testing.assert_allclose(v2, v, atol=1e-9)


def test_bad_input() -> None:
    c = np.array([A_CHIEF, 0, 0, 0, V_REF, 0.0])
    with pytest.raises(ValueError, match="unknown navigation frame 'hill'"):
        relative_state("hill", c, c, v_ref=V_REF)
    with pytest.raises(ValueError, match="v_ref"):
        path_relative_state(c[:3], c[3:], c[:3], c[3:], -1.0)
    with pytest.raises(ValueError, match="finite"):
        propagate_gravity([np.nan, 0, 0], [0, 1, 0], 1.0)


def test_single_sample_kernels_match_the_vectorised_functions(track) -> None:
    """The float kernels navigation runs on agree with ddvi_core.orbit and ddvi_core.truth."""
    from ddvi_core.orbit import hill_to_curvilinear, rv_to_hill
    from ddvi_core.relnav import _curvilinear3, _gravity3
    from ddvi_core.truth import gravity

    rng = np.random.default_rng(3)
    for k in range(0, 5500, 500):
        c = track[k]
        d = c + np.r_[rng.normal(0, 2e4, 3), rng.normal(0, 5, 3)]
        expected = hill_to_curvilinear(c[:3], c[3:], rv_to_hill(c[:3], c[3:], d[:3], d[3:]))
        got = _curvilinear3(tuple(c[:3]), tuple(c[3:]), tuple(d[:3]), tuple(d[3:]))
        np.testing.assert_allclose(got, expected, rtol=1e-9, atol=1e-9)
        for j2 in (True, False):
            np.testing.assert_allclose(
                _gravity3(tuple(d[:3]), j2), gravity(d[:3], j2=j2), rtol=1e-13, atol=0
            )
