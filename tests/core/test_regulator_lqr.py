"""Regulator equations (Problem 1), the Riccati solution and Kleinman's policy iteration."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
import scipy.linalg

from ddvi_core import models
from ddvi_core.lqr import NotStabilisingError, policy_iteration, relative_gain_error, solve_lqr
from ddvi_core.regulator import (
    InfeasibleError,
    feedforward_gain,
    solve_equality_constrained_lstsq,
    solve_regulator_equations,
)


def _residuals(A, B, C, D, E, F, X, U) -> tuple[float, float]:
    r1 = np.linalg.norm(X @ E - A @ X - B @ U - D)
    r2 = np.linalg.norm(C @ X + F)
    return float(r1), float(r2)


def test_regulator_equations_thrust_rendezvous() -> None:
    P = models.thrust_rendezvous_problem()
    X, U = solve_regulator_equations(P.A, P.B, P.C, P.D, P.E, P.F)
    assert X.shape == (6, 8) and U.shape == (3, 8)
    r1, r2 = _residuals(P.A, P.B, P.C, P.D, P.E, P.F, X, U)
    # scales: X ~ 200 m, |E| ~ 4n ~ 5e-3, D ~ 1e-6
    assert r1 < 1e-12 * max(1.0, np.linalg.norm(X) * np.linalg.norm(P.E))
    assert r2 < 1e-9 * np.linalg.norm(P.F)
    # m = p: the solution is unique; independently solve the Sylvester-type system
    n, m, q = 6, 3, 8
    G = np.block(
        [
            [np.kron(P.E.T, np.eye(n)) - np.kron(np.eye(q), P.A), -np.kron(np.eye(q), P.B)],
            [np.kron(np.eye(q), P.C), np.zeros((3 * q, m * q))],
        ]
    )
    z = np.linalg.solve(
        G, np.concatenate([P.D.reshape(-1, order="F"), -P.F.reshape(-1, order="F")])
    )
    np.testing.assert_allclose(X, z[: n * q].reshape(n, q, order="F"), atol=1e-8)
    np.testing.assert_allclose(U, z[n * q :].reshape(m, q, order="F"), atol=1e-12)


@pytest.mark.parametrize("seed", range(5))
def test_regulator_equations_random_square(seed: int) -> None:
    rng = np.random.default_rng(seed)
    n, m, q = 5, 2, 4
    A = rng.standard_normal((n, n))
    B = rng.standard_normal((n, m))
    C = rng.standard_normal((m, n))
    D = rng.standard_normal((n, q))
    F = rng.standard_normal((m, q))
    w = rng.uniform(0.2, 3.0, 2)
    E = scipy.linalg.block_diag([[0, -w[0]], [w[0], 0]], [[0, -w[1]], [w[1], 0]])
    X, U = solve_regulator_equations(A, B, C, D, E, F)
    r1, r2 = _residuals(A, B, C, D, E, F, X, U)
    assert r1 < 1e-9 and r2 < 1e-9


def test_minimum_trace_underdetermined() -> None:
    rng = np.random.default_rng(11)
    n, m, p, q = 3, 2, 1, 2
    A = rng.standard_normal((n, n))
    B = rng.standard_normal((n, m))
    C = rng.standard_normal((p, n))
    D = rng.standard_normal((n, q))
    F = rng.standard_normal((p, q))
    E = np.array([[0.0, -1.3], [1.3, 0.0]])
    Qbar = np.diag([1.0, 2.0, 0.5])
    Rbar = np.diag([3.0, 1.0])
    X, U = solve_regulator_equations(A, B, C, D, E, F, Qbar, Rbar)
    r1, r2 = _residuals(A, B, C, D, E, F, X, U)
    assert r1 < 1e-10 and r2 < 1e-10

    def cost(X, U) -> float:
        return float(np.trace(X.T @ Qbar @ X + U.T @ Rbar @ U))

    # every feasible solution is (X, U) + a null-space direction of the linear constraints
    N = n * q + m * q
    G = np.block(
        [
            [np.kron(E.T, np.eye(n)) - np.kron(np.eye(q), A), -np.kron(np.eye(q), B)],
            [np.kron(np.eye(q), C), np.zeros((p * q, m * q))],
        ]
    )
    Z = scipy.linalg.null_space(G)
    assert Z.shape[1] == N - G.shape[0] > 0  # truly under-determined
    c_star = cost(X, U)
    for _ in range(200):
        z = Z @ rng.standard_normal(Z.shape[1]) * rng.choice([1e-3, 1e-1, 10.0])
        X2 = X + z[: n * q].reshape(n, q, order="F")
        U2 = U + z[n * q :].reshape(m, q, order="F")
        assert max(_residuals(A, B, C, D, E, F, X2, U2)) < 1e-8
        assert cost(X2, U2) >= c_star - 1e-9 * c_star
    # brute-force optimum along the null space: minimise |W (z0 + Z y)|
    Wh = scipy.linalg.block_diag(
        np.kron(np.eye(q), np.sqrt(Qbar)), np.kron(np.eye(q), np.sqrt(Rbar))
    )
    z0 = np.concatenate([X.reshape(-1, order="F"), U.reshape(-1, order="F")])
    y, *_ = np.linalg.lstsq(Wh @ Z, -Wh @ z0, rcond=None)
    assert np.linalg.norm(y) < 1e-8 * max(1.0, np.linalg.norm(z0))


def test_infeasible_names_eigenvalue() -> None:
    # G(s) = (s^2 + 4) / s^3 has transmission zeros at +-2j = eigenvalues of E
    A = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [0.0, 0.0, 0.0]])
    B = np.array([[0.0], [0.0], [1.0]])
    C = np.array([[4.0, 0.0, 1.0]])
    E = np.array([[0.0, -2.0], [2.0, 0.0]])
    with pytest.raises(InfeasibleError) as exc:
        solve_regulator_equations(A, B, C, np.zeros((3, 2)), E, np.array([[1.0, 0.0]]))
    msg = str(exc.value)
    assert "2j" in msg and "needed n + p = 4" in msg


def test_equality_constrained_lstsq_direct() -> None:
    # minimise |z - c| subject to z1 + z2 = 1: projection of c onto the line
    c = np.array([3.0, -1.0])
    z, res = solve_equality_constrained_lstsq(np.eye(2), c, np.array([[1.0, 1.0]]), np.array([1.0]))
    np.testing.assert_allclose(z, [2.5, -1.5], atol=1e-12)
    assert res < 1e-12
    with pytest.raises(InfeasibleError):
        solve_equality_constrained_lstsq(
            np.eye(2), c, np.array([[1.0, 1.0], [1.0, 1.0]]), np.array([1.0, 2.0])
        )


def test_feedforward_gain() -> None:
    K = np.array([[1.0, 2.0]])
    X = np.array([[1.0, 0.0], [0.0, 1.0]])
    U = np.array([[0.5, -0.5]])
    np.testing.assert_allclose(feedforward_gain(K, X, U), [[1.5, 1.5]])


# ---- LQR ------------------------------------------------------------------------------------
def _random_lqr(seed: int, n: int = 4, m: int = 2):
    rng = np.random.default_rng(seed)
    A = rng.standard_normal((n, n)) + 0.5 * np.eye(n)  # usually unstable
    B = rng.standard_normal((n, m))
    M = rng.standard_normal((n, n))
    Q = M @ M.T + 0.1 * np.eye(n)
    Rm = rng.standard_normal((m, m))
    R = Rm @ Rm.T + np.eye(m)
    return A, B, Q, R


@pytest.mark.parametrize("seed", range(4))
def test_solve_lqr_matches_scipy(seed: int) -> None:
    A, B, Q, R = _random_lqr(seed)
    res = solve_lqr(A, B, Q, R)
    P_ref = scipy.linalg.solve_continuous_are(A, B, Q, R)
    np.testing.assert_allclose(res.P, P_ref, rtol=1e-9, atol=1e-9 * np.linalg.norm(P_ref))
    np.testing.assert_allclose(res.K, np.linalg.solve(R, B.T @ P_ref), rtol=1e-8, atol=1e-10)
    np.testing.assert_array_equal(res.P, res.P.T)
    ric = A.T @ res.P + res.P @ A + Q - res.P @ B @ np.linalg.solve(R, B.T @ res.P)
    assert np.linalg.norm(ric) < 1e-8 * np.linalg.norm(res.P)
    eig = np.linalg.eigvals(A - B @ res.K)
    assert np.all(eig.real < 0)
    np.testing.assert_allclose(np.sort_complex(res.closed_loop_eigenvalues), np.sort_complex(eig))


def test_solve_lqr_rendezvous_hurwitz() -> None:
    for P in (models.rendezvous_problem(), models.thrust_rendezvous_problem()):
        res = solve_lqr(P.A, P.B, P.Q, P.R)
        assert np.max(np.linalg.eigvals(P.A - P.B @ res.K).real) < 0
        assert np.min(np.linalg.eigvalsh(res.P)) > 0


def test_solve_lqr_unstabilisable_raises() -> None:
    A = np.diag([1.0, -1.0])
    B = np.array([[0.0], [1.0]])
    with pytest.raises(NotStabilisingError):
        solve_lqr(A, B, np.eye(2), np.eye(1))


def test_policy_iteration_matches_lqr_and_is_monotone() -> None:
    A, B, Q, R = _random_lqr(7)
    assert np.max(np.linalg.eigvals(A).real) > 0
    # a stabilising K0 from a different (heavier) cost
    K0 = solve_lqr(A, B, 100.0 * np.eye(4), np.eye(2)).K
    ref = solve_lqr(A, B, Q, R)
    res = policy_iteration(A, B, Q, R, K0=K0, tol=1e-13)
    assert res.iterations < 100
    assert np.linalg.norm(res.K - ref.K) <= 1e-8 * np.linalg.norm(ref.K)
    assert np.linalg.norm(res.P - ref.P) <= 1e-8 * np.linalg.norm(ref.P)
    # Kleinman: P_1 >= P_2 >= ... >= P*  (Loewner order)
    Ps = [policy_iteration(A, B, Q, R, K0=K0, max_iterations=k).P for k in range(1, 7)]
    Ps.append(ref.P)
    for Pa, Pb in itertools.pairwise(Ps):
        assert np.min(np.linalg.eigvalsh(Pa - Pb)) >= -1e-9 * np.linalg.norm(Pa)
    assert np.linalg.norm(Ps[0] - ref.P) > 1e-6 * np.linalg.norm(ref.P)  # not trivially at P*


def test_policy_iteration_default_K0_on_hurwitz() -> None:
    A = np.array([[-1.0, 2.0], [0.0, -3.0]])
    B = np.array([[0.0], [1.0]])
    res = policy_iteration(A, B, np.eye(2), np.eye(1))
    ref = scipy.linalg.solve_continuous_are(A, B, np.eye(2), np.eye(1))
    np.testing.assert_allclose(res.P, ref, rtol=1e-8)


def test_policy_iteration_rejects_non_stabilising_K0() -> None:
    A, B, Q, R = _random_lqr(7)
    with pytest.raises(NotStabilisingError, match="K0"):
        policy_iteration(A, B, Q, R, K0=np.zeros((2, 4)))


def test_relative_gain_error_is_the_frobenius_ratio_and_guards_its_edges() -> None:
    K_ref = np.array([[3.0, 4.0]])
    assert relative_gain_error([[3.0, 4.5]], K_ref) == pytest.approx(0.1)
    assert relative_gain_error(np.zeros((1, 2)), np.zeros((1, 2))) == 0.0
    assert relative_gain_error([[1e-9, 0.0]], np.zeros((1, 2))) == math.inf
    with pytest.raises(ValueError, match=r"K is \(1, 3\), K_ref \(1, 2\)"):
        relative_gain_error(np.ones((1, 3)), K_ref)
    with pytest.raises(ValueError, match="non-finite"):
        relative_gain_error([[np.nan, 0.0]], K_ref)
