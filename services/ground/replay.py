"""A run's report from its recorded messages, as the monitor would have written it live.

``replay`` feeds every recorded bus message (``services.ground.recording``'s JSON channels)
back through the monitor's rules into a ``RunData`` and writes the report: a message seen
already or older than its publisher's window (``services.bus.SequenceGuards``) is kept out, a
clock from anyone but the environment is not obeyed, undecodable payloads are counted as
rejected by reason.  Used by ``ddvi report`` (``services.ground.recover``).
"""

from __future__ import annotations

import json
import logging
from pathlib import Path
from typing import Any

from services.bus import SEQUENCE_REASONS, SequenceGuards
from services.config import Deployment
from services.ground.outcome import TIME_MASTER
from services.ground.recording import TIMELINE
from services.ground.report import write_report
from services.ground.rundata import RunData
from services.interface import (
    REASONS,
    SCHEMAS,
    MessageError,
    decode,
    encode,
    topics,
    upgrade,
)

log = logging.getLogger("ddvi.report")


def _counters() -> dict[str, int]:
    counters = dict.fromkeys(("received", "recorded", "rejected", "handler_errors"), 0)
    counters.update({f"rejected.{r}": 0 for r in sorted(REASONS)})
    counters.update({f"ignored.{r}": 0 for r in SEQUENCE_REASONS})
    counters["refused.clock"] = 0
    counters["refused.origin"] = 0
    return counters


def _message(topic: str, data: dict[str, Any], counters: dict[str, int]) -> Any:
    """The recorded JSON message as a decoded Message, its body upgraded to the current
    version of its schema (None, counted, when it is not one)."""
    try:
        body, version = upgrade(data["schema"], data["version"], data["body"])
        spec = SCHEMAS.get(data["schema"])
        if spec is not None and isinstance(body, dict) and version != spec.version:
            raise MessageError("version", f"{spec.name}: recorded at version {version}, which "
                               f"this version ({spec.version}) cannot read")  # fmt: skip
        payload = encode(data["schema"], body, seq=data["seq"], t=data["t"],
                         src=data["src"])  # fmt: skip
        return decode(payload, data["schema"])
    except (MessageError, KeyError, TypeError) as exc:
        reason = exc.reason if isinstance(exc, MessageError) else "bad_field"
        counters["rejected"] += 1
        counters[f"rejected.{reason}"] = counters.get(f"rejected.{reason}", 0) + 1
        log.warning("recorded %s does not decode: %s", topic, exc)
        return None


def replay(folder: Path, dep: Deployment, run: str, records: Any) -> dict[str, Any]:
    """Write the report of ``records`` (``services.ground.recover.Records``) to ``folder``;
    return its summary."""
    data = RunData(dep, run)
    guards = SequenceGuards()
    counters = _counters()
    alive = topics.alive_topic("")
    wall = _receive_wall_time(records)
    for m in records.messages:
        channel = records.channels.get(m.channel_id)
        if channel is None:
            continue
        counters["recorded"] += 1  # every record, liveliness too: as the monitor counts them
        if channel.topic.startswith(alive):
            continue
        counters["received"] += 1
        data.seen(getattr(m, wall))
        body = json.loads(m.data)
        if channel.topic.startswith("rejected/"):
            counters["rejected"] += 1
            key = f"rejected.{body.get('reason', 'bad_field')}"
            counters[key] = counters.get(key, 0) + 1
            continue
        msg = _message(channel.topic, body, counters)
        if msg is None:
            continue
        if msg.schema == "clock" and msg.src != TIME_MASTER:
            counters["refused.clock"] += 1
            continue
        if not data.refusals.accepts(channel.topic, msg):
            counters["refused.origin"] += 1
            continue
        if (why := guards.check(msg, channel.topic)) is not None:
            counters[f"ignored.{why}"] += 1
            continue
        try:
            data.ingest(channel.topic, msg)
        except Exception:  # one odd message must not lose the report
            counters["handler_errors"] += 1
            log.exception("could not use %s at t = %s", channel.topic, msg.t)
    summary = write_report(folder, data, completed=data.final_seen, monitor_counters=counters)
    summary["recovered"] = {"messages": len(records.messages), "complete": records.complete}
    (folder / "summary.json").write_text(json.dumps(_plain(summary), indent=2))
    with (folder / "report.md").open("a") as f:
        f.write(
            f"\nWritten by `ddvi report` from the recording: {len(records.messages)} messages"
            + ("" if records.complete else " up to its last complete chunk (it was cut short)")
            + ".\n"
        )
    return summary


def _receive_wall_time(records: Any) -> str:
    """The message field that holds the receive wall time: publish_time in a recording whose
    metadata says so (``recording.TIMELINE``), log_time in one made before."""
    meta = next((dict(m.metadata) for m in records.metadata if m.name == "ddvi"), {})
    return "publish_time" if meta.get("publish_time") == TIMELINE["publish_time"] else "log_time"


def _plain(value: Any) -> Any:
    """``value`` with numpy arrays and scalars as lists and numbers (for JSON)."""
    return json.loads(json.dumps(value, default=lambda v: v.tolist()))
