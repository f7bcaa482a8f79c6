"""The monitor's memory of a run, in one process: Hill states from truth, stats across
restarts, and a message of every kind ingested."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ddvi_core.constants import MU_EARTH
from ddvi_core.orbit import rv_to_hill
from services.config import deployment_from_table
from services.ground.analysis.rundata import RunData, chief_acceleration, hill_states
from services.interface import decode, encode, topics

A = 6678136.0
INC = math.radians(45.0)


def circular(theta: float, a: float = A) -> tuple[np.ndarray, np.ndarray]:
    c, s = math.cos(theta), math.sin(theta)
    r = a * np.array([c, s * math.cos(INC), s * math.sin(INC)])
    v = math.sqrt(MU_EARTH / a) * np.array([-s, c * math.cos(INC), c * math.sin(INC)])
    return r, v


def test_hill_states_match_rv_to_hill() -> None:
    rng = np.random.default_rng(3)
    r_c, v_c = zip(*(circular(th) for th in rng.uniform(0, 6, 20)), strict=True)
    rc, vc = np.array(r_c), np.array(v_c)
    rd, vd = rc + rng.normal(0, 1e3, rc.shape), vc + rng.normal(0, 1.0, vc.shape)
    ac = chief_acceleration(rc, vc, j2=True)
    batch = hill_states(rc, vc, ac, rd, vd)
    for k in range(len(rc)):
        np.testing.assert_allclose(
            batch[k], rv_to_hill(rc[k], vc[k], rd[k], vd[k], ac[k]), rtol=1e-12, atol=1e-9
        )


def _ingest(
    data: RunData, topic: str, schema: str, body: dict, t: float, src: str = "test"
) -> None:
    msg = decode(encode(schema, body, seq=0, t=t, src=src), schema)
    data.received(msg)  # as the monitor: counted against its publisher's stats, then used
    data.ingest(topic, msg)


def _log(data: RunData, service: str, t: float) -> None:
    body = {"service": service, "level": "info", "text": "x"}
    _ingest(data, topics.log_topic(service), "log", body, t, src=service)


def _stats(data: RunData, service: str, sent: int, t: float) -> None:
    body = {"service": service, "counters": {"sent": sent}}
    _ingest(data, topics.stats_topic(service), "stats", body, t, src=service)


def test_what_a_service_published_and_the_monitor_never_got_is_counted() -> None:
    data = RunData(deployment_from_table({"deputy": [{"name": "alpha"}]}), "r")
    for k in range(3):
        _log(data, "nav-alpha", float(k))
    _stats(data, "nav-alpha", 3, 3.0)  # three sent before its stats: all arrived
    assert data.unrecorded() == {}
    _log(data, "nav-alpha", 4.0)  # of the next three, one arrives
    _stats(data, "nav-alpha", 7, 5.0)  # 3 + stats + 3
    assert data.unrecorded() == {"nav-alpha": 2}
    # a restarted process counts from 0 again; what it sent arrived
    _log(data, "nav-alpha", 6.0)
    _stats(data, "nav-alpha", 1, 7.0)
    assert data.unrecorded() == {"nav-alpha": 2}
    # one that sent more than its last stats say (killed before its final ones) invents none
    for k in range(5):
        _log(data, "ctrl-alpha", float(k))
    _stats(data, "ctrl-alpha", 2, 1.0)
    assert data.unrecorded() == {"nav-alpha": 2}


def test_stats_of_a_restarted_service_add_up_and_the_final_clock_is_kept() -> None:
    data = RunData(deployment_from_table({"deputy": [{"name": "alpha"}]}), "r")
    for t, sent in ((10.0, 5), (20.0, 8), (30.0, 2)):  # the third: a restarted process
        body = {"service": "ctrl-alpha", "counters": {"sent": sent}}
        _ingest(data, topics.stats_topic("ctrl-alpha"), "stats", body, t)
    assert data.stats["ctrl-alpha"] == {"sent": 10} and data.stats_t["ctrl-alpha"] == 30.0
    clock = {"step": 4, "dt": 10.0, "fsw": True, "mode": "lockstep", "final": True}
    _ingest(data, topics.CLOCK, "clock", clock, 40.0)
    assert data.final_seen and data.final_t == 40.0 and data.sim_t == 40.0
    assert data.counts == {"stats": 3, "clock": 1}


def test_hill_of_a_deputy_from_truth_at_common_times() -> None:
    data = RunData(deployment_from_table({"deputy": [{"name": "alpha"}]}), "r")
    for k, theta in enumerate((0.0, 0.001, 0.002)):
        for sc, lag in (("chief", 0.0), ("alpha", 1e-5)):
            r, v = circular(theta - lag)
            body = {"sc": sc, "r_N": r, "v_N": v, "sigma_BN": np.zeros(3)}
            _ingest(data, topics.truth_topic(sc), "truth", body, 10.0 * k)
    t, hill = data.hill("alpha")
    assert list(t) == [0.0, 10.0, 20.0] and hill.shape == (3, 6)
    assert hill[:, 1] == pytest.approx(-A * math.sin(1e-5), rel=1e-6)
