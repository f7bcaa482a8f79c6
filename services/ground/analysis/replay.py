"""A run's report from its recorded messages, as the monitor would have written it live.

``replay`` feeds every recorded bus message (``services.ground.storage.recording``'s JSON channels)
back through the monitor's rules into a ``RunData`` and writes the report: a message seen
already or older than its publisher's window (``services.bus.SequenceGuards``) is kept out, a
clock from anyone but the environment is not obeyed, undecodable payloads are counted as
rejected by reason.  Used by ``ddvi report`` (``services.ground.analysis.recover``).
"""

from __future__ import annotations

import contextlib
import json
import logging
from collections.abc import Callable
from pathlib import Path
from typing import Any

from services.bus import SEQUENCE_REASONS, SequenceGuards
from services.config import Deployment
from services.ground.analysis.outcome import TIME_MASTER
from services.ground.analysis.report import write_report
from services.ground.analysis.rundata import RunData
from services.ground.storage.record import RecordGaps
from services.ground.storage.recording import TIMELINE
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
            raise MessageError(
                "version",
                f"{spec.name}: recorded at version {version}, which "
                f"this version ({spec.version}) cannot read",
            )
        payload = encode(
            data["schema"],
            body,
            seq=data["seq"],
            t=data["t"],
            src=data["src"],
            boot=data.get("boot", 0),  # a recording without boots: one boot for all
        )
        return decode(payload, data["schema"])
    except (MessageError, KeyError, TypeError) as exc:
        reason = exc.reason if isinstance(exc, MessageError) else "bad_field"
        counters["rejected"] += 1
        counters[f"rejected.{reason}"] = counters.get(f"rejected.{reason}", 0) + 1
        log.warning("recorded %s does not decode: %s", topic, exc)
        return None


def replay(folder: Path, dep: Deployment, run: str, records: Any) -> dict[str, Any]:
    """Write the report of ``records`` (``services.ground.analysis.recover.Records``) to ``folder``;
    return its summary."""
    data, counters = replayed(dep, run, records)
    n, complete = len(records.messages), records.complete
    return write_report(
        folder,
        data,
        completed=data.final_seen,
        monitor_counters=counters,
        gaps=RecordGaps(cut_short=not complete),
        source=f"the {n} messages read from the recording",
        recovered={"messages": n, "complete": complete},
    )


def replayed(dep: Deployment, run: str, records: Any) -> tuple[RunData, dict[str, int]]:
    """What the monitor would have learned from ``records``, and its counters."""
    data = RunData(dep, run, _dropped(records))
    guards = SequenceGuards()
    counters = _counters()
    alive = topics.alive_topic("")
    wall = _receive_wall_time(records)
    for m in records.messages:
        channel = records.channels.get(m.channel_id)
        if channel is None or channel.message_encoding != "json":
            continue  # the scene is made from the bus's messages: not one of them
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
        data.received(msg)
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
    return data, counters


def _dropped(records: Any) -> Callable[[str], int]:
    """What the monitor's rate budget dropped unread from each publisher, as its last stats
    in the recording say (``flood.<publisher>``): a service's stats may count those
    (``services.ground.analysis.claims``)."""
    stats = topics.stats_topic("monitor")
    ids = {k for k, c in records.channels.items() if c.topic == stats}
    last = next((m for m in reversed(records.messages) if m.channel_id in ids), None)
    counters: dict[str, Any] = {}
    if last is not None:
        with contextlib.suppress(ValueError, KeyError, TypeError, AttributeError):
            counters = dict(json.loads(last.data)["body"]["counters"])
    return lambda publisher: int(counters.get(f"flood.{publisher}", 0) or 0)


def _receive_wall_time(records: Any) -> str:
    """The message field that holds the receive wall time: publish_time in a recording whose
    metadata says so (``recording.TIMELINE``), log_time in one made before."""
    meta = next((dict(m.metadata) for m in records.metadata if m.name == "ddvi"), {})
    return "publish_time" if meta.get("publish_time") == TIMELINE["publish_time"] else "log_time"
