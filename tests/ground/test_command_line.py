"""The command line explains itself: its version, its help, a closed pipe, bad input found
before launch, topic patterns for the monitor, one convention for units, sweep warnings,
short progress lines, failures said with their reason, and what an installed package holds."""

from __future__ import annotations

import argparse
import glob
import os
import subprocess
import sys
import tomllib
from pathlib import Path
from typing import Any

import pytest

from services.bus import error_text
from services.cli import build_parser, main
from services.config import deployment_from_table, read_table
from services.config.files import DEPLOYMENTS_DIR, campaign_file, system_example
from services.ground.analysis.rundata import RunData
from services.ground.launch import netns
from services.ground.launch.lifecycle import log_reason
from services.ground.monitoring.run_keys import run_keyexpr
from services.ground.monitoring.status import Status
from services.ground.sweeps.sweep import _point_text, sweep_points, unlearned_points

ROOT = DEPLOYMENTS_DIR.parent


def run(capsys: pytest.CaptureFixture, *argv: str) -> tuple[int, str, str]:
    try:
        code = main(list(argv))
    except SystemExit as exc:  # argparse: --version, --help, usage errors
        code = int(exc.code or 0)
    out, err = capsys.readouterr()
    return code, out, err


def test_version_names_the_installed_package(capsys: pytest.CaptureFixture) -> None:
    from importlib.metadata import version

    code, out, _ = run(capsys, "--version")
    assert code == 0 and out.strip() == f"ddvi {version('ddvi-fsw')}"


def test_learn_help_explains_every_method_and_the_default(capsys: pytest.CaptureFixture) -> None:
    from ddvi_core.solve import METHODS

    code, out, _ = run(capsys, "learn", "--help")
    assert code == 0
    listed = out.split("methods (docs/methods.md):", 1)[1]
    for method in METHODS:
        assert f"\n  {method} " in listed, method
    assert "(default: ddvi)" in out


def _commands(parser: argparse.ArgumentParser, prefix: str = "") -> dict[str, Any]:
    """Every command and sub-command (``sweep noise``) of ``parser``, by its words."""
    found: dict[str, Any] = {}
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                found[f"{prefix}{name}"] = sub
                found.update(_commands(sub, f"{prefix}{name} "))
    return found


def test_every_option_of_every_command_has_help() -> None:
    commands = _commands(build_parser())
    assert {"sweep delay", "sweep loss", "sweep noise"} <= set(commands)
    bare = [
        f"{name} {'/'.join(action.option_strings) or action.dest}"
        for name, sub in commands.items()
        for action in sub._actions
        if not isinstance(action, argparse._HelpAction) and not action.help
    ]
    assert not bare, bare


def test_each_sweep_kind_has_its_own_help(capsys: pytest.CaptureFixture) -> None:
    """``ddvi sweep KIND --help`` says what that sweep varies and takes only its options;
    ``ddvi sweep --help`` names the kinds."""
    code, out, _ = run(capsys, "sweep", "--help")
    assert code == 0 and "what to sweep (ddvi sweep KIND --help)" in out
    helps = {}
    for kind in ("delay", "loss", "noise"):
        code, helps[kind], _ = run(capsys, "sweep", kind, "--help")
        assert code == 0 and helps[kind].startswith(f"usage: ddvi sweep {kind} ")
        assert f"sweep-{kind}-<run name>-<stamp>" in " ".join(helps[kind].split())
    assert "The mission once per delay" in helps["delay"] and "s (simulation time" in helps["delay"]
    assert "The mission once per loss rate" in helps["loss"]
    assert "loss probabilities in [0, 1]" in helps["loss"]
    noise = " ".join(helps["noise"].split())
    assert "navigation.position_noise = v" in noise and "--mismatch" in noise
    assert "--filter {kalman,none}" in noise
    for kind in ("delay", "loss"):
        assert "--mismatch" not in helps[kind] and "--filter" not in helps[kind]


def test_an_option_another_command_takes_is_named_by_the_command_given(
    capsys: pytest.CaptureFixture,
) -> None:
    code, _, err = run(capsys, "sweep", "delay", "--values", "0", "--mismatch", "2")
    assert code == 2
    assert err == (
        "ddvi sweep delay: unrecognized arguments: --mismatch (see ddvi sweep delay --help)\n"
    )
    code, _, err = run(capsys, "run", "--bogus")
    assert code == 2 and err == "ddvi run: unrecognized arguments: --bogus (see ddvi run --help)\n"


def test_campaign_help_names_the_shipped_campaigns(capsys: pytest.CaptureFixture) -> None:
    shipped = sorted(p.stem for p in (ROOT / "deployments" / "campaigns").glob("*.toml"))
    code, out, _ = run(capsys, "campaign", "--help")
    assert code == 0 and "shipped campaign's name" in out
    (file,) = [a for a in _commands(build_parser())["campaign"]._actions if a.dest == "file"]
    assert file.help.endswith("or a shipped campaign's name: " + ", ".join(shipped))
    assert "rendezvous-200" in shipped
    code, _, err = run(capsys, "campaign", "rendezvous200")
    assert code == 2 and "(did you mean 'rendezvous-200'?)" in err and err.count("\n") == 1


@pytest.mark.integration  # starts a Python process
def test_a_pipe_closed_early_ends_quietly() -> None:
    """``ddvi scenarios | head -1``: the reader is gone before the writer writes."""
    read, write = os.pipe()
    os.close(read)
    try:
        r = subprocess.run(
            [sys.executable, "-m", "services.cli", "scenarios"],
            stdout=write,
            stderr=subprocess.PIPE,
            text=True,
            timeout=60,
        )
    finally:
        os.close(write)
    assert r.stderr == ""
    assert r.returncode == 1


def test_a_basilisk_deployment_without_basilisk_is_bad_input_before_launch(
    capsys: pytest.CaptureFixture, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import importlib.util

    from services.ground.launch import launcher

    real = importlib.util.find_spec

    def find_spec(name: str, *rest: object) -> object:
        return None if name == "Basilisk" else real(name, *rest)

    monkeypatch.setattr(importlib.util, "find_spec", find_spec)
    monkeypatch.setattr(launcher.Launcher, "__init__", lambda *a, **k: pytest.fail("launched"))
    table = read_table("rendezvous")
    table["environment"]["backend"] = "basilisk"
    path = tmp_path / "bsk.toml"
    import tomli_w

    path.write_bytes(tomli_w.dumps(table).encode())
    code, out, err = run(capsys, "run", str(path), "--output", str(tmp_path / "runs"))
    assert code == 2 and out == ""
    assert 'environment.backend = "basilisk" needs Basilisk, which is not installed' in err
    assert "pip install -e '.[basilisk]'" in err
    assert not (tmp_path / "runs").exists()


@pytest.mark.parametrize(
    ("pattern", "key"),
    [
        (None, "ddvi/R/**"),
        ("ctrl/*/status", "ddvi/R/ctrl/*/status"),
        ("ddvi/*/ctrl/*/status", "ddvi/R/ctrl/*/status"),
        ("ddvi/R/nav/*/state", "ddvi/R/nav/*/state"),
        ("**/status", "ddvi/R/**/status"),
        ("ddvi/**", "ddvi/R/**"),
    ],
)
def test_the_monitor_takes_a_topic_pattern_or_a_full_key(pattern: str | None, key: str) -> None:
    assert run_keyexpr("R", pattern) == key


@pytest.mark.parametrize(
    ("pattern", "said"),
    [
        ("ctrl/*/statuz", "matches no topic; the topics are clock, exo/state"),
        ("ddvi/S/clock", "names run 'S', not this run ('R')"),
        ("a//b", "is not a key expression"),
    ],
)
def test_a_pattern_matching_nothing_is_said(pattern: str, said: str) -> None:
    with pytest.raises(ValueError, match="^" + repr(pattern).replace("*", r"\*")) as err:
        run_keyexpr("R", pattern)
    assert said in str(err.value)


def test_ddvi_monitor_refuses_a_pattern_matching_nothing_at_once(
    capsys: pytest.CaptureFixture,
) -> None:
    code, out, err = run(capsys, "monitor", "ctrl/*/statuz", "--hub", "tcp/127.0.0.1:9")
    assert code == 2 and out == ""
    assert err.startswith("ddvi monitor: 'ctrl/*/statuz' matches no topic")


def test_zenoh_errors_lose_their_rust_source_path() -> None:
    exc = RuntimeError(
        "Unable to connect to any of [Single(tcp/127.0.0.1:1)]!  at "
        "/root/.cargo/git/checkouts/zenoh-9c5/cc83980/zenoh/src/net/runtime/"
        "orchestrator.rs:447."
    )
    assert error_text(exc) == "Unable to connect to any of [Single(tcp/127.0.0.1:1)]!"


def test_netns_takes_seconds_and_a_probability(capsys: pytest.CaptureFixture) -> None:
    assert netns.netem_problem(0.05, 0.01) is None
    assert "seconds" in netns.netem_problem(50.0 * 10, 0.0)
    assert "probability in [0, 1]" in netns.netem_problem(0.0, 1.5)
    code, _, err = run(capsys, "netns", "up", "multihost", "--delay", "0", "--loss", "2")
    assert code == 2 and "--loss 2: a probability in [0, 1] (0.01 for 1 %)" in err


def test_a_sweep_warns_when_its_runs_end_before_a_learner_learns() -> None:
    runs = sweep_points("delay", read_table("rendezvous"), [0.0, 60.0], orbits=[10.0])
    warned = unlearned_points(runs)
    assert [p for p, _ in warned] == [{"value": 0.0}, {"value": 60.0}]
    assert all(
        "deputy 'ddvi' learns at orbit 15 but the run ends at orbit 10" in w for _, w in warned
    )
    assert unlearned_points(sweep_points("delay", read_table("rendezvous"), [0.0])) == []


def test_a_sweep_point_is_labelled_with_its_unit() -> None:
    assert _point_text("delay", {"value": 60.0}).startswith("delay = 60 s on the nav -> ctrl")
    assert _point_text("loss", {"value": 0.2}).startswith("loss = 0.2 (probability)")
    assert _point_text("noise", {"noise": 1.0, "mismatch": 2.0}) == "noise = 1 m, mismatch = 2"


def test_a_swarms_plain_progress_line_stays_short(capsys: pytest.CaptureFixture) -> None:
    swarm = deployment_from_table(read_table("swarm"))
    assert len(swarm.deputy) == 4
    status = Status(RunData(swarm, "swarm-20260101-000000-1"), tty=False)
    status.data.sim_t = 0.5 * status.data.duration
    status.update({})
    (line,) = capsys.readouterr().err.splitlines()
    assert line.startswith("monitor:  50%") and len(line) <= 160, line
    assert "y-y_ref" in line and all(f"| {d.name}: " in line for d in swarm.deputy)


def test_a_failed_service_is_said_with_the_reason_its_log_gives(tmp_path: Path) -> None:
    log = tmp_path / "environment.log"
    log.write_text(
        "2026-01-01 00:00:00,000 environment INFO stepping\n"
        "2026-01-01 00:00:01,000 environment ERROR mission ended early: chief fell to 147.5 km "
        "altitude at t = 1800 s\n"
        "2026-01-01 00:00:01,100 environment INFO closed\n"
    )
    assert log_reason(log) == "mission ended early: chief fell to 147.5 km altitude at t = 1800 s"
    assert log_reason(tmp_path / "none.log") == "its log is empty"


def test_the_packaged_data_files_cover_every_shipped_file() -> None:
    """A plain ``pip install .`` installs every campaign file and example beside the named
    deployments (pyproject.toml's data files), where the commands find them by name."""
    data = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    patterns = [p for files in data["data-files"].values() for p in files]
    packaged = {Path(f) for p in patterns for f in glob.glob(p, root_dir=ROOT)}
    shipped = {
        p.relative_to(ROOT)
        for folder in ("deployments", "docs/examples")
        for p in (ROOT / folder).rglob("*")
        if p.is_file()
    }
    assert shipped and shipped <= packaged, sorted(shipped - packaged)
    for target, files in data["data-files"].items():
        for pattern in files:  # each installed under share/ddvi-fsw/<its own folder>
            assert target == f"share/ddvi-fsw/{Path(pattern).parent}", target


def test_campaigns_and_examples_are_found_by_name_from_any_folder(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    monkeypatch.chdir(tmp_path)
    shipped = DEPLOYMENTS_DIR / "campaigns" / "rendezvous-200.toml"
    assert campaign_file("rendezvous-200") == shipped.resolve()
    assert campaign_file("deployments/campaigns/rendezvous-200.toml") == shipped.resolve()
    assert campaign_file("no-such-campaign") is None
    assert system_example("cart-pole") == (ROOT / "docs/examples/systems/cart-pole.toml").resolve()


@pytest.mark.integration  # flies a mission to its early end (a third of an orbit)
def test_a_run_the_truth_ends_early_says_why_and_where(tmp_path: Path) -> None:
    """The environment's exit is said with the reason its log gives and the log's path, and
    the monitor's log agrees with the report that the mission did not complete."""
    table = read_table("rendezvous")
    table["environment"]["min_altitude"] = 299.7e3  # the chief decays below it within an orbit
    table["run"]["orbits"] = 2.0
    import tomli_w

    path = tmp_path / "reentry.toml"
    path.write_bytes(tomli_w.dumps(table).encode())
    r = subprocess.run(
        [
            sys.executable,
            "-m",
            "services.cli",
            "run",
            str(path),
            "--quiet",
            "--output",
            str(tmp_path / "runs"),
        ],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert r.returncode == 1, r.stderr[-3000:]
    (folder,) = (tmp_path / "runs").iterdir()
    log = folder / "logs" / "environment.log"
    said = "environment exited with status 3: mission ended early: chief fell to 299.7 km"
    assert said in r.stderr and f"(log: {log})" in r.stderr, r.stderr[-3000:]
    monitor_log = (folder / "logs" / "monitor.log").read_text()
    assert "(completed=False," in monitor_log and "(completed=True," not in monitor_log
    assert "- completed: **no**" in (folder / "report.md").read_text()
