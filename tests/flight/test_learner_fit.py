"""The model-fit learner in the controller (learning.method = "model-fit"), flown in one
process on short missions: it learns from orbit 3 on by orbit 6 or on a retry, its gain is
close to the optimal gain of the truth's own linear model, and nothing diverges; the paper's
value iteration stays the default."""

from __future__ import annotations

import numpy as np
import pytest

from services.config import DeploymentError, deployment_from_table, load_deployment, read_table
from services.flight.control import Controller
from services.flight.inprocess import run_in_process
from services.flight.phases import Gains, Phase
from services.flight.station import StationKeeping
from services.flight.trim import StationTrim
from services.interface import decode, encode
from services.model import lqr_gains, orbit_period, true_lqr_gains

FIT = {
    "method": "model-fit",
    "data_from_orbits": 3.0,
    "learn_at_orbits": 6.0,
    "retry_orbits": 0.5,
    "density_exostate": True,
    "K0": [-0.023, 0.0, 0.0, -10.0],
}


def _fit_only(base: str, orbits: float, **learning) -> object:
    """``base`` with its LQR deputy and a model-fit deputy in place of its DDVI one."""
    table = read_table(base)
    table["run"]["orbits"] = orbits
    ddvi = table["deputy"][1]
    ddvi["name"], ddvi["learning"] = "fit", {**FIT, **learning}
    return deployment_from_table(table, base)


def _gain_error(dep, ctrl: Controller) -> float:
    K_true, _ = true_lqr_gains(dep, ctrl.deputy)
    return float(np.linalg.norm(ctrl.K - K_true) / np.linalg.norm(K_true))


@pytest.mark.integration  # two 7-orbit missions, a few seconds each
@pytest.mark.parametrize("base", ["rendezvous", "mismatch-2x"])
def test_model_fit_learns_by_orbit_6_near_the_true_gain(base):
    dep = _fit_only(base, 7.0)
    out = run_in_process(dep)
    ctrl = out["fit"]["controller"]
    period = orbit_period(dep)
    assert ctrl.phase == "learned" and ctrl.source == "model-fit"
    assert 6.0 <= ctrl.learning.learned_at[0] / period <= 6.1
    assert _gain_error(dep, ctrl) <= 0.02
    assert ctrl.L.shape == (1, 6)  # the density ratio is in the learner's exostate
    assert "model fit (condition" in out["fit"]["log"][-1]
    # the learned gains travel on the bus as the controller process publishes them
    body = {
        "sc": "fit",
        "K": ctrl.K,
        "L": ctrl.L,
        "source": ctrl.source,
        "iteration": ctrl.learning.iteration,
        "converged": ctrl.converged,
    }
    assert decode(encode("gains", body, seq=0, t=1.0, src="ctrl-fit")).body["source"] == "model-fit"
    # no divergence: after learning the deputy closes on its slot (33 km behind at orbit 6)
    t, y = out["fit"]["t"], out["fit"]["x"][:, 1]
    assert np.all(np.isfinite(y)) and abs(y[-1]) < abs(y[t >= ctrl.learning.learned_at[0]][0])


@pytest.mark.integration  # a 7-orbit mission
def test_an_uncertain_fit_retries_on_a_growing_window():
    dep = _fit_only("rendezvous", 7.0, fit_tolerance=1e-6, learn_until_orbits=7.5)
    out = run_in_process(dep)
    ctrl = out["fit"]["controller"]
    assert ctrl.phase == "exploring" and ctrl.learning.learn_attempts == 2  # at orbits 6 and 6.5
    assert not ctrl.learning.learned_at
    assert "predicted relative error" in out["fit"]["log"][0]


@pytest.mark.integration  # a 7-orbit mission
def test_the_deadline_tolerance_applies_from_its_orbit():
    dep = _fit_only(
        "rendezvous", 7.0, fit_tolerance=1e-6, fit_deadline_orbits=6.5, learn_until_orbits=7.0
    )
    ctrl = run_in_process(dep)["fit"]["controller"]
    # refused at 6, taken at 6.5
    assert ctrl.learning.learn_attempts == 2 and ctrl.phase == "learned"
    assert ctrl.learning.learned_at[0] / orbit_period(dep) == pytest.approx(6.5, abs=0.05)
    assert _gain_error(dep, ctrl) <= 0.02


def test_station_trim_moves_the_constant_only_on_station():
    trim = StationTrim(period=100.0, radius=50.0, gain=0.5, start=0.0)
    for t in range(0, 100, 10):
        trim.add(float(t), 60.0 if t == 50 else 10.0)  # one sample off station
    assert trim.due(100.0)
    delta, log = trim.update(100.0, K_y=4e-4)
    assert delta == 0.0 and "not on station" in log
    for t in range(100, 200, 10):
        trim.add(float(t), 10.0)
    delta, log = trim.update(200.0, K_y=4e-4)
    assert delta == pytest.approx(-0.5 * 4e-4 * 10.0) and trim.total == delta
    assert not trim.due(250.0) and "mean along-track error +10.00 m" in log
    with pytest.raises(ValueError, match="gain in"):
        StationTrim(period=100.0, radius=50.0, gain=1.5, start=0.0)


def test_value_iteration_stays_the_default():
    dep = load_deployment("rendezvous")
    assert dep.deputy_named("ddvi").learning.method == "value-iteration"
    ctrl = Controller(dep, "ddvi")
    assert ctrl.collect_from == 0.0 and ctrl.L.shape == (1, 5)
    assert type(ctrl.collector).__name__ == "IntervalCollector"


def test_realistic_nav_flies_three_controllers_side_by_side():
    dep = load_deployment("realistic-nav")
    methods = {d.name: (d.controller, d.learning.method) for d in dep.deputy}
    assert methods == {
        "lqr": ("lqr", "value-iteration"),
        "ddvi": ("ddvi", "value-iteration"),
        "fit": ("ddvi", "model-fit"),
    }
    assert all(d.navigation.position_noise == 1.0 for d in dep.deputy)


@pytest.mark.parametrize(
    ("key", "value", "message"),
    [
        ("method", "magic", "learning.method: expected 'value-iteration' or 'model-fit'"),
        ("data_from_orbits", 6.0, "data_from_orbits: must lie in"),
        ("fit_stride", 15.0, "fit_stride: must be a whole multiple"),
        ("fit_smoothing", 900.0, "fit_smoothing: must lie in"),
        ("refresh_orbits", -1.0, "refresh_orbits: must be >= 0"),
        ("fit_tolerance", 0.0, "fit_tolerance: must be positive"),
        ("trim_orbits", -1.0, "trim_orbits: must be >= 0"),
        ("station_radius", 0.0, "station_radius: must be positive"),
        ("trim_gain", 2.0, "trim_gain: must lie in"),
        ("learn_from", "measurment", "learn_from: expected 'estimate' or 'measurement'"),
    ],
)
def test_bad_learner_keys_name_the_key(key, value, message):
    table = read_table("rendezvous")
    table["deputy"][1]["learning"] = {**FIT, key: value}
    with pytest.raises(DeploymentError, match=message):
        deployment_from_table(table, "rendezvous")


@pytest.mark.parametrize(("source", "collected"), [("estimate", 1.0), ("measurement", 2.0)])
def test_the_learner_collects_the_source_its_deployment_names(source, collected):
    table = read_table("realistic-nav")
    table["deputy"][2]["learning"]["learn_from"] = source
    ctrl = Controller(deployment_from_table(table, "realistic-nav"), "fit")
    v = np.array([1.0, 0.0, 1.0, 0.0, 1.0])
    for k in range(3):
        t = ctrl.collect_from + 10.0 * k
        estimate, measurement = np.full(4, 1.0), np.full(4, 2.0)
        assert ctrl.collect(t, estimate, v, 300e3, measurement) is None
    assert np.all(ctrl.collector.data().x == collected)


def _on_station(ctrl, times, y=0.0) -> None:
    """Feed the controller's refresh samples at ``times`` (s), along-track error ``y`` (m)."""
    n = ctrl.n_rate
    for t in times:
        v = np.array([1.0, np.cos(n * t), np.sin(n * t), np.cos(2 * n * t), np.sin(2 * n * t)])
        x = np.array([0.0, y, 0.0, 0.0])
        ctrl.collect(float(t), x, v, 300e3, x)


def _learned(dep, name="fit"):
    """A model-fit controller flying learned gains, its fit the truth's own linear model."""
    from types import SimpleNamespace

    from services.model import true_problem

    ctrl = Controller(dep, name)
    p = true_problem(dep, ctrl.deputy)
    ctrl.phases.move(Phase.LEARNED, Gains(ctrl.K, ctrl.L, ctrl.learner.source))
    ctrl.learning.result = SimpleNamespace(model=SimpleNamespace(A=p.A, B=p.B))
    store = ctrl.learner.new_store(ctrl.exosystem[1].shape[0])
    ctrl.learner.station = StationKeeping(
        ctrl.deputy.learning,
        orbit_period(dep),
        0.0,
        ctrl.K,
        ctrl.learning.result.model,
        ctrl.exosystem,
        store,
    )
    return ctrl


def _refit(ctrl, t: float) -> str:
    """Refit the learned controller's feedforward at t (s), as its step does when due."""
    L, log = ctrl.learner.station.refit(t, ctrl.L, ctrl.learning.learning_window(t))
    ctrl.phases.trim(L)
    return log


def test_a_refresh_waits_for_a_stay_of_refresh_orbits_and_fits_that_stay_only():
    """A fly-through of the station radius is not a stay: a refit waits for refresh_orbits P
    of uninterrupted stay, and fits the newest stay's last P and one interval."""
    dep = load_deployment("realistic-nav")
    ctrl = _learned(dep)
    P = 2.0 * orbit_period(dep)  # refresh_orbits = 2
    L = np.full_like(ctrl.L, 0.01)  # a refit of still, unforced data gives L = 0
    ctrl.phases.trim(L)
    _on_station(ctrl, np.arange(0.0, 3000.0, 10.0))  # a fly-through
    _on_station(ctrl, np.arange(3000.0, 5000.0, 10.0), y=5000.0)  # off station: a gap
    stay = 5000.0
    _on_station(ctrl, np.arange(stay, stay + 0.9 * P, 10.0))
    log = _refit(ctrl, stay + 0.9 * P)
    assert "not refitted" in log and np.array_equal(ctrl.L, L)
    _on_station(ctrl, np.arange(stay + 0.9 * P, stay + 1.5 * P, 10.0))
    log = _refit(ctrl, stay + 1.5 * P)
    assert "feedforward refitted" in log and not np.array_equal(ctrl.L, L)
    window = P + ctrl.deputy.learning.interval  # 1,146 samples of 10 s
    assert f"from {round(window / 10.0)} samples" in log and not ctrl.L.any()


def test_a_refit_replaces_the_trim_and_drops_its_errors():
    table = read_table("realistic-nav")
    table["deputy"][2]["learning"]["trim_orbits"] = 2.0
    dep = deployment_from_table(table, "realistic-nav")
    ctrl = _learned(dep)
    ctrl.learner.station.trim = trim = StationTrim(2.0 * orbit_period(dep), 1000.0, 0.5, start=0.0)
    trim.total = 0.02
    P = 2.0 * orbit_period(dep)
    _on_station(ctrl, np.arange(0.0, 1.5 * P, 10.0), y=40.0)
    assert trim.errors
    assert "feedforward refitted" in _refit(ctrl, 1.5 * P)
    assert trim.total == 0.0 and not trim.errors
    assert not trim.due(1.5 * P + 0.5 * P) and trim.due(2.5 * P)


def _faulted_before_learning(learn_at: float) -> object:
    """The rendezvous mission with a model-fit deputy (data from orbit 3, any predicted error
    accepted) whose panels lose 70 % of their area at orbit 5.3, inside the newest orbit."""
    table = read_table("rendezvous")
    table["run"]["orbits"] = 6.6
    fit = table["deputy"][1]
    fit["name"], fit["learning"] = (
        "fit",
        {**FIT, "learn_at_orbits": learn_at, "fit_tolerance": 100.0},
    )
    table["fault"] = [{"at_orbits": 5.3, "kind": "panel", "deputy": "fit", "area_factor": 0.3}]
    return deployment_from_table(table, "rendezvous")


@pytest.mark.integration  # a 6.6-orbit mission
def test_a_gain_that_fails_its_validation_is_not_flown():
    """The plant changed inside the hold-out: the gain learned from data across the change
    does not stabilise the model of the data before it, so it stays unflown, and says why."""
    dep = _faulted_before_learning(6.5)
    out = run_in_process(dep)
    ctrl = out["fit"]["controller"]
    # no retry before learn_until_orbits (6.55): the fallback, never the unvalidated gain
    assert ctrl.phase == "fallback" and not ctrl.learning.learned_at
    assert ctrl.learning.learn_attempts == 1
    np.testing.assert_array_equal(ctrl.K, lqr_gains(dep, ctrl.deputy)[0])
    assert "failed validation" in out["fit"]["log"][0]
    assert "no gain validated by orbit 6.55: flying the fallback" in out["fit"]["log"][0]
    assert "does not stabilise the model fitted without the newest" in out["fit"]["log"][0]


@pytest.mark.integration  # a 7-orbit mission
def test_validation_compares_the_gain_with_that_of_the_fit_without_the_hold_out():
    from services.flight.fitting import validate_gain

    dep = _fit_only("rendezvous", 7.0)
    out = run_in_process(dep)
    ctrl = out["fit"]["controller"]
    assert "validated on the hold-out" in out["fit"]["log"][0]
    lrn, data = ctrl.deputy.learning, ctrl.collector.data()
    options = {
        "length": lrn.interval,
        "stride": lrn.fit_stride,
        "smoothing": 0.0,
        "translation": [0.0, 1.0, 0.0, 0.0],
    }
    holdout = orbit_period(dep)
    info: dict = {}
    assert validate_gain(data, ctrl.K, ctrl.problem, lrn, options, holdout, info) is None
    assert info["validation"] < 0.1 and info["validation_margin"] > 0
    assert info["validation_gain"] < 0.1
    why = validate_gain(data, 1.5 * ctrl.K, ctrl.problem, lrn, options, holdout, {})
    assert why is not None and "validation_gain_change = 0.25" in why
    why = validate_gain(
        data.since(data.t[-1] - 1.2 * holdout), ctrl.K, ctrl.problem, lrn, options, holdout, {}
    )
    assert why is not None and "too little to fit on and check" in why


def test_the_model_fit_learner_carries_the_density_ratio_unless_told_not_to():
    table = read_table("realistic-nav")
    assert "density_exostate" not in table["deputy"][2]["learning"]
    dep = deployment_from_table(table, "realistic-nav")
    assert Controller(dep, "fit").L.shape == (1, 6)  # [v; rho / rho_0]
    assert Controller(dep, "ddvi").L.shape == (1, 5)  # value iteration: v
    table["deputy"][2]["learning"]["density_exostate"] = False
    assert Controller(deployment_from_table(table, "realistic-nav"), "fit").L.shape == (1, 5)


@pytest.mark.integration  # a 7.5-orbit mission
@pytest.mark.integration  # a 7.5-orbit mission
def test_with_no_gain_validated_by_learn_until_orbits_it_flies_the_lqr_fallback_to_the_end():
    dep = _fit_only("rendezvous", 7.5, fit_tolerance=1e-6, learn_until_orbits=6.6)
    out = run_in_process(dep)
    ctrl = out["fit"]["controller"]
    # at orbits 6.01 and 6.51, not 7.01: the second attempt's retry would be past 6.6
    assert ctrl.learning.learn_attempts == 2 and not ctrl.learning.learned_at
    assert ctrl.phase == "fallback" and not ctrl.exploring and ctrl.next_attempt == float("inf")
    assert len(ctrl.learning.fallback_at) == 1
    assert ctrl.learning.fallback_at[0] / ctrl.orbit == pytest.approx(6.5, abs=0.02)
    K, L = lqr_gains(dep, dep.deputy_named("fit"))
    np.testing.assert_array_equal(ctrl.K, K)
    np.testing.assert_array_equal(ctrl.L[:, :5], L)
    assert not ctrl.L[:, 5:].any()  # the density ratio: a mode the nominal model has not
    assert ctrl.source == "lqr"
    last = out["fit"]["log"][-1]
    assert "no gain validated by orbit 6.6: flying the fallback" in last, last


def test_learn_until_orbits_follows_from_the_mission_and_before_learn_at_is_refused():
    dep = _fit_only("rendezvous", 7.5)
    lrn = dep.deputy_named("fit").learning
    assert lrn.learn_until_orbits == pytest.approx(6.0 + (7.5 - 6.0) / 2)
    assert lrn.fallback == "last"
    with pytest.raises(DeploymentError, match="learn_until_orbits: must be at least"):
        _fit_only("rendezvous", 7.0, learn_until_orbits=3.0)
    with pytest.raises(DeploymentError, match="fallback: expected 'last' or 'lqr'"):
        _fit_only("rendezvous", 7.0, fallback="K0")
