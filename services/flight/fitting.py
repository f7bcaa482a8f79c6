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
(``ddvi_core.fit_uncertainty.gain_standard_error``) is at most the tolerance in force:
``fit_tolerance``, or from ``fit_deadline_orbits`` on (when set) ``fit_deadline_tolerance``.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np

from ddvi_core.exostate_fit import exostate_groups, fit_exosystem_input, static_groups
from ddvi_core.fit_uncertainty import gain_standard_error
from ddvi_core.learning import LearningError
from ddvi_core.learning_config import LearningConfig
from ddvi_core.lqr import NotStabilisingError, relative_gain_error, solve_lqr
from ddvi_core.model_fit import (
    IntegralData,
    ModelFitError,
    fit_linear_model,
    interval_regressors,
    learn_by_model_fit,
    prediction_residual,
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
    holdout: float = 0.0,
) -> tuple[Any, dict, str | None]:
    """(the result: K, L, and ``model``, the kinematic fit the feedforward was solved on; what
    the learning log reports; why it is not accepted, or None).  ``problem`` gives Q and R,
    ``exosystem`` (C, E, F); ``holdout`` > 0 (s): an accepted gain must pass
    :func:`validate_gain` on the newest ``holdout`` s.  Raises LearningError (ModelFitError)
    when a fit gives no gains."""
    C, E, F = exosystem
    options = {
        "length": lrn.interval,
        "stride": lrn.fit_stride,
        "smoothing": lrn.fit_smoothing,
        "translation": translation,
    }
    r = learn_by_model_fit(data, problem.Q, problem.R, C=C, E=E, F=F, **options)
    fit = r.model
    error = gain_standard_error(data, r.K, problem.Q, problem.R, **options)
    kin = fit_linear_model(data, positions=POSITIONS, **options)
    if lrn.feedforward_significance > 0 or lrn.feedforward_modes != "all":
        kin = dataclasses.replace(kin, D=select_feedforward_modes(data, kin, lrn, E))
    try:
        X, U = solve_regulator_equations(kin.A, kin.B, C, kin.D, E, F)
    except InfeasibleError as exc:
        raise ModelFitError(f"the kinematic fit gives no feedforward: {exc}") from None
    r = dataclasses.replace(r, L=feedforward_gain(r.K, X, U), X=X, U=U, model=kin)
    info = {
        "condition": fit.condition,
        "residual": fit.residual,
        "error": error,
        "intervals": fit.intervals,
        "rank": fit.rank,
        "needed": fit.needed,
        "B": kin.B.ravel().tolist(),
    }
    if error > tolerance:
        why = f"the gain's predicted relative error {error:.3g} exceeds the tolerance"
        return r, info, f"{why} {tolerance:g}; fit condition {fit.condition:.3g}"
    if holdout > 0:
        refused = validate_gain(data, r.K, problem, lrn, options, holdout, info)
        if refused is not None:
            return r, info, f"the gain failed validation: {refused}"
    return r, info, None


def validate_gain(
    data: IntegralData,
    K: Any,
    problem: Any,
    lrn: LearningConfig,
    options: dict,
    holdout: float,
    info: dict,
) -> str | None:
    """Check a gain K (1, n) learned from ``data`` on data its check was not fitted on: the
    model fitted without the newest ``holdout`` s must predict that hold-out's motion (every
    state's interval residual RMS there at most ``lrn.validation_residual`` times the RMS of
    its change over the interval), K must stabilise that model (every closed-loop
    eigenvalue in the open left half-plane), and that model's own gain must differ from K
    by at most ``lrn.validation_gain_change`` (relative): one orbit of data more must not
    change the answer much.  Why
    it fails, or None; ``info`` gets the figures ("validation": the worst relative residual,
    "validation_margin": the closed loop's slowest decay rate, 1/s, "validation_gain": the
    two gains' relative difference).  A fit that explains the exploration and not what came
    after it, or a gain that stabilises only the model of the data it came from, is not
    flown.  (A ratio to the fit's own residual says nothing on clean data, where both are
    the model's small nonlinearity.)"""
    end = float(data.t[-1]) if data.samples else 0.0
    train, test = data.before(end - holdout), data.since(end - holdout)
    span = (float(train.t[-1] - train.t[0]) if train.samples else 0.0), holdout
    if min(span) < 2 * lrn.interval:
        return (
            f"{span[0]:.0f} s of data before a {holdout:.0f} s hold-out: too little to fit on "
            f"and check (each needs two intervals of {lrn.interval:g} s)"
        )
    fit_options = {k: options[k] for k in ("length", "stride", "smoothing")}
    try:
        model = fit_linear_model(train, **options)
        change, _ = interval_regressors(test, **fit_options)
        scale = np.sqrt(np.mean(change**2, axis=0))
        relative = prediction_residual(model, test, **fit_options) / np.where(scale > 0, scale, 1)
    except LearningError as exc:
        return f"the model fitted without the hold-out: {exc}"
    K = np.asarray(K, dtype=float)
    margin = -float(np.max(np.linalg.eigvals(model.A - model.B @ K).real))
    worst = float(np.max(relative))
    try:
        K_train = solve_lqr(model.A, model.B, problem.Q, problem.R).K
        change = relative_gain_error(K_train, K)
    except NotStabilisingError:  # no gain: nothing K could agree with
        change = math.inf
    info.update(validation=worst, validation_margin=margin, validation_gain=change)
    if not margin > 0:
        return (
            f"the gain does not stabilise the model fitted without the newest {holdout:.0f} s "
            f"(closed-loop eigenvalue real part {-margin:.3g} 1/s)"
        )
    if not change <= lrn.validation_gain_change:
        return (
            f"the gain of the model fitted without the newest {holdout:.0f} s differs from it "
            f"by {change:.3g} (relative; the limit is validation_gain_change = "
            f"{lrn.validation_gain_change:g})"
        )
    if worst > lrn.validation_residual:
        return (
            f"the model fitted without the newest {holdout:.0f} s predicts state "
            f"{int(np.argmax(relative))}'s change over them with a residual {worst:.3g} times "
            f"its RMS (the limit is validation_residual = {lrn.validation_residual:g})"
        )
    return None


def select_feedforward_modes(
    data: IntegralData, model: Any, lrn: LearningConfig, E: Any, on_station: bool = False
) -> Any:
    """D (n, q) refitted on ``data`` with ``model``'s A and B held.

    ``lrn.feedforward_modes = "static"``: only the modes E holds constant (the constant and,
    in a density exostate, the density ratio), each along B (``matched``: a drag offset acts
    where the drag does, so the fit's errors in A cannot leak into it), the harmonics zero;
    in closed loop the state itself oscillates at the orbit rate, so a harmonic of the
    exostate there cannot be told from the fitted A's error on that oscillation, and in the
    exploration it is nearly collinear with the density ratio.  ``"all"``: every mode, free
    in every fitted row; on station (``on_station``, data flown on the learned gains) the
    static modes only, the harmonics held at ``model.D``'s.  Either way, with
    ``lrn.feedforward_significance`` > 0 only the modes the data tell from zero at that
    level stay (on the right model the drag offset is nil, and a feedforward solved on the
    fit's noise drives the loop's lightly damped orbit-rate mode).  Raises LearningError when
    the exostate's integrals do not have full column rank."""
    static = lrn.feedforward_modes == "static"
    groups = static_groups(E) if static or on_station else exostate_groups(E)
    return fit_exosystem_input(
        data,
        model.A,
        model.B,
        length=lrn.interval,
        stride=lrn.fit_stride,
        smoothing=lrn.fit_smoothing,
        positions=POSITIONS,
        groups=groups,
        significance=lrn.feedforward_significance,
        matched=static,
        held=model.D if on_station and not static else None,
    )
