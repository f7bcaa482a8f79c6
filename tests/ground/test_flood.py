"""A flood from a stolen credential against a running mission (``benchmarks.flood``, shorter):
the excess is dropped unread, the monitor's memory stays bounded, the recording reads with the
standard mcap reader, the deputies the credential does not own fly as without the flood, and
the run names the flooding service and exits 3."""

from __future__ import annotations

from pathlib import Path

import pytest

from benchmarks.flood import ATTACKS, Outcome, deployment, run_attack

pytestmark = pytest.mark.integration

ORBITS = 8.0  # long enough to be flying for the whole flood
SECONDS = 3.0  # the closing measurement is benchmarks/flood.py's 10 s


@pytest.fixture(scope="module")
def clean(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Outcome]:
    root = tmp_path_factory.mktemp("flood")
    dep = deployment(root, ORBITS)
    return dep, run_attack(dep, root / "clean", None)


@pytest.mark.parametrize("batch", [1, 64])
@pytest.mark.parametrize("kind", sorted(ATTACKS))
def test_a_flood_is_dropped_named_and_changes_nothing_else(
    clean: tuple[Path, Outcome], tmp_path: Path, kind: str, batch: int
) -> None:
    dep, base = clean
    assert base.status == 0 and base.summary["outcome"]["flooded"] == {}
    user = ATTACKS[kind]
    flooded = run_attack(dep, tmp_path / "run", kind, batch, SECONDS)
    assert flooded.sent["messages"] > 10_000, flooded.sent  # it did flood
    assert flooded.status == 3, flooded.said
    assert f"flooded by {user}" in flooded.said
    dropped = flooded.summary["outcome"]["flooded"]
    assert set(dropped) == {user} and dropped[user]["monitor"] > 1000, dropped
    if kind == "cmd":
        assert dropped[user]["environment"] > 1000  # dropped at the receiver it aimed at
    report = next((tmp_path / "run").glob("*/report.md")).read_text()
    assert f"flooded by {user}" in report
    assert flooded.summary["completed"] is True and flooded.readable
    assert flooded.monitor_peak <= 1.5 * base.monitor_peak, (flooded.monitor_peak, base)
    others = [sc for sc in base.summary["deputies"] if not user.endswith(f"-{sc}")]
    assert others
    for sc in others:
        assert flooded.summary["deputies"][sc] == base.summary["deputies"][sc]
