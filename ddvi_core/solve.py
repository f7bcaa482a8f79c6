"""One entry point for every method on a System: lqr, pi, vi (model-based), and ddvi, dpi,
hybrid (from data: value iteration, policy iteration, value then policy iteration).

Each returns a :class:`Solution` with K, L (empty without an exosystem), P and the method's
diagnostics.  The data-driven methods simulate the system's linear model exactly (zero-order
hold) with the configured exploration and learn from those data with the same collector and
learner the controller service uses: the learner sees samples, never A or B.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ddvi_core.exploration import InterleavedExploration, periodic_start
from ddvi_core.learning import IntervalCollector, LearningError, learn_from_data
from ddvi_core.lqr import NotStabilisingError, policy_iteration, relative_gain_error, solve_lqr
from ddvi_core.regulator import feedforward_gain, solve_regulator_equations
from ddvi_core.scaling import Scaling, balanced_scaling
from ddvi_core.simulate import Exploration, simulate_zoh
from ddvi_core.systems import System
from ddvi_core.value_iteration import value_iteration

__all__ = ["DATA_METHODS", "METHODS", "Solution", "collect", "reference_errors", "solve"]

METHODS = ("lqr", "pi", "vi", "ddvi", "dpi", "hybrid")


@dataclass(frozen=True)
class Solution:
    method: str
    K: NDArray[np.float64]
    L: NDArray[np.float64]
    P: NDArray[np.float64]
    iterations: int
    converged: bool
    details: dict[str, Any] = field(default_factory=dict)


def _feedforward(system: System, K: NDArray) -> NDArray:
    pr = system.problem
    if not pr.has_exosystem:
        return np.zeros((pr.m, 0))
    X, U = solve_regulator_equations(pr.A, pr.B, pr.C, pr.D, pr.E, pr.F)
    return feedforward_gain(K, X, U)


def _vi_scaling(system: System) -> Scaling:
    pr, cfg = system.problem, system.learning
    sc = balanced_scaling(pr.A, pr.B, pr.Q, pr.R, time_unit=cfg.time_unit)
    if cfg.state_scale is not None:
        S = np.asarray(cfg.state_scale, dtype=float)
        q = float(np.linalg.norm(pr.Q * np.outer(S, S) / sc.time_unit, 2))
        sc = replace(sc, state_scale=S, cost_scale=1.0 / q if q > 0 else 1.0)
    return sc


def solve(system: System, method: str, seed: int | None = None) -> Solution:
    """Solve ``system`` by ``method`` (one of METHODS).  ``seed`` overrides the exploration
    seed of the system's learning configuration (ddvi only)."""
    pr, cfg = system.problem, system.learning
    if method == "lqr":
        r = solve_lqr(pr.A, pr.B, pr.Q, pr.R)
        return Solution(
            "lqr",
            r.K,
            _feedforward(system, r.K),
            r.P,
            0,
            True,
            {"closed_loop_eigenvalues": r.closed_loop_eigenvalues},
        )
    if method == "pi":
        K0 = cfg.K0_matrix(pr)
        start = "learning.K0"
        if np.max(np.linalg.eigvals(pr.A - pr.B @ K0).real) >= 0:
            # PI needs a stabilising start: a deliberately detuned LQR gain (R x 100)
            K0 = solve_lqr(pr.A, pr.B, pr.Q, 100.0 * pr.R).K
            start = "LQR gain for 100 R (learning.K0 does not stabilise)"
        r = policy_iteration(pr.A, pr.B, pr.Q, pr.R, K0=K0)
        return Solution(
            "pi", r.K, _feedforward(system, r.K), r.P, r.iterations, True, {"initial_gain": start}
        )
    if method == "vi":
        r = value_iteration(
            pr.A,
            pr.B,
            pr.Q,
            pr.R,
            steps=cfg.steps(),
            bounds=cfg.bound_schedule(),
            tol=cfg.tol,
            max_iterations=cfg.max_iterations,
            scaling=_vi_scaling(system),
            rule=cfg.stopping,
        )
        return Solution(
            "vi",
            r.K,
            _feedforward(system, r.K),
            r.P,
            r.iterations,
            r.converged,
            {
                "resets": r.resets,
                "residual": r.residual,
                "scaling": r.scaling.as_dict(),
                "message": r.message,
            },
        )
    if method in DATA_METHODS:
        return _learn(system, method, cfg.seed if seed is None else seed)
    raise ValueError(f"method must be one of {', '.join(METHODS)}, got {method!r}")


DIVERGENCE = 1e6
"""The data diverge when |x| exceeds this many times its largest value over the first
interval: far below any overflow, far above what a bounded exploration produces."""

# --method name: the learner's iteration (ddvi_core.policy_learning.LEARNING_METHODS)
DATA_METHODS = {"ddvi": "vi", "dpi": "pi", "hybrid": "hybrid"}


def _diverged(times: list[float], norms: list[float], first: float, K0: NDArray) -> LearningError:
    """The one-line error for data whose |x| grew DIVERGENCE-fold over ``first`` (its largest
    value over the first interval), with the growth rate fitted to log |x| over the second half
    of the samples (times, norms: per sample)."""
    half = len(times) // 2
    t, lg = np.asarray(times[half:]), np.log(np.maximum(norms[half:], 1e-300))
    rate = float(np.polyfit(t, lg, 1)[0]) if t.size > 1 and np.ptp(t) > 0 else math.inf
    return LearningError(
        f"the data diverge: |x| grew {norms[-1] / first:.3g}-fold by t = {times[-1]:.4g} s, "
        f"at {rate:.3g} 1/s (e-folding every {1 / rate:.3g} s), under the initial gain "
        f"learning.K0 = {np.round(K0, 6).tolist()}: the plant is unstable with it; give a "
        "stabilising learning.K0 in the system file's [learning] table"
    )


def collect(system: System, seed: int) -> IntervalCollector:
    """The interval data of the system's linear model simulated exactly under
    u = -K0 x + exploration (the system's learning configuration); raises LearningError,
    naming learning.K0 and the growth rate, when the state diverges."""
    pr, cfg = system.problem, system.learning
    rate = cfg.time_unit or float(np.max(np.abs(np.linalg.eigvals(pr.A)))) or 1.0
    freqs = cfg.exploration_frequencies or tuple(np.geomspace(0.3 * rate, 30 * rate, 6))
    kind = InterleavedExploration if cfg.exploration_channels == "interleaved" else Exploration
    exploration = kind(cfg.exploration_amplitude, tuple(freqs), seed)
    x0 = np.zeros(pr.n) if cfg.x0 is None else np.asarray(cfg.x0, float)
    if "x0" in system.derived and seed != cfg.seed:  # the periodic start of this exploration
        x0 = periodic_start(pr.A - pr.B @ cfg.K0_matrix(pr), pr.B, exploration)
    v0 = None
    if pr.has_exosystem:
        v0 = np.ones(pr.q) if cfg.v0 is None else np.asarray(cfg.v0, float)
    K0 = cfg.K0_matrix(pr)
    collector = IntervalCollector(pr.n, pr.m, pr.q, cfg.interval)
    times: list[float] = []
    norms: list[float] = []
    first = 0.0
    samples = simulate_zoh(
        pr.A,
        pr.B,
        pr.D,
        pr.E,
        x0,
        v0,
        K0=K0,
        exploration=exploration,
        sample_period=cfg.sample_period,
        command_period=cfg.command_period,
        duration=cfg.interval * cfg.intervals,
        input_limit=cfg.input_limit,
    )
    with np.errstate(all="ignore"):
        for t, x, u, v in samples:
            size = float(np.sqrt(x @ x))
            times.append(t)
            norms.append(size)
            if t <= cfg.interval:
                first = max(first, size)
            elif not size <= DIVERGENCE * max(first, 1e-300):
                raise _diverged(times, norms, first, K0)
            collector.add(t, x, u, v)
    return collector


def _learn(system: System, method: str, seed: int) -> Solution:
    """ddvi, dpi or hybrid: the data, then the learner on them alone (timed apart)."""
    pr, cfg = system.problem, system.learning
    t0 = time.perf_counter()
    collector = collect(system, seed)
    t1 = time.perf_counter()
    with np.errstate(all="ignore"):  # a non-finite iterate stops the loop with its reason
        r = learn_from_data(
            collector.data(),
            pr.Q,
            pr.R,
            time_unit=cfg.time_unit or float(np.max(np.abs(np.linalg.eigvals(pr.A)))) or 1.0,
            C=pr.C,
            E=pr.E,
            F=pr.F,
            iteration=cfg.iteration_settings(DATA_METHODS[method]),
            state_scale=cfg.state_scale,
            K0=cfg.K0_matrix(pr),
        )
    t2 = time.perf_counter()
    return Solution(
        method,
        r.K,
        r.L,
        r.P,
        r.iterations,
        r.converged,
        {
            "resets": r.resets,
            "rank": r.rank,
            "rank_needed": r.rank_needed,
            "condition": r.condition,
            "residual": r.residual,
            "intervals": r.intervals,
            "samples": collector.samples,
            "data_s": t1 - t0,
            "learning_s": t2 - t1,
            "scaling": r.scaling.as_dict(),
            "message": r.message,
        },
    )


def reference_errors(system: System, sol: Solution) -> dict[str, float]:
    """|K - K*| / |K*| and |L - L*| / |L*| against the Riccati / regulator-equation solution,
    or {} when the system has no stabilising Riccati solution."""
    try:
        ref = solve(system, "lqr")
    except (NotStabilisingError, ValueError):
        return {}
    out = {"K_error": relative_gain_error(sol.K, ref.K)}
    if ref.L.size and np.linalg.norm(ref.L) > 0:
        out["L_error"] = relative_gain_error(sol.L, ref.L)
    return out
