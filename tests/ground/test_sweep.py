"""ddvi sweep: the impaired deployments it derives, its table, and a short real sweep."""

from __future__ import annotations

import csv
import subprocess
import sys
from pathlib import Path

import pytest

from services.config import deployment_from_table
from services.ground.sweep import impaired_table, largest_learning_value, summary_rows

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
        return {"value": value, "controller": "ddvi", "learned": learned, "completed": True,
                "gain_error_vs_lqr": error if learned else None}  # fmt: skip

    rows = [row(0, True), row(60, True), row(120, False), row(180, True)]
    assert largest_learning_value(rows) == 60
    assert largest_learning_value([row(0, False)]) is None
    # converged, but to a gain far from the optimum: not a success
    assert largest_learning_value([row(0, True), row(60, True, error=1.2)]) == 0


@pytest.mark.integration
def test_delay_sweep_runs_each_value(tmp_path: Path) -> None:
    dep = tmp_path / "short.toml"
    dep.write_text(SHORT)
    r = subprocess.run(
        [sys.executable, "-m", "services.cli", "sweep", "delay", str(dep), "--values", "0",
         "120", "--output", str(tmp_path)],
        capture_output=True,
        text=True,
        timeout=170,
    )  # fmt: skip
    assert r.returncode == 0, r.stderr[-3000:]
    folder = Path(r.stdout.strip().splitlines()[-1])
    rows = list(csv.DictReader((folder / "sweep.csv").read_text().splitlines()))
    assert [(float(x["value"]), x["deputy"]) for x in rows] == [(0.0, "lqr"), (120.0, "lqr")]
    assert all(x["completed"] == "True" and x["late"] == "0" for x in rows)
    assert int(rows[0]["delayed"]) == 0 and int(rows[1]["delayed"]) > 0
    assert (folder / "sweep.png").stat().st_size > 0
    assert "| delay (s) |" in (folder / "sweep.md").read_text()


def test_a_fallback_to_old_gains_is_not_learning() -> None:
    """A deputy whose re-learning fell back to its old gains is flying learned gains, but not
    ones learned for the plant it has: the sweep does not count it as learned."""
    deputy = {
        "controller": "ddvi", "phase": "learned", "final_along_track_error_m": 673.0,
        "max_along_track_error_last_orbit_m": 3363.0, "learned_at_orbits": 15.0,
        "gain_error_vs_lqr": 0.003, "gains": {"source": "fallback"},
    }  # fmt: skip
    summary = {"completed": True, "messages": {"services": {}}, "deputies": {"ddvi": deputy}}
    (row,) = summary_rows(0.0, summary)
    assert row["learned"] is False and row["gain_error_vs_lqr"] is None
    deputy["gains"] = {"source": "ddvi"}
    (row,) = summary_rows(0.0, summary)
    assert row["learned"] is True and row["gain_error_vs_lqr"] == 0.003
