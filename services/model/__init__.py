"""The bridge between a deployment and the mathematics: mission timing and exosystem, the
nominal linear model and its LQR gains, initial states, and the truth backends (built-in
propagator, Basilisk) behind one protocol.

May import: ``ddvi_core``, ``services.config``. Not the bus, processes or tools.
``services.model.basilisk`` needs the optional ``basilisk`` extra and is imported only when a
deployment asks for it.
"""

from services.model.mission import (
    IN_PLANE,
    BuiltinTruth,
    ReentryError,
    Truth,
    describe_panel,
    duration,
    exostate,
    facet_normal,
    holding_margin,
    initial_states,
    lqr_gains,
    mean_motion,
    navigation_state,
    nominal_problem,
    on_grid,
    open_truth,
    orbit_period,
    panel_schedule,
    truth_atmosphere,
    truth_craft,
    truth_step,
)

__all__ = [
    "IN_PLANE",
    "BuiltinTruth",
    "ReentryError",
    "Truth",
    "describe_panel",
    "duration",
    "exostate",
    "facet_normal",
    "holding_margin",
    "initial_states",
    "lqr_gains",
    "mean_motion",
    "navigation_state",
    "nominal_problem",
    "on_grid",
    "open_truth",
    "orbit_period",
    "panel_schedule",
    "truth_atmosphere",
    "truth_craft",
    "truth_step",
]
