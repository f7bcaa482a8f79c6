"""What ``ddvi bench`` prints: its table shows every text literally, its ``--json`` is valid
JSON (a value not measured is null), and a ratio with a target gets a met/missed verdict."""

from __future__ import annotations

import argparse
import json
import math
import sys

import pytest

from benchmarks import run as bench


def _row(metric: str, ratio: float, target: str) -> dict:
    return {
        "benchmark": "fake",
        "metric": metric,
        "unit": "s",
        "project": ratio,
        "baseline": 1.0,
        "baseline_name": "plain [bold]",
        "cost_ratio": ratio,
        "target": target,
    }


ROWS = [
    _row("skipped: Basilisk is not installed (pip install -e '.[basilisk]')", math.nan, ""),
    _row("within", 1.2, "<= 1.3"),
    _row("beyond", 4.1, "<= 2x; 40 orbits < 30 s"),
    _row("not a ratio target", 9.0, "|dK|/|K*| < 0.01"),
]


@pytest.fixture
def fake_benchmarks(monkeypatch: pytest.MonkeyPatch) -> None:
    def explode(quick: bool) -> list[dict]:
        raise RuntimeError("no [cluster] here")

    monkeypatch.setattr(bench, "BENCHMARKS", {"fake": "fake", "broken": "broken"})
    loaders = {"fake": lambda quick: [dict(r) for r in ROWS], "broken": explode}
    monkeypatch.setattr(bench, "_load", loaders.__getitem__)


def _args(**kw: object) -> argparse.Namespace:
    return argparse.Namespace(**{"quick": True, "json": False, "only": None, **kw})


def test_a_ratio_with_a_target_gets_a_verdict() -> None:
    assert [bench.verdict(r) for r in ROWS] == [None, "met", "missed", None]
    assert bench.verdict({"target": "<= 1.3", "cost_ratio": math.nan}) == "missed"
    assert bench.verdict({"target": "> 2", "cost_ratio": 3.0}) == "met"


def test_a_figure_with_a_target_in_its_unit_gets_a_verdict() -> None:
    memory = {"unit": "MB", "project": 334.0, "cost_ratio": 3.5}
    assert bench.verdict({**memory, "target": "<= 350 MB"}) == "met"
    assert bench.verdict({**memory, "target": "<= 300 MB"}) == "missed"
    assert bench.verdict({"unit": "s", "project": 2.58, "target": "< 2 s"}) == "missed"
    assert bench.verdict({"unit": "s", "project": math.nan, "target": "< 2 s"}) == "missed"
    assert bench.verdict({**memory, "target": "< 2 s"}) is None  # another unit


def test_json_is_valid_and_a_value_not_measured_is_null(
    fake_benchmarks: None, capsys: pytest.CaptureFixture
) -> None:
    assert bench.run(_args(json=True)) == 0
    text = capsys.readouterr().out
    doc = json.loads(text, parse_constant=lambda c: pytest.fail(f"{c} is not JSON"))
    rows = doc["rows"]
    assert rows[0]["project"] is None and rows[0]["cost_ratio"] is None
    assert [r["verdict"] for r in rows[:4]] == [None, "met", "missed", None]
    failed = rows[4]
    assert failed["metric"] == "FAILED: no [cluster] here" and failed["project"] is None


def test_the_table_shows_brackets_literally(
    fake_benchmarks: None, capsys: pytest.CaptureFixture
) -> None:
    assert bench.run(_args()) == 0
    out = capsys.readouterr().out
    assert "pip install -e '.[basilisk]'" in out
    assert "plain [bold]" in out and "FAILED: no [cluster] here" in out
    assert "| met" in out.replace("│", "|") and "| missed" in out.replace("│", "|")


def test_quick_bench_without_the_optional_packages_skips_and_lists_them(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture
) -> None:
    """A plain installation (no test extra, no Basilisk), as ``ddvi bench --quick`` meets it:
    the live benchmark's client and the Basilisk truth cannot be imported.  Each is skipped
    before anything is launched, its row and the list after the table say why, and the
    command completes."""
    from benchmarks import live
    from services.cli import main

    for module in ("websockets", "Basilisk"):
        monkeypatch.setitem(sys.modules, module, None)  # `import` raises ImportError

    def launched(*args: object, **kw: object) -> None:
        raise AssertionError(f"a skipped benchmark launched {args}")

    monkeypatch.setattr(live.subprocess, "Popen", launched)
    assert main(["bench", "--quick", "--only", "live", "basilisk"]) == 0
    out = capsys.readouterr().out
    said = {
        "live": "websockets (the benchmark's Foxglove client) is not installed "
        "(pip install -e '.[test]')",
        "basilisk": "Basilisk is not installed (pip install -e '.[basilisk]')",
    }
    listed = out.split("skipped 2 benchmarks:\n", 1)[1].splitlines()
    assert listed == [f"  {name}: {why}" for name, why in said.items()]
    assert main(["bench", "--quick", "--json", "--only", "live", "basilisk"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["meta"]["skipped"] == said
    assert [r["metric"] for r in doc["rows"]] == [f"skipped: {why}" for why in said.values()]
