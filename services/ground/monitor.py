"""The ground monitor: records every bus message, shows live status, writes the run report.

Run by the launcher, first of all services::

    python -m services.ground.monitor --deployment F --run R --hub H --out DIR

It subscribes to ``ddvi/<run>/**`` with a raw zenoh subscriber (not ``Bus.subscribe``, so that
undecodable payloads are recorded too) and to the run's liveliness tokens, and writes
``DIR/recording.mcap`` (a batch, ``services.interface.schema.unpack_batch``, message by message):

    <topic>            one channel per topic (and schema), message_encoding "json": the wire
                       message as JSON {"schema", "version", "seq", "t", "src", "body"} with a
                       jsonschema per message schema; log_time = receive wall time (ns since the
                       epoch), publish_time = simulation time t (ns)
    rejected/<topic>   payloads that do not decode: {"key", "reason", "error", "size",
                       "payload_b64", "truncated"}; publish_time = the latest simulation time
    alive/<service>    liveliness changes {"service", "alive"} (a service came up or went away)

A message whose (publisher, topic, seq) was seen already, or is older than the receiver's
sequence window (``services.bus.endpoint.SequenceGuard``), is recorded but kept out of the
report and counted (``ignored.duplicate``, ``ignored.stale``); a payload whose schema is not
the one its topic carries (``services.interface.schema.TOPIC_SCHEMAS``) is rejected
``wrong_schema``.

The file is flushed (chunk closed and written to the OS) every ``FLUSH_PERIOD`` s, so a kill -9
of the monitor loses at most that much; ``read_recording`` reads such a footer-less file too.
On a normal stop and on SIGTERM the writer is closed (summary and footer written).

When the ``clock`` message with ``final = true`` arrives the monitor waits until every other
service of the deployment has finished or ``FINAL_WAIT`` s pass, then closes the recording,
writes the report (``services.ground.report``) and exits 0. A service seen alive has finished
when its liveliness token is gone (services publish their final stats before leaving); one
never seen alive, when it has sent stats with t >= the final time. Messages from different
publishers are
not ordered with respect to each other, so a service's final stats may arrive before the final
clock; what arrives within ``FINAL_GRACE`` s after the last service finished is still recorded.
SIGTERM before that closes the recording and writes a partial report (``"completed": false``),
also exit 0.

Live status: a rich table, one row per deputy, refreshed at 2 Hz when stderr is a terminal;
otherwise one plain progress line on stderr every 10 % of the mission.

``monitor_command(args)`` is the ``ddvi monitor [KEYEXPR]`` command: print every message on the
bus, one line each.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse
import base64
import functools
import json
import logging
import math
import queue
import sys
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

import numpy as np
import orjson
import zenoh
from mcap.reader import NonSeekingReader, make_reader
from mcap.writer import CompressionType, Writer

from services.bus import (
    DEFAULT_HUB,
    EPHEMERAL_LOOPBACK,
    SEQUENCE_REASONS,
    BusSettings,
    SequenceGuards,
    open_session,
)
from services.flight.runtime import ServiceContext, run_service
from services.ground.report import RunData, ns, warm_up, write_report
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
    decode,
    schema_for_topic,
    unpack_batch,
)

log = logging.getLogger("ddvi.monitor")

FLUSH_PERIOD = 0.5  # s between recording flushes (bounds the loss on kill -9)
DRAW_PERIOD = 0.5  # s between live status refreshes
FINAL_WAIT = 5.0  # s to wait for the other services' final stats after the final clock
FINAL_GRACE = 0.25  # s to keep recording once every service has finished
STOP_DRAIN = 1.0  # s to keep recording what is already queued after SIGTERM
# The monitor is the ground: it records and reports, and no step of the flight loop waits on it.
# On two cores its main thread yields the CPU to the flight services, and takes what arrived in
# batches instead of waking for every sample. The threads that receive and stamp samples
# (zenoh's, and the subscriber's callback thread) keep their priority: a slowed receiver would
# fill zenoh's queue to the callback and hold up every publisher (congestion control BLOCK).
NICENESS = 10
BATCH_PERIOD = 0.005  # s the main loop lets samples gather once one has come
BATCH_MAX = 512  # samples a batch at most: flushing, the status and a stop are looked at between
MAX_RAW = 64 * 1024  # bytes of a rejected payload kept in the recording
CHUNK_SIZE = 256 * 1024
RECORDING = "recording.mcap"

_DATA, _ALIVE = 0, 1


# ---- recording ------------------------------------------------------------------------------


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
            "body": {
                "type": "object",
                "properties": {k: _field_json_schema(f) for k, f in spec.fields.items()},
                "required": list(spec.fields),
                "additionalProperties": False,
            },
        },
        "required": ["schema", "version", "seq", "t", "src", "body"],
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


class Recorder:
    """An MCAP file of JSON channels, flushed on demand, closed exactly once."""

    def __init__(self, path: Path, metadata: dict[str, str], attachment: Path | None) -> None:
        path.parent.mkdir(parents=True, exist_ok=True)
        self.path = path
        self._file: IO[bytes] = path.open("wb")
        self._writer = Writer(self._file, chunk_size=CHUNK_SIZE, compression=CompressionType.ZSTD)
        self._writer.start(profile="", library="ddvi-fsw monitor")
        self._writer.add_metadata("ddvi", metadata)
        if attachment is not None and attachment.is_file():
            now = time.time_ns()
            self._writer.add_attachment(
                now, now, attachment.name, "application/toml", attachment.read_bytes()
            )
        self._schemas: dict[str, int] = {}
        self._channels: dict[tuple[str, str], int] = {}
        self.messages = 0
        self.closed = False
        self.flush()

    def _schema_id(self, name: str, schema: dict[str, Any]) -> int:
        sid = self._schemas.get(name)
        if sid is None:
            data = json.dumps(schema).encode()
            sid = self._schemas[name] = self._writer.register_schema(name, "jsonschema", data)
        return sid

    def _channel(self, topic: str, schema_name: str, schema: dict[str, Any]) -> int:
        cid = self._channels.get((topic, schema_name))
        if cid is None:
            sid = self._schema_id(schema_name, schema)
            cid = self._writer.register_channel(topic, "json", sid)
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
    ) -> None:
        cid = self._channel(topic, schema_name, schema)
        payload = orjson.dumps(data, option=orjson.OPT_SERIALIZE_NUMPY)
        self._writer.add_message(cid, log_ns, payload, pub_ns, seq & 0xFFFFFFFF)
        self.messages += 1

    def message(self, topic: str, msg: Message, log_ns: int) -> None:
        data = {
            "schema": msg.schema,
            "version": msg.version,
            "seq": msg.seq,
            "t": msg.t,
            "src": msg.src,
            "body": msg.body,  # validated: finite float64 arrays, which orjson writes as lists
        }
        schema = _recorded_schema(msg.schema)
        self.write(topic, f"ddvi.{msg.schema}", schema, data, log_ns, ns(msg.t), msg.seq)

    def rejected(
        self, topic: str, key: str, payload: bytes, err: MessageError, log_ns: int, t: float
    ) -> None:
        data = {
            "key": key,
            "reason": err.reason,
            "error": str(err)[:2000],
            "size": len(payload),
            "payload_b64": base64.b64encode(payload[:MAX_RAW]).decode(),
            "truncated": len(payload) > MAX_RAW,
        }
        self.write(f"rejected/{topic}", "ddvi.rejected", REJECTED_SCHEMA, data, log_ns, ns(t))

    def alive(self, service: str, alive: bool, log_ns: int, t: float) -> None:
        data = {"service": service, "alive": alive}
        self.write(f"alive/{service}", "ddvi.alive", ALIVE_SCHEMA, data, log_ns, ns(t))

    def flush(self) -> None:
        if not self.closed:
            self._writer.flush()

    def close(self) -> None:
        if self.closed:
            return
        self.closed = True
        try:
            self._writer.finish()
            self._file.flush()
            os.fsync(self._file.fileno())
        finally:
            self._file.close()


@dataclass(frozen=True)
class Recorded:
    """One message read back from a recording."""

    topic: str
    schema: str
    log_time: int
    publish_time: int
    data: dict[str, Any]


def read_recording(path: str | Path) -> tuple[list[Recorded], bool]:
    """Every message of a recording in file order, and whether the file was complete.

    A file cut short (the monitor killed with -9) has no footer: it is then read sequentially
    up to the last complete chunk.
    """

    def convert(items: Iterator[Any]) -> Iterator[Recorded]:
        for schema, channel, message in items:
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


# ---- live status ----------------------------------------------------------------------------


def _f(v: Any, fmt: str) -> str:
    return "-" if v is None else format(v, fmt)


def _rank(s: dict[str, Any]) -> str:
    if "samples" not in s or s.get("mode") == "lqr":
        return "-"
    return f"{s['samples']}/{s['intervals']}/{s['rank']}:{s['rank_needed']}"


class Status:
    """Terminal status: rich live table on a TTY, plain 10 % progress lines otherwise."""

    def __init__(self, data: RunData, tty: bool) -> None:
        self.data = data
        self.tty = tty
        self.next_pct = 10
        self.last_line = ""
        self._live: Any = None
        if tty:
            from rich.console import Console
            from rich.live import Live

            self._live = Live(
                console=Console(stderr=True), auto_refresh=False, redirect_stdout=False
            )
            self._live.start()

    def _table(self, counters: dict[str, int]) -> Any:
        from rich.table import Table

        d = self.data
        title = (
            f"ddvi {d.run}  t = {d.sim_t:.0f} s ({d.sim_t / d.period:.2f} / "
            f"{d.duration / d.period:.2f} orbits)  recorded {counters.get('recorded', 0)}  "
            f"rejected {counters.get('rejected', 0)}"
        )
        table = Table(title=title, title_justify="left", expand=False)
        for col in ("deputy", "orbits", "y - y_ref [m]", "x [m]", "sigma3", "phase", "s/i/rank"):
            table.add_column(col, justify="left" if col in ("deputy", "phase") else "right")
        for dep in d.dep.deputy:
            s = d.live(dep)
            table.add_row(
                f"{dep.name} ({dep.controller})",
                f"{s['orbits']:.2f}",
                _f(s.get("ey"), "+.3f"),
                _f(s.get("x"), "+.3f"),
                _f(s.get("sigma3"), "+.4f"),
                str(s.get("phase", "-")),
                _rank(s),
            )
        return table

    def _line(self) -> str:
        d = self.data
        parts = [f"monitor: {100 * d.sim_t / d.duration:3.0f}% t={d.sim_t:.0f} s "
                 f"({d.sim_t / d.period:.2f} orbits)"]  # fmt: skip
        for dep in d.dep.deputy:
            s = d.live(dep)
            parts.append(
                f"{dep.name}: y-y_ref={_f(s.get('ey'), '+.2f')} x={_f(s.get('x'), '+.2f')} "
                f"sigma3={_f(s.get('sigma3'), '+.3f')} {s.get('phase', '-')} s/i/rank={_rank(s)}"
            )
        return " | ".join(parts)

    def update(self, counters: dict[str, int]) -> None:
        if self._live is not None:
            self._live.update(self._table(counters), refresh=True)
            return
        d = self.data
        pct = 100 * d.sim_t / d.duration if d.duration > 0 else 0
        if pct >= self.next_pct:
            self.last_line = self._line()
            print(self.last_line, file=sys.stderr, flush=True)
            while self.next_pct <= pct:
                self.next_pct += 10

    def close(self, counters: dict[str, int]) -> None:
        if self._live is not None:
            self._live.update(self._table(counters), refresh=True)
            self._live.stop()
            self._live = None
        elif not self.tty and self._line() != self.last_line:
            print(self._line(), file=sys.stderr, flush=True)


# ---- the service ----------------------------------------------------------------------------


class Monitor:
    """The monitor's state machine, driven by ``handle`` (one queued item at a time)."""

    def __init__(self, ctx: ServiceContext) -> None:
        self.ctx = ctx
        self.prefix = f"ddvi/{ctx.run}/"
        self.data = RunData(ctx.deployment, ctx.run)
        self.counters: dict[str, int] = dict.fromkeys(
            ("received", "recorded", "rejected", "handler_errors"), 0
        )
        self.counters.update({f"rejected.{r}": 0 for r in sorted(REASONS)})
        # recorded, but kept out of the report: a replayed stats or gains message must not
        # overwrite newer figures
        self.counters.update({f"ignored.{r}": 0 for r in SEQUENCE_REASONS})
        self.guards = SequenceGuards()
        self.alive: set[str] = set()
        self.ever_alive: set[str] = set()
        self.others = [s for s in ctx.deployment.services if s != ctx.name]
        self.recorder: Recorder | None = None

    def open_recording(self) -> None:
        dep = self.ctx.deployment
        meta = {
            "run": self.ctx.run,
            "deployment": dep.path,
            "deputies": ",".join(f"{d.name}:{d.controller}" for d in dep.deputy),
            "orbit_period_s": repr(self.data.period),
            "started_ns": str(time.time_ns()),
            "services": ",".join(dep.services),
        }
        attach = Path(dep.path) if dep.path else None
        self.recorder = Recorder(Path(self.ctx.out) / RECORDING, meta, attach)

    def handle(self, item: tuple[int, str, Any, int]) -> None:
        kind, key, value, recv_ns = item
        rec = self.recorder
        assert rec is not None
        if kind == _ALIVE:
            name = key[len(self.prefix) + len("alive/") :]
            if value:
                self.alive.add(name)
                self.ever_alive.add(name)
            else:
                self.alive.discard(name)
            rec.alive(name, bool(value), recv_ns, self.data.sim_t)
            return
        topic = key[len(self.prefix) :] if key.startswith(self.prefix) else key
        try:
            parts = unpack_batch(value)
        except MessageError as err:
            self.counters["received"] += 1
            self.data.seen(recv_ns)
            self.reject(topic, key, value, err, recv_ns)
            return
        for part in parts or (value,):  # a batch is recorded message by message
            self.handle_message(topic, key, part, recv_ns)

    def reject(self, topic: str, key: str, value: bytes, err: MessageError, recv_ns: int) -> None:
        assert self.recorder is not None
        self.counters["rejected"] += 1
        self.counters[f"rejected.{err.reason}"] += 1
        n = self.counters[f"rejected.{err.reason}"]
        if n <= 10 or n % 1000 == 0:
            log.warning("rejected %s (%s, #%d): %s", key, err.reason, n, err)
        self.recorder.rejected(topic, key, value, err, recv_ns, self.data.sim_t)
        self.counters["recorded"] = self.recorder.messages

    def handle_message(self, topic: str, key: str, value: bytes, recv_ns: int) -> None:
        rec = self.recorder
        assert rec is not None
        self.counters["received"] += 1
        self.data.seen(recv_ns)
        try:
            msg = decode(value, schema_for_topic(topic))  # a truth on a cmd topic is garbage
        except MessageError as err:
            self.reject(topic, key, value, err, recv_ns)
            return
        rec.message(topic, msg, recv_ns)  # everything received is recorded
        if (why := self.guards.check(msg, topic)) is not None:
            n = self.counters[f"ignored.{why}"] = self.counters[f"ignored.{why}"] + 1
            if n <= 10 or n % 1000 == 0:
                log.warning("not reported %s seq %d (%s, #%d)", key, msg.seq, why, n)
            self.counters["recorded"] = rec.messages
            return
        try:
            self.data.ingest(topic, msg)
        except Exception:  # one odd message must not take the recording down
            self.counters["handler_errors"] += 1
            log.exception("could not use %s at t = %s", key, msg.t)
        self.counters["recorded"] = rec.messages

    def done(self, service: str) -> bool:
        """After the final clock: has ``service`` finished? A service seen alive is finished
        when its liveliness token is gone (it publishes its final stats before leaving); one
        never seen alive, when it has sent stats for the final time."""
        d = self.data
        if not d.final_seen or d.final_t is None:
            return False
        if service in self.ever_alive:
            return service not in self.alive
        return d.stats_t.get(service, -math.inf) >= d.final_t - 1e-6

    def pending(self) -> list[str]:
        """The other services not finished yet."""
        return [s for s in self.others if not self.done(s)]


def _subscribe(
    session: zenoh.Session, run: str, inbox: queue.SimpleQueue[tuple[int, str, Any, int]]
) -> tuple[Any, Any]:
    """The raw data subscriber and the liveliness subscriber, feeding ``inbox``."""

    def on_data(sample: zenoh.Sample) -> None:
        try:
            inbox.put((_DATA, str(sample.key_expr), sample.payload.to_bytes(), time.time_ns()))
        except Exception:  # a zenoh callback must never raise
            log.exception("monitor: could not queue a sample")

    def on_alive(sample: zenoh.Sample) -> None:
        try:
            up = sample.kind == zenoh.SampleKind.PUT
            inbox.put((_ALIVE, str(sample.key_expr), up, time.time_ns()))
        except Exception:
            log.exception("monitor: could not queue a liveliness change")

    prefix = f"ddvi/{run}/"
    data_sub = session.declare_subscriber(prefix + "**", on_data)
    alive_sub = session.liveliness().declare_subscriber(prefix + "alive/*", on_alive, history=True)
    return data_sub, alive_sub


def main(ctx: ServiceContext) -> int:
    inbox: queue.SimpleQueue[tuple[int, str, Any, int]] = queue.SimpleQueue()
    # Subscribe before anything else: the launcher starts the other services once it sees
    # this process alive.
    subs = _subscribe(ctx.bus.session, ctx.run, inbox)
    os.nice(NICENESS)  # this thread and those it starts later; not the callback's, started
    ctx.ready()
    mon = Monitor(ctx)
    status: Status | None = None
    completed = False
    # the report's imports, on a thread once the mission flies (not during the services'
    # start-up, which is CPU-bound too); joined before the report
    warming = threading.Thread(target=warm_up, name="report-warm-up", daemon=True)
    try:
        mon.open_recording()
        assert mon.recorder is not None
        status = Status(mon.data, sys.stderr.isatty())
        log.info("recording %s to %s", f"ddvi/{ctx.run}/**", mon.recorder.path)
        last_flush = last_draw = time.monotonic()
        final_deadline: float | None = None
        grace_deadline: float | None = None
        stop_deadline: float | None = None
        while True:
            try:
                item = inbox.get(timeout=0.05)
            except queue.Empty:
                item = None
            idle = item is None  # nothing came for 0.05 s
            if item is not None:
                time.sleep(BATCH_PERIOD)
                mon.handle(item)
                for _ in range(BATCH_MAX - 1):
                    try:
                        next_item = inbox.get_nowait()
                    except queue.Empty:
                        break
                    mon.handle(next_item)
                if mon.data.sim_t > 0.0 and warming.ident is None:
                    warming.start()
            now = time.monotonic()
            if now - last_flush >= FLUSH_PERIOD:
                mon.recorder.flush()
                last_flush = now
            if now - last_draw >= DRAW_PERIOD:
                status.update(mon.counters)
                last_draw = now
            if mon.data.final_seen:
                if final_deadline is None:
                    final_deadline = now + FINAL_WAIT
                    log.info("final clock at t = %.0f s; waiting for final stats", mon.data.sim_t)
                if not mon.pending() and grace_deadline is None:
                    grace_deadline = now + FINAL_GRACE  # stragglers racing the token drops
                if (grace_deadline is not None and now >= grace_deadline) or now >= final_deadline:
                    if missing := mon.pending():
                        log.warning("no final stats from %s after %.0f s", missing, FINAL_WAIT)
                    completed = True
                    break
            if ctx.stop.is_set():
                # Record what has already arrived (bounded), then stop.
                if stop_deadline is None:
                    stop_deadline = now + STOP_DRAIN
                    log.info("stop requested at t = %.0f s", mon.data.sim_t)
                if idle or now >= stop_deadline:
                    completed = mon.data.final_seen
                    break
        _final_stats(ctx, mon, inbox)
    finally:
        for sub in subs:
            sub.undeclare()
        while mon.recorder is not None:  # whatever arrived before the undeclare
            try:
                mon.handle(inbox.get_nowait())
            except queue.Empty:
                break
        if status is not None:
            status.close(mon.counters)
        if mon.recorder is not None:
            mon.recorder.close()
    if warming.ident is not None:
        warming.join()
    summary = write_report(
        Path(ctx.out), mon.data, completed=completed, monitor_counters=mon.counters
    )
    log.info(
        "report written to %s (completed=%s, %d messages recorded, %d rejected)",
        ctx.out,
        completed,
        mon.counters["recorded"],
        mon.counters["rejected"],
    )
    ok = len(summary["figures"]) > 0
    return 0 if ok else 1


def _final_stats(
    ctx: ServiceContext, mon: Monitor, inbox: queue.SimpleQueue[tuple[int, str, Any, int]]
) -> None:
    """Publish the monitor's own stats and record them too (they loop back locally)."""
    try:
        ctx.publish_stats(mon.data.sim_t, mon.counters)
    except Exception:
        log.exception("could not publish the monitor's stats")
        return
    deadline = time.monotonic() + 0.5
    topic = f"ddvi/{ctx.run}/stats/{ctx.name}"
    while time.monotonic() < deadline:
        try:
            item = inbox.get(timeout=0.05)
        except queue.Empty:
            continue
        mon.handle(item)
        if item[0] == _DATA and item[1] == topic:
            break


# ---- ddvi monitor [KEYEXPR] -----------------------------------------------------------------


def add_monitor_arguments(p: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """The arguments of ``ddvi monitor``, for ``services.cli``."""
    p.add_argument("keyexpr", nargs="?", default="ddvi/**", help="zenoh key expression")
    p.add_argument("--hub", default=DEFAULT_HUB, help="zenoh endpoint to connect to")
    p.add_argument("--count", type=int, default=0, help="stop after N messages (0: no limit)")
    p.add_argument("--seconds", type=float, default=0.0, help="stop after S s (0: no limit)")
    return p


def _compact(value: Any, width: int = 160) -> str:
    def short(v: Any) -> Any:
        if isinstance(v, np.ndarray):
            return np.round(v, 6).tolist()
        if isinstance(v, float):
            return float(f"{v:.6g}")
        if isinstance(v, dict):
            return {k: short(x) for k, x in v.items()}
        return v

    text = json.dumps(short(value), separators=(",", ":"), default=str)
    return text if len(text) <= width else text[: width - 3] + "..."


def format_sample(key: str, payload: bytes) -> list[str]:
    """One line per bus message of a zenoh sample (a batch holds several): key, schema, t,
    compact body (or why it is rejected)."""
    try:
        parts = unpack_batch(payload)
    except MessageError as err:
        return [f"{key} REJECTED {err.reason} ({len(payload)} B): {err}"]
    lines = []
    for part in parts or (payload,):
        try:
            msg = decode(part)
        except MessageError as err:
            lines.append(f"{key} REJECTED {err.reason} ({len(part)} B): {err}")
            continue
        body = _compact(msg.body)
        lines.append(f"{key} {msg.schema} t={msg.t:.3f} src={msg.src} seq={msg.seq} {body}")
    return lines


def monitor_command(args: argparse.Namespace, out: Callable[[str], None] | None = None) -> int:
    """``ddvi monitor [KEYEXPR] [--hub H] [--count N] [--seconds S]``: print each message on
    the bus as one line until Ctrl-C, N messages or S seconds. Returns 0."""
    emit = out or (lambda line: print(line, flush=True))
    settings = BusSettings(mode="peer", listen=[EPHEMERAL_LOOPBACK], connect=[args.hub])
    inbox: queue.SimpleQueue[tuple[str, bytes]] = queue.SimpleQueue()
    count, seconds = int(args.count or 0), float(args.seconds or 0.0)
    shown = 0
    with open_session(settings) as session:
        sub = session.declare_subscriber(
            args.keyexpr, lambda s: inbox.put((str(s.key_expr), s.payload.to_bytes()))
        )
        deadline = time.monotonic() + seconds if seconds > 0 else None
        try:
            while count <= 0 or shown < count:
                if deadline is not None and time.monotonic() >= deadline:
                    break
                try:
                    key, payload = inbox.get(timeout=0.1)
                except queue.Empty:
                    continue
                for line in format_sample(key, payload):
                    if count <= 0 or shown < count:
                        emit(line)
                        shown += 1
        except KeyboardInterrupt:
            pass
        finally:
            sub.undeclare()
    return 0


if __name__ == "__main__":
    sys.exit(run_service(main, "monitor"))
