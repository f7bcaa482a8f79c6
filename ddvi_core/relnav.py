"""Relative navigation states: what a deputy's navigation filter tells its controller.

Two frames for the in-plane state [x, y, z, xdot, ydot, zdot]:

- ``curvilinear``: the chief's curvilinear Hill frame at the same instant
  (:func:`ddvi_core.orbit.hill_to_curvilinear`).  Exact kinematics, but far along track it
  compares the two craft at different points of the orbit: under J2 the chief's radius and
  rate change with the argument of latitude u (the short-period terms, a few km of radius at
  2u), so a deputy that flies the chief's own path Delta-t behind it shows x, xdot, ydot
  oscillating at 2n with amplitudes proportional to the separation.  At 35 km that is about
  1e-4 m/s^2 of apparent acceleration, 25 times what differential drag can command, and no
  linear model of the relative motion has it.
- ``path``: the deputy against the chief's own path.  The chief is propagated back (or
  forward) by the time lag tau at which it stood at the deputy's argument of latitude;
  then x is the difference of the radii at the same point of the path, y = -v_ref tau (the
  separation in time, as a distance at the reference orbital speed), and the rates follow
  with tau' = 1 - u'_d / u'_c.  A deputy on the chief's path, wherever along it, has x = 0,
  y constant: the J2 short-period terms cancel to first order in the separation, and the
  relative motion is linear (HCW with Schweighart-Sedwick's J2 and drag) over tens of km.
  Near the chief both frames agree to first order.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ddvi_core.constants import J2_EARTH, MU_EARTH, R_EARTH
from ddvi_core.orbit import hill_to_curvilinear, rv_to_hill

__all__ = ["FRAMES", "path_relative_state", "propagate_gravity", "relative_state"]

FRAMES = ("curvilinear", "path")


# Navigation evaluates this once per sample per deputy, on single 3-vectors: numpy's per-call
# overhead exceeds the arithmetic by far, so the single-sample kernels below work on Python
# floats.  tests/core/test_relnav.py checks them against the vectorised ddvi_core.orbit
# and ddvi_core.truth functions they mirror.
_Vec = tuple[float, float, float]
_J2_K = -1.5 * J2_EARTH * MU_EARTH * R_EARTH * R_EARTH


def _dot(a: _Vec, b: _Vec) -> float:
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def _cross3(a: _Vec, b: _Vec) -> _Vec:
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def _gravity3(r: _Vec, j2: bool) -> _Vec:
    """Two-body (+ J2) acceleration at r: ``ddvi_core.truth.gravity`` for one position."""
    x, y, z = r
    r2 = x * x + y * y + z * z
    inv_r3 = 1.0 / (r2 * math.sqrt(r2))
    f = -MU_EARTH * inv_r3
    if not j2:
        return (f * x, f * y, f * z)
    zr2 = z * z / r2
    k = _J2_K * inv_r3 / r2
    f_xy = f + k * (1.0 - 5.0 * zr2)
    return (f_xy * x, f_xy * y, (f + k * (3.0 - 5.0 * zr2)) * z)


def _rk4_gravity(r: _Vec, v: _Vec, dt: float, j2: bool, max_step: float) -> tuple[_Vec, _Vec]:
    steps = max(1, math.ceil(abs(dt) / max_step))
    h = dt / steps
    h2, h6 = 0.5 * h, h / 6.0
    for _ in range(steps):
        a1 = _gravity3(r, j2)
        r2 = (r[0] + h2 * v[0], r[1] + h2 * v[1], r[2] + h2 * v[2])
        v2 = (v[0] + h2 * a1[0], v[1] + h2 * a1[1], v[2] + h2 * a1[2])
        a2 = _gravity3(r2, j2)
        r3 = (r[0] + h2 * v2[0], r[1] + h2 * v2[1], r[2] + h2 * v2[2])
        v3 = (v[0] + h2 * a2[0], v[1] + h2 * a2[1], v[2] + h2 * a2[2])
        a3 = _gravity3(r3, j2)
        r4 = (r[0] + h * v3[0], r[1] + h * v3[1], r[2] + h * v3[2])
        v4 = (v[0] + h * a3[0], v[1] + h * a3[1], v[2] + h * a3[2])
        a4 = _gravity3(r4, j2)
        r = tuple(r[i] + h6 * (v[i] + 2.0 * v2[i] + 2.0 * v3[i] + v4[i]) for i in range(3))
        v = tuple(v[i] + h6 * (a1[i] + 2.0 * a2[i] + 2.0 * a3[i] + a4[i]) for i in range(3))
    return r, v  # type: ignore[return-value]


def _curvilinear3(rc: _Vec, vc: _Vec, rd: _Vec, vd: _Vec) -> tuple[float, ...]:
    """``hill_to_curvilinear(rc, vc, rv_to_hill(rc, vc, rd, vd))`` for one deputy (6,)."""
    h = _cross3(rc, vc)
    r02 = _dot(rc, rc)
    r0 = math.sqrt(r02)
    hn = math.sqrt(_dot(h, h))
    xh = (rc[0] / r0, rc[1] / r0, rc[2] / r0)
    zh = (h[0] / hn, h[1] / hn, h[2] / hn)
    yh = _cross3(zh, xh)
    dr = (rd[0] - rc[0], rd[1] - rc[1], rd[2] - rc[2])
    w = (h[0] / r02, h[1] / r02, h[2] / r02)  # the Hill frame's rate (Keplerian part)
    wxr = _cross3(w, dr)
    dv = (vd[0] - vc[0] - wxr[0], vd[1] - vc[1] - wxr[1], vd[2] - vc[2] - wxr[2])
    r0dot = _dot(rc, vc) / r0
    R0, R1, R2 = _dot(xh, dr) + r0, _dot(yh, dr), _dot(zh, dr)
    D0, D1, D2 = _dot(xh, dv) + r0dot, _dot(yh, dv), _dot(zh, dv)
    rho2 = R0 * R0 + R1 * R1
    rho = math.sqrt(rho2)
    rn = math.sqrt(rho2 + R2 * R2)
    rn_dot = (R0 * D0 + R1 * D1 + R2 * D2) / rn
    theta = math.atan2(R1, R0)
    theta_dot = (R0 * D1 - R1 * D0) / rho2
    phi = math.atan2(R2, rho)
    rho_dot = (R0 * D0 + R1 * D1) / rho
    phi_dot = (D2 * rho - R2 * rho_dot) / (rn * rn)
    return (
        rn - r0,
        r0 * theta,
        r0 * phi,
        rn_dot - r0dot,
        r0dot * theta + r0 * theta_dot,
        r0dot * phi + r0 * phi_dot,
    )


def _vec3(a: ArrayLike, name: str) -> _Vec:
    """``a`` as three finite floats; ValueError naming ``name`` otherwise.  Element by element,
    not through np.asarray: this runs four times a sample, and numpy's call overhead would be a
    large share of the navigation's time; other array-likes take numpy's path."""
    v = a
    if not isinstance(v, np.ndarray | list | tuple):
        try:
            v = np.asarray(v, dtype=float)
        except (TypeError, ValueError):
            raise ValueError(f"{name} must be a finite 3-vector, got {a!r}") from None
    if (v.shape == (3,)) if isinstance(v, np.ndarray) else len(v) == 3:
        try:
            x, y, z = float(v[0]), float(v[1]), float(v[2])
        except (TypeError, ValueError):
            pass
        else:
            if math.isfinite(x) and math.isfinite(y) and math.isfinite(z):
                return (x, y, z)
    raise ValueError(f"{name} must be a finite 3-vector, got {a!r}")


def propagate_gravity(
    r: ArrayLike, v: ArrayLike, dt: float, *, j2: bool = True, max_step: float = 5.0
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Two-body (+ J2) state (3,), (3,) after ``dt`` seconds (either sign), by classical RK4
    with steps of at most ``max_step`` s.  Meant for the seconds of a time lag: over 10 s
    its error is below 1e-6 m; drag (about 1e-5 m/s^2) is left out, 5e-4 m over 10 s."""
    if not math.isfinite(dt):
        raise ValueError(f"propagate_gravity needs a finite dt, got {dt}")
    r1, v1 = _rk4_gravity(_vec3(r, "r"), _vec3(v, "v"), dt, j2, max_step)
    return np.array(r1), np.array(v1)


def path_relative_state(
    r_c: ArrayLike,
    v_c: ArrayLike,
    r_d: ArrayLike,
    v_d: ArrayLike,
    v_ref: float,
    *,
    j2: bool = True,
    iterations: int = 2,
) -> NDArray[np.float64]:
    """The deputy's state (6,) against the chief's path (module docstring).

    r_c, v_c, r_d, v_d : (3,) inertial, m and m/s.  v_ref : the reference orbital speed
    n a (m/s) that turns the time lag into a distance.  Returns [x, y, z, xdot, ydot, zdot]:
    x = |r_d| - |r_c(t - tau)|, y = -v_ref tau, z and zdot out of the chief's plane there,
    xdot = r'_d - r'_c(t - tau) (1 - tau'), ydot = -v_ref tau'.
    """
    if not (v_ref > 0 and math.isfinite(v_ref)):
        raise ValueError(f"v_ref must be a positive speed, got {v_ref}")
    rc0, vc0 = _vec3(r_c, "r_c"), _vec3(v_c, "v_c")
    rd, vd = _vec3(r_d, "r_d"), _vec3(v_d, "v_d")
    tau = 0.0
    rc, vc = rc0, vc0
    for _ in range(iterations):
        # the deputy's angle ahead of the chief's point, in that point's orbit plane
        h = _cross3(rc, vc)
        r2 = _dot(rc, rc)
        rn, hn = math.sqrt(r2), math.sqrt(_dot(h, h))
        x_hat = (rc[0] / rn, rc[1] / rn, rc[2] / rn)
        z_hat = (h[0] / hn, h[1] / hn, h[2] / hn)
        theta = math.atan2(_dot(_cross3(z_hat, x_hat), rd), _dot(x_hat, rd))
        tau -= theta / (hn / r2)  # over the chief's u'
        rc, vc = _rk4_gravity(rc0, vc0, -tau, j2, 5.0)
    rel = _curvilinear3(rc, vc, rd, vd)
    r02 = _dot(rc, rc)
    r0 = math.sqrt(r02)
    h = _cross3(rc, vc)
    rate = math.sqrt(_dot(h, h)) / r02
    r0_dot = _dot(rc, vc) / r0
    # u'_d = u'_c + theta' with r0 theta' = ydot - r0' theta, so tau' = 1 - u'_d / u'_c
    tau_dot = -(rel[4] - r0_dot * rel[1] / r0) / (r0 * rate)
    return np.array(
        [
            rel[0],
            -v_ref * tau,
            rel[2],
            rel[3] + r0_dot * tau_dot,
            -v_ref * tau_dot,
            rel[5],
        ]
    )


def relative_state(
    frame: str,
    chief: ArrayLike,
    deputy: ArrayLike,
    *,
    v_ref: float,
    j2: bool = True,
) -> NDArray[np.float64]:
    """The deputy's relative state (6,) in ``frame`` ('curvilinear' or 'path') from inertial
    states chief (6,) and deputy (6,) [r; v]."""
    c, d = np.asarray(chief, dtype=float), np.asarray(deputy, dtype=float)
    if frame == "curvilinear":
        return hill_to_curvilinear(c[:3], c[3:], rv_to_hill(c[:3], c[3:], d[:3], d[3:]))
    if frame == "path":
        return path_relative_state(c[:3], c[3:], d[:3], d[3:], v_ref, j2=j2)
    raise ValueError(f"unknown navigation frame {frame!r}: expected one of {FRAMES}")
