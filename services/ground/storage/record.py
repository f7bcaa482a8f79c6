"""Whether a run's record is whole, and what it lacks when it is not.

The record is whole when the recording holds the run from start to end and every message a
service's stats say it sent is in it.  It is not when:

- messages were published and never recorded (``unrecorded``: a service's believed stats against
  what arrived from it, ``services.ground.analysis.claims``);
- samples were still queued when the recording closed (``queued_at_close``: the monitor records
  its backlog for a bounded time only);
- the recording stopped before the run ended (``recording``: its disk was nearly full, or a
  write failed; ``RecordingStop``);
- ``ddvi report`` read a recording cut short, up to its last complete chunk (``cut_short``).

``record_block`` is summary.json's ``outcome.record``; ``record_line`` says it on report.md's
first lines; a completed run whose record is not whole exits 3, one whose recording stopped 1
(``services.ground.launch.lifecycle.verdict``).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from services.ground.storage.disk import size_text


@dataclass(frozen=True)
class RecordingStop:
    """The recording stopped before the run ended: its disk was nearly full (``footer``: it
    was closed whole, summary and footer written) or a write failed (it is cut back to its
    last whole record: ``ddvi report`` repairs it where there is room)."""

    path: str
    why: str  # in a few words: the disk nearly full, or the error of the write that failed
    space_left: int | None  # bytes left on its disk when it stopped
    at_t: float  # simulated time of the last message in the file, s
    messages: int  # messages in the file
    footer: bool


@dataclass(frozen=True)
class RecordGaps:
    """What the recorder knows the record lacks (the stats' account is the report's)."""

    recording: RecordingStop | None = None  # the recording stopped before the run ended
    not_recorded: int = 0  # messages received after it stopped, or lost when it was cut
    queued_at_close: int = 0  # samples still queued when the recording closed
    cut_short: bool = False  # the report is from a recording cut short (``ddvi report``)


def record_block(gaps: RecordGaps, unrecorded: Mapping[str, int]) -> dict[str, Any]:
    """summary.json's ``outcome.record`` (see the module's docstring)."""
    stop = gaps.recording
    recording = None
    if stop is not None:
        recording = {
            "file": stop.path,
            "stopped_at_s": stop.at_t,
            "messages": stop.messages,
            "footer": stop.footer,
            "why": stop.why,
            "space_left_bytes": stop.space_left,
            "not_recorded": gaps.not_recorded,
        }
    lost = {k: int(v) for k, v in sorted(unrecorded.items()) if v}
    return {
        "complete": not (lost or gaps.queued_at_close or recording or gaps.cut_short),
        "unrecorded": lost,
        "queued_at_close": gaps.queued_at_close,
        "recording": recording,
        "cut_short": gaps.cut_short,
    }


def gaps_text(record: Mapping[str, Any]) -> str:
    """What the record lacks, in words ("" when it is whole)."""
    said = []
    if (stop := record.get("recording")) is not None:
        said.append(
            f"{stopped_text(stop)}; {stop['not_recorded']} messages received after it are not in it"
        )
    if lost := record.get("unrecorded"):
        by = ", ".join(f"{n} from {pub}" for pub, n in lost.items())
        said.append(f"{sum(lost.values())} messages published and never recorded ({by})")
    if n := record.get("queued_at_close"):
        said.append(f"{n} samples still queued when the recording closed are not in it")
    if record.get("cut_short"):
        said.append("the recording was cut short: read up to its last complete chunk")
    return "; ".join(said)


def stopped_text(stop: Mapping[str, Any]) -> str:
    """A recording that stopped: when, why, the space left, what it holds."""
    path = Path(stop["file"])
    how = "closed whole" if stop["footer"] else "cut short: `ddvi report` repairs it"
    return (
        f"the recording stopped at t = {stop['stopped_at_s']:.0f} s: {stop['why']}, "
        f"{size_text(stop['space_left_bytes'])} left on {path.parent}; {path.name} holds "
        f"{stop['messages']} messages ({how})"
    )


def record_line(record: Mapping[str, Any], source: str) -> str:
    """report.md's line on the record; ``source``: what the report's figures are from."""
    if record.get("complete", True):
        return "- record: whole (every message its publishers say they sent is recorded)"
    return f"- record: **incomplete**: {gaps_text(record)}; this report is from {source}"


def stop_text(record: Mapping[str, Any], written: list[str], missing: list[str]) -> str:
    """``ddvi run``'s one line on a recording that stopped: when, why, the space left, what
    was saved there, and what was not."""
    said = f"{stopped_text(record['recording'])}; also saved there: {', '.join(written)}"
    return f"{said}; not written: {', '.join(missing)}" if missing else said
