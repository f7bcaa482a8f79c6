"""``ddvi report RUN``: the run's report written again from its recording, recovering a
recording cut short (the monitor killed with -9: no summary, no footer).

    ddvi report RUN_FOLDER        (or a run's name under runs/)

A recording cut short is read record by record with mcap's low-level ``StreamReader`` up to
its last complete chunk; every message read is written into a new, complete MCAP file
(``recording.mcap``, which mcap's ``make_reader`` and Foxglove then open) and the original is
kept beside it as ``recording.truncated.mcap``; on a disk with no room for the copy, the
recording stays as it is, and the copy is not left in part.  The report
(``services.ground.analysis.report``) is then written from the messages, as the monitor would have:
duplicates and replays kept out, clocks from anyone but the environment not obeyed.  The
deployment is the one attached to the recording.  Exit status 0 when a report was written, 1
when the recording holds nothing usable or the report cannot be written, 2 when RUN is not a
run folder.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import sys
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.records import Attachment, Channel, Message, Metadata, Schema
from mcap.stream_reader import StreamReader
from mcap.writer import CompressionType, Writer

from services.config import Deployment, DeploymentError, deployment_from_table, load_deployment
from services.ground.analysis.report import ReportNotWrittenError
from services.ground.analysis.rundata import RunData
from services.ground.storage.disk import failure
from services.ground.storage.recording import CHUNK_SIZE, RECORDING

log = logging.getLogger("ddvi.report")

TRUNCATED = "recording.truncated.mcap"
REPAIRED = "recording.repaired.mcap"  # the repaired copy, until it replaces the recording


@dataclass
class Records:
    """What a stream read of an MCAP file found, in file order, up to the first damage."""

    schemas: dict[int, Schema] = field(default_factory=dict)
    channels: dict[int, Channel] = field(default_factory=dict)
    messages: list[Message] = field(default_factory=list)
    metadata: list[Metadata] = field(default_factory=list)
    attachments: list[Attachment] = field(default_factory=list)
    complete: bool = False  # the footer was read: nothing was cut


@dataclass(frozen=True)
class Recovered:
    """The outcome of ``recover``: messages read, whether the file was complete, the report."""

    messages: int
    complete: bool
    summary: dict[str, Any]
    unrepaired: str | None = None  # why a recording cut short could not be repaired


def stream_records(path: Path) -> Records:
    """Every record of an MCAP file read in order (chunks broken up), up to its end or its
    first damaged or cut record."""
    out = Records()
    with path.open("rb") as f:
        try:
            for record in StreamReader(f, skip_magic=False).records:
                if isinstance(record, Schema):
                    out.schemas[record.id] = record
                elif isinstance(record, Channel):
                    out.channels[record.id] = record
                elif isinstance(record, Message):
                    out.messages.append(record)
                elif isinstance(record, Metadata):
                    out.metadata.append(record)
                elif isinstance(record, Attachment):
                    out.attachments.append(record)
                elif type(record).__name__ == "Footer":
                    out.complete = True
        except Exception as exc:  # the cut tail: EndOfFile, a zstd error, a short read
            log.info("%s: read up to the damage (%s)", path, exc)
    return out


def is_complete(path: Path) -> bool:
    """Whether mcap's standard reader opens the file (its summary and footer are there)."""
    try:
        with path.open("rb") as f:
            return make_reader(f).get_summary() is not None
    except (McapError, EOFError, ValueError, OSError, AssertionError):
        return False


def rewrite(records: Records, path: Path) -> None:
    """Write ``records`` as a complete MCAP file at ``path`` (zstd chunks, as the monitor's),
    whole or not at all: nothing of it is left when a write fails (a full disk)."""
    try:
        _write(records, path)
    except OSError:
        path.unlink(missing_ok=True)
        raise


def _write(records: Records, path: Path) -> None:
    with path.open("wb") as f:
        w = Writer(f, chunk_size=CHUNK_SIZE, compression=CompressionType.ZSTD)
        w.start(profile="", library="ddvi-fsw report (recovered)")
        for m in records.metadata:
            w.add_metadata(m.name, dict(m.metadata))
        for a in records.attachments:
            w.add_attachment(a.log_time, a.create_time, a.name, a.media_type, a.data)
        sid = {k: w.register_schema(s.name, s.encoding, s.data) for k, s in records.schemas.items()}
        cid = {}
        for k, c in records.channels.items():
            cid[k] = w.register_channel(
                c.topic, c.message_encoding, sid.get(c.schema_id, 0), dict(c.metadata)
            )
        for m in records.messages:
            if m.channel_id in cid:
                w.add_message(cid[m.channel_id], m.log_time, m.data, m.publish_time, m.sequence)
        w.finish()
        f.flush()
        os.fsync(f.fileno())


def _deployment(records: Records, meta: dict[str, str]) -> Deployment:
    """The deployment attached to the recording (else the file its metadata names)."""
    for a in records.attachments:
        if a.media_type == "application/toml":
            table = tomllib.loads(a.data.decode("utf-8"))
            return deployment_from_table(table, meta.get("deployment", a.name))
    return load_deployment(meta.get("deployment") or None)


def recover(folder: Path) -> Recovered:
    """Write ``folder``'s report from its recording (repairing a recording cut short first).
    Raises FileNotFoundError without a recording, ValueError when it names no run."""
    from services.ground.analysis.replay import replay  # the report's imports: only when needed

    path = folder / RECORDING
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no recording")
    records = stream_records(path)
    complete = records.complete and is_complete(path)
    unrepaired = None
    if not complete:
        try:  # the repaired copy first: on a full disk the recording stays as it was
            rewrite(records, folder / REPAIRED)
        except OSError as exc:
            unrepaired = failure(path, exc)
            log.error("%s cannot be repaired here: %s", path, unrepaired)
        else:
            os.replace(path, folder / TRUNCATED)
            os.replace(folder / REPAIRED, path)
    dep, run = recorded_run(records, path)
    summary = replay(folder, dep, run, records)
    return Recovered(len(records.messages), complete, summary, unrepaired)


def recorded_run(records: Records, path: Path) -> tuple[Deployment, str]:
    """The deployment and the run's name the recording at ``path`` holds; ValueError when it
    names no run."""
    meta = next((dict(m.metadata) for m in records.metadata if m.name == "ddvi"), {})
    if "run" not in meta:
        raise ValueError(f"{path}: no ddvi metadata (not a ddvi recording?)")
    return _deployment(records, meta), meta["run"]


def run_data(folder: Path) -> RunData:
    """What the monitor learned of the run in ``folder``, again from its recording (read up to
    any damage, nothing written): the report's data, for its figures."""
    from services.ground.analysis.replay import replayed

    path = folder / RECORDING
    records = stream_records(path)
    dep, run = recorded_run(records, path)
    return replayed(dep, run, records)[0]


def _folder(run: str) -> Path | None:
    """A run folder by path, or by name under runs/."""
    for p in (Path(run), Path("runs") / run):
        if (p / RECORDING).is_file() or (p / TRUNCATED).is_file():
            return p
    return None


def add_report_arguments(p: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """The arguments of ``ddvi report``, for ``services.cli``."""
    p.add_argument("run", help="a run folder (ddvi run prints it), or a run's name in runs/")
    return p


def report_command(args: argparse.Namespace) -> int:
    """``ddvi report RUN``: 0 when the report was written, 1 when it could not be, 2 when RUN
    is no run folder."""
    folder = _folder(args.run)
    if folder is None:
        print(
            f"ddvi report: {args.run}: no run folder with a {RECORDING} (give the folder "
            "ddvi run printed)",
            file=sys.stderr,
        )
        return 2
    if not (folder / RECORDING).is_file():  # a repair interrupted: start from the original
        os.replace(folder / TRUNCATED, folder / RECORDING)
    try:
        got = recover(folder)
    except (OSError, ValueError, DeploymentError, tomllib.TOMLDecodeError) as exc:
        print(f"ddvi report: {folder}: {exc}", file=sys.stderr)
        return 1
    except ReportNotWrittenError as exc:
        print(f"ddvi report: no report: {exc}", file=sys.stderr)
        return 1
    how = "complete" if got.complete else f"cut short; repaired, the original is {TRUNCATED}"
    if got.unrepaired:
        how = f"cut short; not repaired: {got.unrepaired}"
    print(
        f"ddvi report: {got.messages} messages read from {folder / RECORDING} ({how}); "
        f"completed: {got.summary['completed']}",
        file=sys.stderr,
    )
    print(json.dumps({"messages": got.messages, "complete": got.complete}))
    return 0
