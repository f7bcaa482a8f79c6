"""Orbit and attitude kinematics: orbital elements, the Hill frame, modified Rodrigues parameters.

Conventions
-----------
- Vectors are inertial (N-frame, Earth-centred, z the Earth's spin axis) unless named otherwise.
- Hill frame H of a spacecraft at (r, v): x = r/|r| (radial), z = h/|h| with h = r × v (orbit
  normal), y = z × x (along-track for a circular orbit). ``hill_frame`` returns the DCM [HN]
  whose rows are those axes written in N, so that ``HN @ w_N`` gives H-frame components.
- Relative Hill state of a deputy d w.r.t. a chief c: [x, y, z, xdot, ydot, zdot], the position
  of d relative to c and its derivative *as seen from the rotating Hill frame of c*, both in
  H-frame components.
- Attitude: modified Rodrigues parameters (MRP) sigma in the convention of Schaub & Junkins,
  sigma = e tan(phi/4); ``mrp_to_dcm(sigma_BN)`` is the DCM [BN] (N-frame components to B-frame
  components). Functions that return MRPs return the short rotation, |sigma| <= 1.
- A deputy's body attitude is [BN] = [BH(sigma_rel)] [HN] (``body_dcm``).

Every function is pure. Vector arguments accept one vector, shape (3,) (or (6,)), or a stack,
shape (N, 3) (or (N, 6)); the result has the matching leading shape.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ddvi_core.constants import MU_EARTH

FloatArray = NDArray[np.float64]

__all__ = [
    "body_dcm",
    "dcm_to_mrp",
    "elements_to_rv",
    "hill_frame",
    "hill_pointing_mrp",
    "hill_to_curvilinear",
    "hill_to_rv",
    "mrp_add",
    "mrp_shadow",
    "mrp_to_dcm",
    "rv_to_elements",
    "rv_to_hill",
]

# ----------------------------------------------------------------------------------- validation


def _stack(x: ArrayLike, name: str, width: int = 3) -> tuple[FloatArray, bool]:
    """Return ``x`` as a finite (N, width) float array and whether it was a single vector."""
    a = np.asarray(x, dtype=float)
    if a.shape == (width,):
        single = True
        a = a[None, :]
    elif a.ndim == 2 and a.shape[1] == width and a.shape[0] >= 1:
        single = False
    else:
        raise ValueError(f"{name} must have shape ({width},) or (N, {width}), got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name} must be finite")
    return a, single


def _cross(a: FloatArray, b: FloatArray) -> FloatArray:
    """Cross product of (..., 3) arrays.  On small arrays np.cross spends most of its time in
    axis bookkeeping, and navigation calls this tens of times per sample."""
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack((a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0), axis=-1)


def _dcm_stack(x: ArrayLike, name: str, tol: float = 1e-6) -> tuple[FloatArray, bool]:
    """Return ``x`` as a (N, 3, 3) array of proper rotation matrices and whether it was one."""
    a = np.asarray(x, dtype=float)
    if a.shape == (3, 3):
        single = True
        a = a[None]
    elif a.ndim == 3 and a.shape[1:] == (3, 3) and a.shape[0] >= 1:
        single = False
    else:
        raise ValueError(f"{name} must have shape (3, 3) or (N, 3, 3), got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name} must be finite")
    err = np.abs(a @ np.swapaxes(a, 1, 2) - np.eye(3)).max()
    if err > tol or np.any(np.linalg.det(a) < 0.0):
        raise ValueError(
            f"{name} must be a proper rotation matrix (orthonormality error {err:.1e})"
        )
    return a, single


def _scalar(x: float, name: str) -> float:
    v = float(x)
    if not np.isfinite(v):
        raise ValueError(f"{name} must be finite, got {x!r}")
    return v


def _unit(a: FloatArray) -> FloatArray:
    return a / np.linalg.norm(a, axis=-1, keepdims=True)


# ------------------------------------------------------------------------------ orbital elements


def elements_to_rv(
    a: float,
    e: float,
    i: float,
    raan: float,
    argp: float,
    f: float,
    mu: float = MU_EARTH,
) -> tuple[FloatArray, FloatArray]:
    """Inertial position and velocity from classical orbital elements.

    Parameters
    ----------
    a : semi-major axis, m (> 0; elliptic orbits only).
    e : eccentricity, 0 <= e < 1.
    i, raan, argp, f : inclination, right ascension of the ascending node, argument of periapsis,
        true anomaly, rad.
    mu : gravitational parameter, m^3/s^2.

    Returns
    -------
    r_N : (3,) position, m.
    v_N : (3,) velocity, m/s.
    """
    names = ("a", "e", "i", "raan", "argp", "f", "mu")
    values = (a, e, i, raan, argp, f, mu)
    a, e, i, raan, argp, f, mu = (_scalar(x, k) for x, k in zip(values, names, strict=True))
    if a <= 0.0:
        raise ValueError(f"a must be positive, got {a}")
    if not 0.0 <= e < 1.0:
        raise ValueError(f"e must be in [0, 1), got {e}")
    if mu <= 0.0:
        raise ValueError(f"mu must be positive, got {mu}")
    p = a * (1.0 - e * e)
    r = p / (1.0 + e * np.cos(f))
    u = argp + f  # argument of latitude
    cO, sO, ci, si, cu, su = np.cos(raan), np.sin(raan), np.cos(i), np.sin(i), np.cos(u), np.sin(u)
    # radial and transverse unit vectors in N
    ir = np.array([cO * cu - sO * su * ci, sO * cu + cO * su * ci, su * si])
    it = np.array([-cO * su - sO * cu * ci, -sO * su + cO * cu * ci, cu * si])
    vr = np.sqrt(mu / p) * e * np.sin(f)
    vt = np.sqrt(mu / p) * (1.0 + e * np.cos(f))
    return r * ir, vr * ir + vt * it


def rv_to_elements(
    r_N: ArrayLike, v_N: ArrayLike, mu: float = MU_EARTH
) -> tuple[float, float, float, float, float, float]:
    """Osculating classical elements (a, e, i, raan, argp, f) of an elliptic orbit.

    Angles in rad: i in [0, pi], raan, argp, f in [0, 2 pi). Singular cases follow the usual
    convention: for a circular orbit (e < 1e-11) argp = 0 and f is the argument of latitude; for
    an equatorial orbit (sin i < 1e-11) raan = 0 and argp is measured from the x axis.

    Parameters
    ----------
    r_N, v_N : (3,) inertial position (m) and velocity (m/s).
    """
    (r,), _ = _stack(r_N, "r_N")
    (v,), _ = _stack(v_N, "v_N")
    mu = _scalar(mu, "mu")
    rn = np.linalg.norm(r)
    h = _cross(r, v)
    hn = np.linalg.norm(h)
    if rn == 0.0 or hn == 0.0:
        raise ValueError("r_N and v_N must be non-zero and not parallel")
    energy = 0.5 * (v @ v) - mu / rn
    if energy >= 0.0:
        raise ValueError("the orbit is not elliptic (energy >= 0)")
    a = -mu / (2.0 * energy)
    e_vec = _cross(v, h) / mu - r / rn
    e = float(np.linalg.norm(e_vec))
    i = float(np.arccos(np.clip(h[2] / hn, -1.0, 1.0)))
    node = np.array([-h[1], h[0], 0.0])  # z × h
    nn = np.linalg.norm(node)
    two_pi = 2.0 * np.pi
    if nn > 1e-11 * hn:
        raan = float(np.arctan2(node[1], node[0]) % two_pi)
        n_hat = node / nn
    else:
        raan = 0.0
        n_hat = np.array([1.0, 0.0, 0.0])
    m_hat = _cross(h / hn, n_hat)  # 90 deg ahead of the node in the orbit plane
    u = float(np.arctan2(r @ m_hat, r @ n_hat) % two_pi)  # argument of latitude
    if e > 1e-11:
        argp = float(np.arctan2(e_vec @ m_hat, e_vec @ n_hat) % two_pi)
        f = float((u - argp) % two_pi)
    else:
        argp, f = 0.0, u
    return float(a), e, i, raan, argp, f


# ----------------------------------------------------------------------------------- Hill frame


def hill_frame(r_N: ArrayLike, v_N: ArrayLike) -> FloatArray:
    """DCM [HN] of the Hill (radial / along-track / orbit-normal) frame.

    Parameters
    ----------
    r_N, v_N : (3,) or (N, 3) inertial position and velocity.

    Returns
    -------
    HN : (3, 3) or (N, 3, 3); rows are x = r/|r|, y = z × x, z = (r × v)/|r × v| in N.
    """
    r, single = _stack(r_N, "r_N")
    v, single_v = _stack(v_N, "v_N")
    if r.shape != v.shape:
        raise ValueError(f"r_N and v_N must have the same shape, got {r.shape} and {v.shape}")
    h = _cross(r, v)
    rn = np.linalg.norm(r, axis=1)
    hn = np.linalg.norm(h, axis=1)
    if np.any(rn == 0.0) or np.any(hn <= 1e-12 * rn * np.linalg.norm(v, axis=1)):
        raise ValueError("r_N and v_N must be non-zero and not parallel")
    x = r / rn[:, None]
    z = h / hn[:, None]
    y = _cross(z, x)
    HN = np.stack((x, y, z), axis=1)
    return HN[0] if single and single_v else HN


def _hill_rate(r: FloatArray, v: FloatArray, a: FloatArray | None) -> FloatArray:
    """Angular velocity (3,) of the Hill frame of (r, v) w.r.t. N, in N components.

    omega = (h/r^2) z_hat + (r a_h / h) x_hat; the second term (the rotation of the osculating
    orbit plane) is only included when the chief's acceleration ``a`` is known.
    """
    h = _cross(r, v)
    r2 = r @ r
    omega = h / r2
    if a is not None:
        hn2 = h @ h
        omega = omega + (a @ h) / hn2 * r  # (r a_h / h) r_hat, with a_h = a·h/|h|
    return omega


def rv_to_hill(
    r_c: ArrayLike,
    v_c: ArrayLike,
    r_d: ArrayLike,
    v_d: ArrayLike,
    a_c: ArrayLike | None = None,
) -> FloatArray:
    """Relative Hill state of deputies d w.r.t. a chief c, in c's rotating Hill frame.

    rho_H = [HN] (r_d - r_c),  rho'_H = [HN] ((v_d - v_c) - omega × (r_d - r_c)),
    with omega the Hill frame's angular velocity: h/r^2 about the orbit normal (Keplerian frame
    rate) and, when the chief's inertial acceleration ``a_c`` is given, also (r a_h / h) about the
    radial axis (the rotation of the osculating orbit plane caused by an out-of-plane
    acceleration a_h, such as J2's). That second term is about 1.3e-6 rad/s under J2 at 300 km,
    i.e. 4 cm/s of zdot at 30 km along-track separation.

    Parameters
    ----------
    r_c, v_c : (3,) chief inertial position (m) and velocity (m/s).
    r_d, v_d : (3,) or (N, 3) deputy inertial positions and velocities.
    a_c : optional (3,) chief inertial acceleration, m/s^2.

    Returns
    -------
    x_hill : (6,) or (N, 6) [x, y, z, xdot, ydot, zdot] in m and m/s.
    """
    (rc,), _ = _stack(r_c, "r_c")
    (vc,), _ = _stack(v_c, "v_c")
    rd, single = _stack(r_d, "r_d")
    vd, single_v = _stack(v_d, "v_d")
    if rd.shape != vd.shape:
        raise ValueError(f"r_d and v_d must have the same shape, got {rd.shape} and {vd.shape}")
    ac = None if a_c is None else _stack(a_c, "a_c")[0][0]
    HN = hill_frame(rc, vc)
    omega = _hill_rate(rc, vc, ac)
    dr = rd - rc
    dv = vd - vc - _cross(omega, dr)
    out = np.concatenate((dr @ HN.T, dv @ HN.T), axis=1)
    return out[0] if single and single_v else out


def hill_to_curvilinear(r_c: ArrayLike, v_c: ArrayLike, x_hill: ArrayLike) -> FloatArray:
    """Curvilinear (cylindrical) Hill state from the rectilinear one.

    x = |r_d| - |r_c| (radial separation), y = |r_c| theta (arc length along the chief's orbit
    to the deputy's projection on the orbit plane), z = |r_c| phi (arc length out of the plane),
    with their time derivatives.  The linearised relative dynamics (Clohessy-Wiltshire,
    Schweighart-Sedwick) hold in these coordinates far beyond the few-km range where the
    rectilinear ones do: at 60 km along-track the frame's curvature alone puts y^2 / 2r = 270 m
    into the rectilinear x.

    r_c, v_c : (3,) chief; x_hill : (6,) or (N, 6) from :func:`rv_to_hill`.  Returns the same
    shape.
    """
    (rc,), _ = _stack(r_c, "r_c")
    (vc,), _ = _stack(v_c, "v_c")
    X, single = _stack(x_hill, "x_hill", 6)
    r0 = float(np.linalg.norm(rc))
    r0dot = float(rc @ vc) / r0
    R = X[:, :3] + np.array([r0, 0.0, 0.0])  # deputy position from Earth's centre, Hill axes
    Rd = X[:, 3:] + np.array([r0dot, 0.0, 0.0])  # its rate of change in the rotating frame
    rho2 = R[:, 0] ** 2 + R[:, 1] ** 2
    rho = np.sqrt(rho2)
    rn = np.sqrt(rho2 + R[:, 2] ** 2)
    rn_dot = np.einsum("ij,ij->i", R, Rd) / rn
    theta = np.arctan2(R[:, 1], R[:, 0])
    theta_dot = (R[:, 0] * Rd[:, 1] - R[:, 1] * Rd[:, 0]) / rho2
    phi = np.arctan2(R[:, 2], rho)
    rho_dot = (R[:, 0] * Rd[:, 0] + R[:, 1] * Rd[:, 1]) / rho
    phi_dot = (Rd[:, 2] * rho - R[:, 2] * rho_dot) / (rn * rn)
    position = (rn - r0, r0 * theta, r0 * phi)
    rate = (rn_dot - r0dot, r0dot * theta + r0 * theta_dot, r0dot * phi + r0 * phi_dot)
    out = np.column_stack([*position, *rate])
    return out[0] if single else out


def hill_to_rv(
    r_c: ArrayLike,
    v_c: ArrayLike,
    x_hill: ArrayLike,
    a_c: ArrayLike | None = None,
) -> tuple[FloatArray, FloatArray]:
    """Inverse of :func:`rv_to_hill`: deputy inertial states from relative Hill states.

    Parameters
    ----------
    r_c, v_c : (3,) chief inertial position (m) and velocity (m/s).
    x_hill : (6,) or (N, 6) relative Hill states [x, y, z, xdot, ydot, zdot].
    a_c : optional (3,) chief inertial acceleration (use the same value as in ``rv_to_hill``).

    Returns
    -------
    r_d, v_d : (3,) or (N, 3) deputy inertial position and velocity.
    """
    (rc,), _ = _stack(r_c, "r_c")
    (vc,), _ = _stack(v_c, "v_c")
    xh, single = _stack(x_hill, "x_hill", 6)
    ac = None if a_c is None else _stack(a_c, "a_c")[0][0]
    HN = hill_frame(rc, vc)
    omega = _hill_rate(rc, vc, ac)
    dr = xh[:, :3] @ HN
    dv = xh[:, 3:] @ HN + _cross(omega, dr)
    rd, vd = rc + dr, vc + dv
    return (rd[0], vd[0]) if single else (rd, vd)


# ------------------------------------------------------------------------------------------ MRP


# [s~]_ij = -eps_ijk s_k: the cross-product matrix as one contraction (no per-element stacking)
_NEG_LEVI_CIVITA = np.zeros((3, 3, 3))
for _i, _j, _k in ((0, 1, 2), (1, 2, 0), (2, 0, 1)):
    _NEG_LEVI_CIVITA[_i, _j, _k], _NEG_LEVI_CIVITA[_j, _i, _k] = -1.0, 1.0


def _tilde(s: FloatArray) -> FloatArray:
    """(N, 3) -> (N, 3, 3) cross-product matrices."""
    return np.einsum("ijk,nk->nij", _NEG_LEVI_CIVITA, s)


def mrp_to_dcm(sigma: ArrayLike) -> FloatArray:
    """DCM [BN] of the MRP sigma_BN (Schaub & Junkins).

    [BN] = I + (8 [s~]^2 - 4 (1 - |s|^2) [s~]) / (1 + |s|^2)^2,  with [s~]^2 = s s^T - |s|^2 I.

    Parameters
    ----------
    sigma : (3,) or (N, 3).

    Returns
    -------
    (3, 3) or (N, 3, 3).
    """
    s, single = _stack(sigma, "sigma")
    s2 = np.einsum("ij,ij->i", s, s)[:, None, None]
    S2 = s[:, :, None] * s[:, None, :] - s2 * np.eye(3)
    C = np.eye(3) + (8.0 * S2 - 4.0 * (1.0 - s2) * _tilde(s)) / (1.0 + s2) ** 2
    return C[0] if single else C


def _sheppard_map() -> tuple[FloatArray, FloatArray, NDArray[np.intp]]:
    """The ten distinct entries of M = 4 beta beta^T (Schaub & Junkins eq. 3.95) are linear in
    the nine of [C]: U = C.reshape(9) @ W + b, and M[i, j] = U[index[i, j]]."""
    W, b = np.zeros((9, 10)), np.zeros(10)
    index = np.zeros((4, 4), dtype=np.intp)
    entries = [  # (i, j): {flat index of C: coefficient}, constant
        ((0, 0), {0: 1, 4: 1, 8: 1}, 1.0),  # 1 + tr
        ((1, 1), {0: 1, 4: -1, 8: -1}, 1.0),  # 1 + 2 C00 - tr
        ((2, 2), {0: -1, 4: 1, 8: -1}, 1.0),
        ((3, 3), {0: -1, 4: -1, 8: 1}, 1.0),
        ((0, 1), {5: 1, 7: -1}, 0.0),  # C12 - C21
        ((0, 2), {6: 1, 2: -1}, 0.0),  # C20 - C02
        ((0, 3), {1: 1, 3: -1}, 0.0),  # C01 - C10
        ((1, 2), {1: 1, 3: 1}, 0.0),  # C01 + C10
        ((1, 3), {6: 1, 2: 1}, 0.0),  # C20 + C02
        ((2, 3), {5: 1, 7: 1}, 0.0),  # C12 + C21
    ]
    for u, ((i, j), coefficients, constant) in enumerate(entries):
        for flat, c in coefficients.items():
            W[flat, u] = c
        b[u] = constant
        index[i, j] = index[j, i] = u
    return W, b, index


_SHEPPARD_W, _SHEPPARD_B, _SHEPPARD_INDEX = _sheppard_map()


def dcm_to_mrp(dcm: ArrayLike) -> FloatArray:
    """Short-rotation MRP (|sigma| <= 1) of a DCM [BN] (Sheppard's quaternion method).

    The symmetric matrix M = 4 beta beta^T is read off [BN] (Schaub & Junkins eq. 3.95); the
    row of its largest diagonal entry, over 2 sqrt of that entry, is beta.

    Parameters
    ----------
    dcm : (3, 3) or (N, 3, 3) proper rotation matrices.

    Returns
    -------
    sigma : (3,) or (N, 3).
    """
    C, single = _dcm_stack(dcm, "dcm")
    n = C.shape[0]
    U = C.reshape(n, 9) @ _SHEPPARD_W + _SHEPPARD_B
    k = np.argmax(U[:, :4], axis=1)  # the diagonal of M comes first
    row = U[np.arange(n)[:, None], _SHEPPARD_INDEX[k]]
    beta = row / (2.0 * np.sqrt(U[np.arange(n), k]))[:, None]
    beta[beta[:, 0] < 0.0] *= -1.0  # beta0 >= 0  <=>  |sigma| <= 1
    sigma = beta[:, 1:] / (1.0 + beta[:, :1])
    return sigma[0] if single else sigma


def mrp_shadow(sigma: ArrayLike) -> FloatArray:
    """Map MRPs to the short rotation: sigma if |sigma| <= 1, else -sigma/|sigma|^2.

    Parameters
    ----------
    sigma : (3,) or (N, 3).
    """
    s, single = _stack(sigma, "sigma")
    s2 = np.einsum("ij,ij->i", s, s)[:, None]
    out = np.where(s2 > 1.0, -s / np.where(s2 > 0.0, s2, 1.0), s)
    return out[0] if single else out


def mrp_add(sigma1: ArrayLike, sigma2: ArrayLike) -> FloatArray:
    """Compose two rotations: sigma1 = sigma_FN, sigma2 = sigma_BF -> sigma_BN (short rotation).

    Equivalent to ``dcm_to_mrp(mrp_to_dcm(sigma2) @ mrp_to_dcm(sigma1))``: [BN] = [BF][FN].

    Parameters
    ----------
    sigma1, sigma2 : (3,) or (N, 3) (broadcast against each other).
    """
    s1, single1 = _stack(sigma1, "sigma1")
    s2, single2 = _stack(sigma2, "sigma2")
    if s1.shape[0] != s2.shape[0] and 1 not in (s1.shape[0], s2.shape[0]):
        raise ValueError(f"sigma1 and sigma2 stacks differ in length: {s1.shape} vs {s2.shape}")
    out = dcm_to_mrp(mrp_to_dcm(s2) @ mrp_to_dcm(s1))
    return out[0] if single1 and single2 else out


# ----------------------------------------------------------------------------- pointing helpers


def hill_pointing_mrp(r_N: ArrayLike, v_N: ArrayLike) -> FloatArray:
    """MRP sigma_HN of the Hill-pointing attitude (body axes = Hill axes).

    Parameters
    ----------
    r_N, v_N : (3,) or (N, 3).

    Returns
    -------
    (3,) or (N, 3), |sigma| <= 1.
    """
    return dcm_to_mrp(hill_frame(r_N, v_N))


def body_dcm(r_N: ArrayLike, v_N: ArrayLike, sigma_rel: ArrayLike) -> FloatArray:
    """Body attitude [BN] = [BH(sigma_rel)] [HN] of craft commanded relative to their Hill frame.

    Parameters
    ----------
    r_N, v_N : (3,) or (N, 3) the craft's own inertial position and velocity (Basilisk's
        drag-rendezvous scenario composes the command with each craft's own Hill frame).
    sigma_rel : (3,) or (N, 3) MRP of B relative to H.

    Returns
    -------
    (3, 3) or (N, 3, 3).
    """
    HN = hill_frame(r_N, v_N)
    BH = mrp_to_dcm(sigma_rel)
    return BH @ HN
