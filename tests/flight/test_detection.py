"""Change detection from the controller's own data (ddvi_core.detection) and re-learning."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg

from ddvi_core.constants import R_EARTH
from ddvi_core.detection import ChangeDetector, DetectionError, fit_predictor
from ddvi_core.lqr import solve_lqr
from services.config import DeploymentError, deployment_from_table, read_table
from services.flight.inprocess import run_in_process
from services.model import nominal_problem, orbit_period

STEP = 10.0


def _plant(gain: float = 1.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A lightly damped oscillator with a constant disturbance, zero-order hold over STEP:
    Phi (2,2), Gamma (2,1) scaled by ``gain`` (an actuator fault), Psi (2,1) on v = [1]."""
    A = np.array([[0.0, 1.0], [-1e-4, -1e-3]])
    B = np.array([[0.0], [1e-3]])
    D = np.array([[0.0], [2e-5]])
    M = scipy.linalg.expm(np.block([[A, np.hstack([B, D])], [np.zeros((2, 4))]]) * STEP)
    return M[:2, :2], gain * M[:2, 2:3], M[:2, 3:4]


def _samples(k: int, gain: float = 1.0, seed: int = 0, u_scale: float = 1.0):
    Phi, Gamma, Psi = _plant(gain)
    rng = np.random.default_rng(seed)
    t = STEP * np.arange(k)
    u = u_scale * rng.normal(0, 1, (k, 1))
    v = np.ones((k, 1))
    x = np.zeros((k, 2))
    for i in range(k - 1):
        x[i + 1] = Phi @ x[i] + Gamma @ u[i] + Psi @ v[i] + rng.normal(0, 1e-6, 2)
    return t, x, u, v


def _watch(detector: ChangeDetector, t, x, u, v) -> list[float]:
    """The times at which the detector is in alarm."""
    return [ti for ti, xi, ui, vi in zip(t, x, u, v, strict=True) if detector.add(ti, xi, ui, vi)]


def test_predictor_recovers_the_plant_and_states_its_residual() -> None:
    t, x, u, v = _samples(2000)
    pred = fit_predictor(t, x, u, v, step=STEP)
    Phi, Gamma, _ = _plant()
    assert np.allclose(pred.gamma, Gamma, rtol=1e-2, atol=1e-9)
    assert np.allclose(np.eye(2) + pred.coef[:2].T, Phi, atol=1e-4)
    assert pred.pairs == 1999 and np.all(pred.residual_rms < 3e-6)
    assert 0 < pred.input_rms[0] < 0.05


def test_detector_alarms_on_an_input_change_and_not_on_the_same_plant() -> None:
    pred = fit_predictor(*_samples(2000), step=STEP)
    window = 200 * STEP
    same = ChangeDetector(pred, bound_factor=5.0, window=window)
    assert _watch(same, *_samples(3000, seed=1)) == []
    assert 0 < same.statistic < 1.0
    # the same plant whose input acts at 0.8x: an actuator fault
    faulted = ChangeDetector(pred, bound_factor=5.0, window=window)
    t, x, u, v = _samples(3000, gain=0.8, seed=1, u_scale=1.0)
    alarms = _watch(faulted, t, x, u + 0.5, v)  # a command offset: the fault shows in its mean
    assert alarms and alarms[0] <= t[0] + 1.2 * window
    assert faulted.statistic > 3.0


def test_detector_skips_pairs_across_a_gap() -> None:
    pred = fit_predictor(*_samples(500), step=STEP)
    det = ChangeDetector(pred, bound_factor=5.0, window=50 * STEP)
    t, x, u, v = _samples(200, seed=2)
    det.add(t[0], x[0], u[0], v[0])
    det.add(t[1] + 5.0, x[1], u[1], v[1])  # off the step: no pair, nothing enters the window
    assert len(det._pairs) == 0


def test_predictor_data_errors_say_what_is_missing() -> None:
    t, x, u, v = _samples(2000)
    with pytest.raises(DetectionError, match="too few sample pairs"):
        fit_predictor(t[:5], x[:5], u[:5], v[:5], step=STEP)
    with pytest.raises(DetectionError, match="not all excited"):
        fit_predictor(t, x, np.zeros_like(u), v, step=STEP)  # no exploration: u = 0
    with pytest.raises(DetectionError, match="share their length"):
        fit_predictor(t, x[:-1], u, v)
    with pytest.raises(DetectionError, match="non-finite"):
        fit_predictor(t, np.where(x == x[3, 0], np.nan, x), u, v)
    with pytest.raises(DetectionError, match="increase"):
        fit_predictor(t[::-1], x, u, v)
    with pytest.raises(DetectionError, match="translation"):
        fit_predictor(t, x, u, v, translation=[0.0, 0.0])
    pred = fit_predictor(t, x, u, v, step=STEP)
    with pytest.raises(DetectionError, match="bound_factor"):
        ChangeDetector(pred, bound_factor=0.0, window=100.0)
    with pytest.raises(DetectionError, match="window"):
        ChangeDetector(pred, bound_factor=1.0, window=1.0)


def test_relearn_keys_are_checked() -> None:
    table = read_table("panel-fault")
    table["deputy"][1]["learning"]["relearn_windw_orbits"] = 3.0
    with pytest.raises(DeploymentError, match="did you mean 'relearn_window_orbits'"):
        deployment_from_table(table)
    table = read_table("panel-fault")
    table["deputy"][1]["learning"]["detector_bound"] = -1.0
    with pytest.raises(DeploymentError, match="detector_bound: must be positive"):
        deployment_from_table(table)
    table = read_table("panel-fault")
    table["deputy"][1]["learning"]["relearn_max_attempts"] = 0
    with pytest.raises(DeploymentError, match="relearn_max_attempts: must be >= 1"):
        deployment_from_table(table)


@pytest.mark.integration  # a whole mission of tens of orbits in one process
def test_panel_fault_is_detected_and_relearned_from_the_deputys_own_data() -> None:
    """deployments/panel-fault.toml in one process, cut after orbit 34, with a second DDVI
    deputy whose panel stays whole: both learn at orbit 15 and arm the detector; the faulted
    one detects its 0.8x panel within an orbit of orbit 21 (not before), explores again and
    re-learns 12 orbits later, with the density ratio in its exostate, a gain much closer to
    the faulted model's LQR gain than the one it flew before; the whole one, through the
    approach's hardest part (orbits 15 to 34), never alarms."""
    table = read_table("panel-fault")
    table["run"]["orbits"] = 34.0
    whole = dict(table["deputy"][1], name="whole")
    table["deputy"].append(whole)
    table["fault"] = [f for f in table["fault"] if f["deputy"] == "ddvi"]
    dep = deployment_from_table(table)
    period = orbit_period(dep)
    out = run_in_process(dep)
    for name in ("ddvi", "whole"):
        assert out[name]["controller"].learning.learned_at[0] == pytest.approx(15 * period, abs=60)
        assert "fault detector: bound = +-" in out[name]["log"][0]
    faulted, intact = out["ddvi"]["controller"], out["whole"]["controller"]
    assert intact.detections == 0 and intact.phase == "learned"
    assert intact.watch.detector is not None and intact.watch.detector.statistic < 0.6
    assert faulted.detections == 1
    assert "left the bound" in out["ddvi"]["log"][1]
    detected = float(out["ddvi"]["log"][1].split("at t = ")[1].split(" s")[0])
    assert 21 * period < detected < 22 * period
    # re-learned 2 + 10 orbits after the detection, and flying it with the detector re-armed
    assert faulted.phase == "learned" and len(faulted.learning.learned_at) == 2
    lrn = dep.deputy[1].learning
    wait = (lrn.relearn_settle_orbits + lrn.relearn_window_orbits) * period
    assert faulted.learning.learned_at[1] == pytest.approx(detected + wait, abs=dep.run.fsw_period)
    assert out["ddvi"]["log"][-1].startswith("re-learned at") and faulted.watch.detector is not None
    pr = nominal_problem(dep, dep.deputy[1])
    K_faulted = solve_lqr(pr.A, 0.8 * pr.B, pr.Q, pr.R).K
    err_old = np.linalg.norm(intact.K - K_faulted) / np.linalg.norm(K_faulted)
    err_new = np.linalg.norm(faulted.K - K_faulted) / np.linalg.norm(K_faulted)
    assert err_new < 0.02 and err_old > 4 * err_new  # measured 0.0095 and 0.086
    assert faulted.L.shape == (1, pr.q + 1)  # L now weighs the density ratio too


@pytest.mark.integration  # a whole mission of tens of orbits in one process
def test_stuck_panel_is_detected_and_the_learner_switches_to_new_gains() -> None:
    """deployments/panel-stuck.toml in one process, cut after orbit 45: the facet's hinge
    sticks at 30 deg at orbit 21.  The DDVI deputy detects it from its own data within three
    orbits (not before), explores again, re-learns (attempts that do not converge are retried
    an orbit later, on the newest window) and flies new gains whose L carries the density
    ratio.  (How well it then flies is measured, not asserted: README, "Re-learning after an
    actuator fault".)"""
    table = read_table("panel-stuck")
    table["run"]["orbits"] = 45.0
    dep = deployment_from_table(table)
    period = orbit_period(dep)
    out = run_in_process(dep)
    ddvi, log = out["ddvi"]["controller"], out["ddvi"]["log"]
    assert ddvi.detections == 1 and "left the bound" in log[1]
    detected = float(log[1].split("at t = ")[1].split(" s")[0])
    assert 21 * period < detected < 24 * period
    assert ddvi.phase == "learned" and len(ddvi.learning.learned_at) == 2
    assert log[-1].startswith("re-learned at") and ddvi.source == "ddvi"
    assert ddvi.learning.learned_at[1] > detected + 12 * period - dep.run.fsw_period
    assert ddvi.L.shape == (1, 6) and ddvi.watch.detector is not None  # re-armed


@pytest.mark.parametrize("fallback", ["last", "lqr"])
def test_relearning_gives_up_and_flies_its_fallback(fallback: str) -> None:
    """After ``relearn_max_attempts`` re-learning attempts that give no gains, the controller
    stops exploring on K0 and flies its fallback, detector off: with learning.fallback =
    "last" the gains it learned before the detection again (with the exostate they were
    learned on), labelled "fallback"; with "lqr" the nominal model's LQR gains (phase
    "fallback").  Until then each failure schedules a retry ``retry_orbits`` later."""
    from types import SimpleNamespace

    from services.flight.control import Controller
    from services.flight.phases import Gains, Phase
    from services.model import lqr_gains

    table = read_table("panel-fault")
    table["deputy"][1]["learning"]["relearn_max_attempts"] = 3
    table["deputy"][1]["learning"]["fallback"] = fallback
    dep = deployment_from_table(table)
    ctrl = Controller(dep, "ddvi")
    K, L = np.array([[-0.02, 4e-4, -0.9, -9.0]]), np.full((1, 5), 1e-3)
    ctrl.phases.move(Phase.LEARNED, Gains(K, L, "ddvi"))
    ctrl.learning.learned_at = [1000.0]
    alarm = SimpleNamespace(mean=np.array([0.1]), bound=np.array([0.05]), statistic=2.0)
    ctrl.watch.detector = alarm
    t = 2000.0
    collector = ctrl.collector
    assert "the plant has changed" in ctrl.learning.start_relearning(t)
    assert ctrl.collector is not collector  # re-learning collects afresh
    assert ctrl.phase == "relearning" and ctrl.L.shape == (1, 6) and ctrl.source == "initial"
    period = orbit_period(dep)
    for attempt in (1, 2, 3):  # no data collected: every attempt fails
        t = ctrl.next_attempt
        log = ctrl.learning.learn(t)
        if attempt < 3:
            assert log.endswith("exploring on") and ctrl.phase == "relearning"
            assert ctrl.next_attempt == pytest.approx(t + period)
    assert "re-learning abandoned after 3 attempts" in log
    assert not ctrl.exploring and not ctrl.density_mode and ctrl.watch.detector is None
    assert ctrl.learning.abandoned_at == [t] and ctrl.collector is collector
    if fallback == "last":
        assert "learned at t = 1000 s" in log and not ctrl.learning.fallback_at
        assert ctrl.phase == "learned" and ctrl.source == "fallback"
        assert ctrl.K is K and ctrl.L is L
    else:
        assert "flying the fallback, the nominal model's LQR gains" in log
        assert ctrl.phase == "fallback" and ctrl.source == "lqr"
        assert ctrl.learning.fallback_at == [t] and ctrl.converged
        K_lqr, L_lqr = lqr_gains(dep, ctrl.deputy)
        np.testing.assert_array_equal(ctrl.K, K_lqr)
        np.testing.assert_array_equal(ctrl.L, L_lqr)  # the exostate of before: 5 elements
    u = ctrl.command(t, np.zeros(4), np.ones(5), dep.chief.a - R_EARTH)
    assert np.isfinite(u)  # flies: the exostate is the 5-element one L was learned on
