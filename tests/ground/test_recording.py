"""The monitor's recording in one process: JSON schemas, and a file written and read back."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from services.ground.recording import Recorder, message_json_schema, ns, read_recording
from services.interface import SCHEMAS, MessageError, decode, encode, topics


def test_every_schema_has_a_json_schema() -> None:
    for spec in SCHEMAS.values():
        js = message_json_schema(spec)
        assert js["title"] == f"ddvi.{spec.name}"
        assert set(js["properties"]["body"]["required"]) == set(spec.fields)
    gains = message_json_schema(SCHEMAS["gains"])["properties"]["body"]["properties"]["K"]
    assert gains["items"]["items"] == {"type": "number"}


def test_simulation_time_as_mcap_nanoseconds_is_clamped() -> None:
    assert ns(1.5) == 1_500_000_000
    assert ns(-1.0) == 0 and ns(float("nan")) == 0
    assert ns(1e30) == 2**64 - 1


def test_a_recording_reads_back_message_rejection_and_liveliness(tmp_path: Path) -> None:
    body = {
        "sc": "alpha",
        "x_hill": np.arange(6.0),
        "z_hill": np.arange(6.0) + 0.5,
        "cov": np.eye(6),
        "altitude": 300e3,
        "valid": True,
    }
    msg = decode(encode("nav", body, seq=4, t=12.5, src="nav-alpha"), "nav")
    rec = Recorder(tmp_path / "recording.mcap", {"run": "r"}, attachment=None)
    rec.message(topics.nav_state_topic("alpha"), msg, log_ns=10**18)
    rec.rejected("junk", "ddvi/r/junk", b"\x00\x01", MessageError("malformed", "bad"), 2, 12.5)
    rec.alive("nav-alpha", False, 3, 12.5)
    rec.close()
    rec.close()  # closed exactly once
    messages, complete = read_recording(tmp_path / "recording.mcap")
    assert complete and rec.messages == 3
    nav, rejected, alive = messages
    assert (nav.topic, nav.schema, nav.publish_time) == ("nav/alpha/state", "ddvi.nav", ns(12.5))
    assert nav.data["body"]["x_hill"] == list(range(6)) and nav.data["seq"] == 4
    assert rejected.topic == "rejected/junk" and rejected.data["reason"] == "malformed"
    assert rejected.data["payload_b64"] == "AAE=" and rejected.data["truncated"] is False
    assert alive.topic == "alive/nav-alpha"
    assert alive.data == {"service": "nav-alpha", "alive": False}
