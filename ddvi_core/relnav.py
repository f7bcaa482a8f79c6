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

from ddvi_core.constants import MU_EARTH
from ddvi_core.orbit import _cross, hill_to_curvilinear, rv_to_hill
from ddvi_core.truth import _gravity

__all__ = ["FRAMES", "path_relative_state", "propagate_gravity", "relative_state"]

FRAMES = ("curvilinear", "path")


def propagate_gravity(
    r: ArrayLike, v: ArrayLike, dt: float, *, j2: bool = True, max_step: float = 5.0
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Two-body (+ J2) state (3,), (3,) after ``dt`` seconds (either sign), by classical RK4
    with steps of at most ``max_step`` s.  Meant for the seconds of a time lag: over 10 s
    its error is below 1e-6 m; drag (about 1e-5 m/s^2) is left out, 5e-4 m over 10 s."""
    y = np.concatenate([np.asarray(r, dtype=float), np.asarray(v, dtype=float)])
    if y.shape != (6,) or not np.all(np.isfinite(y)) or not math.isfinite(dt):
        raise ValueError(f"propagate_gravity needs finite r (3,), v (3,) and dt, got {y}, {dt}")
    steps = max(1, math.ceil(abs(dt) / max_step))
    h = dt / steps
    r_, v_ = y[None, :3], y[None, 3:]
    for _ in range(steps):
        # RK4 on (r, v) with gravity straight from its kernel: the validated public entry
        # point costs more than the arithmetic at this size
        a1 = _gravity(r_, np.sqrt(np.sum(r_ * r_, axis=1)), j2, MU_EARTH)
        r2 = r_ + 0.5 * h * v_
        v2 = v_ + 0.5 * h * a1
        a2 = _gravity(r2, np.sqrt(np.sum(r2 * r2, axis=1)), j2, MU_EARTH)
        r3 = r_ + 0.5 * h * v2
        v3 = v_ + 0.5 * h * a2
        a3 = _gravity(r3, np.sqrt(np.sum(r3 * r3, axis=1)), j2, MU_EARTH)
        r4 = r_ + h * v3
        v4 = v_ + h * a3
        a4 = _gravity(r4, np.sqrt(np.sum(r4 * r4, axis=1)), j2, MU_EARTH)
        r_, v_ = (
            r_ + h / 6.0 * (v_ + 2 * v2 + 2 * v3 + v4),
            v_ + h / 6.0 * (a1 + 2 * a2 + 2 * a3 + a4),
        )
    y = np.concatenate([r_[0], v_[0]])
    return y[:3], y[3:]


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
    rc0, vc0 = np.asarray(r_c, dtype=float), np.asarray(v_c, dtype=float)
    rd, vd = np.asarray(r_d, dtype=float), np.asarray(v_d, dtype=float)
    tau = 0.0
    rc, vc = rc0, vc0
    for _ in range(iterations):
        # the deputy's angle ahead of the chief's point, in that point's orbit plane
        h = _cross(rc, vc)
        r2 = float(rc @ rc)
        x_hat = rc / math.sqrt(r2)
        z_hat = h / math.sqrt(float(h @ h))
        theta = math.atan2(float(_cross(z_hat, x_hat) @ rd), float(x_hat @ rd))
        tau -= theta / (math.sqrt(float(h @ h)) / r2)  # over the chief's u'
        rc, vc = propagate_gravity(rc0, vc0, -tau, j2=j2)
    rel = hill_to_curvilinear(rc, vc, rv_to_hill(rc, vc, rd, vd))
    r0 = float(np.linalg.norm(rc))
    rate = float(np.linalg.norm(_cross(rc, vc)) / (r0 * r0))
    r0_dot = float(rc @ vc) / r0
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
