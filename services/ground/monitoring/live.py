"""The live view: a run's messages served to Foxglove over its WebSocket protocol, as they arrive.

``ddvi run --live [HOST:PORT]`` serves from the monitor (the process that receives every
message already); ``ddvi monitor --run R --live [HOST:PORT]`` from a tap on a running mission.
``LiveServer`` (``foxglove-sdk``, an optional dependency: ``live_address.INSTALL``)
advertises one channel per topic of the run (``Deployment.topics``), each with the JSON schema the
recording gives it (``services.ground.storage.recording``), and sends each message as the
recording's JSON with its simulation time t as the message time.  The server's clock (the
protocol's ``time`` capability, which Foxglove stamps received messages with) is the
mission's simulation time, moved by the time master's clock messages.  Beside the bus
topics it serves ``live/<sc>/gains`` (``live_gains_topic``), sent with each of a deputy's
gains messages: the gains it flies and the optimal gains K*, L* of the truth's model
(``services.model.reference_gains``), each flattened, which Foxglove's message
paths index (they index one array level, and K is a matrix).

It also serves the formation as a 3D scene in Foxglove's schemas (``scene``: the scene
messages the monitor records, ``services.ground.monitoring.scene``) and the run's deployment
(``DEPLOYMENT_TOPIC``).  A client that subscribes is sent the last message of each state-like
channel at once (``services.ground.monitoring.live_latch``), so that one joining late sees who
is alive, each controller's phase, the gains against K* and the scene without waiting for them
to change.

The server never holds the caller up: a message no client subscribes to is not even encoded
(but a latched channel's last, when a client subscribes), the others are queued and handed to
the server in bursts from a thread of their own (``services.ground.monitoring.live_handoff``),
and a client that reads too slowly loses its oldest messages (``BACKLOG``) instead of slowing
the sender.  An error in the live view is logged and counted; it never reaches the recording.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import logging
import os
import threading
import time
from typing import Any

import orjson

from services.bus import worth_saying
from services.config import Deployment
from services.ground.analysis.outcome import TIME_MASTER
from services.ground.monitoring.live_address import LiveAddress
from services.ground.monitoring.live_handoff import Handoff
from services.ground.monitoring.live_latch import (
    LATCH_DELAY,
    LATCHED,
    Latch,
    Payload,
    payload_bytes,
    schema_kind,
)
from services.ground.monitoring.scene import SceneMessage
from services.ground.storage.recording import (
    ALIVE_SCHEMA,
    REJECTED_SCHEMA,
    message_json_schema,
    message_record,
    ns,
    rejected_record,
)
from services.interface import SCHEMAS, Message, MessageError, topics

log = logging.getLogger("ddvi.live")

BACKLOG = 8192  # messages queued per client before its oldest are dropped (a few MB at most)
SERVER_THREADS = "1"
"""The SDK server's worker threads (tokio's ``TOKIO_WORKER_THREADS``, unless the environment
sets it): one sends every client's frames; two cost about 12 % more CPU for the same messages
(``benchmarks.live_floor``) and take both of a 2-core machine's cores from the flight."""
CLOSE_DRAIN_S = 0.2
"""Wall seconds the server is given to send its last messages before it stops (it has no call
that waits for its queues, and stopping drops what they hold)."""
_ROW = {"type": "array", "items": {"type": "number"}}
LIVE_GAINS_SCHEMA: dict[str, Any] = {
    "title": "ddvi.live_gains",
    "type": "object",
    "description": "a deputy's flown gains against the optimal ones, flattened (live view only)",
    "properties": {
        "sc": {"type": "string"},
        "t": {"type": "number", "description": "simulation time, s"},
        "source": {"type": "string", "description": "where the flown gains come from"},
        "K": _ROW | {"description": "the flown K, row by row (1/m, s/m)"},
        "L": _ROW | {"description": "the flown L, row by row (1)"},
        "K_star": _ROW | {"description": "K* of the truth's model (empty: none, or not yet)"},
        "L_star": _ROW | {"description": "L* of the truth's model (empty: none, or not yet)"},
    },
    "required": ["sc", "t", "source", "K", "L", "K_star", "L_star"],
}
DEPLOYMENT_TOPIC = "live/deployment"
"""The run's deployment, every key with its value (``DEPLOYMENT_SCHEMA``), sent at t = 0."""
DEPLOYMENT_SCHEMA: dict[str, Any] = {
    "title": "ddvi.deployment",
    "type": "object",
    "description": "the run and its deployment, every key with the value it flies with",
    "properties": {
        "run": {"type": "string"},
        "path": {"type": "string", "description": "the deployment file"},
        "deployment": {"type": "object"},
    },
    "required": ["run", "path", "deployment"],
}


def _json(data: Any) -> bytes:
    return orjson.dumps(data, option=orjson.OPT_SERIALIZE_NUMPY)


def live_gains_topic(deputy: str) -> str:
    """``live/<deputy>/gains``: the live view's gains against K* (``LIVE_GAINS_SCHEMA``)."""
    return f"live/{deputy}/gains"


@functools.cache
def _bus_channel(name: str) -> tuple[str, dict[str, Any]]:
    """A bus message type's channel schema: its name (``ddvi.<type>``) and the recording's
    JSON schema, built once."""
    return f"ddvi.{name}", message_json_schema(SCHEMAS[name])


def reference_gains(dep: Deployment) -> dict[str, tuple[list[float], list[float]]]:
    """Deputy -> (K*, L*) flattened, empty for a deputy whose truth has no optimal gains."""
    from services.model import reference_gains as optimal

    out: dict[str, tuple[list[float], list[float]]] = {}
    for d in dep.deputy:
        K, L = optimal(dep, d)
        flat = K is not None and L is not None
        out[d.name] = (K.ravel().tolist(), L.ravel().tolist()) if flat else ([], [])
    return out


def _subscriptions(latch: Latch, watched: threading.Event) -> Any:
    """The server's listener (a ``foxglove.websocket.ServerListener``, whose other callbacks
    do nothing): each subscription is owed its channel's last message (``Latch``); the first
    sets ``watched`` ``LATCH_DELAY`` s later, once the server routes to the client what it
    asked for in the same request (a message said because it came, such as the monitor's
    "a client subscribed", would otherwise race its own channel's subscription)."""
    from foxglove.websocket import ServerListener

    class Subscriptions(ServerListener):
        def __init__(self) -> None:
            self.first = threading.Timer(LATCH_DELAY, watched.set)
            self.first.daemon = True
            self.lock = threading.Lock()

        def on_subscribe(self, client: Any, channel: Any) -> None:
            try:
                latch.subscribed(channel.topic)
                with self.lock:
                    if self.first.ident is None:  # not started yet
                        self.first.start()
            except Exception:  # a callback of the server's must never raise
                log.exception("live view: a subscription to %s not taken", channel.topic)

    return Subscriptions()


class LiveServer:
    """A Foxglove WebSocket server of one run's messages (see the module's docstring)."""

    def __init__(
        self,
        address: LiveAddress,
        name: str,
        advertise: dict[str, tuple[str, dict[str, Any] | Any]],
        references: dict[str, tuple[list[float], list[float]]],
    ) -> None:
        """Listen on ``address`` and advertise ``advertise`` (topic -> (schema name, JSON
        schema or Foxglove schema)) at once; other topics are advertised when their first
        message comes."""
        import foxglove
        from foxglove.websocket import Capability

        self._foxglove = foxglove
        self._context = foxglove.Context()
        # topic -> (its channel, the schema name it was made with, latched): what a message
        # on it needs, looked up once a message
        self._routes: dict[str, tuple[Any, str, bool]] = {}
        self.references = references  # deputy -> (K*, L*), flattened
        self._time = -1
        self.counters = {"served": 0, "errors": 0, "unserved": 0}
        for topic, (schema_name, schema) in advertise.items():
            self._route(topic, schema_name, schema)
        self.latch = Latch(self._resend)
        self.watched = threading.Event()  # set once a client has subscribed (LATCH_DELAY after)
        os.environ.setdefault("TOKIO_WORKER_THREADS", SERVER_THREADS)  # read as the server starts
        self._server = foxglove.start_server(
            name=name,
            host=address.host,
            port=address.port,
            capabilities=[Capability.Time],
            server_listener=_subscriptions(self.latch, self.watched),
            context=self._context,
            message_backlog_size=BACKLOG,
        )
        self._handoff = Handoff(self._server.broadcast_time)

    def _route(
        self, topic: str, schema_name: str, schema: dict[str, Any] | Any
    ) -> tuple[Any, str, bool]:
        """``topic``'s route (its channel, schema name, latched), its channel made on first use
        with ``schema``: a JSON schema (a dict: the recording's), or a Foxglove schema from the
        SDK (the scene's, protobuf)."""
        route = self._routes.get(topic)
        if route is None:
            if isinstance(schema, dict):
                data = json.dumps(schema).encode()  # the recording's schema bytes
                schema = self._foxglove.Schema(name=schema_name, encoding="jsonschema", data=data)
                encoding = "json"
            else:
                encoding = schema.encoding
            channel = self._foxglove.Channel(
                topic, schema=schema, message_encoding=encoding, context=self._context
            )
            latched = schema_kind(schema_name) in LATCHED
            route = self._routes[topic] = (channel, schema_name, latched)
        return route

    def _send(
        self,
        topic: str,
        schema_name: str,
        schema: dict[str, Any] | Any,
        payload: Payload,
        t: int,
    ) -> None:
        """Serve ``payload`` on ``topic`` at ``t`` ns if a client subscribes to it; keep it
        for a client to come when its channel is latched."""
        channel, advertised, latched = self._routes.get(topic) or self._route(
            topic, schema_name, schema
        )
        if advertised != schema_name:  # one channel a topic: a stray schema
            self.counters["unserved"] += 1
            return
        if latched:
            self.latch.keep(topic, payload, t)
        if channel.has_sinks():  # nobody subscribed: not even encoded
            self._handoff.put(channel, payload_bytes(payload), t)
            self.counters["served"] += 1

    def _resend(self, topic: str, data: bytes, t: int) -> None:
        """A latched message, to a client that has just subscribed (the latch's thread)."""
        self._routes[topic][0].log(data, log_time=t)

    def _failed(self, what: str) -> None:
        n = self.counters["errors"] = self.counters["errors"] + 1
        if worth_saying(n):
            log.exception("live view: could not serve %s (#%d)", what, n)

    def message(self, topic: str, msg: Message, recorded: bytes | None = None) -> None:
        """Serve a decoded bus message at its simulation time (``recorded``: its JSON as the
        recording has it, when it was written there); the time master's clock moves the
        server's time."""
        try:
            t = ns(msg.t)
            if msg.schema == "clock" and msg.src == TIME_MASTER and t > self._time:
                self._time = t
                self._handoff.time(t)
            payload: Payload = (
                recorded if recorded is not None else functools.partial(_json, message_record(msg))
            )
            name, schema = _bus_channel(msg.schema)
            self._send(topic, name, schema, payload, t)
            if msg.schema == "gains":
                self._gains(topic.split("/")[1], msg)  # the topic's deputy, not the body's
        except Exception:
            self._failed(topic)

    def _gains(self, sc: str, msg: Message) -> None:
        topic = live_gains_topic(sc)
        payload = functools.partial(self._gains_payload, sc, msg)
        self._send(topic, "ddvi.live_gains", LIVE_GAINS_SCHEMA, payload, ns(msg.t))

    def _gains_payload(self, sc: str, msg: Message) -> bytes:
        """A deputy's gains against K* as known when it is sent: a client joining once K* is
        solved gets it with the last gains, however long before those were flown."""
        K_star, L_star = self.references.get(sc, ([], []))
        b = msg.body
        data = {
            "sc": sc,
            "t": msg.t,
            "source": b["source"],
            "K": b["K"].ravel(),
            "L": b["L"].ravel(),
            "K_star": K_star,
            "L_star": L_star,
        }
        return _json(data)

    def scene(self, msg: SceneMessage) -> None:
        """Serve a scene message (``services.ground.monitoring.scene``), as recorded."""
        try:
            self._send(msg.topic, msg.schema.name, msg.schema, msg.data, msg.log_ns)
        except Exception:
            self._failed(msg.topic)

    def deployment(self, dep: Deployment, run: str) -> None:
        """Serve ``run``'s deployment (``DEPLOYMENT_TOPIC``), at t = 0."""
        try:
            data = {"run": run, "path": dep.path, "deployment": dataclasses.asdict(dep)}
            payload = functools.partial(_json, data)
            self._send(DEPLOYMENT_TOPIC, "ddvi.deployment", DEPLOYMENT_SCHEMA, payload, 0)
        except Exception:
            self._failed(DEPLOYMENT_TOPIC)

    def rejected(self, topic: str, key: str, payload: bytes, err: MessageError, t: float) -> None:
        """Serve a payload that did not decode, as the recording has it, at simulation time t."""
        try:
            data = functools.partial(_json, rejected_record(key, payload, err))
            self._send(f"rejected/{topic}", "ddvi.rejected", REJECTED_SCHEMA, data, ns(t))
        except Exception:
            self._failed(f"rejected/{topic}")

    def alive(self, service: str, alive: bool, t: float) -> None:
        """Serve a liveliness change, as the recording has it, at simulation time t."""
        try:
            data = functools.partial(_json, {"service": service, "alive": alive})
            self._send(topics.alive_topic(service), "ddvi.alive", ALIVE_SCHEMA, data, ns(t))
        except Exception:
            self._failed(topics.alive_topic(service))

    def subscribed(self, topic: str) -> bool:
        """Whether a client subscribes to ``topic`` now."""
        route = self._routes.get(topic)
        return route is not None and route[0].has_sinks()

    def close(self) -> None:
        """Stop serving (clients see the connection close); idempotent."""
        self.latch.close()
        self._handoff.close()
        if self.counters["served"] or self.latch.sent:  # a client may have some still to come
            time.sleep(CLOSE_DRAIN_S)
        try:
            self._server.stop()
        except Exception:
            log.exception("live view: could not stop the server")
        counters = {**self.counters, "latched": self.latch.sent, "lost": self._handoff.errors}
        log.info("live view closed: %s", counters)


def live_server(
    address: LiveAddress,
    dep: Deployment,
    run: str,
    liveliness: bool = True,
    scene: list[tuple[str, Any]] | None = None,
) -> LiveServer:
    """A LiveServer of ``run`` advertising every topic of ``dep`` (with its liveliness topics:
    ``liveliness``), each deputy's gains against K*, the deployment and the ``scene``'s
    channels ((topic, Foxglove schema); ``services.ground.monitoring.scene.Scene.channels``).
    K* is solved on a thread of its own (a second of imports and Riccati solves, which must
    not hold the caller up): the live gains carry an empty K* until it is known."""
    advertise: dict[str, tuple[str, Any]] = {t: _bus_channel(s) for t, s in dep.topics().items()}
    for d in dep.deputy:
        advertise[live_gains_topic(d.name)] = ("ddvi.live_gains", LIVE_GAINS_SCHEMA)
    if liveliness:
        for service in dep.services:
            advertise[topics.alive_topic(service)] = ("ddvi.alive", ALIVE_SCHEMA)
    for topic, schema in scene or []:
        advertise[topic] = (schema.name, schema)
    server = LiveServer(address, f"ddvi {run}", advertise, {})
    server.deployment(dep, run)

    def solve() -> None:
        try:
            server.references = reference_gains(dep)
        except Exception:
            log.exception("live view: no K* (its gains are served without)")

    threading.Thread(target=solve, name="live-k-star", daemon=True).start()
    return server
