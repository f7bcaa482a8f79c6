"""``ddvi monitor``'s lines, in one process (the command on a hub: test_monitor.py)."""

from __future__ import annotations

from services.ground.monitoring.tap import format_sample
from services.interface import encode, pack_batch


def test_a_batch_prints_one_line_per_message_and_garbage_its_reason() -> None:
    clock = {"step": 1, "dt": 10.0, "fsw": True, "mode": "lockstep", "final": False}
    parts = [encode("clock", clock, seq=k, t=10.0 * k, src="environment") for k in (1, 2)]
    lines = format_sample("ddvi/r/clock", pack_batch(parts))
    assert [ln.split(" src=")[0] for ln in lines] == [
        "ddvi/r/clock clock t=10.000",
        "ddvi/r/clock clock t=20.000",
    ]
    assert lines[1].startswith("ddvi/r/clock clock t=20.000 src=environment seq=2 {")
    assert "REJECTED malformed" in format_sample("k", b"\x00\x01")[0]
