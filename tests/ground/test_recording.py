"""The monitor's recording in one process: JSON schemas, and a file written and read back."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from services.ground.storage.recording import Recorder, message_json_schema, ns, read_recording
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
    rec.message(topics.nav_state_topic("alpha"), msg, recv_ns=10**18)
    rec.rejected("junk", "ddvi/r/junk", b"\x00\x01", MessageError("malformed", "bad"), 2, 12.5)
    rec.alive("nav-alpha", False, 3, 12.5)
    rec.close()
    rec.close()  # closed exactly once
    messages, complete = read_recording(tmp_path / "recording.mcap")
    assert complete and rec.messages == 3
    nav, rejected, alive = messages
    assert (nav.topic, nav.schema) == ("nav/alpha/state", "ddvi.nav")
    # the timeline is simulation time; the receive wall time is the publish time
    assert (nav.log_time, nav.publish_time) == (ns(12.5), 10**18)
    assert (rejected.log_time, rejected.publish_time) == (ns(12.5), 2)
    assert nav.data["body"]["x_hill"] == list(range(6)) and nav.data["seq"] == 4
    assert rejected.topic == "rejected/junk" and rejected.data["reason"] == "malformed"
    assert rejected.data["payload_b64"] == "AAE=" and rejected.data["truncated"] is False
    assert alive.topic == "alive/nav-alpha"
    assert alive.data == {"service": "nav-alpha", "alive": False}


def test_a_recorded_message_of_an_older_version_is_upgraded_on_replay() -> None:
    """A nav message recorded before the measurement and covariance fields replays with the
    estimate as its measurement and a zero covariance; a current one replays as recorded."""
    from services.ground.analysis.replay import _counters, _message

    old = {
        "schema": "nav",
        "version": 1,
        "seq": 3,
        "t": 10.0,
        "src": "nav-alpha",
        "body": {
            "sc": "alpha",
            "x_hill": [1.0, 2.0, 3.0, 0.1, 0.2, 0.3],
            "altitude": 3e5,
            "valid": True,
        },
    }
    counters = _counters()
    msg = _message("nav/alpha/state", old, counters)
    assert counters["rejected"] == 0 and msg.version == SCHEMAS["nav"].version
    assert np.array_equal(msg.body["z_hill"], msg.body["x_hill"]) and not msg.body["cov"].any()
    current = {
        **old,
        "version": SCHEMAS["nav"].version,
        "body": {**old["body"], "z_hill": [0.0] * 6, "cov": np.eye(6).tolist()},
    }
    msg = _message("nav/alpha/state", current, counters)
    assert not msg.body["z_hill"].any() and msg.body["cov"][0, 0] == 1.0
    broken = {**old, "body": {"sc": "alpha"}}  # no upgrade makes this a nav message
    assert _message("nav/alpha/state", broken, counters) is None and counters["rejected"] == 1
    assert _message("nav/alpha/state", {**old, "body": [1.0]}, counters) is None  # not a map
    newer = {**current, "version": SCHEMAS["nav"].version + 1}  # a later version's: unreadable
    assert _message("nav/alpha/state", newer, counters) is None
    cmd = {
        "schema": "cmd",
        "version": 0,
        "seq": 1,
        "t": 10.0,
        "src": "ctrl-alpha",
        "body": {"sc": "alpha", "sigma": [0.0, 0.0, 0.1], "for_t": 10.0},
    }
    assert _message("cmd/alpha/att", cmd, counters) is None  # an old one with no upgrade
    assert counters["rejected"] == 4 and counters["rejected.version"] == 2


def test_replay_reads_the_receive_wall_time_where_the_recording_keeps_it() -> None:
    """A recording whose metadata says its timeline is simulation time keeps the receive wall
    time in publish_time; one made before keeps it in log_time."""
    from mcap.records import Metadata

    from services.ground.analysis.recover import Records
    from services.ground.analysis.replay import _receive_wall_time
    from services.ground.storage.recording import TIMELINE

    now = Records(metadata=[Metadata(name="ddvi", metadata={"run": "r", **TIMELINE})])
    before = Records(metadata=[Metadata(name="ddvi", metadata={"run": "r"})])
    assert _receive_wall_time(now) == "publish_time"
    assert _receive_wall_time(before) == "log_time"
