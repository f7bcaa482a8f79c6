"""The relative navigation filter: HCW discretisation, the covariance's steady state, the
estimate's error on a CW trajectory, the identity without noise, and bad parameters."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import quad_vec, solve_ivp

from ddvi_core.navfilter import (
    DEFAULT_ACCELERATION_NOISE,
    RelativeNavFilter,
    hcw_matrix,
    process_noise,
    steady_state_covariance,
    transition,
)
from services.config import Deputy

N = 1.1569e-3  # rad/s, a 300 km orbit
DT = 10.0
SIGMA = np.array([1.0, 1.0, 1.0, 1e-3, 1e-3, 1e-3])  # 1 m, 1 mm/s
X0 = np.array([240.0, -29_000.0, 30.0, 0.0, -1.5 * N * 240.0, 0.02])  # a drifting ellipse


def _cw_track(steps: int) -> np.ndarray:
    """(steps, 6) states of the free CW motion from X0, every DT s, integrated numerically."""
    t = np.arange(steps) * DT
    sol = solve_ivp(lambda _, x: hcw_matrix(N) @ x, (0, t[-1]), X0, t_eval=t, rtol=1e-12, atol=1e-9)
    return sol.y.T


def test_transition_is_the_cw_flow_and_process_noise_the_integral() -> None:
    track = _cw_track(50)
    Phi = transition(N, DT)
    assert np.allclose(track[1:], track[:-1] @ Phi.T, rtol=1e-8, atol=1e-6)
    q = 1e-9
    G = np.vstack([np.zeros((3, 3)), np.eye(3)])
    by_quadrature = quad_vec(lambda s: transition(N, s) @ G @ G.T @ transition(N, s).T * q, 0, DT)
    assert np.allclose(process_noise(N, DT, q), by_quadrature[0], rtol=1e-9, atol=1e-20)
    assert np.all(np.linalg.eigvalsh(process_noise(N, DT, q)) > 0)


def test_covariance_converges_to_the_steady_state() -> None:
    f = RelativeNavFilter(N, SIGMA, 3e-5, DT)
    rng = np.random.default_rng(2)
    steady = steady_state_covariance(transition(N, DT), process_noise(N, DT, f.q), f.R)
    gaps = []
    for k, x in enumerate(_cw_track(1500)):
        _, P = f.update(k * DT, x + rng.normal(size=6) * SIGMA)
        gaps.append(np.abs(P - steady).max() / np.abs(steady).max())
    assert gaps[0] > 10 and gaps[300] < 1e-2 and gaps[-1] < 1e-10  # converges, to it
    assert np.all(np.diag(P) < SIGMA**2)  # the steady state is tighter than one measurement


@pytest.mark.parametrize("scale", [0.1, 1.0, 10.0])
def test_estimate_error_is_well_below_the_measurement_noise(scale: float) -> None:
    sigma = SIGMA * scale
    track = _cw_track(2000)
    rng = np.random.default_rng(3)
    measured = track + rng.normal(size=track.shape) * sigma
    f = RelativeNavFilter(N, sigma, DEFAULT_ACCELERATION_NOISE, DT)
    estimate = np.array([f.update(k * DT, z)[0] for k, z in enumerate(measured)])
    err, raw = (estimate - track)[200:], (measured - track)[200:]
    rms_pos = np.sqrt((err[:, :3] ** 2).sum(1).mean())
    assert rms_pos < 0.3 * np.sqrt((raw[:, :3] ** 2).sum(1).mean())
    assert np.sqrt((err[:, 3:] ** 2).sum(1).mean()) < np.sqrt((raw[:, 3:] ** 2).sum(1).mean())
    # the covariance tells the error's size: the RMS within a factor 2 of the predicted one
    predicted = np.sqrt(np.trace(f.P[:3, :3]))
    assert 0.5 * predicted < rms_pos < 2.0 * predicted


def test_without_noise_the_estimate_is_the_measurement_exactly() -> None:
    f = RelativeNavFilter(N, np.zeros(6), DEFAULT_ACCELERATION_NOISE, DT)
    rng = np.random.default_rng(4)
    for k in range(20):
        z = rng.normal(size=6) * 1e4
        x, P = f.update(k * DT, z)
        assert np.array_equal(x, z) and not P.any()


def test_a_component_measured_without_noise_is_published_as_measured() -> None:
    sigma = np.array([1.0, 1.0, 1.0, 0.0, 0.0, 0.0])  # exact velocities
    f = RelativeNavFilter(N, sigma, DEFAULT_ACCELERATION_NOISE, DT)
    rng = np.random.default_rng(5)
    for k, x in enumerate(_cw_track(50)):
        z = x + rng.normal(size=6) * sigma
        est, P = f.update(k * DT, z)
        assert np.array_equal(est[3:], z[3:])
    assert np.all(np.diag(P)[3:] < 1e-12)


def test_a_missed_sample_is_bridged_by_the_longer_interval() -> None:
    track = _cw_track(30)
    f = RelativeNavFilter(N, SIGMA * 1e-3, DEFAULT_ACCELERATION_NOISE, DT)
    for k in [*range(10), *range(20, 30)]:  # samples 10..19 lost
        x, _ = f.update(k * DT, track[k])
    assert np.allclose(x, track[-1], atol=1e-3)


@pytest.mark.parametrize(
    ("kwargs", "text"),
    [
        ({"sigma": [-1.0] * 6}, "measurement sigmas must be finite and >= 0"),
        ({"sigma": [np.nan] * 6}, "measurement sigmas must be finite and >= 0"),
        ({"acceleration_noise": 0.0}, r"acceleration_noise must be > 0 m/s\^2"),
        ({"acceleration_noise": np.inf}, r"acceleration_noise must be > 0 m/s\^2"),
        ({"period": -10.0}, "period must be > 0 s"),
    ],
)
def test_bad_parameters_are_refused(kwargs: dict, text: str) -> None:
    args = {"n": N, "sigma": SIGMA, **kwargs}
    with pytest.raises(ValueError, match=text):
        RelativeNavFilter(**args)


def test_the_deployment_default_is_the_filter_default() -> None:
    assert Deputy().navigation.acceleration_noise == DEFAULT_ACCELERATION_NOISE
    assert Deputy().navigation.filter == "kalman"


def test_an_outage_propagates_the_estimate_and_grows_its_covariance() -> None:
    """With no measurement the filter predicts: the estimate moves by the CW flow, the
    covariance grows by the process noise, and the next measurement updates from there."""
    f = RelativeNavFilter(N, SIGMA, 3e-5, DT)
    with pytest.raises(ValueError, match="no measurement yet"):
        f.predict(0.0)
    track = _cw_track(40)
    for k in range(20):
        x, P = f.update(k * DT, track[k])
    Phi = transition(N, DT)
    previous = np.trace(P)
    for k in range(20, 30):
        expected = Phi @ x
        x, P = f.predict(k * DT)
        assert np.allclose(x, expected, rtol=0, atol=1e-12)
        assert np.trace(P) > previous and np.allclose(P, P.T)
        previous = np.trace(P)
    x, P = f.update(30 * DT, track[30])  # measured again: the covariance falls back
    assert np.trace(P) < previous
