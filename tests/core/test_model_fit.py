"""The model-fit learner (ddvi_core.model_fit) on a linear system simulated exactly: the
interval fit recovers (A, B, D), its gains are the Riccati and regulator gains of the true
model, and bad data give one clear error."""

from __future__ import annotations

import functools
import math

import numpy as np
import pytest
import scipy.linalg

from ddvi_core.exostate_fit import exostate_groups, fit_exosystem_input, static_groups
from ddvi_core.fit_uncertainty import gain_standard_error
from ddvi_core.learning import LearningError, RankDeficientError
from ddvi_core.lqr import solve_lqr
from ddvi_core.model_fit import (
    FittedModel,
    IntegralData,
    IntegralHistory,
    ModelFitError,
    fit_linear_model,
    gains_from_model,
    interval_pairs,
    learn_by_model_fit,
    prediction_residual,
)
from ddvi_core.models import harmonic_exosystem
from ddvi_core.regulator import feedforward_gain, solve_regulator_equations

W = 0.01  # rad/s, the oscillator's rate
A = np.array([[0.0, 1.0], [-(W**2), -0.2 * W]])
B = np.array([[0.0], [1e-3]])
E = harmonic_exosystem([0.5 * W], constant=True)  # v = [1, cos, sin]
D = np.array([[0.0, 0.0, 0.0], [2e-5, -1e-5, 3e-6]])
C, F = np.array([[1.0, 0.0]]), np.array([[-5.0, 0.0, 0.0]])
Q, R = np.eye(2), np.array([[10.0]])
DT, LENGTH, STRIDE = 2.0, 600.0, 10.0  # trapezoid error ~ (w DT)^2 / 12: 4e-4 at 11 W


@functools.cache
def simulate(
    steps: int, feedback: bool = False, explore: float = 1.0, noise: float = 0.0
) -> IntegralHistory:
    """Exact ZOH simulation of x' = A x + B u + D v, v' = E v, sampled every DT s into an
    IntegralHistory (cached: read it, do not add to it); u = ``explore`` times a multi-sine,
    plus the LQR feedback -K x on the measured x with ``feedback``."""
    K = solve_lqr(A, B, Q, R).K
    n, q = 2, 3
    M = np.zeros((n + q + 1, n + q + 1))
    M[:n, :n], M[:n, n : n + q], M[:n, -1:] = A, D, B
    M[n : n + q, n : n + q] = E
    Phi = scipy.linalg.expm(M * DT)
    rng = np.random.default_rng(3)
    x, v = np.array([3.0, 0.0]), np.array([1.0, 1.0, 0.0])
    hist = IntegralHistory(n, 1, q, LENGTH, STRIDE, max_gap=3 * DT, max_samples=20_000)
    for k in range(steps):
        t = k * DT
        x_meas = x + noise * rng.normal(size=n)
        u = explore * sum(math.sin(w * W * t + w) for w in (0.7, 3.0, 11.0))
        if feedback:
            u -= float((K @ x_meas)[0])
        hist.add(t, x_meas, [u], v)
        z = Phi @ np.concatenate([x, v, [u]])
        x, v = z[:n], z[n : n + q]
    return hist


def test_fit_recovers_the_model_and_its_gains():
    data = simulate(6000).data()
    fit = fit_linear_model(data, LENGTH, STRIDE)
    assert fit.rank == fit.needed == 2 + 1 + 3 and fit.intervals == (12000 - 2 - 600) // 10 + 1
    assert np.allclose(fit.A, A, rtol=1e-3, atol=1e-6) and np.allclose(
        fit.B, B, rtol=1e-2, atol=1e-5
    )
    assert np.allclose(fit.D, D, atol=1e-7)
    assert fit.residual < 1e-4 and 1 < fit.condition < 1e6
    r = learn_by_model_fit(data, Q, R, length=LENGTH, stride=STRIDE, C=C, E=E, F=F)
    K = solve_lqr(A, B, Q, R).K
    X, U = solve_regulator_equations(A, B, C, D, E, F)
    assert np.linalg.norm(r.K - K) / np.linalg.norm(K) < 1e-2
    assert np.allclose(r.L, feedforward_gain(K, X, U), rtol=1e-2, atol=1e-5)
    assert "condition" in r.message


def test_smoothing_is_exact():
    fit = fit_linear_model(simulate(6000).data(), LENGTH, STRIDE, smoothing=300.0)
    assert np.allclose(fit.A, A, rtol=1e-3, atol=1e-6) and np.allclose(fit.D, D, atol=1e-7)
    assert np.allclose(fit.B, B, rtol=1e-2, atol=1e-5)


def test_translation_holds_a_direction_the_dynamics_do_not_see():
    fit = fit_linear_model(simulate(6000).data(), LENGTH, STRIDE, translation=[0.0, 1.0])
    assert np.allclose(fit.A[:, 1], 0.0) and fit.needed == 1 + 1 + 3


def test_no_input_excitation_is_a_rank_error_naming_the_input():
    data = simulate(6000, explore=0.0).data()
    with pytest.raises(RankDeficientError, match="int u0") as err:
        fit_linear_model(data, LENGTH, STRIDE)
    assert err.value.rank < err.value.needed


def test_too_few_samples_for_an_interval():
    with pytest.raises(RankDeficientError, match="0 intervals"):
        fit_linear_model(simulate(30).data(), LENGTH, STRIDE)


def test_intervals_never_span_a_gap():
    t = np.concatenate([np.arange(0, 1000, 10.0), np.arange(2000, 3000, 10.0)])
    segment = (t >= 2000).astype(np.int64)
    idx = interval_pairs(t, segment, 600.0, 10.0, 100.0)
    assert len(idx) and np.all(segment[idx] == segment[idx[:, :1]])
    assert np.allclose(t[idx[:, 2]] - t[idx[:, 0]], 600.0)


def test_history_refuses_bad_samples_and_keeps_a_bounded_window():
    hist = IntegralHistory(2, 1, 0, LENGTH, STRIDE, max_samples=100)
    hist.add(0.0, [0.0, 0.0], [0.0])
    with pytest.raises(LearningError, match="does not increase"):
        hist.add(0.0, [0.0, 0.0], [0.0])
    with pytest.raises(LearningError, match="expected 2 values"):
        hist.add(10.0, [0.0], [0.0])
    with pytest.raises(LearningError, match="non-finite"):
        hist.add(10.0, [math.nan, 0.0], [0.0])
    for k in range(1, 300):
        hist.add(10.0 * k, [1.0, 0.0], [0.0])
    data = hist.data()
    assert data.samples == 100 and data.t[0] == 2000.0
    assert hist.intervals == (990 - 600) // 10 + 1


def test_unstabilisable_fit_is_a_model_fit_error():
    model = FittedModel(np.eye(2), np.zeros((2, 1)), np.zeros((2, 0)), 10, 3, 3, 1.0, 0.0)
    with pytest.raises(ModelFitError, match="no gain"):
        gains_from_model(model, Q, R)


def test_exosystem_input_refit_on_closed_loop_data():
    data = simulate(6000, feedback=True, explore=0.0).data()
    D_fit = fit_exosystem_input(data, A, B, length=LENGTH, stride=STRIDE, smoothing=300.0)
    assert np.allclose(D_fit, D, atol=1e-7)


def test_gain_standard_error_is_small_on_clean_data_and_grows_with_noise():
    predicted = []
    for s in (0.0, 0.02, 0.2):
        data = simulate(6000, noise=s).data()
        K = learn_by_model_fit(data, Q, R, length=LENGTH, stride=STRIDE, C=C, E=E, F=F).K
        predicted.append(gain_standard_error(data, K, Q, R, length=LENGTH, stride=STRIDE))
    assert predicted[0] < 1e-3 < predicted[1] < predicted[2]
    # deterministic (a fixed seed): the same data give the same answer
    again = gain_standard_error(data, K, Q, R, length=LENGTH, stride=STRIDE)
    assert again == predicted[2]


def test_kinematic_rows_are_not_fitted():
    data = simulate(6000, noise=0.2).data()
    model = fit_linear_model(data, LENGTH, STRIDE, positions=1)
    assert np.array_equal(model.A[0], [0.0, 1.0]) and model.B[0, 0] == 0.0
    assert np.all(model.D[0] == 0.0) and model.needed == 2 + 1 + 3
    clean = fit_linear_model(simulate(6000).data(), LENGTH, STRIDE, positions=1)
    assert np.allclose(clean.A, A, atol=2e-6) and np.allclose(clean.B, B, rtol=1e-3)
    with pytest.raises(LearningError, match="positions must lie in"):
        fit_linear_model(data, LENGTH, STRIDE, positions=2)


def _with_spurious_mode(data: IntegralData, rate: float) -> IntegralData:
    """``data`` with one more exostate column, sin(rate t), that the system does not feel."""
    extra = (1.0 - np.cos(rate * data.t)) / rate  # its running integral from t = 0
    extra -= extra[0]
    return IntegralData(
        data.t, data.x, data.Ix, data.Iu, np.hstack([data.Iv, extra[:, None]]), data.segment
    )


def test_exostate_groups_follow_the_exosystem():
    E4 = scipy.linalg.block_diag(E, 0.0)  # v = [1, cos, sin, a ratio]
    assert exostate_groups(E) == [[0], [1, 2]]
    assert exostate_groups(E4) == [[0], [1, 2], [3]]
    assert static_groups(E4) == [[0], [3]]


def test_a_mode_the_data_cannot_tell_from_zero_is_dropped_and_the_others_kept():
    data = _with_spurious_mode(simulate(6000, noise=0.01).data(), 0.37 * W)
    # the velocity row fitted, the position row kinematic (as the controller fits)
    options = {"length": LENGTH, "stride": STRIDE, "groups": [[0], [1, 2], [3]], "positions": 1}
    kept = fit_exosystem_input(data, A, B, significance=0.01, **options)
    every = fit_exosystem_input(data, A, B, **options)
    assert not kept[:, 3].any() and every[1, 3] != 0.0  # dropped, though fitted nonzero
    assert np.allclose(kept[:, :3], D, atol=2.5e-6)  # the modes the system feels stay
    assert np.all(kept[1, :3] != 0.0)


def test_a_matched_fit_gives_one_number_per_mode_along_b():
    data = simulate(6000).data()  # D = B theta: the exostate acts where the input does
    D_fit = fit_exosystem_input(data, A, B, length=LENGTH, stride=STRIDE, matched=True)
    assert np.allclose(D_fit, D, atol=1e-7)
    assert np.allclose(D_fit[0], 0.0)  # along B, whose first row is zero


def test_a_refit_of_some_modes_holds_the_others():
    data = simulate(6000).data()
    held = D.copy()
    held[:, 0] = 5.0  # a wrong constant column: refitted, the harmonics held
    D_fit = fit_exosystem_input(data, A, B, length=LENGTH, stride=STRIDE, groups=[[0]], held=held)
    assert np.allclose(D_fit, D, atol=1e-7)
    with pytest.raises(LearningError, match="disjoint"):
        fit_exosystem_input(data, A, B, length=LENGTH, stride=STRIDE, groups=[[0], [0, 1]])


def test_prediction_residual_tells_the_model_from_a_wrong_one():
    data = simulate(6000).data()
    fit = fit_linear_model(data.before(6000.0), LENGTH, STRIDE)
    later = data.since(6000.0)
    dx = np.asarray(later.x[-1] - later.x[0])
    good = prediction_residual(fit, later, LENGTH, STRIDE)
    wrong = prediction_residual(
        FittedModel(fit.A, 0.5 * fit.B, fit.D, 0, 0, 0, 1.0, 0.0), later, LENGTH, STRIDE
    )
    assert good.shape == (2,) and np.all(good < 1e-3 * np.abs(dx).max())
    assert np.all(wrong[1] > 100 * good[1])
    with pytest.raises(LearningError, match="no interval"):
        prediction_residual(fit, data.since(11900.0), LENGTH, STRIDE)
