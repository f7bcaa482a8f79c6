"""The truth backends' common ground: the ``Truth`` protocol an environment backend implements,
what every backend shares (the truth's spacecraft and atmosphere, the re-entry check), and the
built-in backend, ``ddvi_core.truth`` stepped one flight-software step at a time.

The Basilisk backend (``services.model.basilisk``) builds on this module;
``services.model.backends.open_truth`` chooses between the two.
"""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING, Protocol

import numpy as np
from numpy.typing import NDArray

from ddvi_core.atmosphere import DensityTrack
from ddvi_core.constants import R_EARTH
from ddvi_core.orbit import mrp_to_dcm
from ddvi_core.truth import Atmosphere, Spacecraft, propagate
from services.config import Deployment, check_panel
from services.model.mission import facet_normal, initial_states, orbit_period

if TYPE_CHECKING:
    from services.model.msis import MsisDensity


class ReentryError(RuntimeError):
    """The truth cannot go on: a craft fell below the deployment's minimum altitude (or the
    integrator failed on the way there).  The message names the craft, its altitude and when."""


def truth_craft(dep: Deployment) -> list[Spacecraft]:
    """The truth's spacecraft: the nominal design, the chief's facet area and each deputy's
    times its area_factor; facet normal in the body x-y plane."""
    sc = dep.spacecraft
    normal = facet_normal(sc.normal_angle)
    chief = Spacecraft(
        mass=sc.mass, area=sc.area * dep.chief.area_factor, cd=sc.cd, normal_B=normal
    )
    craft = [chief]
    for d in dep.deputy:
        craft.append(
            Spacecraft(mass=sc.mass, area=sc.area * d.area_factor, cd=sc.cd, normal_B=normal)
        )
    return craft


def truth_atmosphere(dep: Deployment) -> Atmosphere:
    """The exponential truth atmosphere: the nominal profile times environment.density_factor
    (with atmosphere.model = "nrlmsis" the built-in backend flies NRLMSIS instead)."""
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
    atmosphere: Atmosphere | DensityTrack,
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
    """The built-in backend: ``ddvi_core.truth`` (two-body + J2 + facet drag in one ODE), with
    the exponential atmosphere or NRLMSIS (``services.model.msis``) as the deployment's
    atmosphere.model says."""

    def __init__(self, dep: Deployment) -> None:
        self._dep = dep
        self._state = initial_states(dep)
        self._craft, self._atmosphere = truth_craft(dep), truth_atmosphere(dep)
        self._msis: MsisDensity | None = None
        if dep.atmosphere.model == "nrlmsis":
            from services.model.msis import MsisDensity  # pymsis only when a deployment asks

            self._msis = MsisDensity.from_deployment(dep)

    @property
    def state(self) -> NDArray[np.float64]:
        return self._state

    def step(self, t_k: float, sigma: NDArray) -> tuple[NDArray, NDArray]:
        atmosphere: Atmosphere | DensityTrack = self._atmosphere
        if self._msis is not None:  # each craft's NRLMSIS density along this step's track
            atmosphere = self._msis.track(t_k, t_k + self._dep.run.fsw_period, self._state)
        samples, traj = truth_step(self._dep, self._state, t_k, sigma, self._craft, atmosphere)
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
