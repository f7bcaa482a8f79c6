"""The monitor's recording: an MCAP file of JSON channels, and reading one back.

``Recorder`` writes ``recording.mcap`` (zstd chunks):

    <topic>            one channel per topic (and schema), message_encoding "json": the wire
                       message as JSON {"schema", "version", "seq", "t", "src", "body"} with a
                       jsonschema per message schema (``message_json_schema``)
    rejected/<topic>   payloads that do not decode: {"key", "reason", "error", "size",
                       "payload_b64", "truncated"}
    alive/<service>    liveliness changes {"service", "alive"} (a service came up or went away)
    scene/...          the formation as a 3D scene in Foxglove's schemas, protobuf
                       (``services.ground.monitoring.scene``; with foxglove-sdk installed)

Every record's log_time is simulation time (ns from the mission's start: a message's own t, or
the latest simulation time for a rejected payload or a liveliness change), so that a viewer's
timeline spans the mission flown; publish_time is the monitor's receive wall time (ns since the
epoch).  The metadata record ``ddvi`` names the run and says so (``TIMELINE``), and the
deployment file is attached.
``read_recording`` reads a file back (its JSON channels: what the bus carried), also one cut
short (no footer) by a kill -9.  The scene is made from what the bus carried, so it is not
counted among the messages recorded (``Recorder.scenes`` counts it).
"""

from __future__ import annotations

import base64
import functools
import json
import logging
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import orjson
from mcap.reader import NonSeekingReader, make_reader
from mcap.writer import CompressionType, Writer

from services.ground.storage.disk import REPORT_ROOM, RecordFile, size_text, space_left
from services.ground.storage.record import RecordGaps, RecordingStop
from services.interface import (
    REASONS,
    SCHEMAS,
    Array,
    Bool,
    Float,
    Int,
    IntMap,
    Message,
    MessageError,
    ScalarMap,
    Schema,
    Str,
    topics,
)

log = logging.getLogger("ddvi.monitor")

RECORDING = "recording.mcap"
"""The recording's file name in the run folder."""
MAX_RAW = 64 * 1024  # bytes of a rejected payload kept in the recording
CHUNK_SIZE = 256 * 1024
TIMELINE = {"log_time": "simulation", "publish_time": "receive_wall"}
"""The ``ddvi`` metadata keys that say what a recording's two timestamps are (a recording
without them has log_time = receive wall time and publish_time = simulation time)."""

_MAX_NS = 2**64 - 1


def ns(t: float) -> int:
    """Simulation seconds as MCAP nanoseconds, clamped to the unsigned 64-bit range."""
    x = t * 1e9
    if not x > 0:
        return 0
    return _MAX_NS if x >= _MAX_NS else round(x)


def _field_json_schema(f: Any) -> dict[str, Any]:
    if isinstance(f, Int):
        return {"type": "integer"}
    if isinstance(f, Float):
        return {"type": "number"}
    if isinstance(f, Bool):
        return {"type": "boolean"}
    if isinstance(f, Str):
        return {"type": "string"} | ({"enum": list(f.choices)} if f.choices else {})
    if isinstance(f, Array):
        item: dict[str, Any] = {"type": "number"}
        for d in reversed(f.shape):
            item = {"type": "array", "items": item}
            if d is not None:
                item |= {"minItems": d, "maxItems": d}
        return item
    if isinstance(f, IntMap):
        return {"type": "object", "additionalProperties": {"type": "integer"}}
    if isinstance(f, ScalarMap):
        return {
            "type": "object",
            "additionalProperties": {"type": ["number", "integer", "string", "boolean"]},
        }
    raise TypeError(f"no JSON schema for field kind {type(f).__name__}")


def message_json_schema(spec: Schema) -> dict[str, Any]:
    """The jsonschema of one message type as recorded (the wire message as JSON)."""
    return {
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "title": f"ddvi.{spec.name}",
        "type": "object",
        "properties": {
            "schema": {"type": "string", "const": spec.name},
            "version": {"type": "integer"},
            "seq": {"type": "integer"},
            "t": {"type": "number", "description": "simulation time, s"},
            "src": {"type": "string"},
            "boot": {"type": "integer", "description": "the publisher's boot"},
            "body": {
                "type": "object",
                "properties": {k: _field_json_schema(f) for k, f in spec.fields.items()},
                "required": list(spec.fields),
                "additionalProperties": False,
            },
        },
        "required": ["schema", "version", "seq", "t", "src", "boot", "body"],
    }


@functools.cache
def _recorded_schema(name: str) -> dict[str, Any]:
    """message_json_schema of a known schema, built once (the recorder asks per message)."""
    return message_json_schema(SCHEMAS[name])


REJECTED_SCHEMA = {
    "title": "ddvi.rejected",
    "type": "object",
    "properties": {
        "key": {"type": "string"},
        "reason": {"type": "string", "enum": sorted(REASONS)},
        "error": {"type": "string"},
        "size": {"type": "integer"},
        "payload_b64": {"type": "string", "contentEncoding": "base64"},
        "truncated": {"type": "boolean"},
    },
}
ALIVE_SCHEMA = {
    "title": "ddvi.alive",
    "type": "object",
    "properties": {"service": {"type": "string"}, "alive": {"type": "boolean"}},
}


def message_record(msg: Message) -> dict[str, Any]:
    """A decoded bus message as recorded (and served live): the wire message as JSON."""
    return {
        "schema": msg.schema,
        "version": msg.version,
        "seq": msg.seq,
        "t": msg.t,
        "src": msg.src,
        "boot": msg.boot,
        "body": msg.body,  # validated: finite float64 arrays, which orjson writes as lists
    }


def rejected_record(key: str, payload: bytes, err: MessageError) -> dict[str, Any]:
    """A payload that did not decode as recorded: why, and its first ``MAX_RAW`` bytes."""
    return {
        "key": key,
        "reason": err.reason,
        "error": str(err)[:2000],
        "size": len(payload),
        "payload_b64": base64.b64encode(payload[:MAX_RAW]).decode(),
        "truncated": len(payload) > MAX_RAW,
    }


class Recorder:
    """An MCAP file of JSON channels, flushed on demand, closed exactly once.

    It stops recording, and says so once, rather than fail: while ``room()`` bytes (the
    pending chunk, the footer and ``disk.REPORT_ROOM`` for the report) are still left on its
    disk it closes the file whole; a write that fails all the same (a disk filled by others, an
    I/O error) cuts the file back to its last whole record.  Either way ``stopped`` says what
    is in the file, and what comes after is counted (``not_recorded``), never written.
    """

    def __init__(self, path: Path, metadata: dict[str, str], attachment: Path | None) -> None:
        self.path = path
        self.messages = 0  # handed to the writer
        self.scenes = 0  # scene messages handed to the writer (not among ``messages``)
        self.not_recorded = 0  # messages after the recording stopped, or lost in its cut
        self.closed = False
        self.stopped: RecordingStop | None = None
        self._saved, self._saved_ns = 0, 0  # messages in whole chunks, their latest log time
        self._pending, self._pending_ns = 0, 0  # messages in the chunk being built
        self._room_seen = -1  # the file's size when its room was last checked
        self._schemas: dict[str, int] = {}
        self._channels: dict[tuple[str, str], int] = {}
        self._file: RecordFile | None = None
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            self._file = RecordFile(path)
        except OSError as exc:
            self._stop(exc.strerror or str(exc), footer=False)
            return
        self._writer = Writer(self._file, chunk_size=CHUNK_SIZE, compression=CompressionType.ZSTD)

        def start() -> None:
            self._writer.start(profile="", library="ddvi-fsw monitor")
            self._writer.add_metadata("ddvi", metadata)
            if attachment is not None and attachment.is_file():
                now = time.time_ns()
                self._writer.add_attachment(
                    now, now, attachment.name, "application/toml", attachment.read_bytes()
                )
            self._writer.flush()

        self._guarded(start)

    def room(self) -> int:
        """Bytes the file must leave on its disk: the chunk being built (at most a chunk and a
        message), the footer (its chunk index, about 0.5 % of the file) and the report's."""
        position = self._file.position if self._file is not None else 0
        return REPORT_ROOM + 2 * CHUNK_SIZE + position // 100

    def _guarded(self, act: Callable[[], Any]) -> bool:
        """Do ``act`` (a call into the writer); whether it went whole.  A write that failed
        stops the recording."""
        assert self._file is not None
        chunks = self._file.chunks
        try:
            act()
        except OSError as exc:
            self._settle(chunks)
            self._cut(exc)
            return False
        self._settle(chunks)
        return True

    def _settle(self, chunks: int) -> None:
        """A chunk that reached the file since there were ``chunks`` holds every message
        pending."""
        assert self._file is not None
        if self._file.chunks != chunks:
            self._saved += self._pending
            self._saved_ns = max(self._saved_ns, self._pending_ns)
            self._pending = 0

    def _cut(self, exc: OSError) -> None:
        """A write failed: cut the file back to its last whole record, and stop."""
        assert self._file is not None
        why = exc.strerror or str(exc)
        try:
            self._file.cut()
        except OSError as cut:
            why += f", and it could not be cut back to its last whole record ({cut.strerror})"
        self._stop(why, footer=False)

    def _stop(self, why: str, footer: bool) -> None:
        """Record nothing more; say so once."""
        self.closed = True
        self.not_recorded += self.messages - self._saved  # handed over, not in the file
        left = space_left(self.path.parent)
        stop = RecordingStop(str(self.path), why, left, self._saved_ns / 1e9, self._saved, footer)
        self.stopped = stop
        how = "closed whole" if footer else "cut back to its last whole record"
        log.error(
            "the recording stopped at t = %.0f s: %s, %s left on %s; %s holds %d messages (%s); "
            "the run goes on without it",
            stop.at_t,
            why,
            size_text(left),
            self.path.parent,
            self.path.name,
            stop.messages,
            how,
        )

    def _schema_id(self, name: str, schema: dict[str, Any] | Any) -> int:
        """The id of schema ``name``: a JSON schema (a dict), or a Foxglove schema (its
        encoding and bytes as the SDK gives them)."""
        sid = self._schemas.get(name)
        if sid is None:
            if isinstance(schema, dict):
                encoding, data = "jsonschema", json.dumps(schema).encode()
            else:
                encoding, data = schema.encoding, bytes(schema.data)
            sid = self._schemas[name] = self._writer.register_schema(name, encoding, data)
        return sid

    def _channel(self, topic: str, schema_name: str, schema: dict[str, Any] | Any) -> int:
        cid = self._channels.get((topic, schema_name))
        if cid is None:
            sid = self._schema_id(schema_name, schema)
            encoding = "json" if isinstance(schema, dict) else schema.encoding
            cid = self._writer.register_channel(topic, encoding, sid)
            self._channels[(topic, schema_name)] = cid
        return cid

    def write(
        self,
        topic: str,
        schema_name: str,
        schema: dict[str, Any],
        data: dict[str, Any],
        log_ns: int,
        pub_ns: int,
        seq: int = 0,
    ) -> bytes | None:
        """Write ``data`` as JSON on channel ``topic`` (registered with its schema on first
        use); ``log_ns``: simulation time, ``pub_ns``: receive wall time, both ns.  The JSON
        written (the live view serves the same bytes), or None once the recording stopped."""
        file = self._file  # its room changes only as it is written
        if self.stopped is None and file is not None and file.position != self._room_seen:
            self._keep_room()
        if self.stopped is not None:
            self.not_recorded += 1
            return None
        payload = orjson.dumps(data, option=orjson.OPT_SERIALIZE_NUMPY)
        self._append(topic, schema_name, schema, payload, log_ns, pub_ns, seq, bus=True)
        return payload

    def scene(self, topic: str, schema: Any, data: bytes, log_ns: int, recv_ns: int) -> None:
        """Record a scene message (``services.ground.monitoring.scene``), encoded in its
        Foxglove ``schema``'s encoding, made from what was received at wall time ``recv_ns``;
        dropped, uncounted, once the recording stopped."""
        if self.stopped is None and self._file is not None:
            seq = self.scenes + 1
            self._append(topic, schema.name, schema, data, log_ns, recv_ns, seq, bus=False)

    def _append(
        self,
        topic: str,
        schema_name: str,
        schema: dict[str, Any] | Any,
        payload: bytes,
        log_ns: int,
        pub_ns: int,
        seq: int,
        bus: bool,
    ) -> None:
        """Hand one record to the writer: a bus message (``bus``, counted in ``messages``) or
        a scene message (``scenes``)."""
        assert self._file is not None
        chunks = self._file.chunks  # written in line, not through _guarded: once a message
        try:
            cid = self._channel(topic, schema_name, schema)
            if bus:
                self.messages += 1
                self._pending += 1
                if log_ns > self._pending_ns:
                    self._pending_ns = log_ns
            else:
                self.scenes += 1
            self._writer.add_message(cid, log_ns, payload, pub_ns, seq & 0xFFFFFFFF)
        except OSError as exc:
            self._settle(chunks)
            self._cut(exc)
            return
        if self._file.chunks != chunks:
            self._settle(chunks)

    def message(self, topic: str, msg: Message, recv_ns: int) -> bytes | None:
        """Record a decoded bus message received at wall time ``recv_ns``; its JSON (None once
        the recording stopped)."""
        schema = _recorded_schema(msg.schema)
        data = message_record(msg)
        return self.write(topic, f"ddvi.{msg.schema}", schema, data, ns(msg.t), recv_ns, msg.seq)

    def rejected(
        self, topic: str, key: str, payload: bytes, err: MessageError, recv_ns: int, t: float
    ) -> None:
        """Record a payload that did not decode (its first ``MAX_RAW`` bytes), at the latest
        simulation time ``t``."""
        data = rejected_record(key, payload, err)
        self.write(f"rejected/{topic}", "ddvi.rejected", REJECTED_SCHEMA, data, ns(t), recv_ns)

    def alive(self, service: str, alive: bool, recv_ns: int, t: float) -> None:
        """Record that ``service``'s liveliness token appeared (alive) or went away."""
        data = {"service": service, "alive": alive}
        self.write(topics.alive_topic(service), "ddvi.alive", ALIVE_SCHEMA, data, ns(t), recv_ns)

    def gaps(self, queued_at_close: int = 0) -> RecordGaps:
        """What the record lacks as far as the recorder knows (``queued_at_close``: samples
        its caller still held when the recording closed)."""
        return RecordGaps(self.stopped, self.not_recorded, queued_at_close)

    def flush(self) -> None:
        """Close the open chunk and hand it to the OS (what a kill -9 cannot lose)."""
        if not self.closed:
            self._guarded(self._writer.flush)

    def close(self) -> None:
        """Write the summary and footer, and sync the file to disk; once only."""
        if self.closed:
            return
        if self._finish():
            self.closed = True
            self._saved, self._saved_ns = self.messages, max(self._saved_ns, self._pending_ns)

    def _finish(self) -> bool:
        """Write the last chunk, the summary and the footer, sync and close the file; whether
        it went whole (if not, the recording has stopped, cut short)."""
        assert self._file is not None
        file = self._file
        if not self._guarded(self._writer.finish) or not self._guarded(file.sync):
            return False
        file.close()
        return True

    def _keep_room(self) -> None:
        """Close the file whole while its disk still has ``room()`` for it and the report."""
        if self._file is None:
            return
        self._room_seen = self._file.position
        left = self._file.left
        if left is not None and left < self.room():
            self._close_full()

    def _close_full(self) -> None:
        """The disk is nearly full: close the file whole now, with what it holds, and stop."""
        room = self.room()
        if self._finish():
            self._saved, self._saved_ns = self.messages, max(self._saved_ns, self._pending_ns)
            kept = f"less than the {size_text(room)} it keeps for its end and the report"
            self._stop(f"its disk is nearly full ({kept})", footer=True)


@dataclass(frozen=True)
class Recorded:
    """One message read back from a recording."""

    topic: str
    schema: str
    log_time: int
    publish_time: int
    data: dict[str, Any]


def read_recording(path: str | Path) -> tuple[list[Recorded], bool]:
    """Every message of a recording's JSON channels (the bus's messages, liveliness changes
    and rejected payloads; not the scene) in file order, and whether the file was complete.

    A file cut short (the monitor killed with -9) has no footer: it is then read sequentially
    up to the last complete chunk.
    """

    def convert(items: Iterator[Any]) -> Iterator[Recorded]:
        for schema, channel, message in items:
            if channel.message_encoding != "json":  # the scene, made from what is here
                continue
            yield Recorded(
                channel.topic,
                schema.name if schema is not None else "",
                message.log_time,
                message.publish_time,
                json.loads(message.data),
            )

    with open(path, "rb") as f:
        try:
            reader = make_reader(f)
            return list(convert(reader.iter_messages(log_time_order=False))), True
        except Exception:  # no footer or summary: read it as a stream below
            pass
    out: list[Recorded] = []
    with open(path, "rb") as f:
        reader = NonSeekingReader(f)
        try:
            for item in convert(reader.iter_messages(log_time_order=False)):
                out.append(item)
        except Exception:  # the truncated tail
            pass
    return out, False
