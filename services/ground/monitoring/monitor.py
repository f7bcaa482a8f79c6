"""The ground monitor: records every bus message, shows live status, writes the run report.

Run by the launcher, first of all services::

    python -m services.ground.monitoring.monitor --deployment F --run R --hub H --out DIR

It subscribes to ``ddvi/<run>/**`` with a raw zenoh subscriber (not ``Bus.subscribe``, so that
undecodable payloads are recorded too) and to the run's liveliness tokens, and writes
``DIR/recording.mcap`` (``services.ground.storage.recording``; a batch,
``services.interface.unpack_batch``, message by message).  A sample past its key's rate budget
(``services.bus.budget``) is dropped in the subscriber's callback
(``services.ground.monitoring.intake``), unread and unqueued, and counted (``flooded``,
``flood.<publisher>``): a flood never puts the monitor behind.

A message whose (publisher, topic, seq) was seen already, or is older than the receiver's
sequence window (``services.bus.SequenceGuard``), is recorded but kept out of the report and
counted (``ignored.duplicate``, ``ignored.stale``); a payload whose schema is not the one its
topic carries (``services.interface.schema_for_topic``) is rejected ``wrong_schema``. One its
publisher may not send, or whose body names another deputy or service than its topic, is
recorded but believed of nobody (``services.ground.analysis.refusals``: counted by publisher,
topic and reason, listed in the report).

The file is flushed (chunk closed and written to the OS) every ``FLUSH_PERIOD`` s, so a kill -9
of the monitor loses at most that much; ``read_recording`` reads such a footer-less file too.
On a normal stop and on SIGTERM the writer is closed (summary and footer written).

When the ``clock`` message with ``final = true`` arrives the monitor waits until every other
service of the deployment has finished or ``FINAL_WAIT`` s pass
(``services.ground.monitoring.ending``), then closes the recording, writes the report
(``services.ground.analysis.report``) and exits 0. A service seen alive has finished when its
liveliness token is gone (services publish their final stats before leaving); one never seen
alive, when it has sent stats with t >= the final time.
Messages from different publishers are not ordered with respect to each other, so a service's
final stats may arrive before the final clock; what arrives within ``FINAL_GRACE`` s after the
last service finished is still recorded. SIGTERM before that closes the recording and writes a
partial report (``"completed": false``), also exit 0.

The formation as a 3D scene in Foxglove's schemas (``services.ground.monitoring.scene``) is
made from the truth and navigation received and recorded beside them.

Live status: ``services.ground.monitoring.status``, refreshed every ``DRAW_PERIOD`` s.  With
``--live HOST:PORT`` (``ddvi run --live``) every message recorded is also served to Foxglove
(``services.ground.monitoring.live``), after it is recorded and never in its way; the first
client is said on ``log/monitor`` (``CLIENT_JOINED``: what ``--wait-for-client`` waits for).
"""

from __future__ import annotations

import os

# BLAS threads would compete with the flight services for the cores
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse
import functools
import logging
import math
import queue
import sys
import time
from pathlib import Path
from typing import Any

from services.bus import SEQUENCE_REASONS, SequenceGuards, worth_saying
from services.flight.health import RECORDER_ACK_STEPS
from services.flight.runtime import ServiceContext, run_service
from services.ground.analysis.outcome import TIME_MASTER
from services.ground.analysis.report import ReportNotWrittenError, write_report
from services.ground.analysis.rundata import RunData
from services.ground.monitoring.ending import Ending
from services.ground.monitoring.intake import ALIVE, DATA, Inbox, Item, subscribe
from services.ground.monitoring.live import LiveServer, live_server
from services.ground.monitoring.live_address import CLIENT_JOINED, parse_address
from services.ground.monitoring.scene import Scene, open_scene
from services.ground.monitoring.status import Status
from services.ground.storage.disk import LogFile
from services.ground.storage.record import RecordGaps
from services.ground.storage.recording import RECORDING, TIMELINE, Recorder
from services.interface import (
    REASONS,
    Message,
    MessageError,
    decode,
    schema_for_topic,
    topics,
    unpack_batch,
)

log = logging.getLogger("ddvi.monitor")

FLUSH_PERIOD = 0.5  # s between recording flushes (bounds the loss on kill -9)
DRAW_PERIOD = 0.5  # s between live status refreshes
# s to record what is still queued once the subscribers are gone: the recording must be closed
# (its summary and footer written) well within the launcher's report grace, whatever the backlog
CLOSE_DRAIN = 10.0
FINAL_STATS_WAIT = 0.5  # s to wait for the monitor's own final stats to loop back
# The monitor is the ground: it records and reports, and the flight loop waits on it only when
# lock-step runs more than its lead past what it has recorded (services.flight.recorder_lead).
# Its main thread yields the CPU to the flight services, and takes what arrived in batches
# instead of waking for every sample. The threads that receive and stamp samples (zenoh's, and
# the subscriber's callback thread) keep their priority: a slowed receiver would fill zenoh's
# queue to the callback and hold up every publisher (congestion control BLOCK).
NICENESS = 10
POLL = 0.05  # s the main loop waits for a sample before it looks at the clocks again
BATCH_PERIOD = 0.005  # s the main loop lets samples gather once one has come
BATCH_MAX = 512  # samples a batch at most: flushing, the status and a stop are looked at between


class Monitor:
    """The monitor's state machine, driven by ``handle`` (one queued item at a time)."""

    def __init__(self, ctx: ServiceContext) -> None:
        self.ctx = ctx
        self.prefix = f"ddvi/{ctx.run}/"
        self.alive_prefix = self.prefix + topics.alive_topic("")
        # what the rate budget dropped from a publisher: its sequence numbers ran on by that
        # much, and its stats may count it (claims)
        budget = ctx.bus.budget
        self.dropped_from = budget.dropped_from if budget is not None else lambda _src: 0
        self.data = RunData(ctx.deployment, ctx.run, self.dropped_from)
        self.counters: dict[str, int] = dict.fromkeys(
            ("received", "recorded", "rejected", "handler_errors"), 0
        )
        self.counters.update({f"rejected.{r}": 0 for r in sorted(REASONS)})
        # recorded, but kept out of the report: a replayed stats or gains message must not
        # overwrite newer figures
        self.counters.update({f"ignored.{r}": 0 for r in SEQUENCE_REASONS})
        # a clock from anyone but the environment (the time master) is recorded, never obeyed:
        # it must not end the mission nor move its time
        self.counters["refused.clock"] = 0
        # a message its publisher may not send, or whose body names another deputy or service
        # than its topic: recorded, never believed (services.ground.analysis.refusals)
        self.counters["refused.origin"] = 0
        self.guards = SequenceGuards()
        self.alive: set[str] = set()
        self.ever_alive: set[str] = set()
        self.others = [s for s in ctx.deployment.services if s != ctx.name]
        self.recorder: Recorder | None = None
        self.scene: Scene | None = None  # the 3D scene, recorded (and served) beside
        self.live: LiveServer | None = None  # the live view, fed after the recorder
        self.client_said = False  # the live view's first client said on log/monitor

    def open_recording(self) -> None:
        dep = self.ctx.deployment
        meta = {
            "run": self.ctx.run,
            "deployment": dep.path,
            "deputies": ",".join(f"{d.name}:{d.controller}" for d in dep.deputy),
            "orbit_period_s": repr(self.data.period),
            "started_ns": str(time.time_ns()),
            "services": ",".join(dep.services),
            **TIMELINE,
        }
        attach = Path(dep.path) if dep.path else None
        self.recorder = Recorder(Path(self.ctx.out) / RECORDING, meta, attach)

    def handle(self, item: Item) -> None:
        kind, key, value, recv_ns = item
        rec = self.recorder
        assert rec is not None
        if kind == ALIVE:
            name = key[len(self.alive_prefix) :]
            if value:
                self.alive.add(name)
                self.ever_alive.add(name)
            else:
                self.alive.discard(name)
            rec.alive(name, bool(value), recv_ns, self.data.sim_t)
            self.counters["recorded"] = rec.messages
            if self.live is not None:
                self.live.alive(name, bool(value), self.data.sim_t)
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

    def draw(self, topic: str, msg: Message, recv_ns: int) -> None:
        """The scene messages ``msg`` completes, recorded and served (an error is counted:
        the recording goes on without the scene)."""
        assert self.scene is not None and self.recorder is not None
        try:
            for m in self.scene.message(topic, msg):
                self.recorder.scene(m.topic, m.schema, m.data, m.log_ns, recv_ns)
                if self.live is not None:
                    self.live.scene(m)
        except Exception:
            if worth_saying(n := self.tally("scene_errors")):
                log.exception("could not draw the scene at t = %s (#%d)", msg.t, n)

    def say_client(self) -> None:
        """Say on ``log/monitor`` that the live view has its first client, once."""
        if self.live is None or self.client_said or not self.live.watched.is_set():
            return
        self.client_said = True
        try:
            self.ctx.log("info", f"{CLIENT_JOINED} at t = {self.data.sim_t:.0f} s", self.data.sim_t)
        except Exception:
            log.exception("could not say the live view's first client")

    def tally(self, key: str) -> int:
        """Count one more ``key``; its count."""
        n = self.counters[key] = self.counters.get(key, 0) + 1
        return n

    def reject(self, topic: str, key: str, value: bytes, err: MessageError, recv_ns: int) -> None:
        assert self.recorder is not None
        self.counters["rejected"] += 1
        if worth_saying(n := self.tally(f"rejected.{err.reason}")):
            log.warning("rejected %s (%s, #%d): %s", key, err.reason, n, err)
        self.recorder.rejected(topic, key, value, err, recv_ns, self.data.sim_t)
        if self.live is not None:
            self.live.rejected(topic, key, value, err, self.data.sim_t)
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
        recorded = rec.message(topic, msg, recv_ns)  # everything received is recorded
        self.counters["recorded"] = rec.messages
        self.data.received(msg)  # and counted against its publisher's stats (claims)
        if self.live is not None:
            self.live.message(topic, msg, recorded)  # the same JSON, encoded once
        if msg.schema == "clock" and msg.src != TIME_MASTER:
            if worth_saying(n := self.tally("refused.clock")):
                log.warning(
                    "refused a clock from %r (only %s keeps time; #%d)", msg.src, TIME_MASTER, n
                )
            return
        if not self.data.refusals.accepts(topic, msg):  # its topic does not let it say that
            self.counters["refused.origin"] += 1
            return
        if (why := self.guards.check(msg, topic, self.dropped_from)) is not None:
            if worth_saying(n := self.tally(f"ignored.{why}")):
                log.warning("not reported %s seq %d (%s, #%d)", key, msg.seq, why, n)
            return
        try:
            self.data.ingest(topic, msg)
        except Exception:  # one odd message must not take the recording down
            self.counters["handler_errors"] += 1
            log.exception("could not use %s at t = %s", key, msg.t)
        if self.scene is not None:  # what the report believes, and no other
            self.draw(topic, msg, recv_ns)
        if msg.schema == "clock":
            self.acknowledge(msg)

    def acknowledge(self, clock: Message) -> None:
        """In lock-step, at every ``RECORDER_ACK_STEPS``-th flight-software step's clock: say
        that it is recorded, with what came before it (the environment flies at most
        ``RECORDER_LEAD_STEPS`` past it, ``services.flight.recorder_lead``)."""
        run = self.ctx.deployment.run
        if run.mode != "lockstep" or not clock.body["fsw"]:
            return
        if round(clock.t / run.fsw_period) % RECORDER_ACK_STEPS:
            return
        assert self.recorder is not None
        body = {"messages": self.recorder.messages}
        try:
            self.ctx.bus.publish(topics.RECORDED, "recorded", body, clock.t)
        except Exception:  # the recording goes on; lock-step then waits and names the monitor
            log.exception("could not acknowledge the recording at t = %s", clock.t)

    def count_floods(self) -> None:
        """The budget's drops into the counters (``flooded``, ``flood.<publisher>``)."""
        budget = self.ctx.bus.budget
        if budget is not None:
            flood = budget.counters()
            self.counters["flooded"] = sum(flood.values())
            self.counters.update(flood)

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


def _take_batch(mon: Monitor, inbox: Inbox, first: Item) -> None:
    """Handle ``first`` and what else gathered within ``BATCH_PERIOD`` (``BATCH_MAX`` at most)."""
    time.sleep(BATCH_PERIOD)
    mon.handle(first)
    for _ in range(BATCH_MAX - 1):
        try:
            item = inbox.get_nowait()
        except queue.Empty:
            break
        mon.handle(item)


def _record(ctx: ServiceContext, mon: Monitor, inbox: Inbox, status: Status) -> bool:
    """Record until the run ends or a stop is requested; return whether it completed."""
    assert mon.recorder is not None
    last_flush = last_draw = time.monotonic()
    ending = Ending()
    while True:
        try:
            item: Item | None = inbox.get(timeout=POLL)
        except queue.Empty:
            item = None
        if item is not None:
            _take_batch(mon, inbox, item)
        now = time.monotonic()
        if now - last_flush >= FLUSH_PERIOD:
            mon.recorder.flush()
            last_flush = now
        mon.say_client()
        if now - last_draw >= DRAW_PERIOD:
            mon.count_floods()
            status.update(mon.counters)
            last_draw = now
        completed = ending.check(mon, ctx.stop.is_set(), idle=item is None, now=now)
        if completed is not None:
            return completed


def _close(subs: tuple[Any, Any], mon: Monitor, inbox: Inbox, status: Status | None) -> None:
    """Undeclare the subscribers, record what arrived before, close the status and the file."""
    for sub in subs:
        sub.undeclare()
    deadline = time.monotonic() + CLOSE_DRAIN
    while mon.recorder is not None:  # whatever arrived before the undeclare (bounded)
        try:
            item = inbox.get_nowait()
        except queue.Empty:
            break
        if time.monotonic() > deadline:  # a backlog: the recording is closed whole instead
            mon.counters["unrecorded"] = mon.counters.get("unrecorded", 0) + 1 + inbox.qsize()
            log.error(
                "%d queued samples not recorded: closing the recording in time",
                mon.counters["unrecorded"],
            )
            break
        mon.handle(item)
    if status is not None:
        status.close(mon.counters)
    if mon.recorder is not None:
        mon.recorder.close()


def _final_stats(ctx: ServiceContext, mon: Monitor, inbox: Inbox) -> None:
    """Publish the monitor's own stats and record them too (they loop back locally)."""
    mon.count_floods()
    try:
        ctx.publish_stats(mon.data.sim_t, mon.counters)
    except Exception:
        log.exception("could not publish the monitor's stats")
        return
    deadline = time.monotonic() + FINAL_STATS_WAIT
    key = f"ddvi/{ctx.run}/{topics.stats_topic(ctx.name)}"
    while time.monotonic() < deadline:
        try:
            item = inbox.get(timeout=POLL)
        except queue.Empty:
            continue
        mon.handle(item)
        if item[0] == DATA and item[1] == key:
            break


def _report(ctx: ServiceContext, mon: Monitor, completed: bool) -> int:
    """Write the run report; 0 when it has figures (or names those its disk had no room for),
    else 1 (also when it could not be written, said in one line)."""
    queued = mon.counters.get("unrecorded", 0)  # still queued when the recording closed
    gaps = mon.recorder.gaps(queued) if mon.recorder else RecordGaps(queued_at_close=queued)
    try:
        summary = write_report(
            Path(ctx.out), mon.data, completed=completed, monitor_counters=mon.counters, gaps=gaps
        )
    except ReportNotWrittenError as exc:
        log.error("no report: %s", exc)
        return 1
    log.info(
        "report written to %s (completed=%s, %d messages recorded, %d rejected)",
        ctx.out,
        summary["completed"],  # the report's word: the final clock at the planned end
        mon.counters["recorded"],
        mon.counters["rejected"],
    )
    return 0 if summary["figures"] or summary["not_written"] else 1


def log_to_file_too() -> None:
    """Also log to stdout when it is not where stderr goes: the launcher gives the monitor the
    terminal's stderr (for the live status) and its log file as stdout, which then holds
    every line logged (and a crash's traceback) as every other service's log does."""
    try:
        out, err = os.fstat(sys.stdout.fileno()), os.fstat(sys.stderr.fileno())
    except (OSError, ValueError, AttributeError):
        return
    if (out.st_dev, out.st_ino) == (err.st_dev, err.st_ino):
        return
    handler = LogFile(sys.stdout)  # on a full disk: its lines lost, said once, no traceback
    root = logging.getLogger()
    if root.handlers and root.handlers[0].formatter is not None:
        handler.setFormatter(root.handlers[0].formatter)
    root.addHandler(handler)


def main(ctx: ServiceContext, live: str | None = None) -> int:
    """Record the run until it ends or is stopped, then write its report; with ``live``
    (HOST:PORT), serve it live too."""
    try:
        return _main(ctx, live)
    except Exception:
        log.exception("the monitor failed")  # into its log file, not the terminal alone
        raise


def _open_live(ctx: ServiceContext, address: str, scene: Scene | None) -> LiveServer | None:
    """The live view on ``address`` (with the ``scene``'s channels), or None (logged) when it
    cannot serve: the recording goes on without it."""
    try:
        channels = scene.channels() if scene is not None else []
        server = live_server(parse_address(address), ctx.deployment, ctx.run, scene=channels)
    except Exception:
        log.exception("the live view on %s is not served", address)
        return None
    log.info("live view on %s", address)
    return server


def _main(ctx: ServiceContext, live_address: str | None = None) -> int:
    inbox: Inbox = queue.SimpleQueue()
    # Subscribe before anything else: the other services declare themselves alive, and
    # publish, once they see this process alive (services.flight.runtime).
    subs = subscribe(ctx.bus.session, ctx.run, inbox, ctx.bus.budget)
    os.nice(NICENESS)  # this thread and those it starts later; not the callback's, started
    # the live view's threads are started here, so they yield to the flight too; before the
    # token, so that it serves once the launcher sees the monitor
    scene = open_scene(ctx.deployment)
    live = _open_live(ctx, live_address, scene) if live_address else None
    ctx.ready()
    mon = Monitor(ctx)
    mon.live, mon.scene = live, scene
    status: Status | None = None
    completed = False
    try:
        mon.open_recording()
        assert mon.recorder is not None
        status = Status(mon.data, sys.stderr.isatty())
        log.info("recording %s to %s", f"ddvi/{ctx.run}/**", mon.recorder.path)
        completed = _record(ctx, mon, inbox, status)
        _final_stats(ctx, mon, inbox)
    finally:
        _close(subs, mon, inbox, status)
        ctx.bus.withdraw()  # the recording is closed: the services that outlast it may go
        if live is not None:
            live.close()
    return _report(ctx, mon, completed)


if __name__ == "__main__":
    logging.basicConfig(
        level=logging.INFO,
        stream=sys.stderr,
        format="%(asctime)s monitor %(levelname)s %(message)s",
    )
    log_to_file_too()
    # --live HOST:PORT is the monitor's own argument; the rest are every service's
    options = argparse.ArgumentParser(add_help=False)
    options.add_argument("--live")
    known, rest = options.parse_known_args()
    sys.exit(run_service(functools.partial(main, live=known.live), "monitor", rest))
