"""A report written from an incomplete record says so on its first lines, and the run's exit
status says it too: messages a service published and the ground never received, samples still
queued when the recording closed, a recording cut short; a whole record says that it is."""

from __future__ import annotations

from pathlib import Path

from services.config import deployment_from_table
from services.ground.analysis.report import write_report
from services.ground.analysis.rundata import RunData
from services.ground.launch.lifecycle import EXIT_DEGRADED, EXIT_FAILED, EXIT_OK, verdict
from services.ground.storage.record import RecordGaps
from services.interface import decode, encode, topics

DEP = deployment_from_table({"run": {"orbits": 0.05}, "deputy": [{"name": "alpha"}]})


def _message(data: RunData, topic: str, schema: str, body: dict, t: float, src: str) -> None:
    """As the monitor takes a message: received (counted against its publisher), then used."""
    msg = decode(encode(schema, body, seq=int(t), t=t, src=src, boot=7), schema)
    data.received(msg)
    data.ingest(topic, msg)


def _run(lost: int) -> RunData:
    """A run that completed, whose nav-alpha published ``lost`` messages more than arrived."""
    data = RunData(DEP, "r")
    for k in range(5):
        body = {"service": "nav-alpha", "level": "info", "text": "x"}
        _message(data, topics.log_topic("nav-alpha"), "log", body, float(k), "nav-alpha")
    stats = {"service": "nav-alpha", "counters": {"sent": 5 + lost}}
    _message(data, topics.stats_topic("nav-alpha"), "stats", stats, 10.0, "nav-alpha")
    clock = {"step": 1, "dt": 10.0, "fsw": True, "mode": "lockstep", "final": True}
    _message(data, topics.CLOCK, "clock", clock, data.duration, "environment")
    return data


def _first_lines(out: Path) -> list[str]:
    return (out / "report.md").read_text().splitlines()[:6]


def test_messages_published_and_never_recorded_are_said_first_and_make_it_exit_3(
    tmp_path: Path,
) -> None:
    summary = write_report(tmp_path, _run(lost=3), completed=True, monitor_counters={})
    assert summary["completed"] is True
    record = summary["outcome"]["record"]
    assert record["complete"] is False and record["unrecorded"] == {"nav-alpha": 3}
    said = "- record: **incomplete**: 3 messages published and never recorded (3 from nav-alpha)"
    assert any(line.startswith(said) for line in _first_lines(tmp_path)), _first_lines(tmp_path)
    status, line = verdict(summary)
    assert status == EXIT_DEGRADED
    assert "the record is incomplete: 3 messages published and never recorded" in line


def test_a_whole_record_says_so_and_what_the_recorder_lost_is_said_first(tmp_path: Path) -> None:
    whole = write_report(tmp_path / "a", _run(lost=0), completed=True, monitor_counters={})
    assert whole["outcome"]["record"]["complete"] is True
    assert "- record: whole (every message its publishers say they sent is recorded)" in (
        _first_lines(tmp_path / "a")
    )
    assert verdict(whole)[0] == EXIT_OK
    gaps = RecordGaps(queued_at_close=4, cut_short=True)
    source = "the 12 messages read from the recording"
    cut = write_report(
        tmp_path / "b", _run(lost=0), completed=True, monitor_counters={}, gaps=gaps, source=source
    )
    first = "\n".join(_first_lines(tmp_path / "b"))
    assert "4 samples still queued when the recording closed are not in it" in first
    assert "the recording was cut short: read up to its last complete chunk" in first
    assert "this report is from the 12 messages read from the recording" in first
    assert verdict(cut)[0] == EXIT_DEGRADED
    assert verdict({**cut, "completed": False})[0] == EXIT_FAILED


def test_no_report_says_why_the_space_left_and_what_is_saved(tmp_path: Path) -> None:
    from services.ground.launch.lifecycle import no_report

    (tmp_path / "logs").mkdir()
    (tmp_path / "logs" / "monitor.log").write_text(
        "2026-01-01 00:00:00,000 monitor ERROR no report: /x/report.md: no room for its 2.4 KB "
        "(0 B left on /x)\n"
    )
    (tmp_path / "recording.mcap").write_bytes(b"\0" * 1500)
    said = no_report(tmp_path, 1)
    assert said.startswith("monitor exited with status 1; no report (/x/report.md: no room for")
    assert f"left on {tmp_path}; saved there: recording.mcap (1.5 KB)" in said
