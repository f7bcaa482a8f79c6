"""Tests of ddvi_core.truth: forces, propagation accuracy, vectorisation, scenario states."""

from __future__ import annotations

import math
from typing import Any, Literal

import numpy as np
import pytest

from ddvi_core.constants import J2_EARTH, MU_EARTH, R_EARTH
from ddvi_core.models import drag_allocation
from ddvi_core.orbit import body_dcm, hill_frame, mrp_to_dcm, rv_to_elements, rv_to_hill
from ddvi_core.truth import (
    Atmosphere,
    Spacecraft,
    acceleration,
    propagate,
    rendezvous_initial_states,
)

A_C = 6678.136e3
N_MEAN = math.sqrt(MU_EARTH / A_C**3)
PERIOD = 2 * math.pi / N_MEAN
I3 = np.eye(3)


def _energy(s: np.ndarray, j2: bool = False) -> float:
    r = float(np.linalg.norm(s[:3]))
    u = MU_EARTH / r
    if j2:
        u *= 1 - J2_EARTH * (R_EARTH / r) ** 2 * (3 * (s[2] / r) ** 2 - 1) / 2
    return 0.5 * float(s[3:] @ s[3:]) - u


def _fly(
    x0: np.ndarray,
    t_end: float,
    sigma_rel: np.ndarray,
    step: float = 60.0,
    **kwargs: Any,
) -> np.ndarray:
    """Propagate like the environment does: one call per step, nav samples every 10 s,
    attitudes Hill-referenced and held over each step."""
    x, t = np.array(x0), 0.0
    att = mrp_to_dcm(sigma_rel)
    while t < t_end - 1e-9:
        t1 = min(t + step, t_end)
        samples = propagate(
            x,
            t,
            t1,
            att,
            attitude_frame="hill",
            t_eval=np.arange(t, t1 + 1e-9, 10.0),
            **kwargs,
        )
        x, t = samples[-1], t1
    return x


# ------------------------------------------------------------------------------------ parameters


def test_spacecraft_defaults_and_validation() -> None:
    sc = Spacecraft()
    assert (sc.mass, sc.area, sc.cd) == (6.0, 0.06, 2.2)
    assert np.linalg.norm(sc.normal_B) == pytest.approx(1.0, abs=1e-15)
    assert sc.normal_B[2] == 0.0 and sc.normal_B[0] == pytest.approx(sc.normal_B[1])
    assert sc.ballistic == pytest.approx(2.2 * 0.06 / 6.0)
    with pytest.raises(ValueError, match="mass"):
        Spacecraft(mass=0.0)
    with pytest.raises(ValueError, match="area"):
        Spacecraft(area=-1.0)
    with pytest.raises(ValueError, match="normal_B must be a unit vector"):
        Spacecraft(normal_B=(1.0, 1.0, 0.0))
    with pytest.raises(ValueError, match="normal_B"):
        Spacecraft(normal_B=(1.0, 0.0))  # type: ignore[arg-type]


def test_atmosphere_density() -> None:
    atm = Atmosphere()
    r300 = np.array([0.0, 0.0, R_EARTH + 300e3])
    assert atm.density(r300) == pytest.approx(2.2e-11, rel=1e-14)
    assert atm.density(r300 * (1 + 8e3 / np.linalg.norm(r300))) == pytest.approx(2.2e-11 / math.e)
    stack = Atmosphere(density_factor=1.3).density(np.stack([r300, r300]))
    np.testing.assert_allclose(stack, [1.3 * 2.2e-11] * 2, rtol=1e-14)
    with pytest.raises(ValueError, match="scale_height"):
        Atmosphere(scale_height=0.0)
    with pytest.raises(ValueError, match="density_factor"):
        Atmosphere(density_factor=-1.0)


# ---------------------------------------------------------------------------------------- forces


def test_gravity_is_the_gradient_of_the_j2_potential() -> None:
    r = np.array([4.1e6, -3.3e6, 4.0e6])
    v = np.array([1.0, 2.0, 3.0])  # irrelevant with drag off

    def potential(p: np.ndarray) -> float:
        rn = float(np.linalg.norm(p))
        return (
            -MU_EARTH / rn * (1 - J2_EARTH * (R_EARTH / rn) ** 2 * (3 * (p[2] / rn) ** 2 - 1) / 2)
        )

    h = 1.0
    grad = np.array([(potential(r + h * e) - potential(r - h * e)) / (2 * h) for e in I3])
    acc = acceleration(r, v, I3, j2=True, drag=False)
    np.testing.assert_allclose(acc, -grad, rtol=1e-8)
    np.testing.assert_allclose(
        acceleration(r, v, I3, j2=False, drag=False), -MU_EARTH * r / np.linalg.norm(r) ** 3
    )


@pytest.mark.parametrize(
    ("sigma3", "exposure"),
    [
        (0.0, math.sin(math.radians(45))),
        (0.2, math.sin(math.radians(45) + 4 * math.atan(0.2))),  # 45 + 45.24 deg: ~1
        (-0.2, 0.0),  # 45 - 45.24 deg: the facet faces away from the flow
    ],
)
def test_facet_projected_area_at_relative_mrp(sigma3: float, exposure: float) -> None:
    """Hill-pointing plus sigma_rel = [0, 0, sigma3] on a circular orbit (v along Hill y):
    A_proj = A max(0, sin(45 deg + 4 atan(sigma3)))."""
    x0 = rendezvous_initial_states()[0]
    r, v = x0[:3], x0[3:]
    sc, atm = Spacecraft(), Atmosphere()
    dcm = body_dcm(r, v, [0.0, 0.0, sigma3])
    a_drag = acceleration(r, v, dcm, sc, atm) - acceleration(r, v, dcm, sc, atm, drag=False)
    rho = atm.density(r)
    expected = -0.5 * rho * (v @ v) * sc.cd * sc.area * exposure / sc.mass * v / np.linalg.norm(v)
    # subtracting the ~9 m/s^2 gravity leaves ~1e-15 m/s^2 of rounding
    np.testing.assert_allclose(a_drag, expected, rtol=0, atol=1e-14)
    if sigma3 == 0.2:
        assert exposure > 0.99999
    assert np.linalg.norm(a_drag) < 1.45e-5  # full exposure: 1/2 rho v^2 C_D A / m, m/s^2


def test_drag_uses_inertial_velocity() -> None:
    """Like Basilisk's facetDragDynamicEffector: flow = inertial velocity, no Earth rotation."""
    r = np.array([R_EARTH + 300e3, 0.0, 0.0])
    v = np.array([0.0, 7000.0, 1000.0])
    sc = Spacecraft(normal_B=(0.0, 1.0, 0.0))
    a_drag = acceleration(r, v, I3, sc, j2=False) - acceleration(r, v, I3, sc, drag=False, j2=False)
    v_hat = v / np.linalg.norm(v)
    expected = -0.5 * 2.2e-11 * (v @ v) * sc.cd * sc.area * v_hat[1] / sc.mass * v_hat
    np.testing.assert_allclose(a_drag, expected, rtol=1e-12)


def test_acceleration_vectorised_equals_single() -> None:
    x0 = rendezvous_initial_states()
    r = np.vstack([x0[:, :3], x0[:1, :3] * 1.001])
    v = np.vstack([x0[:, 3:], x0[:1, 3:]])
    dcm = body_dcm(r, v, [[0, 0, 0], [0, 0, 0.2], [0.1, -0.1, 0.05]])
    crafts = [Spacecraft(), Spacecraft(area=0.08), Spacecraft(mass=4.0, cd=2.0)]
    stack = acceleration(r, v, dcm, crafts)
    for k in range(3):
        np.testing.assert_allclose(
            stack[k], acceleration(r[k], v[k], dcm[k], crafts[k]), rtol=1e-15
        )


def test_acceleration_validates() -> None:
    x0 = rendezvous_initial_states()
    with pytest.raises(ValueError, match="same craft"):
        acceleration(x0[:, :3], x0[:, 3:], I3)
    with pytest.raises(ValueError, match="craft must be one Spacecraft or 2"):
        acceleration(x0[:, :3], x0[:, 3:], np.stack([I3, I3]), [Spacecraft()])
    with pytest.raises(ValueError, match="dcm_BN must be a proper rotation"):
        acceleration(x0[0, :3], x0[0, 3:], 2 * I3)


# ----------------------------------------------------------------------------------- propagation


def test_two_body_energy_conserved_over_one_orbit() -> None:
    x0 = rendezvous_initial_states()[:1]
    x1 = propagate(x0, 0.0, PERIOD, I3[None], j2=False, drag=False)
    assert abs(_energy(x1[0]) / _energy(x0[0]) - 1) < 1e-13
    assert np.linalg.norm(x1[0, :3] - x0[0, :3]) < 1e-5  # closes after one period, m
    # with J2 the energy including the J2 potential is conserved
    x1 = propagate(x0, 0.0, PERIOD, I3[None], j2=True, drag=False)
    assert abs(_energy(x1[0], j2=True) / _energy(x0[0], j2=True) - 1) < 1e-13


def test_j2_raan_regression_rate() -> None:
    """Secular RAAN rate -1.5 n J2 (R/p)^2 cos i: least-squares slope over 3 orbits."""
    x0 = rendezvous_initial_states()[:1]
    t = np.arange(0.0, 3 * PERIOD, 60.0)
    s = propagate(x0, 0.0, t[-1], I3[None], j2=True, drag=False, t_eval=t)[:, 0]
    h = np.cross(s[:, :3], s[:, 3:])
    raan = np.unwrap(np.arctan2(h[:, 0], -h[:, 1]))
    rate = np.polyfit(t, raan, 1)[0]
    textbook = -1.5 * N_MEAN * J2_EARTH * (R_EARTH / A_C) ** 2 * math.cos(math.radians(45))
    assert rate == pytest.approx(textbook, rel=0.01)
    assert raan[0] == pytest.approx(math.radians(20.0), abs=1e-12)


def test_drag_decay_rate_of_semi_major_axis() -> None:
    """da/dt = -rho sqrt(mu a) C_D A_proj / m on a circular orbit; Hill-pointing attitude keeps
    A_proj = A sin 45 deg."""
    x0 = rendezvous_initial_states()[:1]
    sc, atm = Spacecraft(), Atmosphere()
    x1 = propagate(x0, 0.0, PERIOD, I3[None], sc, atm, attitude_frame="hill", j2=False)
    a0 = -MU_EARTH / (2 * _energy(x0[0]))
    a1 = -MU_EARTH / (2 * _energy(x1[0]))
    a_mid = 0.5 * (a0 + a1)
    rho = atm.density([a_mid, 0.0, 0.0])
    rate = (
        -rho * math.sqrt(MU_EARTH * a_mid) * sc.cd * sc.area * math.sin(math.radians(45)) / sc.mass
    )
    assert (a1 - a0) / PERIOD == pytest.approx(rate, rel=0.01)
    assert a1 - a0 == pytest.approx(-96.5, abs=0.5)  # m per orbit at 300 km


def test_step_halving_changes_relative_position_by_less_than_1_cm() -> None:
    """Environment-like propagation (60 s calls, 10 s samples, J2 + drag, deputy at
    sigma_rel = [0, 0, 0.2]) over one orbit: halving the step or tightening the tolerances ten
    times moves the chief-deputy Hill position by < 1 cm (measured: 1e-7 m and 0)."""
    x0 = rendezvous_initial_states()
    sigma = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.2]])

    def rel(x: np.ndarray) -> np.ndarray:
        return rv_to_hill(x[0, :3], x[0, 3:], x[1, :3], x[1, 3:])[:3]

    base = rel(_fly(x0, PERIOD, sigma))
    halved = rel(_fly(x0, PERIOD, sigma, max_step=30.0))
    tight = rel(_fly(x0, PERIOD, sigma, rtol=1e-12, atol_pos=1e-6, atol_vel=1e-9))
    assert np.linalg.norm(halved - base) < 0.01
    assert np.linalg.norm(tight - base) < 0.01  # 0: a 60 s step already meets both tolerances
    # and against a much finer reference: the error itself is sub-millimetre
    ref = rel(_fly(x0, PERIOD, sigma, max_step=6.0, rtol=1e-13, atol_pos=1e-8, atol_vel=1e-11))
    assert np.linalg.norm(ref - base) < 1e-3
    # the scenario moved: the drag and J2 effects are far above that error
    assert np.linalg.norm(base - rel(_fly(x0, PERIOD, sigma, drag=False, j2=False))) > 10.0


def test_tolerance_tightening_on_a_tolerance_driven_orbit() -> None:
    """One call over a whole orbit with no step limit, so the tolerances choose the steps:
    tightening them ten times moves the relative Hill position by < 1 cm (measured: 4e-7 m)."""
    x0 = rendezvous_initial_states()
    att = mrp_to_dcm([[0.0, 0.0, 0.0], [0.0, 0.0, 0.2]])

    def rel(**kwargs: Any) -> np.ndarray:
        x = propagate(x0, 0.0, PERIOD, att, attitude_frame="hill", max_step=np.inf, **kwargs)
        return rv_to_hill(x[0, :3], x[0, 3:], x[1, :3], x[1, 3:])[:3]

    base = rel()
    tight = rel(rtol=1e-12, atol_pos=1e-6, atol_vel=1e-9)
    assert np.linalg.norm(tight - base) < 0.01
    assert np.linalg.norm(tight - base) < 1e-5


def test_hill_attitude_mode_tracks_the_hill_frame() -> None:
    """``attitude_frame='hill'`` equals re-pointing an inertially held attitude ever more often;
    holding [BN] for a full 60 s step instead is a different (lagging) plant."""
    x0 = rendezvous_initial_states()
    sigma = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.1]])
    t_end = 600.0
    hill = propagate(x0, 0.0, t_end, mrp_to_dcm(sigma), attitude_frame="hill")

    def held(step: float) -> np.ndarray:
        x, t = x0, 0.0
        while t < t_end - 1e-9:
            x = propagate(x, t, t + step, body_dcm(x[:, :3], x[:, 3:], sigma))
            t += step
        return x

    fine, coarse = held(2.0), held(60.0)
    assert np.linalg.norm(fine[1, :3] - hill[1, :3]) < 2e-3
    assert np.linalg.norm(coarse[1, :3] - hill[1, :3]) > 5e-3


@pytest.mark.parametrize("frame", ["inertial", "hill"])
def test_stacked_propagation_equals_separate(frame: Literal["inertial", "hill"]) -> None:
    x0 = rendezvous_initial_states()
    x0 = np.vstack([x0, x0[1] + [50.0, -20.0, 10.0, 0.01, 0.0, -0.02]])
    crafts = [Spacecraft(), Spacecraft(area=0.08), Spacecraft(mass=4.0)]
    att = mrp_to_dcm([[0, 0, 0], [0, 0, 0.2], [0, 0, -0.1]])
    if frame == "inertial":
        att = att @ hill_frame(x0[:, :3], x0[:, 3:])
    t_eval = np.arange(0.0, 60.0 + 1e-9, 10.0)
    stack = propagate(x0, 0.0, 60.0, att, crafts, attitude_frame=frame, t_eval=t_eval)
    assert stack.shape == (7, 3, 6)
    np.testing.assert_allclose(stack[0], x0, atol=0)
    for k in range(3):
        alone = propagate(
            x0[k : k + 1],
            0.0,
            60.0,
            att[k : k + 1],
            crafts[k],
            attitude_frame=frame,
            t_eval=t_eval,
        )
        np.testing.assert_allclose(stack[:, k], alone[:, 0], rtol=0, atol=1e-8)
    # without t_eval: the state at t1, equal to the last sample
    final = propagate(x0, 0.0, 60.0, att, crafts, attitude_frame=frame)
    np.testing.assert_allclose(final, stack[-1], rtol=0, atol=1e-8)


def test_propagate_validates() -> None:
    x0 = rendezvous_initial_states()
    att = np.stack([I3, I3])
    with pytest.raises(ValueError, match="t1 > t0"):
        propagate(x0, 10.0, 10.0, att)
    with pytest.raises(ValueError, match=r"attitude must have shape \(2, 3, 3\)"):
        propagate(x0, 0.0, 60.0, I3[None])
    with pytest.raises(ValueError, match="state must have shape"):
        propagate(x0[:, :5], 0.0, 60.0, att)
    with pytest.raises(ValueError, match="t_eval"):
        propagate(x0, 0.0, 60.0, att, t_eval=[0.0, 70.0])
    with pytest.raises(ValueError, match="attitude_frame"):
        propagate(x0, 0.0, 60.0, att, attitude_frame="body")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="state must be finite"):
        propagate(np.full((1, 6), np.nan), 0.0, 60.0, I3[None])


def test_hill_rate_with_chief_acceleration_under_j2() -> None:
    """Under J2 the chief's Hill frame also turns about its radial axis (r a_h / h); with a_c
    given, rv_to_hill's rates equal the finite-difference derivative of the Hill position."""
    x0 = rendezvous_initial_states()
    att = np.stack([I3, I3])
    dt = 0.5
    xm = propagate(x0, 0.0, dt, att, j2=True, drag=False)
    x_back = x0.copy()
    x_back[:, 3:] *= -1  # time reversal: fly the reversed velocities forward
    xb = propagate(x_back, 0.0, dt, att, j2=True, drag=False)
    xb[:, 3:] *= -1

    def pos(x: np.ndarray) -> np.ndarray:
        return rv_to_hill(x[0, :3], x[0, 3:], x[1, :3], x[1, 3:])[:3]

    fd = (pos(xm) - pos(xb)) / (2 * dt)
    a_c = acceleration(x0[0, :3], x0[0, 3:], I3, j2=True, drag=False)
    with_ac = rv_to_hill(x0[0, :3], x0[0, 3:], x0[1, :3], x0[1, 3:], a_c=a_c)[3:]
    without = rv_to_hill(x0[0, :3], x0[0, 3:], x0[1, :3], x0[1, 3:])[3:]
    np.testing.assert_allclose(with_ac, fd, atol=1e-5)
    assert abs(without[2] - fd[2]) > 0.01  # the Keplerian frame rate misses ~4 cm/s of zdot
    np.testing.assert_allclose(without[:2], fd[:2], atol=1e-5)


# -------------------------------------------------------------------------------------- scenario


def test_rendezvous_initial_states() -> None:
    x0 = rendezvous_initial_states()
    assert x0.shape == (2, 6)
    a, e, i, raan, _, u = rv_to_elements(x0[0, :3], x0[0, 3:])
    assert (a, e, i, raan, u) == pytest.approx(
        (A_C, 0.0, math.radians(45), math.radians(20), math.radians(50)), abs=1e-9
    )
    a, _, _, _, _, u = rv_to_elements(x0[1, :3], x0[1, 3:])
    assert (a, u) == pytest.approx((6678.376e3, math.radians(49.75)), abs=1e-9)
    xh = rv_to_hill(x0[0, :3], x0[0, 3:], x0[1, :3], x0[1, 3:])
    assert xh[:3] == pytest.approx([176.4, -29139.8, 0.0], abs=0.1)


# ---- drag allocation: the attitude that makes the facet's drag linear in u ------------------
@pytest.mark.parametrize("u", [-0.25, -0.2, -0.1, -0.01, 0.0, 0.02, 0.05, 0.1])
def test_drag_allocation_is_linear_in_u(u: float) -> None:
    alpha = math.radians(45.0)
    sigma, applied = drag_allocation(u, alpha, 0.2)
    assert abs(sigma) <= 0.2 + 1e-12
    assert applied == pytest.approx(u, abs=1e-12)
    projected = math.sin(alpha + 4 * math.atan(sigma))
    assert projected == pytest.approx(math.sin(alpha) + 4 * math.cos(alpha) * u, abs=1e-12)


def test_drag_allocation_first_order_and_limits() -> None:
    alpha = math.radians(45.0)
    sigma, _ = drag_allocation(1e-6, alpha, 0.2)
    assert sigma == pytest.approx(1e-6, rel=1e-5)  # a gain on u is a gain on sigma3
    # out of reach: broadside (full area) on one side, edge-on (zero area) on the other
    hi_sigma, hi = drag_allocation(1.0, alpha, 0.2)
    lo_sigma, lo = drag_allocation(-1.0, alpha, 0.2)
    assert hi == pytest.approx((1 - math.sin(alpha)) / (4 * math.cos(alpha)))
    assert lo == pytest.approx(-math.sin(alpha) / (4 * math.cos(alpha)))
    assert abs(hi_sigma) <= 0.2 and abs(lo_sigma) <= 0.2
    # a tight limit binds before the facet geometry does
    s, applied = drag_allocation(0.1, alpha, 0.01)
    assert s == pytest.approx(0.01)
    assert applied < 0.1
    with pytest.raises(ValueError, match="not finite"):
        drag_allocation(float("nan"), alpha, 0.2)
    with pytest.raises(ValueError, match="normal_angle"):
        drag_allocation(0.0, math.radians(95.0), 0.2)
