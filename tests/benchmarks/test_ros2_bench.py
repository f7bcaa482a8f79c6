"""The ROS 2 benchmark in its quickest form: the bridge's delay in lock-step and real time, per
step, against the built-in deputy's in the same run, and the cost rows of alternated runs with
and without ``--ros2``; and its skipped row where a package it needs is missing."""

from __future__ import annotations

import math

import pytest

from benchmarks import ros2


def test_the_ros2_benchmark_is_skipped_with_the_reason_when_a_package_is_missing(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setitem(ros2.NEEDS, "no_such_module_here", "no-such-package (the reason)")
    (row,) = ros2.bench_ros2(quick=True)
    assert row["benchmark"] == "ros2"
    assert "no-such-package (the reason) is not installed" in row["skipped"]
    assert math.isnan(row["project"])


@pytest.mark.integration  # four short missions: two with the example node, one pair for cost
def test_the_ros2_benchmark_gives_the_delay_per_step_and_the_cost_rows() -> None:
    pytest.importorskip("zenoh_ros2_sdk")
    pytest.importorskip("rosbags")
    rows = ros2.bench_ros2(quick=True, delay_orbits=0.5, cost_orbits=0.5, pairs=1)
    assert {r["benchmark"] for r in rows} == {"ros2"}
    assert not any(r["metric"].startswith(("skipped", "FAILED")) for r in rows)
    delays = [r for r in rows if r["unit"] == "ms"]
    assert len(delays) == 6
    for mode, group in (("lock-step", delays[:3]), ("real time", delays[3:])):
        assert [r["metric"].split(", ")[1] for r in group] == ["p50", "p95", "max"], mode
        assert all(r["metric"].startswith(mode) for r in group)
        assert all(r["baseline_name"] == "the built-in LQR deputy, same run" for r in group)
        # every step the node commanded was matched with its navigation sample
        steps = int(group[0]["metric"].rsplit("(", 1)[1].split(" steps")[0])
        assert steps >= 40
        p50, p95, top = (r["project"] for r in group)
        assert 0 < p50 <= p95 <= top
        assert all(math.isfinite(r["cost_ratio"]) for r in group)
    assert "commands late" in delays[3]["metric"]
    costs = [r for r in rows if r["unit"] == "s"]
    assert len(costs) == 5
    assert all(r["baseline_name"] == "without --ros2" and r["target"] == ros2.TARGET for r in costs)
    assert all("0.5-orbit mission" in r["metric"] and "(runs: " in r["metric"] for r in costs)
    assert all(r["project"] > 0 and r["baseline"] > 0 for r in costs)
    run_cpu, every_cpu = costs[1], costs[2]
    assert every_cpu["project"] >= run_cpu["project"]  # the ROS 2 side's CPU on top
    assert every_cpu["baseline"] == run_cpu["baseline"]  # nothing but the run without
    floor_wall, floor_cpu = costs[3], costs[4]
    assert all("--ros2 and no subscriber" in r["metric"] for r in (floor_wall, floor_cpu))
    assert floor_cpu["baseline"] == run_cpu["baseline"]  # against the same runs without
    (received,) = [r for r in rows if r["unit"] == "count"]
    assert received["metric"] == "ROS 2 messages the subscriber received"
    assert received["project"] > 100 and received["baseline"] > 100
