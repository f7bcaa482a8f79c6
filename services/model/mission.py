"""The mission as the services see it: a deployment mapped onto ddvi_core's models.

One place for what several services must agree on: the chief's mean motion, the exosystem
(v = [1, cos u, sin u, cos 2u, sin 2u] with u = u0 + n t the chief's mean argument of latitude),
the nominal linear model a deputy's controller is given, and the truth's initial states.
"""

from __future__ import annotations

import dataclasses
import math
from typing import TYPE_CHECKING, Protocol

import numpy as np
from numpy.typing import NDArray

from ddvi_core.constants import MU_EARTH, R_EARTH
from ddvi_core.orbit import elements_to_rv, mrp_to_dcm
from ddvi_core.relnav import relative_state
from ddvi_core.truth import Atmosphere, Spacecraft, propagate
from services.config import Deployment, Deputy, Orbit, check_panel

if TYPE_CHECKING:
    from ddvi_core.models import DragRendezvous
    from ddvi_core.problem import RegulationProblem

# The model-side imports (scipy.linalg, about 0.3 s) are made inside the functions that need
# them: a navigation process never does, and a swarm starts one per deputy.


class ReentryError(RuntimeError):
    """The truth cannot go on: a craft fell below the deployment's minimum altitude (or the
    integrator failed on the way there).  The message names the craft, its altitude and when."""


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


def lqr_gains(dep: Deployment, deputy: Deputy) -> tuple[NDArray, NDArray]:
    """K (1,4) and L (1,5) of the model-based baseline from the nominal model."""
    from ddvi_core.lqr import solve_lqr
    from ddvi_core.regulator import feedforward_gain, solve_regulator_equations

    pr = nominal_problem(dep, deputy)
    K = solve_lqr(pr.A, pr.B, pr.Q, pr.R).K
    X, U = solve_regulator_equations(pr.A, pr.B, pr.C, pr.D, pr.E, pr.F)
    return K, feedforward_gain(K, X, U)


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
    dep: Deployment, deputy: Deputy, area_factor: float | None = None,
    normal_angle: float | None = None,
) -> float:  # fmt: skip
    """How far the deputy's truth drag can be raised above the chief's, as a fraction of the
    chief's: max over |sigma3| <= limit of f A sin(alpha_d + phi) / (A sin alpha) - 1, with
    phi = 4 atan(sigma3) (the facet geometry of ``ddvi_core.models.drag_sensitivity``), f the
    deputy's area factor and alpha_d its facet normal angle (both default to the deployment's:
    pass a panel fault's to ask about after it).  Below zero, no attitude makes the deputy's
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
    return factor * best / math.sin(alpha) - 1.0


def facet_normal(angle: float) -> tuple[float, float, float]:
    """The facet's unit normal in body axes for a normal angle (deg from body x, in x-y)."""
    a = math.radians(angle)
    return (math.cos(a), math.sin(a), 0.0)


def truth_craft(dep: Deployment) -> list[Spacecraft]:
    """The truth's spacecraft: the nominal design, each deputy's facet area times its
    area_factor; facet normal in the body x-y plane."""
    sc = dep.spacecraft
    normal = facet_normal(sc.normal_angle)
    craft = [Spacecraft(mass=sc.mass, area=sc.area, cd=sc.cd, normal_B=normal)]
    for d in dep.deputy:
        craft.append(
            Spacecraft(mass=sc.mass, area=sc.area * d.area_factor, cd=sc.cd, normal_B=normal)
        )
    return craft


def truth_atmosphere(dep: Deployment) -> Atmosphere:
    atm = dep.atmosphere
    return Atmosphere(
        rho0=atm.rho0,
        h_ref=atm.h_ref,
        scale_height=atm.scale_height,
        density_factor=dep.environment.density_factor,
    )


def truth_step(
    dep: Deployment,
    state: NDArray,
    t_k: float,
    sigma: NDArray,
    craft: list[Spacecraft],
    atmosphere: Atmosphere,
) -> tuple[NDArray, NDArray]:
    """Propagate the truth over one flight-software step from t_k with each deputy's relative
    MRP ``sigma`` (N, 3) held (chief Hill-pointing).  Returns the navigation sample times
    (K,) in (t_k, t_k + fsw] and the states there (K, 1 + N, 6)."""
    run = dep.run
    samples = t_k + run.nav_period * np.arange(1, round(run.fsw_period / run.nav_period) + 1)
    attitudes = np.concatenate([np.eye(3)[None], mrp_to_dcm(sigma).reshape(-1, 3, 3)])
    env = dep.environment
    try:
        traj = propagate(
            state,
            t_k,
            t_k + run.fsw_period,
            attitudes,
            craft,
            atmosphere,
            attitude_frame="hill",
            j2=env.j2,
            drag=env.drag,
            t_eval=samples,
            max_step=env.max_step,
            rtol=env.rtol,
        )
    except RuntimeError as exc:  # the integrator gives up only on a plunging orbit
        raise ReentryError(f"truth propagation failed after t = {t_k:.0f} s: {exc}") from exc
    check_altitude(dep, samples, traj)
    return samples, traj


def check_altitude(dep: Deployment, samples: NDArray, traj: NDArray) -> None:
    """Raise ReentryError, naming the craft, when any sample of ``traj`` (K, 1 + N, 6) at
    ``samples`` (K,) is below environment.min_altitude: the truth of any backend ends there."""
    env = dep.environment
    altitude = np.linalg.norm(traj[:, :, :3], axis=2) - R_EARTH
    if np.any(low := altitude < env.min_altitude):
        k, i = np.argwhere(low)[0]
        name = "chief" if i == 0 else dep.deputy[i - 1].name
        raise ReentryError(
            f"{name} fell to {altitude[k, i] / 1e3:.1f} km altitude at t = {samples[k]:.0f} s "
            f"(orbit {samples[k] / orbit_period(dep):.1f}), below environment.min_altitude = "
            f"{env.min_altitude / 1e3:g} km: it has re-entered; shorten run.orbits or lower "
            "the density"
        )


class Truth(Protocol):
    """An environment backend: the truth of every craft, stepped one flight-software step at a
    time.  ``state`` is the (1 + N, 6) inertial state now (chief first); ``step`` propagates
    it over one flight-software step from t_k with each deputy's relative MRP ``sigma`` (N, 3)
    held and the chief Hill-pointing, and returns the navigation sample times (K,) in
    (t_k, t_k + fsw] and the states there (K, 1 + N, 6); it raises ReentryError when a craft
    falls below environment.min_altitude."""

    @property
    def state(self) -> NDArray[np.float64]: ...

    def step(self, t_k: float, sigma: NDArray) -> tuple[NDArray, NDArray]: ...

    def set_panel(
        self, deputy: int, area_factor: float | None = None, normal_angle: float | None = None
    ) -> None:
        """A panel fault: from the next step on, deputy number ``deputy``'s true facet area is
        ``area_factor`` times the nominal design's and/or its facet normal is stuck at
        ``normal_angle`` (deg in the body x-y plane); None leaves either as it is.  Raises
        ValueError for a value out of range, RuntimeError where the backend cannot."""
        ...

    def close(self) -> None: ...


class BuiltinTruth:
    """The built-in backend: ``ddvi_core.truth`` (two-body + J2 + facet drag in one ODE)."""

    def __init__(self, dep: Deployment) -> None:
        self._dep = dep
        self._state = initial_states(dep)
        self._craft, self._atmosphere = truth_craft(dep), truth_atmosphere(dep)

    @property
    def state(self) -> NDArray[np.float64]:
        return self._state

    def step(self, t_k: float, sigma: NDArray) -> tuple[NDArray, NDArray]:
        samples, traj = truth_step(
            self._dep, self._state, t_k, sigma, self._craft, self._atmosphere
        )
        self._state = traj[-1]
        return samples, traj

    def set_panel(
        self, deputy: int, area_factor: float | None = None, normal_angle: float | None = None
    ) -> None:
        check_panel(area_factor, normal_angle)
        craft = self._craft[deputy + 1]
        if area_factor is not None:
            craft = dataclasses.replace(craft, area=self._dep.spacecraft.area * area_factor)
        if normal_angle is not None:
            craft = dataclasses.replace(craft, normal_B=facet_normal(normal_angle))
        self._craft[deputy + 1] = craft

    def close(self) -> None:
        pass


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


def open_truth(dep: Deployment) -> Truth:
    """The truth backend that ``environment.backend`` names: "builtin" or "basilisk" (the
    optional extra: pip install 'ddvi-fsw[basilisk]')."""
    if dep.environment.backend == "basilisk":
        try:
            from services.model.basilisk import BasiliskTruth
        except ImportError as exc:
            raise RuntimeError(
                f'environment.backend = "basilisk" needs Basilisk ({exc}): install the extra '
                "with pip install -e '.[basilisk]', or set backend = \"builtin\""
            ) from exc
        return BasiliskTruth(dep)
    return BuiltinTruth(dep)
