"""The distributed services and the one-process runner fly one code: on a deployment with
navigation noise and its filter, a scheduled navigation bias and a panel fault, every deputy's
per-step commands through ``ddvi run`` are bit for bit those of ``run_in_process``."""

from __future__ import annotations

import tomllib
from pathlib import Path

import pytest

from services.config import deployment_from_table
from services.flight.inprocess import run_in_process
from services.ground.recording import read_recording
from services.model import orbit_period
from tests.support import fly

pytestmark = pytest.mark.integration

FAULTED = """
[run]
orbits = 5.0
command_deadline = 20.0
[[deputy]]
name = "biased"               # on its slot from the start: commands off the attitude limit
controller = "lqr"
y_ref = -29139.0
orbit = {a = 6678136.0, i = 45.0, raan = 20.0, argp = 30.0, f = 19.75}
navigation = {position_noise = 1.0, velocity_noise = 1e-3}
[[deputy]]
name = "panel"
controller = "lqr"
y_ref = -29139.0
orbit = {a = 6678136.0, i = 45.0, raan = 20.0, argp = 30.0, f = 19.75}
[[fault]]
at_orbits = 1.5
kind = "bias"
deputy = "biased"
position_bias = [0.0, 40.0, 0.0]
velocity_bias = [0.0, 0.0, 0.01]
[[fault]]
at_orbits = 2.5
kind = "panel"
deputy = "panel"
area_factor = 0.7
"""


def test_services_and_the_one_process_runner_fly_the_same_commands(tmp_path: Path) -> None:
    path = tmp_path / "faulted.toml"
    path.write_text(FAULTED)
    rc, err, out = fly(path, tmp_path / "runs")
    assert rc == 0, err[-3000:]
    recorded, complete = read_recording(out / "recording.mcap")
    assert complete
    flown: dict[str, dict[float, float]] = {"biased": {}, "panel": {}}
    for r in recorded:
        if r.schema == "ddvi.cmd":
            body = r.data["body"]
            flown[body["sc"]][body["for_t"]] = body["sigma"][2]
    dep = deployment_from_table(tomllib.loads(FAULTED))
    reference = run_in_process(dep)
    fsw = 60.0
    for sc, commands in flown.items():
        ref = reference[sc]
        on_step = (ref["t"] % fsw) == 0.0
        expected = dict(zip(ref["t"][on_step].tolist(), ref["u"][on_step].tolist(), strict=True))
        assert len(commands) == len(expected) > 400, sc
        differ = [t for t in expected if commands.get(t) != expected[t]]
        assert not differ, f"{sc}: {len(differ)} steps differ, the first at t = {differ[0]} s"
    # the faults were flown: each moved its deputy's commands off a clean run's
    clean = run_in_process(deployment_from_table(tomllib.loads(FAULTED.split("[[fault]]")[0])))
    for sc, at_orbits in (("biased", 1.5), ("panel", 2.5)):
        moved = reference[sc]["t"][reference[sc]["u"] != clean[sc]["u"]]
        assert moved.size > 0 and moved.min() >= at_orbits * orbit_period(dep) - 1e-6, sc
