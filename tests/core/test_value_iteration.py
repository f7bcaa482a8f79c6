"""Model-based value iteration (Algorithm 1) and its scaling."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg

from ddvi_core import models
from ddvi_core.lqr import solve_lqr
from ddvi_core.scaling import Scaling, balanced_scaling
from ddvi_core.value_iteration import (
    BoundSchedule,
    IterationSettings,
    StepSequence,
    value_iteration,
    value_iteration_loop,
)


def _rel(a, b) -> float:
    return float(np.linalg.norm(a - b) / np.linalg.norm(b))


def test_small_damped_system_paper_defaults() -> None:
    A = np.array([[0.0, 1.0], [-2.0, -3.0]])
    B = np.array([[0.0], [1.0]])
    Q, R = np.eye(2), np.eye(1)
    P_are = scipy.linalg.solve_continuous_are(A, B, Q, R)
    K_are = np.linalg.solve(R, B.T @ P_are)
    for scaling in (True, False):
        res = value_iteration(A, B, Q, R, scaling=scaling)  # eps_k = 1/k, bounds 10 (r+1)
        assert res.converged, res.message
        assert _rel(res.K, K_are) < 1e-4
        assert _rel(res.P, P_are) < 1e-4
        assert res.iterations == len(res.history)
        assert "converged" in res.message


def test_rendezvous_with_balanced_scaling_converges() -> None:
    prob = models.rendezvous_problem()
    n = models.DragRendezvous().mean_motion
    A, B, Q, R = prob.A, prob.B, prob.Q, prob.R
    sc = balanced_scaling(A, B, Q, R, time_unit=n)
    res = value_iteration(
        A,
        B,
        Q,
        R,
        steps=StepSequence("constant", 0.01),
        bounds=BoundSchedule("geometric"),
        scaling=sc,
    )
    P_are = scipy.linalg.solve_continuous_are(A, B, Q, R)
    K_are = np.linalg.solve(R, B.T @ P_are)
    assert res.converged, res.message
    assert _rel(res.K, K_are) < 1e-3
    assert res.scaling is sc and res.scaling.time_unit == n
    assert res.iterations > 0 and res.resets >= 0
    assert res.history.shape == (res.iterations,)
    assert np.all(np.isfinite(res.history)) and np.all(res.history >= 0)
    assert np.max(np.linalg.eigvals(A - B @ res.K).real) < 0


def test_raw_rendezvous_with_harmonic_steps_does_not_converge() -> None:
    """docs/design.md, "The paper's errata": eps_k = 1/k in seconds with R = 1e7 gets nowhere."""
    prob = models.rendezvous_problem()
    K_are = solve_lqr(prob.A, prob.B, prob.Q, prob.R).K
    res = value_iteration(prob.A, prob.B, prob.Q, prob.R, scaling=False, max_iterations=3000)
    assert not res.converged
    assert res.iterations == 3000
    assert "not converged" in res.message
    assert _rel(res.K, K_are) > 0.5
    assert res.scaling.time_unit == 1.0


def test_scaling_round_trip_and_are_invariance() -> None:
    rng = np.random.default_rng(5)
    n, m = 4, 2
    A = rng.standard_normal((n, n))
    B = rng.standard_normal((n, m))
    Mq = rng.standard_normal((n, n))
    Q = Mq @ Mq.T + np.eye(n)
    R = np.diag([2.0, 0.5])
    sc = Scaling(0.37, np.array([1.0, 10.0, 0.1, 3.0]), np.array([2.0, 0.25]), 0.03)
    Pr = rng.standard_normal((n, n))
    Pr = Pr + Pr.T
    np.testing.assert_allclose(sc.unscale_P(sc.scale_P(Pr)), Pr, rtol=1e-14)
    np.testing.assert_allclose(sc.scale_P(sc.unscale_P(Pr)), Pr, rtol=1e-14)

    A_s, B_s = sc.dynamics(A, B)
    Q_s, R_s = sc.weights(Q, R)
    # direct formulas: A_s = S^-1 A S / w0, B_s = S^-1 B s_u / w0
    S, su = np.diag(sc.state_scale), np.diag(sc.input_scale)
    np.testing.assert_allclose(A_s, np.linalg.solve(S, A @ S) / 0.37, rtol=1e-13)
    np.testing.assert_allclose(B_s, np.linalg.solve(S, B @ su) / 0.37, rtol=1e-13)
    np.testing.assert_allclose(Q_s, 0.03 * S @ Q @ S / 0.37, rtol=1e-13)

    P = scipy.linalg.solve_continuous_are(A, B, Q, R)
    K = np.linalg.solve(R, B.T @ P)
    P_s = scipy.linalg.solve_continuous_are(A_s, B_s, Q_s, R_s)
    K_s = np.linalg.solve(R_s, B_s.T @ P_s)
    np.testing.assert_allclose(sc.unscale_P(P_s), P, rtol=1e-8, atol=1e-10 * np.linalg.norm(P))
    np.testing.assert_allclose(sc.scale_P(P), P_s, rtol=1e-8, atol=1e-10 * np.linalg.norm(P_s))
    np.testing.assert_allclose(sc.unscale_K(K_s), K, rtol=1e-8, atol=1e-10 * np.linalg.norm(K))
    assert sc.as_dict()["state_scale"] == [1.0, 10.0, 0.1, 3.0]


def test_identity_scaling_and_balanced_scaling_properties() -> None:
    ident = Scaling.identity(3, 2)
    A = np.arange(9.0).reshape(3, 3)
    B = np.ones((3, 2))
    np.testing.assert_array_equal(ident.dynamics(A, B)[0], A)
    prob = models.rendezvous_problem()
    sc = balanced_scaling(prob.A, prob.B, prob.Q, prob.R)
    # default unit: A's fastest eigenvalue modulus / 100
    fastest = np.max(np.abs(np.linalg.eigvals(prob.A)))
    assert sc.time_unit == pytest.approx(fastest / 100)
    Q_s, _ = sc.weights(prob.Q, prob.R)
    assert np.linalg.norm(Q_s, 2) == pytest.approx(1.0)
    assert np.max(sc.state_scale) == 1.0
    # powers of two: scaling is exact
    np.testing.assert_array_equal(np.log2(sc.state_scale), np.round(np.log2(sc.state_scale)))


def test_step_and_bound_sequences() -> None:
    h = StepSequence()
    assert [h(k) for k in range(3)] == [1.0, 0.5, 1.0 / 3.0]
    assert StepSequence("constant", 0.2)(1000) == 0.2
    assert [BoundSchedule()(r) for r in range(3)] == [10.0, 20.0, 30.0]
    assert [BoundSchedule("geometric")(r) for r in range(3)] == [10.0, 20.0, 40.0]
    assert np.isfinite(BoundSchedule("geometric")(10**6))


@pytest.mark.parametrize(
    "make",
    [
        lambda: StepSequence("sqrt"),
        lambda: StepSequence("harmonic", 0.0),
        lambda: StepSequence("constant", -1.0),
        lambda: StepSequence("constant", float("nan")),
        lambda: StepSequence("constant", float("inf")),
        lambda: BoundSchedule("exponential"),
        lambda: BoundSchedule("linear", 0.0),
        lambda: BoundSchedule("geometric", -2.0),
        lambda: Scaling(0.0, np.ones(2), np.ones(1), 1.0),
        lambda: Scaling(1.0, np.ones(2), np.ones(1), float("inf")),
        lambda: Scaling(1.0, np.array([1.0, -1.0]), np.ones(1), 1.0),
        lambda: Scaling(1.0, np.ones(2), np.array([np.nan]), 1.0),
    ],
)
def test_validation_errors(make) -> None:
    with pytest.raises(ValueError):
        make()


def test_bounds_reset_counted() -> None:
    """A tiny bound forces resets; the iteration must still report them and not converge."""
    A = np.array([[0.0, 1.0], [-2.0, -3.0]])
    B = np.array([[0.0], [1.0]])
    res = value_iteration(
        A,
        B,
        100 * np.eye(2),
        np.eye(1),
        scaling=False,
        bounds=BoundSchedule("linear", 1e-3),
        max_iterations=50,
    )
    assert res.resets > 0
    assert not res.converged


def test_a_map_that_leaves_the_psd_cone_stops_early_and_says_so() -> None:
    """Q is zero along the second axis; a Lyapunov map A^T P + P A could not push P out of
    the cone there, but this one (as a map estimated from poor data can) takes from P_22 in
    proportion to P_11.  Every restart from P0 leaves the cone alike: the loop stops after
    ``max_psd_resets`` of them instead of running to ``max_iterations``."""
    Q_s, R_s = np.diag([1.0, 0.0]), np.eye(1)

    def leaky_map(P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return np.diag([-0.1 * P[0, 0], -0.5 * P[0, 0]]), np.zeros((1, 2))

    settings = IterationSettings(
        steps=StepSequence("constant", 0.01),
        bounds=BoundSchedule("geometric", 1e6),
        tol=1e-9,
        max_iterations=200_000,
        memory=0,
        max_psd_resets=20,
    )
    out = value_iteration_loop(leaky_map, Q_s, R_s, 1e-3 * np.eye(2), settings)
    P, _, iterations, resets, converged, _, _, why = out
    assert not converged and resets == 20
    assert iterations < 2_000  # not the 200,000 it would otherwise spin through
    assert "positive semidefinite cone 20 times from P0 with a step of 0.01" in why
    assert np.linalg.eigvalsh(P)[0] > 0  # what it returns is P0, not the indefinite iterate
    # the same loop on the Lyapunov map of a stable A converges with no reset at all
    A_s = np.array([[-0.1, 0.0], [1.0, -0.5]])

    def lyap(P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return A_s.T @ P + P @ A_s, np.zeros((1, 2))

    out = value_iteration_loop(lyap, Q_s, R_s, 1e-3 * np.eye(2), settings)
    assert out[4] and out[3] == 0 and out[7].startswith("residual")
