"""Truth dynamics: two-body + J2 gravity and facet drag, any number of craft.

The environment service propagates the truth with :func:`propagate`, once per flight-software
step, with every spacecraft stacked in one ODE. All functions are pure.

The density is an exponential atmosphere (:class:`Atmosphere`), or, for a truth from an
upper-atmosphere model such as NRLMSIS, each craft's density along its own track over the call
(``ddvi_core.atmosphere.DensityTrack``, evaluated at every integrator stage as cheaply as the
exponential).

Drag model (the one of Basilisk's ``facetDragDynamicEffector``): each craft has one flat facet of
area A, drag coefficient C_D and body-frame unit normal n_B. The flow velocity is the craft's
*inertial* velocity v (no co-rotating atmosphere), the facet's projected area is
A max(0, n_N · v/|v|) with n_N = [BN]^T n_B, and the force is -1/2 rho |v|^2 C_D A_proj v/|v|.

Differences from Basilisk's drag-rendezvous example worth knowing when comparing the backends:
Basilisk reads the density once per task step (60 s there) and holds it over the step, here it
is evaluated at every integrator stage; its example uses rho0 = 2.022e-11 kg/m^3 (the paper and
docs/design.md, "The default mission": 2.2e-11) with the reference radius R_E + 300 km; its
spacecraft follow the commanded attitude reference, which rotates with the Hill frame
(``attitude_frame="hill"`` here).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ddvi_core.atmosphere import DensityTrack
from ddvi_core.constants import J2_EARTH, MU_EARTH, R_EARTH
from ddvi_core.orbit import _dcm_stack, _stack, elements_to_rv

FloatArray = NDArray[np.float64]

__all__ = [
    "DEFAULT_ATOL_POS",
    "DEFAULT_ATOL_VEL",
    "DEFAULT_MAX_STEP",
    "DEFAULT_RTOL",
    "Atmosphere",
    "Spacecraft",
    "acceleration",
    "gravity",
    "propagate",
    "rendezvous_initial_states",
]

_C45 = math.cos(math.radians(45.0))

# Integrator settings, checked by the convergence tests in tests/core/test_truth.py: on 60 s calls
# (J2 and drag on) halving max_step moves the chief-deputy relative Hill position after one orbit
# by 1e-7 m; on a tolerance-driven one-orbit call, tightening rtol/atol ten times moves it 4e-7 m.
DEFAULT_RTOL: float = 1e-11
DEFAULT_ATOL_POS: float = 1e-5  # m
DEFAULT_ATOL_VEL: float = 1e-8  # m/s
DEFAULT_MAX_STEP: float = 60.0  # s


# ------------------------------------------------------------------------------------ parameters


@dataclass(frozen=True)
class Spacecraft:
    """Mass and drag-facet parameters of one spacecraft (defaults: docs/design.md, "The default
    mission").

    Attributes
    ----------
    mass : kg, > 0.
    area : facet area, m^2, >= 0 (0 models a craft without drag).
    cd : drag coefficient, >= 0.
    normal_B : facet unit normal in the body frame, 3 components (|n| = 1 within 1e-9); the
        default is in the body x-y plane at 45 deg, as in Basilisk's drag-rendezvous scenario.
    """

    mass: float = 6.0
    area: float = 0.06
    cd: float = 2.2
    normal_B: tuple[float, float, float] = (_C45, _C45, 0.0)

    def __post_init__(self) -> None:
        for name in ("mass", "area", "cd"):
            value = float(getattr(self, name))
            if not math.isfinite(value):
                raise ValueError(f"{name} must be finite, got {value}")
            object.__setattr__(self, name, value)
        if self.mass <= 0.0:
            raise ValueError(f"mass must be positive, got {self.mass}")
        if self.area < 0.0:
            raise ValueError(f"area must be non-negative, got {self.area}")
        if self.cd < 0.0:
            raise ValueError(f"cd must be non-negative, got {self.cd}")
        n = np.asarray(self.normal_B, dtype=float)
        if n.shape != (3,) or not np.all(np.isfinite(n)):
            raise ValueError(f"normal_B must be 3 finite numbers, got {self.normal_B!r}")
        if abs(float(np.linalg.norm(n)) - 1.0) > 1e-9:
            raise ValueError(f"normal_B must be a unit vector, |normal_B| = {np.linalg.norm(n)}")
        object.__setattr__(self, "normal_B", (float(n[0]), float(n[1]), float(n[2])))

    @property
    def ballistic(self) -> float:
        """C_D A / m, m^2/kg (the inverse ballistic coefficient at full facet exposure)."""
        return self.cd * self.area / self.mass


@dataclass(frozen=True)
class Atmosphere:
    """Exponential atmosphere rho = density_factor rho0 exp(-(|r| - r_planet - h_ref) / H).

    Attributes
    ----------
    rho0 : density at h_ref, kg/m^3 (> 0).
    h_ref : reference altitude, m.
    scale_height : H, m (> 0).
    density_factor : multiplier (>= 0) for density-mismatch studies; 0 switches drag off.
    r_planet : radius the altitude is measured from, m.
    """

    rho0: float = 2.2e-11
    h_ref: float = 300e3
    scale_height: float = 8e3
    density_factor: float = 1.0
    r_planet: float = R_EARTH

    def __post_init__(self) -> None:
        for name in ("rho0", "h_ref", "scale_height", "density_factor", "r_planet"):
            value = float(getattr(self, name))
            if not math.isfinite(value):
                raise ValueError(f"{name} must be finite, got {value}")
            object.__setattr__(self, name, value)
        if self.rho0 <= 0.0:
            raise ValueError(f"rho0 must be positive, got {self.rho0}")
        if self.scale_height <= 0.0:
            raise ValueError(f"scale_height must be positive, got {self.scale_height}")
        if self.density_factor < 0.0:
            raise ValueError(f"density_factor must be non-negative, got {self.density_factor}")
        if self.r_planet <= 0.0:
            raise ValueError(f"r_planet must be positive, got {self.r_planet}")

    def density(self, r_N: ArrayLike) -> FloatArray:
        """Density at inertial positions r_N, (3,) -> () or (N, 3) -> (N,), kg/m^3."""
        r, single = _stack(r_N, "r_N")
        rho = self._density_of_radius(np.linalg.norm(r, axis=1))
        return rho[0] if single else rho

    def _density_of_radius(self, rn: FloatArray) -> FloatArray:
        # rho = f rho0 exp(-(rn - r_planet - h_ref)/H), one exp for the whole stack
        return (self.density_factor * self.rho0) * np.exp(
            (self.r_planet + self.h_ref - rn) / self.scale_height
        )


def _craft_arrays(
    craft: Spacecraft | Sequence[Spacecraft], n: int
) -> tuple[FloatArray, FloatArray]:
    """(C_D A / m (N,), n_B (N, 3)) for one Spacecraft (shared) or a sequence of N."""
    if isinstance(craft, Spacecraft):
        items: Sequence[Spacecraft] = [craft] * n
    else:
        items = list(craft)
        if len(items) != n:
            raise ValueError(f"craft must be one Spacecraft or {n} of them, got {len(items)}")
        for k, c in enumerate(items):
            if not isinstance(c, Spacecraft):
                raise ValueError(f"craft[{k}] must be a Spacecraft, got {type(c).__name__}")
    bc = np.array([c.ballistic for c in items])
    normal_B = np.array([c.normal_B for c in items])
    return bc, normal_B


# -------------------------------------------------------------------------------- acceleration


def _gravity(r: FloatArray, rn: FloatArray, j2: bool, mu: float) -> FloatArray:
    """Two-body (+ J2) acceleration, (N, 3)."""
    inv_r3 = 1.0 / (rn * rn * rn)
    acc = (-mu * inv_r3)[:, None] * r
    if j2:
        zr2 = (r[:, 2] / rn) ** 2
        k = (-1.5 * J2_EARTH * mu * R_EARTH * R_EARTH) * inv_r3 / (rn * rn)
        f_xy = k * (1.0 - 5.0 * zr2)
        acc[:, 0] += f_xy * r[:, 0]
        acc[:, 1] += f_xy * r[:, 1]
        acc[:, 2] += (k * (3.0 - 5.0 * zr2)) * r[:, 2]
    return acc


def gravity(r_N: ArrayLike, *, j2: bool = True, mu: float = MU_EARTH) -> FloatArray:
    """Two-body (+ J2) acceleration (3,) or (N, 3), m/s^2, at inertial positions r_N (m)."""
    r, single = _stack(r_N, "r_N")
    acc = _gravity(r, np.sqrt(np.einsum("ij,ij->i", r, r)), j2, mu)
    return acc[0] if single else acc


def acceleration(
    r_N: ArrayLike,
    v_N: ArrayLike,
    dcm_BN: ArrayLike,
    craft: Spacecraft | Sequence[Spacecraft] = Spacecraft(),
    atmosphere: Atmosphere = Atmosphere(),
    *,
    j2: bool = True,
    drag: bool = True,
    mu: float = MU_EARTH,
) -> FloatArray:
    """Inertial acceleration of N spacecraft: two-body + J2 (zonal, z = spin axis) + facet drag.

    Parameters
    ----------
    r_N, v_N : (N, 3) (or (3,)) inertial positions (m) and velocities (m/s).
    dcm_BN : (N, 3, 3) (or (3, 3)) body attitudes [BN].
    craft : one Spacecraft shared by all, or a sequence of N.
    atmosphere : exponential atmosphere.
    j2, drag : switch the J2 and drag terms.
    mu : gravitational parameter, m^3/s^2.

    Returns
    -------
    (N, 3) (or (3,)) acceleration, m/s^2.
    """
    r, single = _stack(r_N, "r_N")
    v, _ = _stack(v_N, "v_N")
    C, _ = _dcm_stack(dcm_BN, "dcm_BN")
    n = r.shape[0]
    if v.shape != r.shape or C.shape[0] != n:
        raise ValueError(
            f"r_N, v_N, dcm_BN must describe the same craft: {r.shape}, {v.shape}, {C.shape}"
        )
    bc, normal_B = _craft_arrays(craft, n)
    normal_N = np.einsum("nji,nj->ni", C, normal_B)  # [BN]^T n_B
    rn = np.sqrt(np.einsum("ij,ij->i", r, r))
    acc = _gravity(r, rn, j2, mu)
    if drag:
        acc += _drag(v, rn, normal_N, bc, atmosphere)
    return acc[0] if single else acc


def _drag(
    v: FloatArray, rn: FloatArray, normal_N: FloatArray, bc: FloatArray, atm: Atmosphere
) -> FloatArray:
    # -1/2 rho |v|^2 C_D A max(0, n·v_hat)/m v_hat  ==  -1/2 rho (C_D A/m) max(0, n·v) v
    nv = np.maximum(np.einsum("ij,ij->i", normal_N, v), 0.0)
    k = -0.5 * atm._density_of_radius(rn) * bc * nv
    return k[:, None] * v


# ---------------------------------------------------------------------------------- propagation


def _checked_interval(t0: float, t1: float) -> tuple[float, float]:
    """(t0, t1) as floats, checked finite with t1 > t0."""
    t0f, t1f = float(t0), float(t1)
    if not (math.isfinite(t0f) and math.isfinite(t1f)) or t1f <= t0f:
        raise ValueError(f"t0 and t1 must be finite with t1 > t0, got t0={t0!r}, t1={t1!r}")
    return t0f, t1f


def _checked_attitude(attitude: ArrayLike, n: int) -> FloatArray:
    """The (n, 3, 3) attitude DCMs, checked proper rotations, one per craft."""
    C, _ = _dcm_stack(attitude, "attitude")
    if C.shape[0] != n:
        raise ValueError(f"attitude must have shape ({n}, 3, 3), got {C.shape}")
    return C


def _check_settings(
    attitude_frame: str, rtol: float, atol_pos: float, atol_vel: float, max_step: float, mu: float
) -> None:
    """Raise ValueError unless the attitude frame is known and the settings are positive."""
    if attitude_frame not in ("inertial", "hill"):
        raise ValueError(f"attitude_frame must be 'inertial' or 'hill', got {attitude_frame!r}")
    for name, value in (("rtol", rtol), ("atol_pos", atol_pos), ("atol_vel", atol_vel)):
        if not (math.isfinite(value) and value > 0.0):
            raise ValueError(f"{name} must be positive, got {value!r}")
    if not (math.isfinite(mu) and mu > 0.0):
        raise ValueError(f"mu must be positive, got {mu!r}")
    if not max_step > 0.0:
        raise ValueError(f"max_step must be positive, got {max_step!r}")


def _checked_t_eval(t_eval: ArrayLike | None, t0: float, t1: float) -> FloatArray | None:
    """t_eval as a (K,) increasing array inside [t0, t1], or None."""
    if t_eval is None:
        return None
    te = np.asarray(t_eval, dtype=float).ravel()
    if te.size == 0 or not np.all(np.isfinite(te)):
        raise ValueError("t_eval must be a non-empty array of finite times")
    if te[0] < t0 or te[-1] > t1 or np.any(np.diff(te) < 0.0):
        raise ValueError(f"t_eval must be increasing and inside [{t0}, {t1}]")
    return te


class _StackedDynamics:
    """dy/dt (6N,) of N craft stacked in y (6N,): two-body + J2 gravity and facet drag, with
    the attitudes C (N, 3, 3) held ([BN], or [BH] when ``hill``).

    The right-hand side runs in scalar Python, craft by craft: for the few craft of a mission,
    numpy's per-call overhead on 3-vectors costs several times the arithmetic (a vectorised
    form only wins beyond about a dozen craft), and DOP853 calls it 16 times a 60 s step."""

    def __init__(
        self,
        C: FloatArray,
        craft: Spacecraft | Sequence[Spacecraft],
        atmosphere: Atmosphere | DensityTrack,
        *,
        hill: bool,
        j2: bool,
        drag: bool,
        mu: float,
    ) -> None:
        n = C.shape[0]
        bc, normal_B = _craft_arrays(craft, n)
        normal = np.einsum("nji,nj->ni", C, normal_B)  # [BN]^T n_B, or [BH]^T n_B in "hill" mode
        self.n, self.hill, self.j2, self.mu = n, hill, j2, mu
        self.k_j2 = -1.5 * J2_EARTH * mu * R_EARTH * R_EARTH
        self.nx, self.ny, self.nz = (normal[:, k].tolist() for k in range(3))
        self.track: tuple[float, tuple[list[float], ...]] | None = None
        if isinstance(atmosphere, DensityTrack):
            if atmosphere.n != n:
                raise ValueError(f"the density track has {atmosphere.n} craft, the state {n}")
            self.use_drag = drag and bool(np.any(bc > 0.0))
            self.track = (atmosphere.t0, atmosphere.coefficients())
            self.drag_k = (-0.5 * bc).tolist()
            self.r_ref = self.inv_h = 0.0
            return
        self.use_drag = drag and atmosphere.density_factor > 0.0 and bool(np.any(bc > 0.0))
        rho_scale = atmosphere.density_factor * atmosphere.rho0
        self.r_ref = atmosphere.r_planet + atmosphere.h_ref
        self.inv_h = 1.0 / atmosphere.scale_height
        self.drag_k = (-0.5 * bc * rho_scale).tolist()

    def __call__(self, t: float, y: FloatArray) -> FloatArray:
        n, mu, j2, k_j2 = self.n, self.mu, self.j2, self.k_j2
        use_drag, hill, r_ref, inv_h = self.use_drag, self.hill, self.r_ref, self.inv_h
        track = self.track
        if track is not None:  # each craft's ln rho = l0 + dl s - (|r| - r0 - dr s)(h0 + dh s)
            s = t - track[0]
            r0, dr, l0, dl, h0, dh = track[1]
        nx_, ny_, nz_, drag_k = self.nx, self.ny, self.nz, self.drag_k
        Y = y.tolist()
        out = [0.0] * (6 * n)
        for i in range(n):
            o = 6 * i
            x, yy, z, vx, vy, vz = Y[o : o + 6]
            r2 = x * x + yy * yy + z * z
            rn = math.sqrt(r2)
            inv_r3 = 1.0 / (r2 * rn)
            f_xy = f_z = -mu * inv_r3
            if j2:
                zr2 = z * z / r2
                k = k_j2 * inv_r3 / r2
                f_xy, f_z = f_xy + k * (1.0 - 5.0 * zr2), f_z + k * (3.0 - 5.0 * zr2)
            ax, ay, az = f_xy * x, f_xy * yy, f_z * z
            if use_drag:
                if hill:
                    # n_N·v with n_N = n_H[0] x_hat + n_H[1] y_hat + n_H[2] z_hat:
                    # x_hat·v = r·v/|r|, y_hat·v = |r × v|/|r|, z_hat·v = 0.
                    hx, hy, hz = yy * vz - z * vy, z * vx - x * vz, x * vy - yy * vx
                    hn = math.sqrt(hx * hx + hy * hy + hz * hz)
                    nv = (nx_[i] * (x * vx + yy * vy + z * vz) + ny_[i] * hn) / rn
                else:
                    nv = nx_[i] * vx + ny_[i] * vy + nz_[i] * vz
                if nv > 0.0:
                    if track is None:
                        kd = drag_k[i] * math.exp((r_ref - rn) * inv_h) * nv
                    else:
                        ln_rho = l0[i] + dl[i] * s + (r0[i] + dr[i] * s - rn) * (h0[i] + dh[i] * s)
                        kd = drag_k[i] * math.exp(ln_rho) * nv
                    ax, ay, az = ax + kd * vx, ay + kd * vy, az + kd * vz
            out[o : o + 6] = (vx, vy, vz, ax, ay, az)
        return np.array(out)


def propagate(
    state: ArrayLike,
    t0: float,
    t1: float,
    attitude: ArrayLike,
    craft: Spacecraft | Sequence[Spacecraft] = Spacecraft(),
    atmosphere: Atmosphere | DensityTrack = Atmosphere(),
    *,
    attitude_frame: Literal["inertial", "hill"] = "inertial",
    j2: bool = True,
    drag: bool = True,
    t_eval: ArrayLike | None = None,
    rtol: float = DEFAULT_RTOL,
    atol_pos: float = DEFAULT_ATOL_POS,
    atol_vel: float = DEFAULT_ATOL_VEL,
    max_step: float = DEFAULT_MAX_STEP,
    mu: float = MU_EARTH,
) -> FloatArray:
    """Propagate N spacecraft from t0 to t1 in one ODE (scipy DOP853), attitudes held.

    Parameters
    ----------
    state : (N, 6) inertial states [r (m), v (m/s)] at t0.
    t0, t1 : interval, s (t1 > t0).
    attitude : (N, 3, 3) attitude DCMs held constant over [t0, t1]:
        - ``attitude_frame="inertial"``: [BN], the body is inertially fixed over the interval;
        - ``attitude_frame="hill"``: [BH] relative to each craft's own instantaneous Hill frame,
          so [BN](t) = [BH] [HN(r(t), v(t))]: the body follows its Hill frame through the
          interval, as an attitude controller tracking a Hill-referenced command does (and as
          Basilisk's drag-rendezvous scenario does). Over a 60 s step the Hill frame turns by
          0.07 rad (4 deg): holding [BN] for 60 s instead moves a deputy at sigma_rel =
          [0, 0, 0.1] by about 9 m per orbit relative to the chief.
    craft : one Spacecraft shared by all craft, or a sequence of N.
    atmosphere : the exponential atmosphere, or each craft's density along its track over
        [t0, t1] (``ddvi_core.atmosphere.DensityTrack``, built for this interval).
    j2, drag : switch the J2 and drag terms.
    t_eval : optional (K,) sample times in [t0, t1] (increasing); when given the result holds
        the states at those times (include t1 to get the final state).
    rtol, atol_pos, atol_vel, max_step : DOP853 settings (defaults: see the module constants).
    mu : gravitational parameter, m^3/s^2.

    Returns
    -------
    (N, 6) state at t1, or (K, N, 6) states at t_eval.

    Notes
    -----
    With the defaults a 60 s call is one DOP853 step (the tolerances are met, max_step binds);
    benchmarks/bench_truth.py measures its cost for 2 to 17 craft and for a 40-orbit mission.
    Halving the step changes the relative Hill position after one orbit by about 1e-7 m.
    """
    y0, _ = _stack(state, "state", 6)
    n = y0.shape[0]
    t0f, t1f = _checked_interval(t0, t1)
    C = _checked_attitude(attitude, n)
    _check_settings(attitude_frame, rtol, atol_pos, atol_vel, max_step, mu)
    te = _checked_t_eval(t_eval, t0f, t1f)

    # imported here, not at module level: navigation imports this module for its constants and
    # kernels and never integrates, and scipy.integrate adds markedly to a process's start-up
    from scipy.integrate import solve_ivp

    hill = attitude_frame == "hill"
    rhs = _StackedDynamics(C, craft, atmosphere, hill=hill, j2=j2, drag=drag, mu=mu)
    atol = np.tile(np.array([atol_pos] * 3 + [atol_vel] * 3), n)
    sol = solve_ivp(
        rhs,
        (t0f, t1f),
        y0.ravel(),
        method="DOP853",
        t_eval=te,
        rtol=rtol,
        atol=atol,
        max_step=max_step,
        first_step=min(max_step, t1f - t0f),
    )
    if not sol.success:  # pragma: no cover - DOP853 on this smooth problem does not fail
        raise RuntimeError(f"propagation failed: {sol.message}")
    if te is None:
        return sol.y[:, -1].reshape(n, 6)
    return sol.y.T.reshape(te.size, n, 6)


# ------------------------------------------------------------------------------------- scenario


def rendezvous_initial_states(mu: float = MU_EARTH) -> FloatArray:
    """Initial inertial states of the ``rendezvous`` scenario (docs/design.md, "The default
    mission").

    Chief: a = 6678.136 km, e = 0, i = 45 deg, RAAN = 20 deg, argp = 30 deg, f = 20 deg.
    Deputy: a = 6678.376 km, f = 19.75 deg, the other elements equal.

    Returns
    -------
    (2, 6) [[r_chief, v_chief], [r_deputy, v_deputy]] in m and m/s.
    """
    d = math.radians
    rc, vc = elements_to_rv(6678.136e3, 0.0, d(45.0), d(20.0), d(30.0), d(20.0), mu)
    rd, vd = elements_to_rv(6678.376e3, 0.0, d(45.0), d(20.0), d(30.0), d(19.75), mu)
    return np.array([np.concatenate((rc, vc)), np.concatenate((rd, vd))])
