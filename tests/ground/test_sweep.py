"""ddvi sweep: the impaired and noisy deployments it derives, its table, and short real
sweeps (a link sweep through the launcher, a noise and mismatch sweep in process)."""

from __future__ import annotations

import csv
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from services.cli import main
from services.config import deployment_from_table, load_deployment, read_table
from services.ground.sweeps.sweep import (
    VELOCITY_NOISE_RATIO,
    impaired_table,
    largest_learning_value,
    noisy_table,
    sweep,
    sweep_points,
)
from services.model import lqr_gains, true_lqr_gains

SHORT = """
[run]
name = "sw"
orbits = 0.5
command_deadline = 20.0
[[deputy]]
name = "lqr"
controller = "lqr"
"""


def test_impaired_table_puts_both_links_first() -> None:
    own = {"publisher": "environment", "subscriber": "ctrl-*", "topic": "exo/state", "delay": 5.0}
    table = {"deputy": [{"name": "a"}], "link": [own]}
    dep = deployment_from_table(impaired_table(table, "delay", 120.0))
    assert [(k.publisher, k.subscriber, k.topic, k.delay) for k in dep.link] == [
        ("nav-*", "ctrl-*", "nav/*/state", 120.0),
        ("ctrl-*", "environment", "cmd/*/att", 120.0),
        ("environment", "ctrl-*", "exo/state", 5.0),
    ]
    lossy = deployment_from_table(impaired_table(table, "loss", 0.25))
    assert [k.loss for k in lossy.link[:2]] == [0.25, 0.25]
    with pytest.raises(ValueError, match="sweep kind"):
        impaired_table(table, "jitter", 1.0)


def test_each_impaired_table_is_its_own() -> None:
    table = {"run": {"name": "r"}, "deputy": [{"name": "a"}]}
    first, second = impaired_table(table, "delay", 10.0), impaired_table(table, "delay", 20.0)
    first["run"]["name"] = "changed"
    assert second["run"]["name"] == "r" and table["run"]["name"] == "r"
    assert "link" not in table


def test_largest_learning_value_stops_at_the_first_failure() -> None:
    def row(value: float, learned: bool, error: float | None = 0.01) -> dict:
        return {
            "value": value,
            "controller": "ddvi",
            "learned": learned,
            "completed": True,
            "gain_error": error if learned else None,
        }

    rows = [row(0, True), row(60, True), row(120, False), row(180, True)]
    assert largest_learning_value(rows) == 60
    assert largest_learning_value([row(0, False)]) is None
    # converged, but to a gain far from the optimum: not a success
    assert largest_learning_value([row(0, True), row(60, True, error=1.2)]) == 0


@pytest.mark.integration
def test_delay_sweep_runs_each_value_alike_through_the_launcher_and_in_process(
    tmp_path: Path,
) -> None:
    dep = tmp_path / "short.toml"
    dep.write_text(SHORT)
    r = subprocess.run(
        [
            sys.executable,
            "-m",
            "services.cli",
            "sweep",
            "delay",
            str(dep),
            "--values",
            "0",
            "120",
            "--output",
            str(tmp_path),
        ],
        capture_output=True,
        text=True,
        timeout=170,
    )
    assert r.returncode == 0, r.stderr[-3000:]
    folder = Path(r.stdout.strip().splitlines()[-1])
    rows = list(csv.DictReader((folder / "sweep.csv").read_text().splitlines()))
    assert [(float(x["value"]), x["deputy"]) for x in rows] == [(0.0, "lqr"), (120.0, "lqr")]
    assert all(x["completed"] == "True" and x["late"] == "0" for x in rows)
    assert int(rows[0]["delayed"]) == 0 and int(rows[1]["delayed"]) > 0
    assert (folder / "sweep.png").stat().st_size > 0
    assert "| delay (s) |" in (folder / "sweep.md").read_text()
    # in one process, its links emulated as the buses have them: the same figures, to the
    # digit; of the links' tallies, only what the messages in flight at the end add differs
    # (the services' final counters are sent while the last messages travel)
    inproc, _ = sweep("delay", str(dep), [0.0, 120.0], str(tmp_path / "in"), in_process=True)
    in_rows = list(csv.DictReader((inproc / "sweep.csv").read_text().splitlines()))
    tallies = ("dropped", "delayed")
    for a, b in zip(in_rows, rows, strict=True):
        assert {k: v for k, v in a.items() if k not in tallies} == {
            k: v for k, v in b.items() if k not in tallies
        }
        # in flight at the end: up to 120 s of samples (every 10 s) and commands (every 60 s)
        # not yet offered to their link; the final step's command the environment may take
        assert -1 <= int(a["delayed"]) - int(b["delayed"]) <= 120 / 10 + 120 / 60


@pytest.mark.integration  # flies a two-orbit mission
def test_a_point_no_attitude_can_hold_is_stated_before_its_run(
    tmp_path: Path, capsys: pytest.CaptureFixture, monkeypatch: pytest.MonkeyPatch
) -> None:
    """At 0.7 x the nominal area no attitude within |sigma3| <= 0.2 matches the chief's drag:
    the sweep says so before it flies that point, and marks every deputy's row."""
    import services.flight.inprocess as inprocess

    fly, before_run = inprocess.run_in_process, []

    def spy(dep, timing=None):
        before_run.append(capsys.readouterr().err)  # what was said before the mission flew
        return fly(dep, timing)

    monkeypatch.setattr(inprocess, "run_in_process", spy)
    deployment = str(Path(__file__).parents[2] / "deployments" / "realistic-nav.toml")
    argv = [
        "sweep",
        "noise",
        deployment,
        "--values",
        "1",
        "--mismatch",
        "0.7",
        "--orbits",
        "2",
        "--in-process",
        "--output",
        str(tmp_path),
    ]
    main(argv)
    (said,) = before_run
    names = [d["name"] for d in read_table("realistic-nav")["deputy"]]
    for name in names:
        assert (
            f"ddvi sweep: noise = 1 m, mismatch = 0.7: warning: deputy {name!r} cannot hold a slot"
            in said
        )
    out = capsys.readouterr().out
    folder = Path(out.strip().splitlines()[-1])
    rows = list(csv.DictReader((folder / "sweep.csv").read_text().splitlines()))
    assert [r["deputy"] for r in rows] == names
    for r in rows:
        assert r["can_hold"] == "False"
        assert r["note"].startswith(f"deputy {r['deputy']!r} cannot hold a slot")
    assert "| can hold slot |" in out and out.count("| yes | no |") == len(names)


def test_a_point_predicted_to_reenter_is_stated_before_any_run_flies(
    tmp_path: Path, capsys: pytest.CaptureFixture, monkeypatch: pytest.MonkeyPatch
) -> None:
    """realistic-nav-2x at 1.25x for 30 orbits re-enters at orbit 27.2 when flown: the sweep
    predicts it before the first run flies, for that point only."""
    import services.ground.sweeps.sweep as sweep_module

    class StopError(Exception):
        pass

    def stop(point, dep):
        raise StopError(capsys.readouterr().err)

    monkeypatch.setattr(sweep_module, "inprocess_rows", stop)
    argv = ["sweep", "noise", "realistic-nav-2x", "--values", "1", "--mismatch", "1", "1.25"]
    with pytest.raises(StopError) as said:
        main([*argv, "--orbits", "30", "--in-process", "--output", str(tmp_path)])
    (line,) = [x for x in str(said.value).splitlines() if "re-enter" in x]
    assert line.startswith(
        "ddvi sweep: noise = 1 m, mismatch = 1.25: warning: the chief is predicted to re-enter"
    )
    assert "of the mission's 30" in line


def test_noisy_table_sets_noise_and_scales_the_truth_as_mismatch_2x_does() -> None:
    table = read_table(None)
    dep = deployment_from_table(noisy_table(table, 1.0, 2.0))
    assert dep.environment.density_factor == 2.0
    for d in dep.deputy:
        assert d.area_factor == 2.0
        assert d.navigation.position_noise == 1.0
        assert d.navigation.velocity_noise == pytest.approx(VELOCITY_NOISE_RATIO)
    # the same truth as deployments/mismatch-2x.toml: the same true K*
    reference = load_deployment("mismatch-2x")
    np.testing.assert_allclose(
        true_lqr_gains(dep, dep.deputy[0])[0], true_lqr_gains(reference, reference.deputy[0])[0]
    )
    assert table["environment"]["density_factor"] == 1.0  # the input is left alone


def test_sweep_points_give_each_mismatch_its_orbits_and_refuse_a_wrong_count() -> None:
    table = read_table(None)
    runs = sweep_points("noise", table, [0.0, 1.0], [1.0, 2.0], [40.0, 30.0])
    assert [(p["noise"], p["mismatch"], t["run"]["orbits"]) for p, t, _ in runs] == [
        (0.0, 1.0, 40.0),
        (1.0, 1.0, 40.0),
        (0.0, 2.0, 30.0),
        (1.0, 2.0, 30.0),
    ]
    assert len({t["run"]["name"] for _, t, _ in runs}) == 4
    with pytest.raises(ValueError, match="one per --mismatch"):
        sweep_points("noise", table, [0.0], [1.0, 2.0], [40.0, 30.0, 20.0])
    with pytest.raises(ValueError, match="sweep noise"):
        sweep_points("delay", table, [0.0], [2.0])


@pytest.mark.integration  # flies four short missions
def test_short_noise_and_mismatch_sweep_in_process(tmp_path: Path) -> None:
    """Two orbits of the default mission at 0 and 1 m noise, nominal and 2x: the LQR rows are
    scored against the truth's K* (0 nominal, 0.68 at 2x: the nominal gain is that far from
    the truth's), the noise reaches the controllers, and the table and plot are written."""
    folder, rows = sweep(
        "noise", None, [0.0, 1.0], str(tmp_path), 2.0, mismatches=[1.0, 2.0], in_process=True
    )
    assert [(r["noise"], r["mismatch"], r["deputy"]) for r in rows] == [
        (v, f, d) for f in (1.0, 2.0) for v in (0.0, 1.0) for d in ("lqr", "ddvi")
    ]
    assert all(r["completed"] for r in rows)
    lqr = {(r["noise"], r["mismatch"]): r["gain_error"] for r in rows if r["deputy"] == "lqr"}
    dep = load_deployment("mismatch-2x")
    K, K_true = lqr_gains(dep, dep.deputy[0])[0], true_lqr_gains(dep, dep.deputy[0])[0]
    gap = np.linalg.norm(K - K_true) / np.linalg.norm(K_true)
    assert lqr == {(0.0, 1.0): 0.0, (1.0, 1.0): 0.0, (0.0, 2.0): gap, (1.0, 2.0): gap}
    ddvi = [r for r in rows if r["deputy"] == "ddvi"]
    assert not any(r["learned"] for r in ddvi) and all(r["gain_error"] is None for r in ddvi)
    assert all(r["note"] == "no learning attempt" for r in ddvi)  # it learns at orbit 15
    for path in (folder / "deployments").glob("noise-1-*.toml"):  # what the runs flew
        assert {d.navigation.position_noise for d in load_deployment(str(path)).deputy} == {1.0}
    csv_rows = list(csv.DictReader((folder / "sweep.csv").read_text().splitlines()))
    assert len(csv_rows) == 8 and csv_rows[0]["noise"] == "0.0"
    assert "| nav noise (m) | mismatch |" in (folder / "sweep.md").read_text()
    assert (folder / "sweep.png").stat().st_size > 0
    assert len(list((folder / "deployments").glob("*.toml"))) == 4
    assert len(list((folder / "deployments").glob("noise-1-*.toml"))) == 2
