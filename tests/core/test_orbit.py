"""Tests of ddvi_core.orbit: elements, Hill frame, relative states, MRPs."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ddvi_core.constants import MU_EARTH
from ddvi_core.orbit import (
    body_dcm,
    dcm_to_mrp,
    elements_to_rv,
    hill_frame,
    hill_pointing_mrp,
    hill_to_rv,
    mrp_add,
    mrp_shadow,
    mrp_to_dcm,
    rv_to_elements,
    rv_to_hill,
)

D = math.radians
A_C = 6678.136e3
A_D = 6678.376e3


def _chief() -> tuple[np.ndarray, np.ndarray]:
    return elements_to_rv(A_C, 0.0, D(45), D(20), D(30), D(20))


def _deputy() -> tuple[np.ndarray, np.ndarray]:
    return elements_to_rv(A_D, 0.0, D(45), D(20), D(30), D(19.75))


def _two_body_step(r: np.ndarray, v: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Keplerian state after dt (universal-free: circular/elliptic via elements)."""
    a, e, i, raan, argp, f = rv_to_elements(r, v)
    ecc_anom = 2 * math.atan(math.sqrt((1 - e) / (1 + e)) * math.tan(f / 2))
    mean = ecc_anom - e * math.sin(ecc_anom) + math.sqrt(MU_EARTH / a**3) * dt
    ea = mean
    for _ in range(50):
        ea -= (ea - e * math.sin(ea) - mean) / (1 - e * math.cos(ea))
    f1 = 2 * math.atan2(math.sqrt(1 + e) * math.sin(ea / 2), math.sqrt(1 - e) * math.cos(ea / 2))
    return elements_to_rv(a, e, i, raan, argp, f1)


# ------------------------------------------------------------------------------------- elements


def test_circular_orbit_speed_radius_and_angular_momentum_direction() -> None:
    i, raan = D(45), D(20)
    r, v = elements_to_rv(A_C, 0.0, i, raan, D(30), D(20))
    assert np.linalg.norm(r) == pytest.approx(A_C, rel=1e-15)
    assert np.linalg.norm(v) == pytest.approx(math.sqrt(MU_EARTH / A_C), rel=1e-14)
    assert r @ v == pytest.approx(0.0, abs=1e-6 * A_C)
    h = np.cross(r, v)
    h_hat = np.array([math.sin(i) * math.sin(raan), -math.sin(i) * math.cos(raan), math.cos(i)])
    np.testing.assert_allclose(h / np.linalg.norm(h), h_hat, atol=1e-15)
    # argument of latitude u = argp + f = 50 deg from the ascending node
    node = np.array([math.cos(raan), math.sin(raan), 0.0])
    assert math.degrees(math.acos(r @ node / A_C)) == pytest.approx(50.0, abs=1e-12)


def test_elements_to_rv_matches_vallado_example_2_6() -> None:
    # Vallado, Fundamentals of Astrodynamics, Example 2-6 (COE2RV), km and km/s. The book's
    # elements are printed to 3 decimals (1e-3 deg is 0.1 km at 6,500 km), hence the tolerance.
    p, e = 11067.790, 0.83285
    r, v = elements_to_rv(
        p / (1 - e * e) * 1e3, e, D(87.87), D(227.89), D(53.38), D(92.335), mu=398600.4418e9
    )
    np.testing.assert_allclose(r / 1e3, [6525.344, 6861.535, 6449.125], atol=0.03)
    np.testing.assert_allclose(v / 1e3, [4.902276, 5.533124, -1.975709], atol=2e-5)


def test_elements_to_rv_matches_perifocal_rotation() -> None:
    """Independent construction: perifocal state rotated by [PN]^T = R3(-raan) R1(-i) R3(-argp)."""

    def r1(t: float) -> np.ndarray:
        c, s = math.cos(t), math.sin(t)
        return np.array([[1, 0, 0], [0, c, s], [0, -s, c]])

    def r3(t: float) -> np.ndarray:
        c, s = math.cos(t), math.sin(t)
        return np.array([[c, s, 0], [-s, c, 0], [0, 0, 1]])

    a, e, i, raan, argp, f = 7200e3, 0.25, D(98.0), D(300.0), D(75.0), D(200.0)
    p = a * (1 - e * e)
    rp = p / (1 + e * math.cos(f)) * np.array([math.cos(f), math.sin(f), 0.0])
    vp = math.sqrt(MU_EARTH / p) * np.array([-math.sin(f), e + math.cos(f), 0.0])
    NP = (r3(argp) @ r1(i) @ r3(raan)).T
    r, v = elements_to_rv(a, e, i, raan, argp, f)
    np.testing.assert_allclose(r, NP @ rp, rtol=0, atol=1e-8)
    np.testing.assert_allclose(v, NP @ vp, rtol=0, atol=1e-11)


def test_elements_round_trip() -> None:
    els = (7000e3, 0.1, D(63), D(110), D(250), D(333))
    r, v = elements_to_rv(*els)
    np.testing.assert_allclose(rv_to_elements(r, v), els, rtol=1e-11, atol=1e-11)
    # circular: argp is folded into f (argument of latitude)
    r, v = elements_to_rv(A_C, 0.0, D(45), D(20), D(30), D(20))
    a, e, i, raan, argp, f = rv_to_elements(r, v)
    assert (a, i, raan, argp) == pytest.approx((A_C, D(45), D(20), 0.0), rel=1e-12, abs=1e-12)
    assert e < 1e-11
    assert f == pytest.approx(D(50), abs=1e-12)


@pytest.mark.parametrize(
    ("kwargs", "name"),
    [
        ({"a": -1.0}, "a"),
        ({"e": 1.0}, "e"),
        ({"i": math.nan}, "i"),
        ({"mu": 0.0}, "mu"),
    ],
)
def test_elements_to_rv_validates(kwargs: dict[str, float], name: str) -> None:
    args = {"a": A_C, "e": 0.0, "i": 0.1, "raan": 0.2, "argp": 0.3, "f": 0.4, "mu": MU_EARTH}
    args.update(kwargs)
    with pytest.raises(ValueError, match=rf"^{name} "):
        elements_to_rv(**args)


# ----------------------------------------------------------------------------------- Hill frame


def test_hill_frame_axes() -> None:
    r, v = _chief()
    HN = hill_frame(r, v)
    np.testing.assert_allclose(HN @ HN.T, np.eye(3), atol=1e-15)
    assert np.linalg.det(HN) == pytest.approx(1.0)
    np.testing.assert_allclose(HN @ r, [A_C, 0, 0], atol=1e-8)
    np.testing.assert_allclose(HN @ v, [0, np.linalg.norm(v), 0], atol=1e-9)
    # stacked input gives stacked frames
    stack = hill_frame(np.stack([r, 2 * r]), np.stack([v, v]))
    assert stack.shape == (2, 3, 3)
    np.testing.assert_allclose(stack[1], HN, atol=1e-15)


def test_rendezvous_deputy_hill_state_at_t0() -> None:
    """Deputy 240 m higher and 0.25 deg behind: x = r_d cos(phi) - r_c ~ +176 m (not 240 m,
    because the chief's radial axis is not the deputy's), y = r_d sin(phi) ~ -29.14 km; in the
    rotating frame the deputy drifts along its own circle at the differential mean motion."""
    rc, vc = _chief()
    rd, vd = _deputy()
    xh = rv_to_hill(rc, vc, rd, vd)
    phi = D(-0.25)
    dn = math.sqrt(MU_EARTH / A_D**3) - math.sqrt(MU_EARTH / A_C**3)  # phi dot
    expected = [
        A_D * math.cos(phi) - A_C,
        A_D * math.sin(phi),
        0.0,
        -A_D * math.sin(phi) * dn,
        A_D * math.cos(phi) * dn,
        0.0,
    ]
    np.testing.assert_allclose(xh, expected, rtol=1e-9, atol=1e-9)
    assert xh[0] == pytest.approx(176.4, abs=0.1)
    assert xh[1] == pytest.approx(-29139.8, abs=0.1)
    assert xh[4] == pytest.approx(-1.5 * math.sqrt(MU_EARTH / A_C**3) * 240.0, rel=1e-3)


def test_hill_round_trip_vectorised() -> None:
    rng = np.random.default_rng(1)
    rc, vc = _chief()
    xh = rng.normal(size=(20, 6)) * [1e3, 3e4, 1e3, 1.0, 1.0, 1.0]
    ac = rng.normal(size=3) * 1e-2
    for a_c in (None, ac):
        rd, vd = hill_to_rv(rc, vc, xh, a_c=a_c)
        assert rd.shape == vd.shape == (20, 3)
        np.testing.assert_allclose(rv_to_hill(rc, vc, rd, vd, a_c=a_c), xh, rtol=0, atol=1e-7)
        # single deputy gives a (6,) result equal to the stacked row
        one = rv_to_hill(rc, vc, rd[3], vd[3], a_c=a_c)
        assert one.shape == (6,)
        np.testing.assert_allclose(one, rv_to_hill(rc, vc, rd, vd, a_c=a_c)[3], atol=1e-12)


def test_hill_rate_is_the_rotating_frame_derivative() -> None:
    """xdot..zdot equal the time derivative of the Hill position (Keplerian chief and deputy)."""
    rc, vc = _chief()
    rd, vd = elements_to_rv(A_D, 1e-3, D(45.05), D(20.02), D(30), D(19.75))
    dt = 0.5
    pos = []
    for s in (-dt, dt):
        rc1, vc1 = _two_body_step(rc, vc, s)
        rd1, vd1 = _two_body_step(rd, vd, s)
        pos.append(rv_to_hill(rc1, vc1, rd1, vd1)[:3])
    fd = (pos[1] - pos[0]) / (2 * dt)
    np.testing.assert_allclose(rv_to_hill(rc, vc, rd, vd)[3:], fd, atol=2e-6)


def test_hill_validates_shapes() -> None:
    rc, vc = _chief()
    with pytest.raises(ValueError, match="r_d"):
        rv_to_hill(rc, vc, np.zeros((2, 4)), np.zeros((2, 4)))
    with pytest.raises(ValueError, match="r_d and v_d"):
        rv_to_hill(rc, vc, np.zeros((2, 3)), np.zeros((3, 3)))
    with pytest.raises(ValueError, match="x_hill"):
        hill_to_rv(rc, vc, np.zeros(5))
    with pytest.raises(ValueError, match="not parallel"):
        hill_frame(rc, 2 * rc)
    with pytest.raises(ValueError, match="r_c must be finite"):
        rv_to_hill([math.nan, 0, 0], vc, rc, vc)


# ------------------------------------------------------------------------------------------ MRP


def test_mrp_90_deg_about_z() -> None:
    sigma = np.array([0.0, 0.0, math.tan(D(90) / 4)])
    C = mrp_to_dcm(sigma)
    # [BN] = M3(90 deg): b1 = n2, b2 = -n1
    np.testing.assert_allclose(C, [[0, 1, 0], [-1, 0, 0], [0, 0, 1]], atol=1e-15)
    np.testing.assert_allclose(dcm_to_mrp(C), sigma, atol=1e-15)


def test_mrp_dcm_round_trip_and_short_rotation() -> None:
    rng = np.random.default_rng(7)
    s = rng.normal(size=(200, 3))
    s *= (rng.uniform(0.0, 1.0, size=200) / np.linalg.norm(s, axis=1))[:, None]  # |s| <= 1
    C = mrp_to_dcm(s)
    assert C.shape == (200, 3, 3)
    np.testing.assert_allclose(
        C @ np.swapaxes(C, 1, 2), np.broadcast_to(np.eye(3), C.shape), atol=1e-14
    )
    np.testing.assert_allclose(dcm_to_mrp(C), s, atol=1e-13)
    # a long rotation (|s| > 1) maps back to its shadow, the same attitude with |s| <= 1
    long = np.array([0.3, -1.2, 0.8])
    back = dcm_to_mrp(mrp_to_dcm(long))
    assert np.linalg.norm(back) <= 1.0
    np.testing.assert_allclose(back, -long / (long @ long), atol=1e-14)
    np.testing.assert_allclose(mrp_shadow(long), back, atol=1e-14)
    np.testing.assert_allclose(mrp_shadow(back), back, atol=0)
    # 180 deg: |sigma| = 1
    assert np.linalg.norm(dcm_to_mrp(np.diag([-1.0, -1.0, 1.0]))) == pytest.approx(1.0)


def test_mrp_add_composes_rotations() -> None:
    s1 = np.array([0.1, -0.2, 0.3])
    s2 = np.array([-0.4, 0.05, 0.2])
    s = mrp_add(s1, s2)
    np.testing.assert_allclose(mrp_to_dcm(s), mrp_to_dcm(s2) @ mrp_to_dcm(s1), atol=1e-14)
    # Schaub & Junkins' closed form for the composite (when its denominator is not small)
    n1, n2 = s1 @ s1, s2 @ s2
    closed = ((1 - n1) * s2 + (1 - n2) * s1 - 2 * np.cross(s2, s1)) / (1 + n1 * n2 - 2 * (s1 @ s2))
    np.testing.assert_allclose(s, closed, atol=1e-14)
    # two 90 deg rotations about z make 180 deg: sigma = [0, 0, +-1]
    q = [0.0, 0.0, math.tan(D(22.5))]
    assert abs(mrp_add(q, q)[2]) == pytest.approx(1.0)


def test_mrp_validation() -> None:
    with pytest.raises(ValueError, match="sigma must have shape"):
        mrp_to_dcm([1.0, 2.0])
    with pytest.raises(ValueError, match="dcm must be a proper rotation"):
        dcm_to_mrp(np.diag([1.0, 1.0, -1.0]))
    with pytest.raises(ValueError, match="dcm must be a proper rotation"):
        dcm_to_mrp(2 * np.eye(3))


def test_hill_pointing_and_body_dcm() -> None:
    rc, vc = _chief()
    HN = hill_frame(rc, vc)
    sigma = hill_pointing_mrp(rc, vc)
    assert np.linalg.norm(sigma) <= 1.0
    np.testing.assert_allclose(mrp_to_dcm(sigma), HN, atol=1e-14)
    np.testing.assert_allclose(body_dcm(rc, vc, np.zeros(3)), HN, atol=0)
    rel = np.array([0.0, 0.0, 0.2])
    np.testing.assert_allclose(body_dcm(rc, vc, rel), mrp_to_dcm(rel) @ HN, atol=0)
    np.testing.assert_allclose(mrp_to_dcm(mrp_add(sigma, rel)), body_dcm(rc, vc, rel), atol=1e-14)
    # stacked
    rd, vd = _deputy()
    stack = body_dcm(np.stack([rc, rd]), np.stack([vc, vd]), np.stack([np.zeros(3), rel]))
    assert stack.shape == (2, 3, 3)
    np.testing.assert_allclose(stack[1], mrp_to_dcm(rel) @ hill_frame(rd, vd), atol=1e-15)


def test_curvilinear_hill_state_of_a_pure_phase_offset() -> None:
    """Same circular orbit, 0.01 rad behind: rectilinear x is the chord's sag (-r(1-cos)),
    curvilinear x is exactly zero and y is the arc length."""
    from ddvi_core.orbit import hill_to_curvilinear

    a = 6678136.0
    r1, v1 = elements_to_rv(a, 0.0, 0.7, 0.3, 0.5, 0.2)
    r2, v2 = elements_to_rv(a, 0.0, 0.7, 0.3, 0.5, 0.19)
    rect = rv_to_hill(r1, v1, r2, v2)
    curv = hill_to_curvilinear(r1, v1, rect)
    assert rect[0] == pytest.approx(-a * (1 - np.cos(0.01)), rel=1e-6)
    np.testing.assert_allclose(curv[:3], [0.0, -0.01 * a, 0.0], atol=1e-6)
    np.testing.assert_allclose(curv[3:], 0.0, atol=1e-9)


def test_curvilinear_matches_rectilinear_for_close_deputies() -> None:
    from ddvi_core.orbit import hill_to_curvilinear

    r1, v1 = elements_to_rv(6678136.0, 0.0, 0.7, 0.3, 0.5, 0.2)
    r2, v2 = elements_to_rv(6678236.0, 0.0, 0.7, 0.3, 0.5, 0.20001)
    rect = rv_to_hill(r1, v1, r2, v2)
    curv = hill_to_curvilinear(r1, v1, rect)
    # second-order differences only: (67 m)^2 / 2r is 3e-4 m
    assert np.all(np.abs(curv - rect) <= np.array([1e-2, 1e-2, 1e-2, 1e-5, 1e-5, 1e-5]))
