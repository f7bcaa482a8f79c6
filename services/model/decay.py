"""Re-entry predicted before flight: the chief's orbit decay under the truth's drag
(``ddvi_core.decay``), and a warning when it falls below environment.min_altitude before the
mission ends.

The deputies hold their slots by matching the chief's drag (``holding_margin``), so the
formation decays with the chief: its decay is the formation's.  The chief flies Hill-pointing
with its facet normal at spacecraft.normal_angle in the body x-y plane, so on a circular orbit
the truth's drag -1/2 rho (C_D A max(0, n.v) / m) v (``ddvi_core.truth``) exposes
A sin(normal_angle) of its facet: B = C_D A sin(normal_angle) / m, A the chief's true area
(spacecraft.area times chief.area_factor).

The density is the truth's, averaged over the chief's first revolution as the truth's gravity
flies it (16 points): the exponential profile times environment.density_factor, or with
atmosphere.model = "nrlmsis" NRLMSIS (times the factor) at those points, the RAAN turned by its
J2 precession at the time asked.  The decay moves the revolution's mean radius and keeps its
shape: J2 holds the mean radius of a craft started on a circular orbit below its initial one
and swings the radius around the orbit, and at the exponential's 8 km scale height that is a
quarter more drag than the initial radius gives (a re-entry at orbit 27 instead of 34 in
deployments/realistic-nav-2x.toml at 2.5x the density).  The decay is that of the mean radius;
the truth ends a run where any sample's altitude falls below the floor, at the bottom of the
swing, where the orbit falls within a fraction of an orbit.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

from ddvi_core.constants import J2_EARTH, MU_EARTH, R_EARTH
from ddvi_core.decay import Decay, drag_decay
from services.config import Deployment
from services.model.mission import duration, initial_states, orbit_period

__all__ = [
    "RING_POINTS",
    "chief_decay",
    "orbit_mean_density",
    "reentry_problems",
    "reentry_warnings",
]

RING_POINTS = 16
"""Points of the chief's first revolution the density is averaged over."""


def _revolution(dep: Deployment) -> NDArray[np.float64]:
    """(RING_POINTS, 3) the chief's positions (m) at RING_POINTS times evenly over its first
    revolution, flown by the truth's gravity (two-body, + J2 when environment.j2) without
    drag.  J2 (and any eccentricity) make its radius swing around the orbit, and its mean
    below the initial semi-major axis: at 300 km and 45 deg, 1.6 km below, with a 5 km swing,
    which at an 8 km scale height is a quarter more drag than the initial radius's."""
    from ddvi_core.truth import propagate

    times = orbit_period(dep) * np.arange(RING_POINTS) / RING_POINTS
    traj = propagate(
        initial_states(dep)[:1],
        0.0,
        orbit_period(dep),
        np.eye(3)[None],
        j2=dep.environment.j2,
        drag=False,
        t_eval=times,
        rtol=1e-7,  # the radius to metres: the density to 1e-4 at an 8 km scale height
        max_step=np.inf,
    )
    return traj[:, 0, :3]


def _density(dep: Deployment, ring: NDArray[np.float64]) -> Callable[[float, float], float]:
    """rho_bar(t, a) kg/m^3: the truth's density averaged over the ``ring`` of positions
    (P, 3) m (:func:`_revolution`), the ring's mean radius moved to a, its shape kept, turned
    about the pole by the J2 precession of the RAAN since time 0 (see the module)."""
    env, atm = dep.environment, dep.atmosphere
    radius = np.linalg.norm(ring, axis=1)
    offset = radius - radius.mean()  # the radius's swing about its mean
    if atm.model != "nrlmsis":  # exp(-(a + offset - R_E - h_ref) / H), averaged over the ring
        scale = atm.rho0 * env.density_factor * float(np.mean(np.exp(-offset / atm.scale_height)))
        return lambda t, a: scale * math.exp((R_EARTH + atm.h_ref - a) / atm.scale_height)
    from services.model.msis import MsisDensity  # pymsis only when a deployment asks

    msis = MsisDensity.from_deployment(dep)
    unit = ring / radius[:, None]
    cos_i = math.cos(math.radians(dep.chief.i))
    points = len(ring)

    def rho_bar(t: float, a: float) -> float:
        # dRAAN/dt = -3/2 n J2 (R_E / a)^2 cos i on a near-circular orbit
        rate = -1.5 * math.sqrt(MU_EARTH / a**3) * J2_EARTH * (R_EARTH / a) ** 2 * cos_i
        turn = rate * t if env.j2 else 0.0
        c, s = math.cos(turn), math.sin(turn)
        x, y = unit[:, 0] * c - unit[:, 1] * s, unit[:, 0] * s + unit[:, 1] * c
        r = (a + offset)[:, None] * np.column_stack((x, y, unit[:, 2]))
        return float(np.mean(msis.density(np.full(points, t), r)))

    return rho_bar


def _circle(dep: Deployment) -> NDArray[np.float64]:
    """(RING_POINTS, 3) points evenly around the chief's orbit plane at its initial
    semi-major axis (a circle: no J2 swing), m."""
    from ddvi_core.orbit import elements_to_rv

    c = dep.chief
    angles = 360.0 * np.arange(RING_POINTS) / RING_POINTS
    args = (math.radians(c.i), math.radians(c.raan), math.radians(c.argp))
    return np.array([elements_to_rv(c.a, 0.0, *args, math.radians(f))[0] for f in angles])


def orbit_mean_density(dep: Deployment, dh: float = 1e3) -> tuple[float, float]:
    """The truth's density averaged around the chief's orbit plane at its initial semi-major
    axis at time 0, kg/m^3, and its local scale height there, m (from the averages ``dh`` m
    below and above): the exponential profile times environment.density_factor, or NRLMSIS's
    at the epoch.  What the truth's linear model (``services.model.reference.true_problem``)
    takes for its density."""
    rho_bar = _density(dep, _circle(dep))
    a = dep.chief.a
    low, high = rho_bar(0.0, a - dh), rho_bar(0.0, a + dh)
    return rho_bar(0.0, a), 2.0 * dh / math.log(low / high)


def chief_decay(dep: Deployment) -> Decay | None:
    """The chief's predicted decay over the mission (``ddvi_core.decay.drag_decay``) under the
    truth's drag, from the mean radius of its first revolution; None when the truth has no
    drag."""
    env, sc = dep.environment, dep.spacecraft
    if not env.drag or env.density_factor <= 0.0:
        return None
    area = sc.area * dep.chief.area_factor  # the chief's true facet area
    ballistic = sc.cd * area * max(0.0, math.sin(math.radians(sc.normal_angle))) / sc.mass
    ring = _revolution(dep)
    return drag_decay(
        float(np.linalg.norm(ring, axis=1).mean()),
        ballistic,
        _density(dep, ring),
        duration(dep),
        min_altitude=env.min_altitude,
        rtol=1e-5,
    )


def reentry_problems(dep: Deployment) -> list[tuple[str, str]]:
    """[("chief", why)] when the chief's predicted decay (:func:`chief_decay`) takes it below
    environment.min_altitude before the mission ends (empty: it stays above).  The deputies
    hold their slots by matching the chief's drag, so the formation decays with the chief and
    the chief stands for it.  A warning, not an error: such a mission flies, and the truth
    ends it where a craft falls below the floor."""
    decay = chief_decay(dep)
    if decay is None or decay.t_reentry is None:
        return []
    orbit = decay.t_reentry / orbit_period(dep)
    floor_km = dep.environment.min_altitude / 1e3
    return [
        (
            "chief",
            f"the chief is predicted to re-enter (fall below environment.min_altitude = "
            f"{floor_km:g} km) at about orbit {orbit:.1f} of the mission's {dep.run.orbits:g}, "
            "from the truth's drag decay: the run will end early; shorten run.orbits to at most "
            f"{math.floor(orbit):d}, or raise the orbit or lower the density",
        )
    ]


def reentry_warnings(dep: Deployment) -> list[str]:
    """The sentences of :func:`reentry_problems` (empty: no re-entry predicted)."""
    return [text for _, text in reentry_problems(dep)]
