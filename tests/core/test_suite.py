"""The example systems of docs/examples/systems by every method, with their matrices alone
(the cart-pole with its K0): K within 1e-3 of the Riccati gain (L of the regulator's for the
tracking problem); settings derived from the system; diverging data named in one line."""

from __future__ import annotations

import json
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from ddvi_core.defaults import DERIVED_KEYS, derive_learning
from ddvi_core.learning import LearningError
from ddvi_core.learning_config import LearningConfig
from ddvi_core.solve import reference_errors, solve
from ddvi_core.systems import system_from_table
from services.cli import main
from services.config.files import load_system

SYSTEMS = Path(__file__).resolve().parents[2] / "docs" / "examples" / "systems"
FILES = sorted(p.stem for p in SYSTEMS.glob("*.toml"))
FAST = ("double-integrator", "mass-spring-tracking")  # data in well under a second
ACCURACY = 1e-3


def _system(name: str):
    return load_system(str(SYSTEMS / f"{name}.toml"))


def _assert_accurate(name: str, method: str, max_iterations: int) -> None:
    system = _system(name)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no numpy warning on the way
        sol = solve(system, method)
    err = reference_errors(system, sol)
    assert sol.converged, sol.details.get("message")
    assert err["K_error"] < ACCURACY, err
    if system.problem.has_exosystem:
        assert err["L_error"] < ACCURACY, err
    assert sol.iterations < max_iterations


def test_the_suite_is_all_here() -> None:
    assert FILES == [
        "boeing747-lateral",
        "cart-pole",
        "dc-motor-position",
        "double-integrator",
        "f16-short-period",
        "mass-spring-tracking",
        "quadrotor-hover",
        "thermal-chain",
    ]


@pytest.mark.parametrize("name", FILES)
def test_model_based_value_iteration_reaches_riccati(name: str) -> None:
    _assert_accurate(name, "vi", 10_000)


@pytest.mark.parametrize("name", FAST)
@pytest.mark.parametrize("method", ["ddvi", "hybrid"])
def test_data_driven_methods_reach_riccati_fast_systems(name: str, method: str) -> None:
    _assert_accurate(name, method, 10_000 if method == "ddvi" else 50)


# the stiff plants' value iteration takes its resets before the hybrid hands over to policy
# iteration (the DC motor's: 7, from P0 to a bound above |P*|)
HYBRID_BUDGET = {"dc-motor-position": 300, "thermal-chain": 300}


@pytest.mark.integration
@pytest.mark.parametrize("name", sorted(set(FILES) - set(FAST)))
@pytest.mark.parametrize("method", ["ddvi", "hybrid"])
def test_data_driven_methods_reach_riccati(name: str, method: str) -> None:
    budget = 10_000 if method == "ddvi" else HYBRID_BUDGET.get(name, 50)
    _assert_accurate(name, method, budget)


@pytest.mark.integration
@pytest.mark.parametrize(
    "name", ["boeing747-lateral", "cart-pole", "f16-short-period", "mass-spring-tracking"]
)
def test_data_driven_policy_iteration_from_a_stabilising_gain(name: str) -> None:
    _assert_accurate(name, "dpi", 50)


def test_policy_iteration_without_a_stabilising_gain_says_so() -> None:
    """K0 = 0 leaves the double integrator's poles at zero: the evaluation's P is not positive
    definite, and the message names learning.K0 and the hybrid."""
    sol = solve(_system("double-integrator"), "dpi")
    assert not sol.converged
    assert "learning.K0" in sol.details["message"] and "hybrid" in sol.details["message"]


def test_every_setting_is_derived_from_the_system_when_none_is_given() -> None:
    system = _system("f16-short-period")
    assert set(system.derived) == set(DERIVED_KEYS) and system.given == ()
    cfg, pr = system.learning, system.problem
    fastest = float(np.max(np.abs(np.linalg.eigvals(pr.A - pr.B @ solve(system, "lqr").K))))
    assert cfg.time_unit >= fastest  # the fastest of the plant's and the closed loop's rates
    assert cfg.sample_period == pytest.approx(0.01 / cfg.time_unit)
    assert cfg.command_period == cfg.sample_period
    assert cfg.intervals >= 2 * (6 + 3)  # twice the unknowns n(n+1)/2 + m n
    assert max(cfg.exploration_frequencies) == pytest.approx(cfg.time_unit)
    assert cfg.interval * cfg.intervals >= 2 * np.pi / min(cfg.exploration_frequencies)


def test_a_file_giving_only_a_short_interval_is_accepted() -> None:
    """interval = 0.5 s alone, under LearningConfig's 10 s sample period: the sample period
    is derived from it (a tenth at most) and the command period from that."""
    table = {
        "A": [[0.0, 1.0], [0.0, 0.0]],
        "B": [[0.0], [1.0]],
        "Q": [[1.0, 0.0], [0.0, 1.0]],
        "R": [[10.0]],
        "learning": {"interval": 0.5},
    }
    system = system_from_table(table)
    cfg = system.learning
    assert cfg.interval == 0.5 and "interval" not in system.derived
    assert cfg.sample_period <= 0.05 and cfg.command_period == cfg.sample_period
    sol = solve(system, "ddvi")
    assert sol.converged and reference_errors(system, sol)["K_error"] < ACCURACY


def test_given_keys_override_and_the_rest_follow() -> None:
    pr = _system("double-integrator").problem
    given = LearningConfig(command_period=0.1, intervals=30)
    cfg, derived = derive_learning(pr, given, frozenset({"command_period", "intervals"}))
    assert cfg.command_period == 0.1 and cfg.intervals == 30
    ratio = cfg.command_period / cfg.sample_period
    assert abs(ratio - round(ratio)) < 1e-9  # a whole number of samples per command
    assert "command_period" not in derived and "sample_period" in derived


def test_diverging_data_name_K0_and_the_growth_rate() -> None:
    """The cart-pole without its K0: one LearningError naming learning.K0 and the growth rate
    (the upright pole's 4.6 1/s), before any overflow and with no numpy warning."""
    system = _system("cart-pole")
    system = replace(system, learning=replace(system.learning, K0=None))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(LearningError, match=r"learning\.K0") as info:
            solve(system, "ddvi")
    text = str(info.value)
    assert "\n" not in text and "diverge" in text
    rate = float(text.split(" at ")[1].split(" 1/s")[0])
    assert rate == pytest.approx(np.sqrt(21.582), rel=0.05)


def test_learn_json_shows_every_setting_and_its_source(capsys) -> None:
    code = main(["learn", str(SYSTEMS / "cart-pole.toml"), "--method", "hybrid", "--json"])
    out = json.loads(capsys.readouterr().out)
    assert code == 0 and out["K_error"] < ACCURACY and out["iterations"] < 50
    settings = out["settings"]
    assert settings["K0"]["source"] == "given"
    assert all(settings[k]["source"] == "derived" for k in DERIVED_KEYS)
    assert {"learning_s", "data_s"} <= set(out)


def test_learn_human_output_lists_the_settings(capsys) -> None:
    code = main(["learn", str(SYSTEMS / "double-integrator.toml"), "--method", "vi"])
    out = capsys.readouterr().out
    assert code == 0
    assert "time_unit = 1 (derived)" in out and "stopping = relative (derived)" in out


def test_builtin_scenarios_keep_their_tuned_tables() -> None:
    system = load_system("thrust-rendezvous")
    assert system.derived == () and system.learning.step == "constant"
    assert system.learning.stopping == "residual"
