"""Windowed value increments (ddvi_core.windowed): exact on clean data, and through white
measurement noise of known covariance they recover P* where the paper's end-point increments
do not."""

from __future__ import annotations

import numpy as np
import pytest

from ddvi_core.learning import IntervalCollector, learn_from_data
from ddvi_core.lqr import solve_lqr
from ddvi_core.policy_learning import IterationSettings
from ddvi_core.simulate import Exploration, simulate_zoh
from ddvi_core.value_iteration import BoundSchedule, StepSequence
from ddvi_core.windowed import WindowedCollector, window

# a lightly damped oscillator, sampled at 20 Hz, 5 s intervals (0.8 of its period)
A = np.array([[0.0, 1.0], [-1.0, -0.2]])
B = np.array([[0.0], [1.0]])
Q, R = np.eye(2), np.eye(1)


def _learn(collector) -> tuple[float, float]:
    """Relative errors of the learned P and K against the Riccati solution."""
    r = learn_from_data(
        collector.data(),
        Q,
        R,
        time_unit=1.0,
        iteration=IterationSettings(
            steps=StepSequence("constant", 0.05), bounds=BoundSchedule("geometric")
        ),
        state_scale=[1.0, 1.0],
    )
    assert r.converged, r.message
    exact = solve_lqr(A, B, Q, R)
    rel = lambda a, b: float(np.linalg.norm(a - b) / np.linalg.norm(b))  # noqa: E731
    return rel(r.P, exact.P), rel(r.K, exact.K)


def _fly(sigma: float, seed: int = 2) -> tuple[IntervalCollector, WindowedCollector]:
    """Both collectors fed the same samples: the state plus white noise of ``sigma`` per
    component (the input acts on the true state)."""
    rng = np.random.default_rng(seed)
    cols = IntervalCollector(2, 1, 0, 5.0), WindowedCollector(2, 1, 0, 5.0)
    for t, x, u, v in simulate_zoh(
        A,
        B,
        None,
        None,
        [1.0, 0.0],
        None,
        K0=np.zeros((1, 2)),
        exploration=Exploration.spread(1.0, 1.0, 6, seed=seed),
        sample_period=0.05,
        command_period=0.05,
        duration=400.0,
    ):
        measured = x + rng.normal(0.0, sigma, 2) if sigma else x
        for c in cols:
            c.add(t, measured, u, v)
    return cols


def test_windowed_increments_are_exact_on_clean_data() -> None:
    plain, windowed = _fly(0.0)
    for col in (plain, windowed):
        P_err, K_err = _learn(col)
        assert P_err < 1e-3 and K_err < 1e-3


def test_windowed_increments_recover_P_through_measurement_noise() -> None:
    # noise 5 % of the state's amplitude: the end points' noise biases the paper's increments
    plain, windowed = _fly(0.05)
    P_plain, _ = _learn(plain)
    P_windowed, K_windowed = _learn(windowed)
    assert P_plain > 0.05
    assert P_windowed < 0.03 and K_windowed < 0.03


def test_windowed_data_carry_increments_and_window_vanishes_at_ends() -> None:
    _, windowed = _fly(0.0)
    data = windowed.data()
    assert data.increments is not None and data.increments.shape == (data.intervals, 2, 2)
    assert data.since(200.0).increments.shape[0] == data.since(200.0).intervals
    assert window(0.0, 5.0)[0] == 0.0 and window(5.0, 5.0)[0] == pytest.approx(0.0, abs=1e-15)
    assert window(2.5, 5.0) == pytest.approx((1.0, 0.0), abs=1e-15)
    windowed.reset()
    assert windowed.data().increments.shape == (0, 2, 2)
