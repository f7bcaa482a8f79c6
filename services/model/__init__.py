"""The bridge between a deployment and the mathematics: mission timing and exosystem, the
nominal linear model and its LQR gains, initial states and slot holding (``mission``), the
truth's linear model and its optimal gains (the reference a learned gain is scored against:
``reference``), the re-entry predicted from the chief's drag decay (``decay``), and the truth
backends behind one protocol (``truth``: the protocol and the built-in propagator;
``basilisk``; ``backends.open_truth`` chooses).

May import: ``ddvi_core``, ``services.config``. Not the bus, processes or tools.
``services.model.basilisk`` needs the optional ``basilisk`` extra and is imported only when a
deployment asks for it.
"""

from services.model.backends import backend_missing, open_truth
from services.model.decay import (
    chief_decay,
    orbit_mean_density,
    reentry_problems,
    reentry_warnings,
)
from services.model.mission import (
    IN_PLANE,
    describe_panel,
    duration,
    exostate,
    facet_normal,
    holding_margin,
    holding_problems,
    holding_warnings,
    initial_states,
    lqr_gains,
    mean_motion,
    navigation_state,
    nominal_problem,
    on_grid,
    orbit_period,
    panel_schedule,
)
from services.model.reference import reference_gains, true_lqr_gains, true_problem
from services.model.truth import (
    BuiltinTruth,
    ReentryError,
    Truth,
    truth_atmosphere,
    truth_craft,
    truth_step,
)

__all__ = [
    "IN_PLANE",
    "BuiltinTruth",
    "ReentryError",
    "Truth",
    "backend_missing",
    "chief_decay",
    "describe_panel",
    "duration",
    "exostate",
    "facet_normal",
    "holding_margin",
    "holding_problems",
    "holding_warnings",
    "initial_states",
    "lqr_gains",
    "mean_motion",
    "navigation_state",
    "nominal_problem",
    "on_grid",
    "open_truth",
    "orbit_mean_density",
    "orbit_period",
    "panel_schedule",
    "reentry_problems",
    "reentry_warnings",
    "reference_gains",
    "true_lqr_gains",
    "true_problem",
    "truth_atmosphere",
    "truth_craft",
    "truth_step",
]
