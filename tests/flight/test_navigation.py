"""The navigation service's filter in a short mission flown in one process (the navigation
component the service runs), and its deployment keys."""

from __future__ import annotations

import dataclasses
import tomllib

import numpy as np
import pytest

from benchmarks.navigation import fly, rms, with_noise
from services.config import Deployment, DeploymentError, deployment_from_table

SHORT = """
[run]
orbits = 1.0
[[deputy]]
name = "lqr"
controller = "lqr"
"""


def short(**navigation: object) -> Deployment:
    table = tomllib.loads(SHORT)
    table["deputy"][0]["navigation"] = navigation
    return deployment_from_table(table)


def test_with_1_m_noise_the_published_estimate_is_closer_to_truth_than_the_measurement() -> None:
    rec = fly(with_noise(short(), 1.0))["lqr"]
    raw = rms(rec["measured"] - rec["truth"])
    est = rms(rec["estimate"] - rec["truth"])
    assert raw[0] == pytest.approx(np.sqrt(3), rel=0.15)  # 1 m per axis was measured
    assert est[0] < 0.3 * raw[0] and est[1] < 0.7 * raw[1]
    # the published covariance is the error's: the position RMS within 2x of its prediction
    predicted = np.sqrt(np.trace(rec["cov"][-1][:3, :3]))
    assert 0.5 * predicted < est[0] < 2 * predicted
    assert np.allclose(rec["cov"][-1], rec["cov"][-1].T)


def test_without_a_filter_the_measurement_is_published_with_its_covariance() -> None:
    rec = fly(with_noise(short(filter="none"), 1.0))["lqr"]
    assert np.array_equal(rec["estimate"], rec["measured"])
    assert np.array_equal(rec["cov"][0], np.diag([1.0] * 3 + [1e-6] * 3))


def test_without_noise_the_filter_publishes_the_truth_exactly_with_its_bias() -> None:
    dep = short(position_bias=[1.0, -2.0, 0.5])
    rec = fly(dataclasses.replace(dep, run=dataclasses.replace(dep.run, orbits=0.2)))["lqr"]
    assert np.array_equal(rec["estimate"], rec["truth"] + np.array([1.0, -2.0, 0.5, 0, 0, 0]))
    assert not rec["cov"].any()


@pytest.mark.parametrize(
    ("navigation", "text"),
    [
        ({"filter": "kalmann"}, "deputy[0].navigation.filter: 'kalmann' is not one of"),
        ({"filtr": "none"}, "did you mean 'filter'"),
        ({"acceleration_noise": 0.0}, "deputy[0].navigation.acceleration_noise: must be a"),
        ({"acceleration_noise": -1e-5}, "deputy[0].navigation.acceleration_noise: must be a"),
    ],
)
def test_a_bad_filter_setting_is_refused_in_one_line(navigation: dict, text: str) -> None:
    with pytest.raises(DeploymentError) as info:
        short(**navigation)
    assert text in str(info.value) and "\n" not in str(info.value)


def test_the_one_process_run_draws_the_navigation_services_noise() -> None:
    """run_in_process draws each deputy's noise as its navigation service does, whichever
    other deputies fly: the same trajectory to rounding; another run seed, another one."""
    from services.flight.inprocess import run_in_process

    def table(seed: int, other: bool) -> dict:
        t = tomllib.loads(SHORT)
        t["run"]["seed"] = seed
        # on its slot from the start, so the commands follow the noise (not the limit)
        t["deputy"][0]["y_ref"] = -29139.0
        t["deputy"][0]["orbit"] = {
            "a": 6678136.0,
            "i": 45.0,
            "raan": 20.0,
            "argp": 30.0,
            "f": 19.75,
        }
        t["deputy"][0]["navigation"] = {"position_noise": 1.0, "velocity_noise": 1e-3}
        if other:  # drawn first, from its own generator
            lone = {"name": "other", "controller": "lqr", "navigation": {"position_noise": 5.0}}
            t["deputy"].insert(0, lone)
        return t

    service = fly(deployment_from_table(table(1, other=False)))["lqr"]
    alone = run_in_process(deployment_from_table(table(1, other=True)))["lqr"]
    assert np.allclose(service["truth"][-1], alone["x"][-1], rtol=0, atol=1e-6)
    assert np.unique(np.round(alone["u"], 6)).size > 10  # the commands follow the noise
    reseeded = run_in_process(deployment_from_table(table(2, other=True)))["lqr"]
    assert np.abs(reseeded["x"][-1] - alone["x"][-1]).max() > 1e-3


def test_deputies_whose_names_have_the_same_letters_draw_their_own_noise() -> None:
    from services.flight.relative_navigation import noise_generator

    dep = deployment_from_table(tomllib.loads(SHORT))
    a, b = (dataclasses.replace(dep.deputy[0], name=n) for n in ("d01", "d10"))
    assert noise_generator(dep, a).normal() != noise_generator(dep, b).normal()
