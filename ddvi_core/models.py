"""Linearised relative dynamics of the mission and the built-in scenarios.

Hill frame: x radial, y along-track, z orbit normal; state [x, y, (z,) xdot, ydot, (zdot)].
Relative dynamics: Clohessy-Wiltshire with J2 by Schweighart-Sedwick (the factor c) and
differential drag linearised about the chief's circular orbit as in Harris et al. (the model of
Basilisk's drag-rendezvous example).  See docs/design.md, "The default mission" and "The
paper's errata", for what the paper prints and what its equations mean.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from ddvi_core.constants import J2_EARTH, MU_EARTH, R_EARTH
from ddvi_core.problem import RegulationProblem

__all__ = [
    "DragRendezvous",
    "drag_allocation",
    "drag_sensitivity",
    "harmonic_exosystem",
    "paper_printed_problem",
    "rendezvous_problem",
    "schweighart_sedwick_c",
    "thrust_rendezvous_problem",
]


def schweighart_sedwick_c(
    a: float, inclination: float, j2: float = J2_EARTH, r_earth: float = R_EARTH
) -> float:
    """c = sqrt(1 + s), s = 3 J2 R_E^2 / (8 a^2) (1 + 3 cos 2i) (Schweighart & Sedwick)."""
    s = 3.0 * j2 * r_earth**2 / (8.0 * a**2) * (1.0 + 3.0 * math.cos(2.0 * inclination))
    return math.sqrt(1.0 + s)


def drag_sensitivity(
    mass: float, area: float, cd: float, normal_angle: float
) -> tuple[float, float]:
    """Ballistic coefficient beta = C_D A_proj / m and its sensitivity d(beta)/d(sigma3).

    One flat facet whose normal lies in the body x-y plane at ``normal_angle`` (rad) from body
    x; the body is Hill-pointing rotated about the orbit normal by phi = 4 atan(sigma3), so the
    projected area on the along-track flow is A sin(normal_angle + phi).  This is Harris et al.'s
    (1/m) sum 4 C_D A n^T (q x) for a single facet.  Returns (beta, dbeta/dsigma3), m^2/kg.
    """
    if mass <= 0 or area <= 0 or cd <= 0:
        raise ValueError("mass, area and C_D must be positive")
    beta = cd * area * math.sin(normal_angle) / mass
    dbeta = 4.0 * cd * area * math.cos(normal_angle) / mass
    return beta, dbeta


def drag_allocation(u: float, normal_angle: float, limit: float) -> tuple[float, float]:
    """The attitude that makes the facet's drag exactly linear in the control input.

    The linear model's input u (B = dbeta/dsigma3 at sigma3 = 0) asks for a projected-area
    fraction sin(alpha) + 4 cos(alpha) u; the facet gives sin(alpha + 4 atan sigma3), which at
    |sigma3| = 0.2 is up to 48% off the line.  This solves sin(alpha + 4 atan sigma3) =
    sin(alpha) + 4 cos(alpha) u for sigma3 (rad, MRP), within |sigma3| <= ``limit`` and the
    monotonic range |alpha + phi| <= 90 deg (the projected area cannot go below zero).
    Returns (sigma3, u_applied): u_applied is the u the drag really follows, u itself unless
    the request was out of reach.  To first order sigma3 = u, so a gain designed for u is a
    gain on sigma3."""
    if not (0.0 < normal_angle < math.pi / 2):
        raise ValueError(f"normal_angle must be in (0, 90) deg, got {math.degrees(normal_angle)}")
    if not math.isfinite(u):
        raise ValueError(f"drag allocation input is not finite: {u}")
    phi_lim = 4.0 * math.atan(limit)
    lo = math.sin(max(normal_angle - phi_lim, 0.0))  # the facet turns edge-on at zero area
    hi = math.sin(min(normal_angle + phi_lim, math.pi / 2))
    s0, slope = math.sin(normal_angle), 4.0 * math.cos(normal_angle)
    s = min(max(s0 + slope * u, lo), hi)
    sigma3 = math.tan((math.asin(s) - normal_angle) / 4.0)
    return sigma3, (s - s0) / slope


def harmonic_exosystem(rates: list[float], constant: bool) -> NDArray[np.float64]:
    """E for v = [1?, cos w1 t, sin w1 t, cos w2 t, sin w2 t, ...]: blocks [[0, -w], [w, 0]]
    (d/dt cos = -w sin, d/dt sin = w cos) after an optional constant mode."""
    blocks = [np.zeros((1, 1))] if constant else []
    blocks += [np.array([[0.0, -w], [w, 0.0]]) for w in rates]
    q = sum(b.shape[0] for b in blocks)
    E = np.zeros((q, q))
    i = 0
    for b in blocks:
        k = b.shape[0]
        E[i : i + k, i : i + k] = b
        i += k
    return E


@dataclass(frozen=True)
class DragRendezvous:
    """Physical parameters of the differential-drag rendezvous (docs/design.md, "The default
    mission")."""

    a_chief: float = 6678.136e3  # m
    inclination: float = math.radians(45.0)
    mass: float = 6.0  # kg
    area: float = 0.06  # m^2
    cd: float = 2.2
    normal_angle: float = math.radians(45.0)
    rho0: float = 2.2e-11  # kg/m^3 at h_ref
    h_ref: float = 300e3  # m
    scale_height: float = 8e3  # m
    j2: bool = True
    mu: float = MU_EARTH
    r_earth: float = R_EARTH
    Q_weight: float = 1.4
    R_weight: float = 1e7
    y_ref: float = 0.0  # along-track slot, m

    @property
    def mean_motion(self) -> float:
        return math.sqrt(self.mu / self.a_chief**3)

    @property
    def density(self) -> float:
        h = self.a_chief - self.r_earth
        return self.rho0 * math.exp(-(h - self.h_ref) / self.scale_height)

    def with_(self, **changes) -> DragRendezvous:
        return replace(self, **changes)

    def in_plane_matrices(self) -> tuple[NDArray, NDArray]:
        """A (4,4), B (4,1) for x = [x, y, xdot, ydot], u = sigma3.

        Drag terms (v = n r_c the orbital speed, rho the chief's density, beta the nominal
        ballistic coefficient): radial damping -rho beta v / 2, along-track damping
        -rho beta v, density gradient rho_d = rho (1 - x/H) giving +rho beta v^2 / (2H) x,
        and the deputy's inertial speed v + ydot + n x.  B: d(ydd)/d(sigma3) =
        -rho v^2 / 2 * dbeta/dsigma3 (more area, more drag, the deputy falls back).
        """
        n = self.mean_motion
        c = schweighart_sedwick_c(self.a_chief, self.inclination) if self.j2 else 1.0
        v = n * self.a_chief
        rho = self.density
        beta, dbeta = drag_sensitivity(self.mass, self.area, self.cd, self.normal_angle)
        kd = rho * beta * v  # 1/s, about 2.6e-9
        A = np.array(
            [
                [0.0, 0.0, 1.0, 0.0],
                [0.0, 0.0, 0.0, 1.0],
                [(5 * c**2 - 2) * n**2, 0.5 * kd * n, -0.5 * kd, 2 * n * c],
                [0.5 * kd * v / self.scale_height - kd * n, 0.0, -2 * n * c, -kd],
            ]
        )
        B = np.array([[0.0], [0.0], [0.0], [-0.5 * rho * v**2 * dbeta]])
        return A, B


def rendezvous_problem(params: DragRendezvous | None = None) -> RegulationProblem:
    """The default mission: in-plane state (n = 4), u = sigma3 (m = 1), e = y - y_ref (p = 1),
    exosystem v = [1, cos nt, sin nt, cos 2nt, sin 2nt] (q = 5): the constant mode carries the
    reference and any differential-drag bias, the harmonics the periodic J2 and density terms.
    The nominal model has identical craft, so D = 0: the truth supplies whatever it supplies,
    and the learner measures it."""
    p = params or DragRendezvous()
    A, B = p.in_plane_matrices()
    n = p.mean_motion
    E = harmonic_exosystem([n, 2 * n], constant=True)
    C = np.array([[0.0, 1.0, 0.0, 0.0]])
    F = np.zeros((1, 5))
    F[0, 0] = -p.y_ref
    D = np.zeros((4, 5))
    return RegulationProblem(
        A=A,
        B=B,
        C=C,
        D=D,
        E=E,
        F=F,
        Q=p.Q_weight * np.eye(4),
        R=np.array([[p.R_weight]]),
        name="rendezvous",
    )


def thrust_rendezvous_problem(
    params: DragRendezvous | None = None,
    ellipse: float = 200.0,
    cross_track: float = 100.0,
    disturbance: float = 1e-6,
) -> RegulationProblem:
    """Same orbit, 3-axis thrust: x = [x, y, z, xdot, ydot, zdot] (n = 6), B = [0; I3/m]
    (m = 3), e = position - reference (p = 3), exosystem at n, 2n, 3n, 4n (q = 8).

    The reference is a natural relative orbit of size ``ellipse`` (the 2:1 HCW ellipse
    x = -a/2 cos nt, y = a sin nt) with a cross-track oscillation z = b sin nt; the
    disturbance is about ``disturbance`` m/s^2 per axis at the higher harmonics.  Q = 1.4 I as
    in the paper; the paper's R = 1e7 weighs a dimensionless attitude, so for a thrust in
    newtons R = Q_weight m^2 / (2n)^4 I3, which puts the closed-loop bandwidth near twice the
    orbit rate (a double integrator with this weight has its poles at about 2n).
    """
    p = params or DragRendezvous()
    n = p.mean_motion
    c = schweighart_sedwick_c(p.a_chief, p.inclination) if p.j2 else 1.0
    A = np.zeros((6, 6))
    A[0:3, 3:6] = np.eye(3)
    A[3, 0] = (5 * c**2 - 2) * n**2
    A[3, 4] = 2 * n * c
    A[4, 3] = -2 * n * c
    A[5, 2] = -(3 * c**2 - 2) * n**2
    B = np.vstack([np.zeros((3, 3)), np.eye(3) / p.mass])
    E = harmonic_exosystem([n, 2 * n, 3 * n, 4 * n], constant=False)
    C = np.hstack([np.eye(3), np.zeros((3, 3))])
    # e = C x + F v = position - reference; v = [cos nt, sin nt, cos 2nt, sin 2nt, ...]
    F = np.zeros((3, 8))
    F[0, 0] = ellipse / 2  # x_ref = -a/2 cos nt
    F[1, 1] = -ellipse  # y_ref = a sin nt
    F[2, 1] = -cross_track  # z_ref = b sin nt
    D = np.zeros((6, 8))
    D[3, 2], D[3, 5] = disturbance, 0.5 * disturbance
    D[4, 3], D[4, 6] = disturbance, -0.5 * disturbance
    D[5, 4], D[5, 7] = disturbance, 0.5 * disturbance
    R = p.Q_weight * p.mass**2 / (2 * n) ** 4 * np.eye(3)
    return RegulationProblem(
        A=A, B=B, C=C, D=D, E=E, F=F, Q=p.Q_weight * np.eye(6), R=R, name="thrust-rendezvous"
    )


def paper_printed_problem() -> RegulationProblem:
    """The matrices exactly as the paper prints them (6 states, 3 inputs, p = 3, q = 8):
    Lambda1 with +n^2 in the z row, Lambda2 with hat-n = n-bar, B with one non-zero row, E at
    0.1..0.4 rad/s, the printed C, F, D, Q = 1.4 I6, R = 1e7 I3, n-bar = 0.00108 1/s,
    r_ref = 6378.136 km and r_c = 300 km as the table lists.  It is kept so that `ddvi check`
    shows which assumption fails and why (docs/design.md, "The paper's errata")."""
    nbar = 0.00108
    r_ref = 6378.136e3
    r_c = 300e3  # the paper's table: an altitude used as a radius (erratum)
    i = math.radians(45.0)
    s = 3 * J2_EARTH * R_EARTH**2 / (8 * r_ref**2) * (1 + 3 * math.cos(2 * i))
    c = math.sqrt(1 + s)
    beta, dbeta = drag_sensitivity(6.0, 0.06, 2.2, math.radians(45.0))
    Pd = 2.2e-11
    damp = beta * Pd * nbar * r_c
    L1 = np.diag([(5 * c**2 - 2) * nbar**2, 0.0, nbar**2])
    L2 = np.array(
        [[-0.5 * damp, 2 * nbar * c, 0.0], [-2 * nbar, -damp, 0.0], [0.0, 0.0, -0.5 * damp]]
    )
    A = np.block([[np.zeros((3, 3)), np.eye(3)], [L1, L2]])
    B = np.zeros((6, 3))
    # d(beta)/d(sigma_p) is a row (1x3); only the rotation about the orbit normal matters
    B[4, :] = 0.5 * nbar**2 * r_c**2 * Pd * np.array([0.0, 0.0, dbeta])
    E = harmonic_exosystem([0.1, 0.2, 0.3, 0.4], constant=False)
    C = np.hstack([np.eye(3), np.zeros((3, 3))])
    F = np.hstack([np.eye(3), np.zeros((3, 5))])
    Xi = -3 * nbar**2 * J2_EARTH * R_EARTH**2 / r_ref
    xi = 0.0  # beta_c P_c = beta_d P_d at the equilibrium (the paper's Assumption 3)
    D = np.zeros((6, 8))
    D[3, 2] = D[3, 5] = Xi
    D[4, 4] = Xi + xi
    D[5, 0] = D[5, 6] = Xi
    return RegulationProblem(
        A=A, B=B, C=C, D=D, E=E, F=F, Q=1.4 * np.eye(6), R=1e7 * np.eye(3), name="paper-printed"
    )
