"""The Basilisk environment backend: the truth integrated by Basilisk, as in the paper.

Chosen with ``environment.backend = "basilisk"`` in a deployment; needs the optional extra
(``pip install -e '.[basilisk]'``).  Everything else (navigation, controllers, monitor, the
environment service's bus traffic) is unchanged: :class:`BasiliskTruth` implements
``services.model.truth.Truth`` as :class:`services.model.truth.BuiltinTruth` does.

One Basilisk ``Spacecraft`` per craft (the chief, then each deputy), each with

- gravity: Earth as central body with ``MU_EARTH``; with ``environment.j2`` a spherical-harmonics
  model of degree 2 whose only non-zero coefficient is the normalised C20 = -J2/sqrt(5), set in
  code (so no gravity file need be fetched).  Without SPICE the planet frame is the
  inertial frame, so J2 acts about inertial z as in the built-in truth;
- drag (with ``environment.drag``): ``exponentialAtmosphere`` and a one-facet
  ``facetDragDynamicEffector`` with the deployment's area (times the deputy's area_factor),
  C_D and normal.  Basilisk's atmosphere gives zero density below its ``planetRadius``, so the
  reference radius is R_E and the base density is rho0 exp(h_ref / H): the same profile as the
  built-in rho0 exp(-(h - h_ref) / H);
- attitude: prescribed through the hub's ``attRefInMsg``, as Basilisk's drag-rendezvous example
  does: ``simpleNav`` -> ``hillPoint`` (the craft's own Hill frame) -> ``attRefCorrection`` with
  sigma_BcB = -sigma (so [BH] is the commanded relative MRP; zero for the chief).

Differences from the built-in truth, by design of Basilisk: a fixed-step RK4 at
``environment.basilisk_step`` (1 s by default), with the density and the attitude reference
refreshed once per step and held over it (the built-in truth evaluates both at every stage of
an adaptive DOP853).  Agreement, measured in tests/model/test_basilisk.py: one orbit of the default
chief and deputy under varying commands, relative Hill position within 4e-7 m without drag (J2
on or off) and 0.16 m with drag, of the 36 m drag moves the deputy in that orbit (the hold
error, proportional to the step).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from Basilisk.architecture import bskLogging
from Basilisk.fswAlgorithms import attRefCorrection, hillPoint
from Basilisk.simulation import (
    exponentialAtmosphere,
    facetDragDynamicEffector,
    simpleNav,
    spacecraft,
)
from Basilisk.simulation.sphericalHarmonicsGravityModel import SphericalHarmonicsGravityModel
from Basilisk.utilities import SimulationBaseClass, simIncludeGravBody
from numpy.typing import NDArray

from ddvi_core.constants import J2_EARTH, MU_EARTH, R_EARTH
from services.config import Deployment
from services.model.mission import initial_states
from services.model.truth import check_altitude, truth_craft

_NS = 1_000_000_000  # Basilisk's clock counts nanoseconds
_TASK = "truth"


def _ns(t: float) -> int:
    return round(t * _NS)


class BasiliskTruth:
    """The truth of every craft in one Basilisk simulation, stepped one flight-software step
    per ``step`` call (ConfigureStopTime + ExecuteSimulation) and sampled at the navigation
    period by a state recorder on each craft."""

    def __init__(self, dep: Deployment) -> None:
        env = dep.environment
        h_ratio = dep.atmosphere.h_ref / dep.atmosphere.scale_height
        if env.drag and h_ratio > 700.0:  # exp() overflows past 709
            raise ValueError(
                f"atmosphere.h_ref / atmosphere.scale_height = {h_ratio:.0f} is too large for "
                "Basilisk's exponential atmosphere (its base density is taken at R_E): keep it "
                "below 700"
            )
        bskLogging.setDefaultLogLevel(bskLogging.BSK_WARNING)
        self._dep = dep
        self._state = initial_states(dep)
        self._sigma_BN = np.full((len(self._state), 3), np.nan)
        self._sim = SimulationBaseClass.SimBaseClass()
        self._sim.CreateNewProcess("dynamics").addTask(
            self._sim.CreateNewTask(_TASK, _ns(env.basilisk_step))
        )
        # Basilisk's objects are kept referenced here: SWIG lets Python free them otherwise.
        self._keep: list[Any] = []
        gravity = simIncludeGravBody.gravBodyFactory()
        earth = gravity.createEarth()
        earth.isCentralBody = True
        earth.mu, earth.radEquator = MU_EARTH, R_EARTH
        if env.j2:
            harmonics = SphericalHarmonicsGravityModel()
            harmonics.muBody, harmonics.radEquator, harmonics.maxDeg = MU_EARTH, R_EARTH, 2
            harmonics.cBar = [[1.0], [0.0, 0.0], [-J2_EARTH / math.sqrt(5.0), 0.0, 0.0]]
            harmonics.sBar = [[0.0], [0.0, 0.0], [0.0, 0.0, 0.0]]
            earth.gravityModel = harmonics
        self._keep.append(gravity)
        atmosphere = None
        if env.drag:
            atmosphere = exponentialAtmosphere.ExponentialAtmosphere()
            atmosphere.ModelTag = "atmosphere"
            atmosphere.planetRadius = R_EARTH
            atmosphere.scaleHeight = dep.atmosphere.scale_height
            atmosphere.baseDensity = dep.atmosphere.rho0 * env.density_factor * math.exp(h_ratio)
            self._keep.append(atmosphere)
        self._corrections: list[Any] = []
        self._recorders: list[Any] = []
        names = ["chief", *(d.name for d in dep.deputy)]
        sc_spec = dep.spacecraft
        for i, (name, craft) in enumerate(zip(names, truth_craft(dep), strict=True)):
            self._add_craft(i, name, craft, gravity, atmosphere, sc_spec.mass)
        if atmosphere is not None:
            self._sim.AddModelToTask(_TASK, atmosphere, 90)
        self._sim.InitializeSimulation()

    def _add_craft(
        self, i: int, name: str, craft: Any, gravity: Any, atmosphere: Any, mass: float
    ) -> None:
        # Priorities: the spacecraft first, so that it integrates [t - h, t] with the density and
        # attitude reference computed from its state at t - h (a hold from the step's start).
        sc = spacecraft.Spacecraft()
        sc.ModelTag = name
        sc.hub.mHub = mass
        # The attitude is prescribed, so the inertia does not act; a 10x20x30 cm box (6U).
        sc.hub.IHubPntBc_B = np.diag(
            [
                mass / 12 * (0.2**2 + 0.3**2),
                mass / 12 * (0.1**2 + 0.3**2),
                mass / 12 * (0.1**2 + 0.2**2),
            ]
        ).tolist()
        sc.hub.r_CN_NInit = self._state[i, :3].tolist()
        sc.hub.v_CN_NInit = self._state[i, 3:].tolist()
        gravity.addBodiesTo(sc)
        self._sim.AddModelToTask(_TASK, sc, 100)
        models: list[Any] = [sc]
        if atmosphere is not None:
            atmosphere.addSpacecraftToModel(sc.scStateOutMsg)
            drag = facetDragDynamicEffector.FacetDragDynamicEffector()
            drag.ModelTag = f"{name}_drag"
            drag.addFacet(craft.area, craft.cd, list(craft.normal_B), [0.0, 0.0, 0.0])
            drag.atmoDensInMsg.subscribeTo(atmosphere.envOutMsgs[i])
            sc.addDynamicEffector(drag)
            self._sim.AddModelToTask(_TASK, drag, 80)
            models.append(drag)
        nav = simpleNav.SimpleNav()
        nav.ModelTag = f"{name}_nav"
        nav.scStateInMsg.subscribeTo(sc.scStateOutMsg)
        hill = hillPoint.hillPoint()
        hill.ModelTag = f"{name}_hill"
        hill.transNavInMsg.subscribeTo(nav.transOutMsg)
        correction = attRefCorrection.attRefCorrection()
        correction.ModelTag = f"{name}_command"
        correction.attRefInMsg.subscribeTo(hill.attRefOutMsg)
        correction.sigma_BcB = [0.0, 0.0, 0.0]
        sc.attRefInMsg.subscribeTo(correction.attRefOutMsg)
        for model, priority in ((nav, 70), (hill, 60), (correction, 50)):
            self._sim.AddModelToTask(_TASK, model, priority)
        recorder = sc.scStateOutMsg.recorder(_ns(self._dep.run.nav_period))
        self._sim.AddModelToTask(_TASK, recorder)
        models += [nav, hill, correction, recorder]
        self._keep.extend(models)
        self._corrections.append(correction)
        self._recorders.append(recorder)

    @property
    def state(self) -> NDArray[np.float64]:
        return self._state

    @property
    def sigma_BN(self) -> NDArray[np.float64]:
        """(1 + N, 3) the attitude MRPs Basilisk held at the last sample (chief first); NaN
        before the first step."""
        return self._sigma_BN

    def set_panel(
        self, deputy: int, area_factor: float | None = None, normal_angle: float | None = None
    ) -> None:
        raise RuntimeError(
            "panel faults need the built-in truth: Basilisk 2.12's facetDragDynamicEffector "
            "cannot change a facet's area or normal once added"
        )

    def step(self, t_k: float, sigma: NDArray) -> tuple[NDArray, NDArray]:
        """Propagate from t_k over one flight-software step with the deputies' relative MRPs
        ``sigma`` (N, 3); returns the navigation sample times (K,) in (t_k, t_k + fsw] and the
        states there (K, 1 + N, 6)."""
        run = self._dep.run
        sigma = np.asarray(sigma, dtype=float)
        for correction, s in zip(self._corrections[1:], sigma, strict=True):
            correction.sigma_BcB = (-s).tolist()
        t_end = t_k + run.fsw_period
        samples = t_k + run.nav_period * np.arange(1, round(run.fsw_period / run.nav_period) + 1)
        self._sim.ConfigureStopTime(_ns(t_end))
        self._sim.ExecuteSimulation()
        wanted = np.array([_ns(t) for t in samples])
        traj = np.empty((len(samples), len(self._recorders), 6))
        for i, recorder in enumerate(self._recorders):
            times = np.asarray(recorder.times())
            keep = np.isin(times, wanted)
            if keep.sum() != len(samples):
                raise RuntimeError(
                    f"Basilisk recorded {keep.sum()} of the {len(samples)} navigation samples "
                    f"of the step from t = {t_k:g} s (recorder times {times / _NS})"
                )
            traj[:, i, :3] = np.asarray(recorder.r_BN_N)[keep]
            traj[:, i, 3:] = np.asarray(recorder.v_BN_N)[keep]
            self._sigma_BN[i] = np.asarray(recorder.sigma_BN)[keep][-1]
            recorder.clear()
        check_altitude(self._dep, samples, traj)
        self._state = traj[-1]
        return samples, traj

    def close(self) -> None:
        self._keep.clear()
        self._corrections.clear()
        self._recorders.clear()
