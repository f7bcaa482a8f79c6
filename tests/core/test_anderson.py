"""Anderson-accelerated value iteration: stiff plants from a non-stabilising start, the
safeguard, and what ``converged`` means."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import scipy.linalg

from ddvi_core import anderson
from ddvi_core.solve import _vi_scaling, solve
from ddvi_core.systems import System
from ddvi_core.value_iteration import StepSequence, VIResult, value_iteration
from services.config.files import load_system

SYSTEMS = Path(__file__).resolve().parents[2] / "docs" / "examples" / "systems"
STIFF = ("dc-motor-position", "thermal-chain")


def _system(name: str) -> System:
    return load_system(str(SYSTEMS / f"{name}.toml"))


def _vi(system: System, memory: int, max_iterations: int = 10_000) -> VIResult:
    pr, cfg = system.problem, system.learning
    # Anderson accelerates the explicit (adaptive) step; the derived step is the implicit one
    return value_iteration(
        pr.A,
        pr.B,
        pr.Q,
        pr.R,
        steps=StepSequence("adaptive", 0.5),
        bounds=cfg.bound_schedule(),
        tol=1e-6,
        max_iterations=max_iterations,
        scaling=_vi_scaling(system),
        rule="relative",
        memory=memory,
    )


def _are_gain(system: System) -> np.ndarray:
    pr = system.problem
    P = scipy.linalg.solve_continuous_are(pr.A, pr.B, pr.Q, pr.R)
    return np.linalg.solve(pr.R, pr.B.T @ P)


def _spread(system: System, K: np.ndarray) -> float:
    rates = np.abs(np.linalg.eigvals(system.problem.A - system.problem.B @ K))
    return float(rates.max() / rates.min())


@pytest.mark.parametrize("name", STIFF)
def test_accelerated_vi_reaches_the_are_gain_on_a_stiff_plant(name: str) -> None:
    system = _system(name)
    K_star = _are_gain(system)
    assert _spread(system, K_star) > 500
    # P0 = 1e-3 I in scaled units: its gain leaves the plant's zero or slow poles unstabilised
    zero_gain_poles = np.linalg.eigvals(system.problem.A)
    assert np.max(zero_gain_poles.real) > -1e-3 * np.max(np.abs(zero_gain_poles))
    plain = _vi(system, memory=0)
    fast = _vi(system, memory=anderson.DEFAULT_MEMORY)
    assert not plain.converged and "not converged after 10000 iterations" in plain.message
    assert fast.converged and fast.iterations < 10_000
    assert np.linalg.norm(fast.K - K_star) / np.linalg.norm(K_star) < 1e-4
    assert "<= tol 1e-06" in fast.message


def test_data_driven_vi_reaches_the_are_gain_on_the_stiff_motor() -> None:
    system = _system("dc-motor-position")
    sol = solve(system, "ddvi")
    K_star = _are_gain(system)
    assert sol.converged, sol.details["message"]
    assert np.linalg.norm(sol.K - K_star) / np.linalg.norm(K_star) < 1e-4


def test_the_safeguard_rejects_an_extrapolation_that_leaves_the_cone_and_recovers(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """On the double integrator raw Anderson proposes indefinite iterates; the loop takes the
    plain step instead and still converges to the Riccati gain."""
    proposals: list[float] = []
    propose = anderson.AndersonHistory.propose

    def spy(self, P, F, eps):
        out = propose(self, P, F, eps)
        if out is not None:
            proposals.append(float(np.linalg.eigvalsh(out)[0] / np.linalg.norm(out)))
        return out

    monkeypatch.setattr(anderson.AndersonHistory, "propose", spy)
    system = _system("double-integrator")
    res = _vi(system, memory=anderson.DEFAULT_MEMORY)
    left = sum(e < -1e-6 for e in proposals)
    assert left > 0  # raw Anderson would have left the cone
    rejected = int(res.message.split(" accelerated steps, ")[1].split()[0])
    assert rejected >= left
    assert res.converged
    K_star = _are_gain(system)
    assert np.linalg.norm(res.K - K_star) / np.linalg.norm(K_star) < 1e-4
    assert np.linalg.eigvalsh(res.P)[0] > 0


def test_not_converged_when_the_tolerance_is_not_met_in_the_budget() -> None:
    res = _vi(_system("dc-motor-position"), memory=anderson.DEFAULT_MEMORY, max_iterations=50)
    assert not res.converged
    assert res.message.startswith("not converged after 50 iterations")
    assert "tol 1e-06" in res.message


def test_the_history_rejects_a_memory_below_one() -> None:
    with pytest.raises(ValueError, match="memory must be a positive integer"):
        anderson.AndersonHistory(0)
