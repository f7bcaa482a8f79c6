"""The distributed services and the one-process executor fly one code: on the default mission,
on realistic-nav, and on realistic-nav with a navigation bias, a panel fault, a navigation
outage and delayed, lossy links, every deputy's per-step commands through ``ddvi run`` are bit
for bit those of ``run_in_process``, and so are the figures each scores."""

from __future__ import annotations

import json
import tomllib
from pathlib import Path

import numpy as np
import pytest

from services.config import Deployment, deployment_from_table, load_deployment, resolve
from services.flight.inprocess import run_in_process
from services.ground.storage.recording import read_recording
from services.ground.sweeps.sweep import inprocess_rows, summary_rows
from services.model import orbit_period
from tests.support import fly

pytestmark = pytest.mark.integration

BIAS_AND_PANEL = """
[[fault]]                 # the model-fit learner's navigation 15 m off along track
at_orbits = 18.0
kind = "bias"
deputy = "fit"
position_bias = [0.0, 15.0, 0.0]

[[fault]]                 # the LQR deputy's panel at 70 %
at_orbits = 25.0
kind = "panel"
deputy = "lqr"
area_factor = 0.7
"""
OUTAGE_AND_LINKS = """
[[fault]]                 # the LQR deputy's navigation measures nothing for a quarter orbit
at_orbits = 10.0
kind = "outage"
deputy = "lqr"
duration_orbits = 0.25

[[link]]
publisher = "nav-*"
subscriber = "ctrl-*"
delay = 20.0
loss = 0.05

[[link]]
publisher = "ctrl-*"
subscriber = "environment"
topic = "cmd/*/att"
delay = 30.0
loss = 0.05
"""
TALLIES = ("dropped", "delayed")
"""Link tallies: the services' final counters are sent while the last messages travel."""


def _realistic_nav(name: str, *parts: str) -> str:
    """deployments/realistic-nav.toml named ``name``, with ``parts`` added."""
    text = resolve("realistic-nav").read_text()
    return text.replace('name = "realistic-nav"', f'name = "{name}"') + "".join(parts)


def _faulted(folder: Path) -> Path:
    path = folder / "faulted.toml"
    path.write_text(_realistic_nav("faulted", BIAS_AND_PANEL, OUTAGE_AND_LINKS))
    return path


@pytest.mark.parametrize("mission", ["rendezvous", "realistic-nav", "faulted"])
def test_services_and_the_one_process_executor_fly_the_same_commands(
    tmp_path: Path, mission: str
) -> None:
    path = _faulted(tmp_path) if mission == "faulted" else resolve(mission)
    rc, err, out = fly(path, tmp_path / "runs")
    # 3: completed, with commands lost on their links
    assert rc == (3 if mission == "faulted" else 0), err[-3000:]
    recorded, complete = read_recording(out / "recording.mcap")
    assert complete
    dep = load_deployment(str(path))
    flown: dict[str, dict[float, list[float]]] = {d.name: {} for d in dep.deputy}
    for r in recorded:
        if r.schema == "ddvi.cmd":
            body = r.data["body"]
            flown[body["sc"]][body["for_t"]] = list(body["sigma"])
    reference = run_in_process(dep)
    for sc, commands in flown.items():
        ref = reference[sc]
        expected = {float(t): list(s) for t, s in zip(ref["step_t"], ref["sigma"], strict=True)}
        assert len(commands) == len(expected) == 3621, sc
        differ = [t for t in expected if commands.get(t) != expected[t]]
        assert not differ, f"{sc}: {len(differ)} steps differ, the first at t = {differ[0]} s"
    # the figures the report scores, and the sweep's from the one-process run
    summary = json.loads((out / "summary.json").read_text())
    launched = summary_rows({}, summary)
    in_process = inprocess_rows({}, dep)
    for a, b in zip(launched, in_process, strict=True):
        assert {k: v for k, v in a.items() if k not in TALLIES} == {
            k: v for k, v in b.items() if k not in TALLIES
        }
    services = summary["messages"]["services"]
    for d in dep.deputy:
        counters = services[f"ctrl-{d.name}"]
        for key, value in reference[d.name]["counters"].items():
            assert counters[key] == value, (d.name, key)
    if mission == "faulted":
        _faults_were_flown(dep, reference, services)


def _faults_were_flown(dep: Deployment, reference: dict, services: dict) -> None:
    """The outage: navigation marked its samples invalid and its covariance grew, the LQR
    deputy flew the safe attitude during it only; the bias and the panel moved their
    deputies' commands from their times on, not before; the links lost and delayed messages."""
    period = orbit_period(dep)
    lqr = reference["lqr"]
    start, end = 10.0 * period, 10.25 * period
    out = ~lqr["valid"]
    assert out.any() and lqr["t"][out].min() >= start - 1e-6 and lqr["t"][out].max() < end
    position_var = lqr["cov"][:, 0, 0] + lqr["cov"][:, 1, 1]
    during = np.flatnonzero(out)
    assert np.all(np.diff(position_var[during]) > 0)  # the filter propagates: it grows
    assert services["nav-lqr"]["outage_samples"] == out.sum()
    assert services["nav-lqr"]["outages"] == 1
    safe = lqr["step_t"][lqr["safe"]]
    # past the stale limit (two steps) after the last valid sample, until the next one
    assert safe.size and safe.min() > start + 120.0 and safe.max() <= end + 60.0
    assert lqr["counters"]["safe_attitude_steps"] == safe.size
    # what the controller saw of them: those its lossy link delivered
    assert 0.85 * out.sum() < lqr["counters"]["invalid_samples"] <= out.sum()
    for d in dep.deputy:
        assert not reference[d.name]["safe"].any() or d.name == "lqr"
    # without the bias and the panel, the same until their times, not after
    table = tomllib.loads(_realistic_nav("outage", OUTAGE_AND_LINKS))
    clean = run_in_process(deployment_from_table(table))
    for sc, at_orbits in (("fit", 18.0), ("lqr", 25.0)):
        before = reference[sc]["step_t"] < at_orbits * period - 1e-6
        assert np.array_equal(reference[sc]["sigma"][before], clean[sc]["sigma"][before])
        assert not np.array_equal(reference[sc]["sigma"][~before], clean[sc]["sigma"][~before])
    assert services["environment"]["dropped"] > 0 and services["ctrl-fit"]["delayed"] > 0
