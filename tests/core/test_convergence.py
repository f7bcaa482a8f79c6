"""The adaptive step, the budget report, and policy evaluation on a regression map."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg

from ddvi_core.convergence import adaptive_step, budget_report, euler_step_limit
from ddvi_core.lqr import solve_lqr
from ddvi_core.policy_learning import basis_images, is_positive_definite, policy_evaluation
from ddvi_core.value_iteration import StepSequence, value_iteration


def test_euler_step_limit_is_that_of_the_lyapunov_operator() -> None:
    lam = np.array([-1.0, -3.0])  # mu = -2, -4, -6: limit min(2 * 2 / 4, 2 * 6 / 36) = 1/3
    assert euler_step_limit(lam) == pytest.approx(1 / 3)
    lam = np.array([-0.1 + 2j, -0.1 - 2j])  # lightly damped: mu = -0.2 +- 4j, and -0.2
    assert euler_step_limit(lam) == pytest.approx(0.4 / (0.04 + 16))
    assert euler_step_limit(np.zeros(3)) == np.inf
    # a forward-Euler step at the limit neither grows nor decays the worst mode
    mu = 2 * lam[0]
    assert abs(1 + euler_step_limit(lam) * mu) == pytest.approx(1.0)


def test_adaptive_step_stays_below_the_limit_and_the_trust_region() -> None:
    lam = np.array([-1.0, -3.0])
    assert adaptive_step(lam, 0.5, 1.0, 1e-9) == pytest.approx(0.5 / 3)
    assert adaptive_step(lam, 0.5, 1e-3, 1.0) == pytest.approx(0.5e-3)  # P grows by half


def test_a_spent_budget_says_the_error_and_its_trend() -> None:
    errors = 1e-2 * np.exp(-np.arange(100) / 50.0)
    text = budget_report(errors, 1e-6)
    assert "estimated relative error" in text and "more iterations" in text
    flat = budget_report(np.full(50, 1e-2), 1e-6)
    assert "not falling" in flat


def test_value_iteration_reports_the_budget_with_its_trend() -> None:
    A = np.array([[0.0, 1.0], [-1.0, -0.01]])  # lightly damped: slow with the paper's 1/k
    B, Q, R = np.array([[0.0], [1.0]]), np.eye(2), np.eye(1)
    plain = {"rule": "relative", "scaling": False, "memory": 0}  # the budget of the plain loop
    res = value_iteration(A, B, Q, R, max_iterations=300, **plain)
    assert not res.converged and "estimated relative error of K" in res.message
    res = value_iteration(
        A, B, Q, R, steps=StepSequence("adaptive", 0.5), rule="relative", scaling=False
    )
    K_star = solve_lqr(A, B, Q, R).K
    assert res.converged and res.iterations < 1_000
    assert np.linalg.norm(res.K - K_star) / np.linalg.norm(K_star) < 1e-5


def test_adaptive_step_needs_a_fraction_below_one() -> None:
    with pytest.raises(ValueError, match="fraction below 1"):
        StepSequence("adaptive", 1.5)


class ExactMap:
    """The regression map of exact data: P -> (A^T P + P A, R^-1 B^T P)."""

    def __init__(self, A: np.ndarray, B: np.ndarray, R: np.ndarray) -> None:
        self.A, self.B, self.R = A, B, R
        self.n, self.m = B.shape

    def __call__(self, P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return self.A.T @ P + P @ self.A, np.linalg.solve(self.R, self.B.T @ P)


def test_policy_evaluation_is_the_lyapunov_solution_and_tells_stability() -> None:
    A = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [-1.0, -2.0, -0.5]])
    B = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
    Q, R = np.diag([1.0, 2.0, 3.0]), np.diag([1.0, 4.0])
    images = basis_images(ExactMap(A, B, R))
    K = np.array([[0.5, 1.0, 0.0], [0.0, 0.2, 1.0]])
    Ak = A - B @ K
    expected = scipy.linalg.solve_continuous_lyapunov(Ak.T, -(Q + K.T @ R @ K))
    P = policy_evaluation(images, Q, R, K)
    np.testing.assert_allclose(P, expected, rtol=1e-10, atol=1e-12)
    assert is_positive_definite(P)
    K_bad = np.array([[-5.0, 0.0, 0.0], [0.0, 0.0, 0.0]])  # puts a pole in the right half-plane
    assert np.max(np.linalg.eigvals(A - B @ K_bad).real) > 0
    assert not is_positive_definite(policy_evaluation(images, Q, R, K_bad))
