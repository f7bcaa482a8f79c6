"""The live view's floor: foxglove-sdk's server alone serves every message of a recording to a
client of every channel, and says what it took."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

pytest.importorskip("foxglove")
pytest.importorskip("websockets")

from mcap.writer import Writer

from benchmarks.live_floor import measure_floor


def _recording(path: Path, messages: int) -> None:
    """A recording of two JSON channels, ``messages`` messages each."""
    with open(path, "wb") as f:
        writer = Writer(f)
        writer.start()
        schema = json.dumps({"type": "object"}).encode()
        channels = []
        for n, topic in enumerate(("clock", "nav/lqr/state")):
            schema_id = writer.register_schema(f"ddvi.s{n}", "jsonschema", schema)
            channels.append(writer.register_channel(topic, "json", schema_id))
        for k in range(messages):
            for channel_id in channels:
                data = json.dumps({"t": 10.0 * k, "body": {"k": k}}).encode()
                writer.add_message(channel_id, log_time=k, publish_time=k, data=data)
        writer.finish()


@pytest.mark.integration
def test_the_floor_serves_every_recorded_message_to_a_client_and_says_its_cpu(
    tmp_path: Path,
) -> None:
    path = tmp_path / "recording.mcap"
    _recording(path, 500)
    floor = measure_floor(path)
    assert floor["served"] == 1000
    assert floor["received"] == 1000  # fewer than the backlog: nothing dropped
    assert floor["cpu_s"] > 0


def test_the_floor_rows_average_the_rounds_and_say_what_the_live_view_took_above_them() -> None:
    from benchmarks.live import floor_rows

    def run(wall: float, cpu: float, monitor: float) -> dict[str, float]:
        return {"wall_s": wall, "loop_s": wall - 4.0, "run_cpu_s": cpu, "monitor_cpu_s": monitor}

    beside = [
        run(21.0, 42.0, 9.0) | {"floor": {"cpu_s": 2.0, "served": 100, "received": 100}},
        run(22.0, 43.0, 8.0) | {"floor": {"cpu_s": 1.0, "served": 100, "received": 99}},
    ]
    live = [run(21.0, 43.0, 11.0), run(21.0, 45.0, 12.0)]
    without = [run(20.0, 40.0, 9.0), run(20.0, 40.0, 8.0)]
    rows = floor_rows(40.0, beside, live, without)
    wall, loop, cpu, floor, above = rows
    assert wall["metric"].startswith("40-orbit mission, whole run, beside the floor")
    assert wall["cost_ratio"] == pytest.approx(21.5 / 20.0)
    assert loop["cost_ratio"] == pytest.approx(17.5 / 16.0)
    assert cpu["cost_ratio"] == pytest.approx(42.5 / 40.0)
    assert floor["project"] == pytest.approx(1.5)
    assert floor["cost_ratio"] == pytest.approx(1.5 / 40.0)
    assert "rounds: 2.00, 1.00" in floor["metric"]
    assert "received 99" in floor["metric"]  # the fewest any round's client got
    # the monitor's added CPU (11.5 - 8.5), not the run's (4.0): less the floor
    assert above["project"] == pytest.approx(11.5 - 8.5 - 1.5)
    assert above["cost_ratio"] == pytest.approx(1.5 / 40.0)


def test_the_live_rows_say_what_the_live_view_added_to_the_monitor_against_the_run() -> None:
    from benchmarks.live import ADDED_TARGET, _rows

    def run(monitor: float, others: float) -> dict[str, float]:
        cpu = monitor + others
        return {
            "wall_s": 20.0,
            "loop_s": 18.0,
            "run_cpu_s": cpu,
            "monitor_cpu_s": monitor,
            "others_cpu_s": others,
            "client_cpu_s": 2.0,
            "received": 110,
            "recorded": 100,
        }

    live = [run(10.0, 30.0), run(11.0, 26.0)]
    without = [run(8.0, 32.0), run(8.0, 28.0)]
    rows = {r["metric"].split(" (")[0]: r for r in _rows(40.0, "every channel", live, without)}
    added = rows["CPU the live view added to the monitor, a client of every channel"]
    assert added["project"] == pytest.approx(10.5 - 8.0)
    assert added["cost_ratio"] == pytest.approx(2.5 / 38.0)
    assert added["target"] == ADDED_TARGET
    monitor = rows["40-orbit mission, CPU of the monitor"]
    assert monitor["cost_ratio"] == pytest.approx(10.5 / 8.0)
    assert monitor["target"] == ""  # the target is the run's, not the monitor's own
