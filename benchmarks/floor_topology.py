"""The lock-step floor on the mission's topology: its processes as authenticated clients of one
router that enforces the run's access control, and a monitor that records every message to
MCAP as the ground monitor does (``benchmarks.floor``, ``--topology routed``).

The driver is the router, as the launcher is in a mission: it issues every process its
credentials (``services.bus.security.issue_credentials``) and enforces
``services.bus.security.access_control`` for the floor's run, so each process may put only
its own topics and liveliness token.  The monitor's subscriber callback stamps and queues what
arrives; its main thread, at the ground monitor's niceness, takes it apart message by message,
decodes it (msgpack maps on the ``plain`` layer; the project's schema decode on ``bus``) and
writes each message to ``recording.mcap`` with ``services.ground.storage.recording.Recorder``,
flushing every ``FLUSH_PERIOD`` s.
"""

from __future__ import annotations

import functools
import os
import queue
import time
from pathlib import Path
from typing import Any

import msgpack
import zenoh

from services.bus import BusSettings
from services.bus.security import (
    DICTIONARY,
    ROUTER,
    SECURITY_DIR,
    access_control,
    credentials_path,
    issue_credentials,
    load_credentials,
)
from services.ground.monitoring.monitor import FLUSH_PERIOD, NICENESS
from services.ground.storage.recording import RECORDING, Recorder, message_json_schema, ns
from services.interface import SCHEMAS, MessageError, decode, schema_for_topic, unpack_batch

TOPOLOGIES = ("peer", "routed")


@functools.cache
def _recorded_schema(name: str) -> dict[str, Any]:
    return message_json_schema(SCHEMAS[name])


def router_settings(folder: Path, run: str, names: list[str], hub: str) -> BusSettings:
    """The driver's session on the routed topology: a router on ``hub`` that authenticates
    every one of ``names`` (credentials written to ``folder``) and enforces the access control
    the launcher gives a run of those services."""
    router = issue_credentials(folder, names)[ROUTER]
    return BusSettings(
        mode="router",
        listen=[hub],
        connect=[],
        user=router.user,
        password=router.password,
        dictionary=str(folder / SECURITY_DIR / DICTIONARY),
        access_control=access_control(run, names),
    )


def client_settings(folder: Path, name: str, hub: str) -> BusSettings:
    """A process's session on the routed topology: the router's client, listening on nothing,
    with its own credentials."""
    creds = load_credentials(credentials_path(folder, name))
    return BusSettings(
        mode="client", listen=[], connect=[hub], user=creds.user, password=creds.password
    )


class FloorRecorder:
    """What the floor's monitor does on the routed topology: every sample queued by the
    callback, recorded message by message on the main thread."""

    def __init__(self, folder: Path, layer: str, prefix: str) -> None:
        self.layer, self.prefix = layer, prefix
        self.recorder = Recorder(folder / RECORDING, {"run": "floor"}, None)
        self.inbox: queue.SimpleQueue[tuple[str, bytes, int]] = queue.SimpleQueue()
        self.flushed = time.monotonic()
        os.nice(NICENESS)  # the main thread, as the ground monitor's

    def on_sample(self, sample: zenoh.Sample) -> None:
        self.inbox.put((str(sample.key_expr), sample.payload.to_bytes(), time.time_ns()))

    def take(self, timeout: float) -> str:
        """Record the next sample; its key."""
        key, payload, recv_ns = self.inbox.get(timeout=timeout)
        self.record(key, payload, recv_ns)
        return key

    def record(self, key: str, payload: bytes, recv_ns: int) -> None:
        topic = key[len(self.prefix) :]
        if self.layer == "plain":
            try:
                messages = msgpack.unpackb(payload)
            except ValueError:
                messages = []  # the stop: nothing to record
            for m in messages:
                schema = m["schema"]
                self.recorder.write(
                    topic,
                    f"ddvi.{schema}",
                    _recorded_schema(schema),
                    m,
                    recv_ns,
                    ns(m["t"]),
                    m["seq"],
                )
        else:
            try:
                parts = unpack_batch(payload) or (payload,)
                for part in parts:
                    self.recorder.message(topic, decode(part, schema_for_topic(topic)), recv_ns)
            except MessageError:
                pass  # the stop: nothing to record
        now = time.monotonic()
        if now - self.flushed >= FLUSH_PERIOD:
            self.recorder.flush()
            self.flushed = now

    def close(self) -> dict[str, Any]:
        self.recorder.close()
        return {"recorded": self.recorder.messages}
