"""One entry point for every method on a System: lqr, pi, vi, ddvi.

Each returns a :class:`Solution` with K, L (empty without an exosystem), P and the method's
diagnostics.  ``ddvi`` simulates the system's linear model exactly (zero-order hold) with the
configured exploration and learns from those data with the same collector and learner the
controller service uses: the learner sees samples, never A or B.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ddvi_core.learning import IntervalCollector, learn_from_data
from ddvi_core.lqr import NotStabilisingError, policy_iteration, solve_lqr
from ddvi_core.regulator import feedforward_gain, solve_regulator_equations
from ddvi_core.simulate import Exploration, simulate_zoh
from ddvi_core.systems import System
from ddvi_core.value_iteration import Scaling, balanced_scaling, value_iteration

__all__ = ["METHODS", "Solution", "solve"]

METHODS = ("lqr", "pi", "vi", "ddvi")


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
    if method == "ddvi":
        return _ddvi(system, cfg.seed if seed is None else seed)
    raise ValueError(f"method must be one of {', '.join(METHODS)}, got {method!r}")


def _ddvi(system: System, seed: int) -> Solution:
    pr, cfg = system.problem, system.learning
    rate = cfg.time_unit or float(np.max(np.abs(np.linalg.eigvals(pr.A)))) or 1.0
    freqs = cfg.exploration_frequencies or tuple(np.geomspace(0.3 * rate, 30 * rate, 6))
    exploration = Exploration(cfg.exploration_amplitude, tuple(freqs), seed)
    x0 = np.zeros(pr.n) if cfg.x0 is None else np.asarray(cfg.x0, float)
    v0 = None
    if pr.has_exosystem:
        v0 = np.ones(pr.q) if cfg.v0 is None else np.asarray(cfg.v0, float)
    collector = IntervalCollector(pr.n, pr.m, pr.q, cfg.interval)
    for t, x, u, v in simulate_zoh(
        pr.A,
        pr.B,
        pr.D,
        pr.E,
        x0,
        v0,
        K0=cfg.K0_matrix(pr),
        exploration=exploration,
        sample_period=cfg.sample_period,
        command_period=cfg.command_period,
        duration=cfg.interval * cfg.intervals,
        input_limit=cfg.input_limit,
    ):
        collector.add(t, x, u, v)
    r = learn_from_data(
        collector.data(),
        pr.Q,
        pr.R,
        time_unit=rate,
        C=pr.C,
        E=pr.E,
        F=pr.F,
        steps=cfg.steps(),
        bounds=cfg.bound_schedule(),
        tol=cfg.tol,
        max_iterations=cfg.max_iterations,
        state_scale=cfg.state_scale,
    )
    return Solution(
        "ddvi",
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
    out = {"K_error": float(np.linalg.norm(sol.K - ref.K) / np.linalg.norm(ref.K))}
    if ref.L.size and np.linalg.norm(ref.L) > 0:
        out["L_error"] = float(np.linalg.norm(sol.L - ref.L) / np.linalg.norm(ref.L))
    return out
