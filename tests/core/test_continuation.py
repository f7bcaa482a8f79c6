"""Value iteration by implicit steps (ddvi_core.continuation): the Newton estimate of the gain's
error, no stabilising initial gain, the cone safeguard, and the user's tolerance deciding
``converged``."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import scipy.linalg

from ddvi_core.continuation import basis_images, continuation_loop, gain_error, linearisation
from ddvi_core.solve import solve
from ddvi_core.value_iteration import (
    BoundSchedule,
    IterationSettings,
    StepSequence,
    value_iteration,
)
from services.cli import main
from services.config.files import load_system

SYSTEMS = Path(__file__).resolve().parents[2] / "docs" / "examples" / "systems"


class ExactMap:
    """The regression map of exact data: P -> (A^T P + P A, R^-1 B^T P)."""

    def __init__(self, A: np.ndarray, B: np.ndarray, R: np.ndarray) -> None:
        self.A, self.B, self.R = A, B, R
        self.n, self.m = B.shape

    def __call__(self, P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return self.A.T @ P + P @ self.A, np.linalg.solve(self.R, self.B.T @ P)


A = np.array([[0.5, 1.0, 0.0], [0.0, 0.2, 1.0], [-1.0, 0.0, -3.0]])  # open-loop unstable
B = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
Q, R = np.diag([1.0, 2.0, 3.0]), np.diag([1.0, 4.0])


def _estimate(P: np.ndarray, Q: np.ndarray, R: np.ndarray) -> float:
    riccati_map = ExactMap(A, B, R)
    H, K = riccati_map(P)
    F = H + Q - K.T @ R @ K
    M = linearisation(basis_images(riccati_map), R, K)
    return gain_error(basis_images(riccati_map), M, np.linalg.eigvals(M), K, F)


def test_the_gain_error_is_the_newton_estimate_and_free_of_units() -> None:
    P_star = scipy.linalg.solve_continuous_are(A, B, Q, R)
    K_star = np.linalg.solve(R, B.T @ P_star)
    rng = np.random.default_rng(3)
    S = rng.standard_normal((3, 3))
    S = (S + S.T) / np.linalg.norm(S + S.T)
    for size in (1e-2, 1e-4):
        P = P_star + size * np.linalg.norm(P_star) * S
        K = np.linalg.solve(R, B.T @ P)
        true = np.linalg.norm(K - K_star) / np.linalg.norm(K)
        # first order in |P - P*|: the estimate's own error is of the order of true^2
        assert _estimate(P, Q, R) == pytest.approx(true, rel=50 * size)
        # the cost's units scale P, Q and R alike and leave K and the estimate as they are
        assert _estimate(7 * P, 7 * Q, 7 * R) == pytest.approx(_estimate(P, Q, R), rel=1e-9)
    # the zero gain leaves A's unstable poles: no estimate
    assert _estimate(1e-9 * np.eye(3), Q, R) == np.inf


def test_implicit_steps_need_no_stabilising_gain() -> None:
    """From P0 = 1e-3 I (a gain that leaves A's poles at +0.5 and +0.2 unstable) the implicit
    steps reach the Riccati gain within the tolerance they report, in a few dozen steps."""
    assert np.max(np.linalg.eigvals(A - B @ np.linalg.solve(R, B.T * 1e-3)).real) > 0
    res = value_iteration(
        A,
        B,
        Q,
        R,
        steps=StepSequence("implicit", 0.5),
        bounds=BoundSchedule("geometric"),
        tol=1e-8,
        rule="relative",
        scaling=False,
        max_iterations=10_000,
    )
    P_star = scipy.linalg.solve_continuous_are(A, B, Q, R)
    K_star = np.linalg.solve(R, B.T @ P_star)
    assert res.converged and res.iterations < 100, res.message
    assert np.linalg.norm(res.K - K_star) / np.linalg.norm(K_star) < 1e-8
    estimate = float(res.message.split("|K - K*|/|K| ")[1].split()[0])
    assert estimate <= 1e-8 and "implicit steps" in res.message


def test_a_map_that_leaves_the_cone_stops_the_implicit_steps_and_says_so() -> None:
    """The map of test_value_iteration's cone test takes from P_22 in proportion to P_11: the
    safeguard shortens the step until it is value iteration's own, and then gives up."""
    Q_s, R_s = np.diag([1.0, 0.0]), np.eye(1)

    def leaky_map(P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return np.diag([-0.1 * P[0, 0], -0.5 * P[0, 0]]), np.zeros((1, 2))

    settings = IterationSettings(
        steps=StepSequence("implicit", 0.5),
        bounds=BoundSchedule("geometric", 1e6),
        tol=1e-9,
        max_iterations=10_000,
        rule="residual",
    )
    P, _, iterations, _, converged, _, _, why = continuation_loop(
        leaky_map, Q_s, R_s, 1e-3 * np.eye(2), settings
    )
    assert not converged and iterations < 200
    assert "P left the positive semidefinite cone 3 times in a row" in why
    assert np.linalg.eigvalsh(P)[0] >= 0  # what it returns is the last iterate in the cone


def _learn(tmp_path: Path, name: str, method: str, learning: str, capsys) -> tuple[int, dict]:
    text = (SYSTEMS / f"{name}.toml").read_text()
    if "[learning]" in text:
        text = text.replace("[learning]", "[learning]\n" + learning)
    else:
        text += "\n[learning]\n" + learning
    path = tmp_path / f"{name}.toml"
    path.write_text(text)
    code = main(["learn", str(path), "--method", method, "--json"])
    return code, json.loads(capsys.readouterr().out)


@pytest.mark.parametrize("name", ["dc-motor-position", "thermal-chain"])
def test_the_tolerance_the_user_asks_for_decides_converged(tmp_path, capsys, name) -> None:
    """learning.tol is the bound on the estimated |K - K*|/|K| that ends the iteration: a
    looser one stops sooner, each is met by the gain (model-based: K* is the Riccati gain),
    and one the budget cannot meet is exit 1 with the estimate and the tolerance said."""
    runs = {}
    for tol in (1e-3, 1e-6, 1e-10):
        code, out = _learn(tmp_path, name, "vi", f"tol = {tol}", capsys)
        assert code == 0 and out["converged"], out["message"]
        assert out["settings"]["tol"] == {"value": tol, "source": "given"}
        assert f"<= tol {tol:g}" in out["message"]
        assert out["K_error"] <= tol
        runs[tol] = out["iterations"]
    assert runs[1e-3] < runs[1e-6] < runs[1e-10]
    code, out = _learn(tmp_path, name, "vi", "tol = 1e-10\nmax_iterations = 20", capsys)
    assert code == 1 and not out["converged"]
    assert out["message"].startswith("not converged after 20 iterations")
    assert "estimated relative error of K" in out["message"] and "> tol 1e-10" in out["message"]


def test_the_data_driven_tolerance_is_met_against_the_data_fixed_point() -> None:
    """ddvi on the stiff motor at tol 1e-3: converged means the estimate is at most 1e-3, and
    the gain is within that of the fixed point the same data give at 1e-10."""
    system = load_system(str(SYSTEMS / "dc-motor-position.toml"))
    loose = solve(replace(system, learning=replace(system.learning, tol=1e-3)), "ddvi")
    tight = solve(replace(system, learning=replace(system.learning, tol=1e-10)), "ddvi")
    assert loose.converged and tight.converged
    assert loose.iterations < tight.iterations
    assert np.linalg.norm(loose.K - tight.K) / np.linalg.norm(loose.K) <= 1e-3
