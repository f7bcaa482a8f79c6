"""The truth's own linear model of a deputy's run and its optimal gains: the reference a
learned gain is scored against, and what the live view and ROS 2 show beside the flown gains.
Nobody flies it.  Its density is the truth's: the exponential profile times
environment.density_factor, or NRLMSIS's around the chief's orbit at the epoch
(``services.model.decay.orbit_mean_density``)."""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from services.config import Deployment, Deputy
from services.model.decay import orbit_mean_density
from services.model.mission import nominal_params, optimal_gains

log = logging.getLogger("ddvi.model")

if TYPE_CHECKING:
    from ddvi_core.problem import RegulationProblem


def true_problem(dep: Deployment, deputy: Deputy) -> RegulationProblem:
    """The truth's own linear model of the deputy's run: the nominal model rebuilt with the
    truth's density (rho0 x environment.density_factor; with atmosphere.model = "nrlmsis",
    NRLMSIS's density averaged around the chief's orbit and its local scale height, at the
    epoch: ``services.model.decay.orbit_mean_density``) and the deputy's true facet area
    (area x its area_factor), and D carrying the constant differential drag between the
    deputy and the chief (its true area: area x chief.area_factor) in the along-track row.  The
    reference a learned gain is scored against; nobody flies it.  At the chief's initial
    altitude, at the start (before a storm) and before any panel fault.  Raises ValueError
    when the truth has no drag (no input, so no optimal gain)."""
    import dataclasses

    from ddvi_core.constants import R_EARTH
    from ddvi_core.models import drag_sensitivity, rendezvous_problem

    if not dep.environment.drag:
        raise ValueError("the truth has no drag (environment.drag = false): no optimal gain")
    nominal = nominal_params(dep, deputy)
    params = nominal.with_(
        rho0=nominal.rho0 * dep.environment.density_factor,
        area=nominal.area * deputy.area_factor,
    )
    if dep.atmosphere.model == "nrlmsis":
        rho, scale_height = orbit_mean_density(dep)
        params = params.with_(rho0=rho, h_ref=dep.chief.a - R_EARTH, scale_height=scale_height)
    pr = rendezvous_problem(params)
    beta_d, _ = drag_sensitivity(params.mass, params.area, params.cd, params.normal_angle)
    chief_area = nominal.area * dep.chief.area_factor
    beta_c, _ = drag_sensitivity(nominal.mass, chief_area, nominal.cd, nominal.normal_angle)
    v = params.mean_motion * params.a_chief
    D = pr.D.copy()
    D[3, 0] -= 0.5 * params.density * v**2 * (beta_d - beta_c)
    return dataclasses.replace(pr, D=D, name="rendezvous-truth")


def true_lqr_gains(dep: Deployment, deputy: Deputy) -> tuple[NDArray, NDArray]:
    """K* (1,4) and L* (1,5): the optimal gains of :func:`true_problem`, the reference every
    learned gain is scored against (equal to :func:`lqr_gains` when the truth is nominal)."""
    return optimal_gains(true_problem(dep, deputy))


def reference_gains(
    dep: Deployment, deputy: Deputy
) -> tuple[NDArray[np.float64] | None, NDArray[np.float64] | None]:
    """K* (1, 4) and L* (1, 5) of the truth's linear model of ``deputy``'s run
    (:func:`true_lqr_gains`), or (None, None) when it has none (no drag in the truth, or no
    stabilising solution): what a learned gain is scored against, and what the live view and
    ROS 2 show beside the flown gains."""
    try:
        K, L = true_lqr_gains(dep, deputy)
    except (ValueError, np.linalg.LinAlgError) as exc:
        log.warning("no optimal gain of the truth's model for %s: %s", deputy.name, exc)
        return None, None
    return np.asarray(K), np.asarray(L)
