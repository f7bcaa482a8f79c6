"""End to end: a short deployment, every service a real process on a real Zenoh bus, through
`ddvi run`; assertions on the run's summary.json and recording."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from ddvi_core.constants import R_EARTH
from services.config import (
    DeploymentError,
    deployment_from_table,
    load_deployment,
    read_table,
)
from services.flight.control import Controller
from services.ground.storage.recording import read_recording
from services.interface import schema_for_topic

SHORT = """
[run]
name = "it"
orbits = 1.5
command_deadline = 20.0
[[deputy]]
name = "lqr"
controller = "lqr"
[[deputy]]
name = "ddvi"
controller = "ddvi"
# a short budget: a learning attempt blocks the controller's loop, and 200k iterations of a
# failing attempt take about 10 s on a loaded machine, against a 20 s command deadline
learning = { learn_at_orbits = 1.0, interval = 120.0, max_iterations = 20000 }
"""


@pytest.mark.integration
def test_short_mission_end_to_end(tmp_path: Path) -> None:
    dep = tmp_path / "short.toml"
    dep.write_text(SHORT)
    r = subprocess.run(
        [
            sys.executable,
            "-m",
            "services.cli",
            "run",
            str(dep),
            "--output",
            str(tmp_path / "runs"),
            "--quiet",
        ],
        capture_output=True,
        text=True,
        timeout=110,
    )
    assert r.returncode == 0, r.stderr[-3000:]
    out = Path(r.stdout.strip().splitlines()[-1])
    summary = json.loads((out / "summary.json").read_text())
    assert summary["completed"] is True
    assert set(summary["deputies"]) == {"lqr", "ddvi"}
    lqr = summary["deputies"]["lqr"]
    # the deputy starts 29.1 km behind the chief; it is still far, but it is the truth's number
    assert 20_000 < lqr["final_along_track_error_m"] < 40_000
    totals = summary["messages"]["totals"]
    assert totals["rejected"] == 0 and totals["late"] == 0 and totals["dropped"] == 0
    # 1.5 orbits of 10 s samples: truth for 3 craft and exo at each, a clock at each 60 s
    # step, all recorded message by message (the environment sends a step's as batches)
    steps = int(1.5 * 5431.18 / 60)
    samples = steps * 6 + 1
    assert summary["messages"]["by_schema"]["truth"] == 3 * samples
    assert summary["messages"]["by_schema"]["exo"] == samples
    assert summary["messages"]["by_schema"]["clock"] == steps + 1
    assert summary["messages"]["recorded"] >= 4 * samples + steps
    recorded, complete = read_recording(out / "recording.mcap")
    assert complete and len(recorded) == summary["messages"]["recorded"]
    # every topic the services use carries the schema the topic table says it does
    data = [r for r in recorded if not r.topic.startswith(("alive/", "rejected/"))]
    assert {r.schema for r in data} >= {"ddvi.truth", "ddvi.nav", "ddvi.cmd", "ddvi.gains"}
    assert all(r.schema == f"ddvi.{schema_for_topic(r.topic)}" for r in data)
    # nothing published was missed, the first message of each service included (a service
    # waits to see the monitor before it publishes): every publisher's seq on every topic
    # runs from 0 without a gap
    seqs: dict[tuple[str, str], list[int]] = {}
    for r in data:
        seqs.setdefault((r.data["src"], r.topic), []).append(r.data["seq"])
    assert {src for src, _ in seqs} >= {"environment", "nav-lqr", "ctrl-ddvi", "monitor"}
    for key, got in seqs.items():
        assert sorted(got) == list(range(len(got))), key
    for name in (
        "hill_x.png",
        "hill_y.png",
        "hill_xy.png",
        "sigma3.png",
        "gains.png",
        "timeseries.csv",
    ):
        assert (out / name).is_file(), name
    log = (out / "logs" / "ctrl-ddvi.log").read_text()
    # the learner ran at the first flight-software step after one orbit (5431 s)
    assert "learning at t = 5460 s" in log


DELAYED = """
[run]
name = "links"
orbits = 1.0
command_deadline = 20.0
[[deputy]]
name = "lqr"
controller = "lqr"
[[link]]                # navigation to controller: one flight-software period late, and
publisher = "nav-*"     # a fifth of the samples arrive twice
subscriber = "ctrl-*"
delay = 60.0
duplicate = 0.2
[[link]]                # controller to environment: another period, and a lossy link
publisher = "ctrl-*"
subscriber = "environment"
topic = "cmd/*/att"
delay = 60.0
loss = 0.3
"""


@pytest.mark.integration
def test_link_delay_and_loss_from_the_deployment(tmp_path: Path) -> None:
    """Delays shift the control loop by whole steps without a late command; each command the
    link drops leaves the previous one in force, counted once as dropped and once as
    missing; each sample the link duplicates is refused once as a duplicate."""
    dep = tmp_path / "links.toml"
    dep.write_text(DELAYED)
    r = subprocess.run(
        [
            sys.executable,
            "-m",
            "services.cli",
            "run",
            str(dep),
            "--output",
            str(tmp_path / "runs"),
            "--quiet",
        ],
        capture_output=True,
        text=True,
        timeout=110,
    )
    # completed, with the commands the lossy link dropped missing: exit status 3
    assert r.returncode == 3 and "commands were" in r.stderr, r.stderr[-3000:]
    out = Path(r.stdout.strip().splitlines()[-1])
    summary = json.loads((out / "summary.json").read_text())
    assert summary["completed"] is True
    assert summary["outcome"]["commands"]["missing"] > 0
    env = summary["messages"]["services"]["environment"]
    ctrl = summary["messages"]["services"]["ctrl-lqr"]
    steps = env["steps"]
    nav = summary["messages"]["services"]["nav-lqr"]
    assert nav["published"] == steps * 6 + 1 and nav["unmatched"] == 0
    # every navigation sample held by its link, each copy counted (the last ones still in
    # flight at the end)
    held = ctrl["delayed"] - ctrl["duplicated"]
    assert nav["published"] - 7 <= held <= nav["published"]
    assert ctrl["dropped"] == 0
    # a duplicated sample is delivered once: its copy is refused as a duplicate (the copies
    # of the last samples, still held by the link at the end, are never delivered)
    assert 0.1 * nav["published"] < ctrl["duplicated"] < 0.3 * nav["published"]
    assert ctrl["duplicated"] - 7 <= ctrl["rejected.duplicate"] <= ctrl["duplicated"]
    assert ctrl["rejected"] == ctrl["rejected.duplicate"]
    assert summary["messages"]["totals"]["duplicated"] == ctrl["duplicated"]
    assert 0.15 * steps < env["dropped"] < 0.45 * steps  # 30 % of about 90 commands
    # a dropped command is missing at the step it was for (those for the last two steps,
    # beyond the end of the mission at 60 s delay, are not)
    assert env["dropped"] - 2 <= env["missing_commands"] <= env["dropped"]
    assert env["late_commands"] == 0 and env["stale_commands"] == 0
    assert summary["messages"]["totals"]["dropped"] == env["dropped"]


def test_default_deployment_loads() -> None:
    dep = load_deployment(None)
    assert dep.services == [
        "monitor",
        "nav-lqr",
        "ctrl-lqr",
        "nav-ddvi",
        "ctrl-ddvi",
        "environment",
    ]


def test_swarm_and_mismatch_deployments() -> None:
    swarm = load_deployment("deployments/swarm.toml")
    assert sorted(d.y_ref for d in swarm.deputy) == [-2000.0, -1000.0, 1000.0, 2000.0]
    # each deputy its own navigation and controller process
    assert len([s for s in swarm.services if s.startswith(("nav-", "ctrl-"))]) == 8
    for factor in (2.0, 0.5):
        dep = load_deployment(f"deployments/mismatch-{factor:g}x.toml")
        assert dep.environment.density_factor == factor
        assert {d.controller for d in dep.deputy} == {"lqr", "ddvi"}
        assert all(d.area_factor == factor for d in dep.deputy)


@pytest.mark.parametrize(
    ("table", "needle"),
    [
        (
            {"run": {"orbtis": 3}, "deputy": [{"name": "a"}]},
            "run.orbtis: unknown key (did you mean 'orbits'?)",
        ),
        ({"run": {"orbits": "3"}, "deputy": [{"name": "a"}]}, "run.orbits: expected a number"),
        ({"deputy": [{"name": "a", "controller": "pid"}]}, "deputy[0].controller"),
        ({"deputy": [{"name": "a"}, {"name": "a"}]}, "used twice"),
        ({}, "at least one [[deputy]]"),
        ({"deputy": [{"name": "a", "navigation": {"period": 7.0}}]}, "navigation.period"),
        (
            {"deputy": [{"name": "a", "learning": {"exploration_amplitude": 0.5}}]},
            "exploration_amplitude",
        ),
        (
            {"deputy": [{"name": "a", "navigation": {"frame": "hill"}}]},
            "deputy[0].navigation.frame: 'hill' is not one of ['curvilinear', 'path']",
        ),
        (
            {"deputy": [{"name": "a", "learning": {"window_orbits": -1.0}}]},
            "deputy[0].learning.window_orbits: must be >= 0",
        ),
        (
            {"deputy": [{"name": "a"}], "link": [{"publisher": "nav-*", "dealy": 60.0}]},
            "link[0].dealy: unknown key (did you mean 'delay'?)",
        ),
        (
            {"deputy": [{"name": "a"}], "link": [{"publisher": "nav-b", "delay": 60.0}]},
            "link[0].publisher: 'nav-b' matches no service",
        ),
        (
            {"deputy": [{"name": "a"}], "link": [{"loss": 1.5}]},
            "link[0].loss: expected a probability in [0, 1]",
        ),
        (
            {"deputy": [{"name": "a"}], "link": [{"loss": 0.1}]},
            "link[0]: impairs the environment's truth to navigation",
        ),
        (
            {"deputy": [{"name": "a"}], "restart": [{"service": "*"}]},
            "restart[0].service: '*' would restart environment, monitor",
        ),
        (
            {"deputy": [{"name": "a"}], "restart": [{"service": "ctrl-*", "policy": "always"}]},
            "restart[0].policy: expected one of never, on-failure",
        ),
        (
            {"deputy": [{"name": "a"}], "fault": [{"kind": "panel", "deputy": "b"}]},
            "fault[0].deputy: 'b' is not one of a",
        ),
        (
            {"deputy": [{"name": "a"}], "fault": [{"kind": "panle", "deputy": "a"}]},
            "fault[0].kind: expected one of panel, bias",
        ),
        (
            {"deputy": [{"name": "a"}], "fault": [{"deputy": "a", "at_orbits": 50.0}]},
            "fault[0].at_orbits: must lie in [0, run.orbits = 40)",
        ),
        (
            {"deputy": [{"name": "a"}], "fault": [{"kind": "panel", "deputy": "a"}]},
            "fault[0]: a panel fault changes area_factor, normal_angle or both: give one",
        ),
        (
            {"deputy": [{"name": "a"}], "fault": [{"deputy": "a", "normal_angle": 95}]},
            "fault[0]: normal_angle must lie in (0, 90) deg",
        ),
        (
            {"deputy": [{"name": "a"}], "fault": [{"deputy": "a", "normal_angle": "35"}]},
            "fault[0].normal_angle: expected a number, got '35'",
        ),
        (
            {
                "deputy": [{"name": "a"}],
                "fault": [{"kind": "bias", "deputy": "a", "area_factor": 0.5}],
            },
            "fault[0]: area_factor and normal_angle belong to panel faults, not 'bias'",
        ),
        (
            {"deputy": [{"name": "a"}], "host": [{"netns": "x", "services": ["nav-*"]}]},
            'host: services on other hosts reach the hub through a router: set bus.mode = "client"',
        ),
        (
            {
                "deputy": [{"name": "a"}],
                "bus": {"mode": "client", "port": 7000},
                "host": [{"netns": "x", "services": ["monitor"]}],
            },
            "host[0].services: the monitor runs beside the launcher",
        ),
    ],
)
def test_bad_deployment_names_the_key(table: dict, needle: str) -> None:
    with pytest.raises(DeploymentError, match=None) as exc:
        deployment_from_table(table)
    assert needle in str(exc.value)


@pytest.mark.integration
def test_bad_deployment_file_exits_2(tmp_path: Path) -> None:
    p = tmp_path / "bad.toml"
    p.write_text('[run]\nmode = "fast"\n[[deputy]]\nname = "a"\n')
    r = subprocess.run(
        [sys.executable, "-m", "services.cli", "run", str(p)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert r.returncode == 2 and "run.mode" in r.stderr and "Traceback" not in r.stderr


def test_holding_margin_flags_a_deputy_that_cannot_match_the_chiefs_drag() -> None:
    from services.model import holding_margin

    nominal = load_deployment("deployments/rendezvous.toml")
    half = load_deployment("deployments/mismatch-0.5x.toml")
    # 45 deg facet, |sigma3| <= 0.2 (phi up to 45.2 deg): broadside is reachable, so the
    # deputy's drag can rise to 1/sin(45 deg) = 1.414 of the chief's
    assert holding_margin(nominal, nominal.deputy[0]) == pytest.approx(2**0.5 - 1, rel=1e-9)
    assert holding_margin(half, half.deputy[0]) == pytest.approx(0.5 * 2**0.5 - 1, rel=1e-9)


def test_truth_step_ends_the_run_on_reentry() -> None:
    import dataclasses

    import numpy as np

    from services.model import (
        ReentryError,
        initial_states,
        truth_atmosphere,
        truth_craft,
        truth_step,
    )

    dep = load_deployment("deployments/rendezvous.toml")
    # a floor above the 300 km orbit: the first step is already "below" it
    dep = dataclasses.replace(
        dep, environment=dataclasses.replace(dep.environment, min_altitude=400e3)
    )
    expected = r"chief fell to 300\.0 km altitude at t = 10 s.*min_altitude = 400 km"
    with pytest.raises(ReentryError, match=expected):
        truth_step(
            dep, initial_states(dep), 0.0, np.zeros((2, 3)), truth_craft(dep), truth_atmosphere(dep)
        )


def test_controller_schedules_drag_on_altitude() -> None:
    """1.4 km below the model's altitude the air is 19% denser: the controller asks the facet
    for 19% less area change, so the drag change (what u stands for) is the same, and the
    learner records the same u."""
    dep = load_deployment(None)
    ctrl = Controller(dep, "lqr")
    x = np.array([0.0, 0.0, 0.0, 0.005])
    v = np.array([1.0, 0.0, 0.0, 0.0, 0.0])
    u = float((-ctrl.K @ x)[0])
    alpha = math.radians(dep.spacecraft.normal_angle)
    h0 = dep.chief.a - R_EARTH
    for dh in (0.0, -1400.0, 2000.0):
        sigma = ctrl.command(0.0, x, v, h0 + dh)
        ratio = math.exp(-dh / dep.atmosphere.scale_height)
        area_change = math.sin(alpha + 4 * math.atan(sigma)) - math.sin(alpha)
        assert area_change * ratio == pytest.approx(4 * math.cos(alpha) * u, rel=1e-9)
        assert ctrl.actuation.u_applied == pytest.approx(u, rel=1e-9)
    assert ctrl.actuation.density_ratio(h0 - 1400.0) == pytest.approx(1.191, abs=1e-3)


def test_learner_pairs_samples_with_the_command_acting_through_a_delayed_link() -> None:
    """With a 90 s command link and 60 s steps, the environment applies the command issued at
    T from the first step boundary at or after T + 90 s: the sample at t is paired with that
    command, not the newest one the controller issued."""
    table = read_table(None)
    table["link"] = [
        {"publisher": "ctrl-ddvi", "subscriber": "environment", "topic": "cmd/*/att", "delay": 90.0}
    ]
    ctrl = Controller(deployment_from_table(table), "ddvi")
    assert ctrl.actuation.delay == 90.0
    x, v = np.zeros(4), np.array([1.0, 0.0, 0.0, 0.0, 0.0])
    h0 = ctrl.dep.chief.a - R_EARTH
    for T in (0.0, 60.0, 120.0, 180.0, 240.0):
        ctrl.tick(T, x, v, h0)
    u = dict(ctrl.actuation.steps)
    assert len(set(u.values())) == 5  # the exploration makes every step's input distinct
    expected = {0.0: 0.0, 110.0: 0.0, 120.0: u[0.0], 179.0: u[0.0], 180.0: u[60.0], 250.0: u[120.0]}
    for t, want in expected.items():
        assert ctrl.actuation.input_acting(t) == want, t
    assert Controller(load_deployment(None), "ddvi").actuation.delay == 0.0


def test_a_stuck_panel_normal_makes_the_drag_its_geometry_says() -> None:
    """A panel fault's normal_angle sticks the deputy's facet normal: at zero attitude a facet
    stuck at 35 deg shows sin 35 / sin 45 of the nominal area to the along-track flow, so it
    flies as a 45 deg facet with that area factor does (to first order: the flow's small
    radial part, from J2, meets the two facets differently), and both leave the unfaulted
    deputy."""
    from services.model import BuiltinTruth, facet_normal

    dep = load_deployment("deployments/rendezvous.toml")  # two deputies on the same orbit
    truth, whole = BuiltinTruth(dep), BuiltinTruth(dep)
    truth.set_panel(0, normal_angle=35.0)
    truth.set_panel(1, area_factor=math.sin(math.radians(35)) / math.sin(math.radians(45)))
    assert truth._craft[1].normal_B == facet_normal(35.0)
    assert truth._craft[1].area == dep.spacecraft.area  # the area is left as it was
    sigma = np.zeros((2, 3))
    for t_k in (0.0, 60.0, 120.0):
        _, traj = truth.step(t_k, sigma)
        _, ref = whole.step(t_k, sigma)
    stuck, smaller, nominal = traj[-1, 1], traj[-1, 2], ref[-1, 1]
    departure = np.linalg.norm(stuck[:3] - nominal[:3])
    assert departure > 1e-3 and np.linalg.norm(stuck[:3] - smaller[:3]) < 1e-2 * departure
    for bad in ({}, {"normal_angle": 90.0}, {"area_factor": 0.0}, {"normal_angle": True}):
        with pytest.raises(ValueError, match=r"area_factor|normal_angle"):
            truth.set_panel(0, **bad)


def test_holding_margin_after_a_panel_fault() -> None:
    from services.model import holding_margin

    dep = load_deployment("deployments/rendezvous.toml")
    d = dep.deputy[0]
    # a facet stuck at 80 deg reaches broadside too; one at 10 deg with half its area reaches
    # 10 + 45.2 deg at most: 0.5 sin(55.2 deg) / sin(45 deg) - 1 < 0
    assert holding_margin(dep, d, normal_angle=80.0) == pytest.approx(2**0.5 - 1, rel=1e-9)
    phi = 4 * math.atan(d.attitude_limit)
    expected = 0.5 * math.sin(math.radians(10) + phi) / math.sin(math.radians(45)) - 1
    assert holding_margin(dep, d, 0.5, 10.0) == pytest.approx(expected, rel=1e-9)
