"""One attempt of the model-fit learner in the controller (``learning.method = "model-fit"``):
the fits, the gains, the acceptance test.  No state: the controller keeps the result.

Two fits of the same intervals (``ddvi_core.model_fit``):

- the gain K comes from the free fit of every row of x' = A x + B u + D v: it fits whatever
  the navigation filter makes of the motion, lag included (measured on the default mission at
  10 m through the Kalman filter: gain error 0.04 at orbit 10, against 2.3 with kinematic
  position rows, which the filtered estimate does not obey);
- the feedforward L = U + K X comes from the regulator equations on the fit with kinematic
  position rows (x' = xdot, y' = ydot; B's and D's position rows zero): the free fit's
  position rows of B and D, noise there, would otherwise enter U directly.

An attempt is accepted when the gain's predicted relative error
(``ddvi_core.model_fit.gain_standard_error``) is at most the tolerance in force:
``fit_tolerance``, or from ``fit_deadline_orbits`` on (when set) ``fit_deadline_tolerance``.
"""

from __future__ import annotations

import dataclasses
from typing import Any

from ddvi_core.learning_config import LearningConfig
from ddvi_core.model_fit import (
    IntegralData,
    ModelFitError,
    fit_linear_model,
    gain_standard_error,
    learn_by_model_fit,
)
from ddvi_core.regulator import InfeasibleError, feedforward_gain, solve_regulator_equations

POSITIONS = 2
"""The controller's state is [x, y, xdot, ydot]: two positions, then their rates."""


def fit_attempt(
    data: IntegralData,
    lrn: LearningConfig,
    problem: Any,
    exosystem: tuple,
    translation: list | None,
    tolerance: float,
) -> tuple[Any, dict, str | None]:
    """(the result: K, L, and ``model``, the kinematic fit the feedforward was solved on; what
    the learning log reports; why it is not accepted, or None).  ``problem`` gives Q and R,
    ``exosystem`` (C, E, F).  Raises LearningError (ModelFitError) when a fit gives no
    gains."""
    C, E, F = exosystem
    options = {"length": lrn.interval, "stride": lrn.fit_stride,
               "smoothing": lrn.fit_smoothing, "translation": translation}  # fmt: skip
    r = learn_by_model_fit(data, problem.Q, problem.R, C=C, E=E, F=F, **options)
    fit = r.model
    error = gain_standard_error(data, r.K, problem.Q, problem.R, **options)
    kin = fit_linear_model(data, positions=POSITIONS, **options)
    try:
        X, U = solve_regulator_equations(kin.A, kin.B, C, kin.D, E, F)
    except InfeasibleError as exc:
        raise ModelFitError(f"the kinematic fit gives no feedforward: {exc}") from None
    r = dataclasses.replace(r, L=feedforward_gain(r.K, X, U), X=X, U=U, model=kin)
    info = {"condition": fit.condition, "residual": fit.residual, "error": error,
            "intervals": fit.intervals, "rank": fit.rank, "needed": fit.needed,
            "B": kin.B.ravel().tolist()}  # fmt: skip
    if error > tolerance:
        why = f"the gain's predicted relative error {error:.3g} exceeds the tolerance"
        return r, info, f"{why} {tolerance:g}; fit condition {fit.condition:.3g}"
    return r, info, None
