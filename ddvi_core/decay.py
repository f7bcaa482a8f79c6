"""Orbit decay under drag: when a near-circular orbit falls to a minimum altitude.

The semi-major axis a of a near-circular orbit under a drag acceleration against the velocity
decays as (Gauss's variational equation for a, with the perturbing force f_T along the
velocity of a circular orbit, v = sqrt(mu / a))

    da/dt = 2 a^2 v f_T / mu,    f_T = -1/2 rho B v^2,

so

    da/dt = -rho B a^2 v^3 / mu = -rho B sqrt(mu a),

with B = C_D A_exposed / m (m^2/kg) the craft's inverse ballistic coefficient and rho the
density the craft meets, averaged over one revolution (``rho_bar(t, a)``, the caller's: an
exponential profile, or an upper-atmosphere model averaged around the orbit).  The orbit is
taken as circular throughout: an eccentric orbit, whose drag concentrates at perigee, is not
modelled.  Pure functions: no I/O, no model library.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

from ddvi_core.constants import MU_EARTH, R_EARTH

__all__ = ["Decay", "drag_decay"]


@dataclass(frozen=True)
class Decay:
    """The outcome of :func:`drag_decay`.

    Attributes
    ----------
    t_reentry : s, when a falls to r_planet + min_altitude; None when it stays above it up to
        the horizon.
    t_end : s, where the integration ended: t_reentry, or t0 + horizon.
    a_end : m, the semi-major axis at t_end.
    altitude_end : m, a_end - r_planet.
    evaluations : the number of density evaluations made.
    """

    t_reentry: float | None
    t_end: float
    a_end: float
    altitude_end: float
    evaluations: int


def _finite(name: str, value: float) -> float:
    x = float(value)
    if not math.isfinite(x):
        raise ValueError(f"{name} must be finite, got {value!r}")
    return x


def drag_decay(
    a0: float,
    ballistic: float,
    density: Callable[[float, float], float],
    horizon: float,
    *,
    min_altitude: float,
    t0: float = 0.0,
    mu: float = MU_EARTH,
    r_planet: float = R_EARTH,
    rtol: float = 1e-6,
) -> Decay:
    """Integrate da/dt = -rho_bar(t, a) B sqrt(mu a) from a0 at t0 over ``horizon`` seconds
    (scipy.integrate.solve_ivp, RK45), stopping where a falls to r_planet + min_altitude.

    Parameters
    ----------
    a0 : initial semi-major axis, m (> r_planet).
    ballistic : B = C_D A_exposed / m, m^2/kg (>= 0; 0 means no drag).
    density : rho_bar(t, a) -> kg/m^3, the orbit-averaged density at time t (s) on a circular
        orbit of radius a (m); must return a finite, non-negative number.
    horizon : s (> 0): how far past t0 to look.
    min_altitude : m above r_planet (>= 0): the floor, the re-entry altitude.
    t0 : s, the time of a0.
    mu : gravitational parameter, m^3/s^2 (> 0).
    r_planet : the radius altitudes are measured from, m (> 0).
    rtol : the integrator's relative tolerance (in (0, 1)); the absolute one is 1 mm.

    Returns
    -------
    :class:`Decay`: when the orbit reaches the floor (None: not within the horizon), and the
    semi-major axis and altitude where the integration ended.  An a0 already at or below the
    floor re-enters at t0.

    Raises
    ------
    ValueError : an input out of range, or a density that is negative or not finite.
    """
    a0 = _finite("a0", a0)
    ballistic = _finite("ballistic", ballistic)
    horizon, t0 = _finite("horizon", horizon), _finite("t0", t0)
    min_altitude = _finite("min_altitude", min_altitude)
    mu, r_planet, rtol = _finite("mu", mu), _finite("r_planet", r_planet), _finite("rtol", rtol)
    if not callable(density):
        raise ValueError(f"density must be a callable rho_bar(t, a), got {type(density).__name__}")
    if mu <= 0.0 or r_planet <= 0.0:
        raise ValueError(f"mu and r_planet must be positive, got {mu}, {r_planet}")
    if a0 <= r_planet:
        raise ValueError(f"a0 must exceed r_planet = {r_planet} m, got {a0} m")
    if ballistic < 0.0:
        raise ValueError(f"ballistic must be non-negative, got {ballistic} m^2/kg")
    if horizon <= 0.0:
        raise ValueError(f"horizon must be positive, got {horizon} s")
    if min_altitude < 0.0:
        raise ValueError(f"min_altitude must be non-negative, got {min_altitude} m")
    if not 0.0 < rtol < 1.0:
        raise ValueError(f"rtol must be in (0, 1), got {rtol}")
    floor = r_planet + min_altitude
    if a0 <= floor:
        return Decay(t0, t0, a0, a0 - r_planet, 0)
    if ballistic == 0.0:
        return Decay(None, t0 + horizon, a0, a0 - r_planet, 0)

    from scipy.integrate import solve_ivp  # scipy.integrate only when asked (start-up cost)

    calls = 0

    def rate(t: float, y: list[float]) -> list[float]:
        nonlocal calls
        a = max(float(y[0]), floor)  # a stage may overshoot the floor; the event stops there
        rho = float(density(t, a))
        calls += 1
        if not (math.isfinite(rho) and rho >= 0.0):
            raise ValueError(f"density({t:g}, {a:g}) must be finite and non-negative, got {rho}")
        return [-rho * ballistic * math.sqrt(mu * a)]

    def at_floor(t: float, y: list[float]) -> float:
        return float(y[0]) - floor

    at_floor.terminal = True  # type: ignore[attr-defined]
    at_floor.direction = -1.0  # type: ignore[attr-defined]
    sol = solve_ivp(
        rate, (t0, t0 + horizon), [a0], method="RK45", events=at_floor, rtol=rtol, atol=1e-3
    )
    if not sol.success:  # pragma: no cover - a monotone scalar ODE does not fail
        raise RuntimeError(f"decay integration failed: {sol.message}")
    hit = sol.t_events[0]
    t_reentry = float(hit[0]) if len(hit) else None
    a_end = floor if t_reentry is not None else float(sol.y[0, -1])
    t_end = t_reentry if t_reentry is not None else t0 + horizon
    return Decay(t_reentry, t_end, a_end, a_end - r_planet, calls)
