"""Learning settings derived from the system: what a system file's ``[learning]`` table leaves out.

The data's simulator knows A, B, Q and R (the learner never reads A or B), so every setting
follows from the plant's rates and the cost, never from the mission:

- rates: the moduli of the eigenvalues of A, of the Riccati closed loop A - B K* and, when
  K0 is given, of A - B K0 (zero moduli left out); w_hi the fastest, w_lo the slowest;
- ``time_unit`` = w_hi, so the iteration's rates are of order one;
- ``sample_period`` = 0.01 / w_hi (the collector's trapezoid costs (w dt)^2 / 12 of accuracy at
  the fastest rate, under 1e-5 at twice it); ``command_period`` = ``sample_period``;
- ``interval`` = SAMPLES_PER_INTERVAL samples, ``intervals`` = twice the unknowns of the
  regression, n(n+1)/2 + (m+q) n, and at least 40 more than them;
- ``exploration_frequencies``: max(6, n + m) frequencies spread geometrically from the slowest
  rate / 2 (no lower than two periods over the data) to twice the fastest;
- ``exploration_amplitude`` = sqrt(|Q| / |R|): the input that costs as much as a unit state
  (for a linear plant with no input limit the amplitude scales the data and not the gain);
- the implicit step (:mod:`ddvi_core.continuation`, starting at half the Euler stability
  limit of the starting closed loop) with geometric bounds (``IMPLICIT_ITERATION``), the
  scale-free stopping rule on the gain's estimated relative error at 1e-6, and a budget of
  10,000 iterations.

K0 is never derived (zero unless given): an open-loop unstable plant needs a stabilising
``learning.K0``, and the data's simulation says so when they diverge.  A key given in the file
is used as given; a derived key that depends on a given one follows from it (``interval`` alone
below the derived sample period brings the sample period down to a tenth of it).
"""

from __future__ import annotations

import contextlib
import math
from dataclasses import replace

import numpy as np
from numpy.typing import NDArray

from ddvi_core.exploration import InterleavedExploration, periodic_start
from ddvi_core.learning_config import (
    IMPLICIT_ITERATION,
    SYSTEM_FILE_LEARNING_KEYS,
    LearningConfig,
)
from ddvi_core.lqr import NotStabilisingError, solve_lqr
from ddvi_core.problem import RegulationProblem
from ddvi_core.scaling import balanced_scaling
from ddvi_core.vec import triangle_size

__all__ = ["DERIVED_KEYS", "SAMPLES_PER_INTERVAL", "derive_learning", "system_rates"]

SAMPLES_PER_INTERVAL = 10
SAMPLES_PER_FAST_RATE = 100  # sample_period = 1 / (SAMPLES_PER_FAST_RATE w_hi)
FREQUENCY_SPAN = 20.0  # the exploration's highest frequency over its lowest, at most
DURATION_SPACINGS = 1.5  # periods of the exploration's closest frequency pair in the data

DERIVED_KEYS = (
    "time_unit",
    "sample_period",
    "command_period",
    "interval",
    "intervals",
    "exploration_frequencies",
    "exploration_amplitude",
    "exploration_channels",
    "x0",
    "state_scale",
    "step",
    "step_size",
    "bounds",
    "stopping",
    "tol",
    "max_iterations",
)
"""The keys derived when a system file does not give them; the others keep LearningConfig's
defaults (x0 and K0 zero, seed 0, no state scale, no input limit)."""


def system_rates(problem: RegulationProblem, K0: NDArray | None = None) -> NDArray:
    """The nonzero moduli (rad/s) of the eigenvalues of A, A - B K* (when the Riccati equation
    has a stabilising solution) and A - B K0 (when given), sorted; [1.0] if all are zero."""
    A, B = problem.A, problem.B
    mats = [A]
    with contextlib.suppress(NotStabilisingError):
        mats.append(A - B @ solve_lqr(A, B, problem.Q, problem.R).K)
    if K0 is not None and np.any(K0):
        mats.append(A - B @ K0)
    rates = np.abs(np.concatenate([np.linalg.eigvals(M) for M in mats]))
    top = float(np.max(rates)) if rates.size else 0.0
    rates = rates[rates > 1e-9 * top] if top > 0 else np.array([1.0])
    return np.sort(rates)


def data_duration(frequencies: tuple[float, ...]) -> float:
    """Seconds of data that tell the exploration's frequencies (rad/s) apart: one period of
    the lowest, and DURATION_SPACINGS periods of the smallest difference between two."""
    w = np.sort(np.asarray(frequencies, dtype=float))
    if not w.size:
        return 0.0
    spacing = float(np.min(np.diff(w))) if w.size > 1 else w[0]
    return max(2 * math.pi / w[0], DURATION_SPACINGS * 2 * math.pi / max(spacing, 1e-300))


def _timing(
    given: LearningConfig, keys: frozenset[str], w_hi: float, duration: float, needed: int
) -> dict[str, float | int]:
    """sample_period, command_period, interval and intervals, each as given or derived
    consistently with the given ones; the intervals together last ``duration`` seconds."""
    out: dict[str, float | int] = {}
    dt = 1.0 / (SAMPLES_PER_FAST_RATE * w_hi)
    if "sample_period" in keys:
        dt = given.sample_period
    elif "interval" in keys:
        dt = min(dt, given.interval / SAMPLES_PER_INTERVAL)
    if "command_period" in keys and "sample_period" not in keys:  # whole samples per command
        dt = given.command_period / max(1, math.ceil(given.command_period / dt - 1e-9))
    out["sample_period"] = dt
    out["command_period"] = given.command_period if "command_period" in keys else dt
    count = given.intervals if "intervals" in keys else max(2 * needed, needed + 40)
    out["intervals"] = count
    if "interval" in keys:
        out["interval"] = given.interval
    else:
        out["interval"] = max(SAMPLES_PER_INTERVAL, math.ceil(duration / count / dt)) * dt
    return out


def _exploration(
    problem: RegulationProblem,
    given: LearningConfig,
    keys: frozenset[str],
    w_lo: float,
    w_hi: float,
) -> dict[str, object]:
    """exploration_amplitude, _frequencies and _channels, and x0 on their periodic response."""
    out: dict[str, object] = {}
    q_norm, r_norm = np.linalg.norm(problem.Q, 2), np.linalg.norm(problem.R, 2)
    out["exploration_amplitude"] = float(math.sqrt(q_norm / r_norm)) if q_norm > 0 else 1.0
    lo = max(0.5 * w_lo, w_hi / FREQUENCY_SPAN)
    count = max(6, problem.n + problem.m)
    out["exploration_frequencies"] = tuple(float(w) for w in np.geomspace(lo, w_hi, count))
    out["exploration_channels"] = "interleaved"
    used = {k: getattr(given, k) if k in keys else v for k, v in out.items()}
    if used["exploration_channels"] == "interleaved":
        exploration = InterleavedExploration(
            used["exploration_amplitude"], used["exploration_frequencies"], given.seed
        )
        K0_cl = problem.A - problem.B @ given.K0_matrix(problem)
        out["x0"] = tuple(float(x) for x in periodic_start(K0_cl, problem.B, exploration))
    else:
        out["x0"] = None
    out["duration"] = data_duration(used["exploration_frequencies"])
    return out


def derive_learning(
    problem: RegulationProblem, given: LearningConfig, keys: frozenset[str]
) -> tuple[LearningConfig, tuple[str, ...]]:
    """The learning configuration for ``problem``: the keys in ``keys`` as ``given``, every
    key of :data:`DERIVED_KEYS` not in it derived (see the module docstring).  Returns the
    configuration and the names of the derived keys."""
    unknown = set(keys) - set(SYSTEM_FILE_LEARNING_KEYS)
    if unknown:
        raise ValueError(f"not system-file learning keys: {sorted(unknown)}")
    n, m, q = problem.n, problem.m, problem.q
    K0 = given.K0_matrix(problem) if "K0" in keys else None
    rates = system_rates(problem, K0)
    w_lo, w_hi = float(rates[0]), float(rates[-1])
    needed = triangle_size(n) + (m + q) * n
    values = _exploration(problem, given, keys, w_lo, w_hi)
    values.update(_timing(given, keys, w_hi, values.pop("duration"), needed))
    values["state_scale"] = tuple(
        float(x)
        for x in balanced_scaling(problem.A, problem.B, problem.Q, problem.R, w_hi).state_scale
    )
    values.update(
        time_unit=w_hi,
        **IMPLICIT_ITERATION,
        stopping="relative",
        tol=1e-6,
        max_iterations=10_000,
    )
    derived = tuple(k for k in DERIVED_KEYS if k not in keys)
    return replace(given, **{k: values[k] for k in derived}), derived
