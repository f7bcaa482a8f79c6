"""The mission as the services see it: a deployment mapped onto ddvi_core's models.

One place for what several services must agree on: the chief's mean motion, the exosystem
(v = [1, cos u, sin u, cos 2u, sin 2u] with u = u0 + n t the chief's mean argument of latitude),
the nominal linear model a deputy's controller is given, the truth's initial states, and
whether a deputy's drag can hold its slot.  The truth's own linear model is
``services.model.reference``; the truth backends are ``services.model.truth``.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from ddvi_core.constants import MU_EARTH
from ddvi_core.orbit import elements_to_rv
from ddvi_core.relnav import relative_state
from services.config import Deployment, Deputy, Orbit

if TYPE_CHECKING:
    from ddvi_core.models import DragRendezvous
    from ddvi_core.problem import RegulationProblem

# The model-side imports (scipy.linalg, a large part of a process's start-up) are made inside
# the functions that need them: a navigation process never does, and a swarm starts one per
# deputy.


IN_PLANE = (0, 1, 3, 4)  # [x, y, xdot, ydot] out of the Hill state [x, y, z, xdot, ydot, zdot]


def on_grid(t: float, period: float) -> bool:
    """Whether time t (s) falls on the grid of ``period`` (a navigation or flight-software
    step), to a tolerance far below any step."""
    k = t / period
    return abs(k - round(k)) < 1e-6


def mean_motion(dep: Deployment) -> float:
    return math.sqrt(MU_EARTH / dep.chief.a**3)


def orbit_period(dep: Deployment) -> float:
    return 2.0 * math.pi / mean_motion(dep)


def duration(dep: Deployment) -> float:
    """Mission length in seconds, rounded down to whole flight-software steps."""
    fsw = dep.run.fsw_period
    return math.floor(dep.run.orbits * orbit_period(dep) / fsw + 1e-9) * fsw


def exosystem_matrix(dep: Deployment) -> NDArray[np.float64]:
    from ddvi_core.models import harmonic_exosystem

    n = mean_motion(dep)
    return harmonic_exosystem([n, 2 * n], constant=True)


def exostate(dep: Deployment, t: float) -> tuple[NDArray[np.float64], float]:
    """v(t) (5,) and the phase u(t) (rad): the exact solution of v' = E v."""
    u = math.radians(dep.chief.argp + dep.chief.f) + mean_motion(dep) * t
    return np.array([1.0, math.cos(u), math.sin(u), math.cos(2 * u), math.sin(2 * u)]), u


def nominal_params(dep: Deployment, deputy: Deputy) -> DragRendezvous:
    """What the deputy's controller is told about the plant: nominal, never the truth's
    factors (density_factor, area_factor)."""
    from ddvi_core.models import DragRendezvous

    sc, atm = dep.spacecraft, dep.atmosphere
    return DragRendezvous(
        a_chief=dep.chief.a,
        inclination=math.radians(dep.chief.i),
        mass=sc.mass,
        area=sc.area,
        cd=sc.cd,
        normal_angle=math.radians(sc.normal_angle),
        rho0=atm.rho0,
        h_ref=atm.h_ref,
        scale_height=atm.scale_height,
        j2=dep.environment.j2,
        y_ref=deputy.y_ref,
    )


def nominal_problem(dep: Deployment, deputy: Deputy) -> RegulationProblem:
    from ddvi_core.models import rendezvous_problem

    return rendezvous_problem(nominal_params(dep, deputy))


def optimal_gains(pr: RegulationProblem) -> tuple[NDArray, NDArray]:
    """K (1,4) and L (1,5): the Riccati gain and the regulator feedforward of ``pr``."""
    from ddvi_core.lqr import solve_lqr
    from ddvi_core.regulator import feedforward_gain, solve_regulator_equations

    K = solve_lqr(pr.A, pr.B, pr.Q, pr.R).K
    X, U = solve_regulator_equations(pr.A, pr.B, pr.C, pr.D, pr.E, pr.F)
    return K, feedforward_gain(K, X, U)


def lqr_gains(dep: Deployment, deputy: Deputy) -> tuple[NDArray, NDArray]:
    """K (1,4) and L (1,5) of the model-based baseline from the nominal model."""
    return optimal_gains(nominal_problem(dep, deputy))


def navigation_state(
    dep: Deployment, deputy: Deputy, chief: NDArray, state: NDArray
) -> NDArray[np.float64]:
    """The deputy's true relative state (6,) in its navigation frame, from the inertial
    states (6,) of the chief and the deputy (before noise and bias)."""
    return relative_state(
        deputy.navigation.frame,
        chief,
        state,
        v_ref=mean_motion(dep) * dep.chief.a,
        j2=dep.environment.j2,
    )


def _rv(orbit: Orbit) -> NDArray[np.float64]:
    r, v = elements_to_rv(
        orbit.a,
        orbit.e,
        math.radians(orbit.i),
        math.radians(orbit.raan),
        math.radians(orbit.argp),
        math.radians(orbit.f),
    )
    return np.concatenate([r, v])


def initial_states(dep: Deployment) -> NDArray[np.float64]:
    """(1 + N, 6) inertial states: the chief, then each deputy in deployment order."""
    return np.array([_rv(dep.chief)] + [_rv(d.orbit) for d in dep.deputy])


def holding_margin(
    dep: Deployment,
    deputy: Deputy,
    area_factor: float | None = None,
    normal_angle: float | None = None,
) -> float:
    """How far the deputy's truth drag can be raised above the chief's, as a fraction of the
    chief's: max over |sigma3| <= limit of f A sin(alpha_d + phi) / (f_c A sin alpha) - 1, with
    phi = 4 atan(sigma3) (the facet geometry of ``ddvi_core.models.drag_sensitivity``), f the
    deputy's area factor and alpha_d its facet normal angle (both default to the deployment's:
    pass a panel fault's to ask about after it), f_c the chief's true area factor
    (``chief.area_factor``).  Below zero, no attitude makes the deputy's
    drag match the chief's: it cannot hold a slot, and the along-track error grows whatever
    the controller does."""
    alpha = math.radians(dep.spacecraft.normal_angle)
    alpha_d = alpha if normal_angle is None else math.radians(normal_angle)
    factor = deputy.area_factor if area_factor is None else area_factor
    phi = 4.0 * math.atan(deputy.attitude_limit)
    best = (
        1.0
        if alpha_d - phi <= math.pi / 2 <= alpha_d + phi
        else max(math.sin(alpha_d + phi), math.sin(alpha_d - phi))
    )
    return factor * best / (dep.chief.area_factor * math.sin(alpha)) - 1.0


def facet_normal(angle: float) -> tuple[float, float, float]:
    """The facet's unit normal in body axes for a normal angle (deg from body x, in x-y)."""
    a = math.radians(angle)
    return (math.cos(a), math.sin(a), 0.0)


def panel_schedule(dep: Deployment) -> list[tuple[float, str, float | None, float | None]]:
    """The deployment's panel faults in time order: (t (s), deputy, area_factor,
    normal_angle), as the environment applies them (later faults change only what they give)."""
    period = orbit_period(dep)
    faults = [f for f in dep.fault if f.kind == "panel"]
    return sorted(
        ((f.at_orbits * period, f.deputy, f.area_factor, f.normal_angle) for f in faults),
        key=lambda f: f[0],
    )


def describe_panel(area_factor: float | None, normal_angle: float | None) -> str:
    """A panel fault in words, for logs: "panel area now 0.8 x nominal, normal stuck at 35 deg"."""
    parts = [] if area_factor is None else [f"area now {area_factor:g} x nominal"]
    parts += [] if normal_angle is None else [f"normal stuck at {normal_angle:g} deg"]
    return "panel " + ", ".join(parts)


def holding_warnings(dep: Deployment) -> list[str]:
    """Why a deputy of ``dep`` cannot hold its slot, one sentence each (empty: every deputy
    can): the sentences of :func:`holding_problems`."""
    return [text for _, text in holding_problems(dep)]


def holding_problems(dep: Deployment) -> list[tuple[str, str]]:
    """(deputy name, why it cannot hold its slot) of every deputy of ``dep`` that cannot
    (empty: every deputy can): a deputy whose :func:`holding_margin` is below zero by design,
    then, in time order, one that falls below zero after a panel fault (panel faults of a
    deputy add up: a later fault changes only what it gives).  Warnings, not errors: such a
    mission still flies, its along-track error growing."""
    chief = dep.chief.area_factor
    against = "chief's" if chief == 1.0 else f"chief's (its area factor {chief:g})"
    problems = [
        (
            d.name,
            f"deputy {d.name!r} cannot hold a slot: its largest drag (area factor "
            f"{d.area_factor:g}, |sigma3| <= {d.attitude_limit:g}) is {-margin:.0%} below the "
            f"{against}, so its along-track error will grow",
        )
        for d in dep.deputy
        if (margin := holding_margin(dep, d)) < 0
    ]
    panel: dict[str, tuple[float | None, float | None]] = {}
    for t, sc, new_factor, new_angle in panel_schedule(dep):
        factor, angle = panel.get(sc, (None, None))
        factor = new_factor if new_factor is not None else factor
        angle = new_angle if new_angle is not None else angle
        panel[sc] = factor, angle
        if holding_margin(dep, dep.deputy_named(sc), factor, angle) < 0:
            problems.append(
                (
                    sc,
                    f"after its panel fault at orbit {t / orbit_period(dep):g} deputy {sc!r} "
                    "cannot hold a slot: no attitude within its limit makes its drag match the "
                    "chief's",
                )
            )
    return problems
