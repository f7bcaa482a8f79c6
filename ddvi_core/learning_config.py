"""How a data-driven learner explores, iterates and is scheduled: one configuration for a
system file's ``[learning]`` table and a deputy's ``learning`` table in a deployment.

:class:`LearningConfig` holds the one table of defaults.  A system file's missing keys are
derived from its system (:mod:`ddvi_core.defaults`); a deputy's from the mission
(:func:`mission_learning`, each of its values a rule stated there).

Kept apart from :mod:`ddvi_core.systems` so that reading a deployment needs numpy alone (the
value iteration's step and bound rules, which need scipy, are imported when asked for).
"""

from __future__ import annotations

import math
from collections.abc import Collection
from dataclasses import dataclass, fields, replace
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from ddvi_core.tables import FlatRowMatrix

if TYPE_CHECKING:
    from ddvi_core.policy_learning import IterationSettings
    from ddvi_core.problem import RegulationProblem
    from ddvi_core.value_iteration import BoundSchedule, StepSequence

__all__ = [
    "FLIGHT_SCHEDULE_KEYS",
    "IMPLICIT_ITERATION",
    "SYSTEM_FILE_LEARNING_KEYS",
    "LearningConfig",
    "SystemFileError",
    "mission_learning",
]


class SystemFileError(ValueError):
    """A system file or name that cannot be used; the message names the key."""


@dataclass(frozen=True)
class LearningConfig:
    """How the data-driven learner explores and iterates (all SI units, seconds, rad/s).

    interval: seconds per data interval; intervals: how many to collect;
    sample_period: navigation sample period; command_period: flight-software period (the input
    is held over it); exploration_amplitude / exploration_frequencies: the multi-sine
    exploration; x0, v0: initial state and exostate; K0: initial gain, m rows of n (zero by
    default, need not stabilise; a single row may be written flat); seed: exploration phases;
    time_unit: the iteration's time unit (1/s; by default A's fastest rate / 100); step /
    step_size: 'harmonic' (step_size / k) or 'constant' (step_size in units of time_unit);
    bounds / bound_base: 'linear' base (r+1) or 'geometric' base 2^r; state_scale: the states'
    units in the iteration; input_limit: actuator saturation; tol, max_iterations: the
    stopping rule; stopping: 'residual' (|F(P)| < tol max(1, |P|)) or 'relative' (the
    scale-free estimate of |K - K*| / |K| at most tol, :mod:`ddvi_core.continuation`); step
    'adaptive': step_size (below 1) times the Euler stability limit of the current closed loop;
    'implicit': linearly implicit steps from that fraction of the limit, growing towards
    Newton's (:mod:`ddvi_core.continuation`).
    exploration_channels: 'common' (every input sums every frequency, each with its own phases)
    or 'interleaved' (input i takes frequencies i, i + m, ...).
    A system file's missing keys are derived from the system (:mod:`ddvi_core.defaults`), a
    deputy's from the mission (:func:`mission_learning`).

    The flight software's schedule (:data:`FLIGHT_SCHEDULE_KEYS`, read from a deployment's
    ``deputy.learning`` table, never from a system file; in chief orbits): learn_at_orbits:
    when to learn and switch gains; retry_orbits: after a failed attempt, explore on and try
    again this much later; learn_until_orbits: no attempt after this orbit (0: no limit; a
    deputy's follows from the mission), and a learner that has validated no gain by then flies
    its fallback (one taken on saturated data may learn on it later: resume_window_orbits);
    fallback: what that is, 'last' (the gains it validated last: after a
    re-learning that failed, those of before the detection; before any, the nominal model's
    LQR gains) or 'lqr' (the nominal model's LQR gains, always);
    saturated_fraction: an attempt at the first gain that fails on data whose input was out of
    reach (the attitude at its limit) in at least this fraction of the steps ends the
    exploration at once and flies the fallback: such data hold no variation of the input to
    learn from;
    resume_window_orbits: after such a fallback, once its command has been off the limit for an
    orbit, explore on the fallback's gains and learn from this many orbits of data, retrying
    every retry_orbits while a gain would still fly this long before the mission's end; only
    where twice this is left (0: never);
    resume_fit_tolerance: model-fit: the tolerance on the predicted relative gain error of an
    attempt on the fallback (fit_tolerance's, past the time to learn);
    window_orbits: learn from the last this many orbits of data (0: all
    of it); along_track_reference: the data's reference state about its mean along-track
    position; relearn: after learning, watch the plant for a change (an actuator fault) and
    learn again; relearn_settle_orbits: after a detection, K0 stops the approach (not data);
    relearn_window_orbits: then explore this long and re-learn from it;
    relearn_max_attempts: re-learning attempts that fail before the old gains return;
    detector_bound: the detection threshold, times the input-equivalent residual's RMS on the
    learning data; detector_window_orbits: the residual's mean is taken over this window.
    method: 'value-iteration' (the paper's Algorithm 2, :mod:`ddvi_core.learning`) or
    'model-fit' (the first-order interval fit, :mod:`ddvi_core.model_fit`);
    data_from_orbits: samples before this are not the learner's (the initial transient);
    learn_from: 'estimate' (the navigation filter's output, what the control law flies on)
    or 'measurement' (the navigation message's measurement before the filter): what the
    learner collects;
    fit_stride: model-fit: one interval of ``interval`` seconds starts every this many seconds;
    fit_smoothing: model-fit: the interval relation averaged over shifts of up to this many
    seconds (0: end points as sampled), which averages the end points' noise;
    fit_tolerance: model-fit: an attempt is accepted when the gain's predicted relative error
    (``ddvi_core.fit_uncertainty.gain_standard_error``) is at most this (else it retries later);
    fit_deadline_orbits, fit_deadline_tolerance: model-fit: from this orbit on (0: never) the
    tolerance is the second (a noisy window's predicted error is pessimistic);
    refresh_orbits: model-fit: refit D (A and B held) and the feedforward every this many
    orbits from the data flown on the learned gains on station (0: off);
    trim_orbits: model-fit: on station, move the feedforward's constant term by -trim_gain x
    K_y x the mean along-track error of every this many orbits (0: off), counted only when
    every |y - y_ref| of the period is at most station_radius m (``services.flight.trim``);
    station_radius: model-fit: on station is within this many m of the slot along track (the
    trim's periods and the refresh's samples);
    density_exostate: the learner's exostate carries the nominal atmosphere's density ratio at
    the navigated altitude from the start (craft that may differ); not given: the model-fit
    learner's does (its feedforward keeps the ratio only where the data tell it from zero),
    value iteration's does not (``carries_density_ratio``);
    feedforward_significance: model-fit: the feedforward is solved on D with only the
    exostate modes the data tell from zero at this level (a cluster-robust Wald test,
    ``ddvi_core.exostate_fit.fit_exosystem_input``); 0: every mode;
    feedforward_modes: model-fit: 'all' (D fitted free for every exostate mode) or 'static'
    (only the modes E holds constant, each along B: a drag offset; harmonics zero);
    validation_orbits: model-fit: an accepted gain flies only when the model fitted without
    the newest this many orbits predicts them (each state's residual at most
    validation_residual times the RMS of its change), the gain stabilises it, and that
    model's own gain differs from it by at most validation_gain_change (relative)
    (``services.flight.fitting.validate_gain``); 0: off.
    """

    interval: float = 600.0
    intervals: int = 200
    sample_period: float = 10.0
    command_period: float = 60.0
    exploration_amplitude: float = 1.0
    exploration_frequencies: tuple[float, ...] = ()
    x0: tuple[float, ...] | None = None
    v0: tuple[float, ...] | None = None
    K0: FlatRowMatrix | None = None
    seed: int = 0
    time_unit: float | None = None
    step: str = "harmonic"
    step_size: float = 1.0
    bounds: str = "linear"
    bound_base: float = 10.0
    state_scale: tuple[float, ...] | None = None
    input_limit: float | None = None
    tol: float = 1e-6
    max_iterations: int = 200_000
    stopping: str = "residual"
    exploration_channels: str = "common"
    # the flight software's schedule (FLIGHT_SCHEDULE_KEYS)
    learn_at_orbits: float = 15.0
    retry_orbits: float = 1.0
    learn_until_orbits: float = 0.0
    fallback: str = "last"
    saturated_fraction: float = 0.9
    resume_window_orbits: float = 3.0
    resume_fit_tolerance: float = 0.5
    window_orbits: float = 0.0
    along_track_reference: bool = True
    relearn: bool = False
    relearn_settle_orbits: float = 2.0
    relearn_window_orbits: float = 10.0
    relearn_max_attempts: int = 5
    detector_bound: float = 100.0
    detector_window_orbits: float = 1.0
    method: str = "value-iteration"
    data_from_orbits: float = 0.0
    learn_from: str = "estimate"
    fit_stride: float = 10.0
    fit_smoothing: float = 0.0
    fit_tolerance: float = 0.01
    fit_deadline_orbits: float = 10.0
    fit_deadline_tolerance: float = 0.5
    refresh_orbits: float = 0.0
    trim_orbits: float = 2.0
    station_radius: float = 1000.0
    trim_gain: float = 0.5
    density_exostate: bool | None = None
    feedforward_significance: float = 0.01
    feedforward_modes: str = "static"
    validation_orbits: float = 1.0
    validation_residual: float = 0.5
    validation_gain_change: float = 0.25

    @property
    def carries_density_ratio(self) -> bool:
        """The learner's exostate carries the density ratio from the start: as
        ``density_exostate`` says, or when it is not given, for the model-fit learner."""
        if self.density_exostate is None:
            return self.method == "model-fit"
        return self.density_exostate

    def steps(self) -> StepSequence:
        from ddvi_core.value_iteration import StepSequence

        return StepSequence(self.step, self.step_size)

    def bound_schedule(self) -> BoundSchedule:
        from ddvi_core.value_iteration import BoundSchedule

        return BoundSchedule(self.bounds, self.bound_base)

    def iteration_settings(self, method: str = "vi") -> IterationSettings:
        """How the learner iterates (``ddvi_core.policy_learning.IterationSettings``): its step,
        bounds, tolerance, iteration limit and stopping rule, by ``method``."""
        from ddvi_core.policy_learning import IterationSettings

        return IterationSettings(
            method,
            self.steps(),
            self.bound_schedule(),
            self.tol,
            self.max_iterations,
            self.stopping,
        )

    def validate(self, problem: RegulationProblem) -> None:
        def bad(key: str, why: str) -> SystemFileError:
            return SystemFileError(f"learning.{key}: {why}")

        for key in (
            "interval",
            "sample_period",
            "command_period",
            "step_size",
            "bound_base",
            "tol",
        ):
            val = getattr(self, key)
            if not (isinstance(val, int | float) and math.isfinite(val) and val > 0):
                raise bad(key, f"must be a positive number, got {val!r}")
        if self.interval < self.sample_period:
            raise bad("interval", "must be at least one sample_period")
        ratio = self.command_period / self.sample_period
        if abs(ratio - round(ratio)) > 1e-9:
            raise bad("command_period", "must be a whole multiple of sample_period")
        for key in ("intervals", "max_iterations"):
            if not (isinstance(getattr(self, key), int) and getattr(self, key) > 0):
                raise bad(key, f"must be a positive integer, got {getattr(self, key)!r}")
        if not (math.isfinite(self.exploration_amplitude) and self.exploration_amplitude >= 0):
            raise bad("exploration_amplitude", "must be a non-negative number")
        if any(not (math.isfinite(w) and w > 0) for w in self.exploration_frequencies):
            raise bad("exploration_frequencies", "must be positive numbers (rad/s)")
        if self.time_unit is not None and not (
            math.isfinite(self.time_unit) and self.time_unit > 0
        ):
            raise bad("time_unit", "must be a positive rate in 1/s")
        if self.step not in ("harmonic", "constant", "adaptive", "implicit"):
            raise bad(
                "step",
                f"must be 'harmonic', 'constant', 'adaptive' or 'implicit', got {self.step!r}",
            )
        if self.step in ("adaptive", "implicit") and not self.step_size < 1:
            raise bad("step_size", f"an {self.step} step's size is a fraction below 1")
        if self.exploration_channels not in ("common", "interleaved"):
            raise bad(
                "exploration_channels",
                f"must be 'common' or 'interleaved', got {self.exploration_channels!r}",
            )
        if self.stopping not in ("residual", "relative"):
            raise bad("stopping", f"must be 'residual' or 'relative', got {self.stopping!r}")
        if self.bounds not in ("linear", "geometric"):
            raise bad("bounds", f"must be 'linear' or 'geometric', got {self.bounds!r}")
        sizes = {"x0": problem.n, "v0": problem.q, "state_scale": problem.n}
        for key, size in sizes.items():
            val = getattr(self, key)
            if val is not None and len(val) != size:
                raise bad(key, f"expected {size} values, got {len(val)}")
        if self.state_scale is not None and any(s <= 0 for s in self.state_scale):
            raise bad("state_scale", "must be positive")
        if self.K0 is not None:
            K0 = np.asarray(self.K0, dtype=float)
            if K0.shape != (problem.m, problem.n):
                raise bad(
                    "K0",
                    f"expected shape {problem.m}x{problem.n}, got {'x'.join(map(str, K0.shape))}",
                )
        if self.input_limit is not None and not self.input_limit > 0:
            raise bad("input_limit", "must be positive")

    def K0_matrix(self, problem: RegulationProblem) -> NDArray[np.float64]:
        if self.K0 is None:
            return np.zeros((problem.m, problem.n))
        return np.asarray(self.K0, dtype=float)


FLIGHT_SCHEDULE_KEYS = (
    "learn_at_orbits",
    "retry_orbits",
    "learn_until_orbits",
    "fallback",
    "saturated_fraction",
    "resume_window_orbits",
    "resume_fit_tolerance",
    "window_orbits",
    "along_track_reference",
    "relearn",
    "relearn_settle_orbits",
    "relearn_window_orbits",
    "relearn_max_attempts",
    "detector_bound",
    "detector_window_orbits",
    "method",
    "data_from_orbits",
    "learn_from",
    "fit_stride",
    "fit_smoothing",
    "fit_tolerance",
    "fit_deadline_orbits",
    "fit_deadline_tolerance",
    "refresh_orbits",
    "trim_orbits",
    "station_radius",
    "trim_gain",
    "density_exostate",
    "feedforward_significance",
    "feedforward_modes",
    "validation_orbits",
    "validation_residual",
    "validation_gain_change",
)
"""The LearningConfig fields only the flight software reads (a deployment's learning table)."""

SYSTEM_FILE_LEARNING_KEYS = tuple(
    f.name for f in fields(LearningConfig) if f.name not in FLIGHT_SCHEDULE_KEYS
)
"""The keys a system file's [learning] table may give."""

IMPLICIT_ITERATION: dict[str, Any] = {"step": "implicit", "step_size": 0.5, "bounds": "geometric"}
"""The implicit step from half the Euler stability limit of the starting closed loop, with
geometric bounds (:mod:`ddvi_core.continuation`): what a system file derives
(:mod:`ddvi_core.defaults`) and what a deputy flies (:func:`mission_learning`)."""

MISSION_SEED = 1
"""The exploration's phases the mission's figures are flown with (docs/results.md)."""


def mission_learning(
    given: LearningConfig, keys: Collection[str], attitude_limit: float, orbits: float
) -> LearningConfig:
    """A deputy's learning configuration: the keys in ``keys`` (its learning table's) as
    ``given``; of the others, those below follow from the mission, and every other key keeps
    LearningConfig's default (no exploration_frequencies: the controller spreads six from 0.3
    to 30 times the orbit rate).

    - exploration_amplitude = ``attitude_limit`` / 2 (MRP): the multi-sine (never above its
      amplitude) takes half the commanded attitude's range and leaves the other half to the
      feedback on K0; the default 1.0 would leave the feedback nothing (a limit is at most 1).
    - K0: the default zero gain, written in the mission's shape (one input on x, y, xdot,
      ydot), the one the flight software reads.
    - step, step_size, bounds: :data:`IMPLICIT_ITERATION`.  On the mission's linear model
      (the ``rendezvous`` scenario's data) the default, the paper's harmonic step 1/k with
      linear bounds, is still at |K - K*| / |K*| = 1 after its 200,000 iterations.
    - seed: :data:`MISSION_SEED`.  The phases are a draw (a campaign disperses them); the
      default 0 is the example systems' (on seed 1 the double integrator's hybrid learner
      does not converge).
    - learn_until_orbits: half-way from learn_at_orbits to the mission's end (``orbits``, in
      chief orbits), never before learn_at_orbits: a learner that has validated no gain by
      then flies its fallback for the rest, rather than K0's exploration to the end.
    """
    mission: dict[str, Any] = {
        "exploration_amplitude": attitude_limit / 2,
        "K0": ((0.0, 0.0, 0.0, 0.0),),
        "seed": MISSION_SEED,
        "learn_until_orbits": given.learn_at_orbits + max(orbits - given.learn_at_orbits, 0) / 2,
        **IMPLICIT_ITERATION,
    }
    return replace(given, **{k: v for k, v in mission.items() if k not in keys})
