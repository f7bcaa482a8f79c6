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

The server never holds the caller up: a message no client subscribes to is not even encoded,
and a client that reads too slowly loses its oldest messages (``BACKLOG``) instead of slowing
the sender.  An error in the live view is logged and counted; it never reaches the recording.
"""

from __future__ import annotations

import functools
import json
import logging
import threading
from typing import Any

import orjson

from services.bus import worth_saying
from services.config import Deployment
from services.ground.monitoring.live_address import LiveAddress
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
TIME_MASTER = "environment"  # the one service whose clock moves the live view's time
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


def live_gains_topic(deputy: str) -> str:
    """``live/<deputy>/gains``: the live view's gains against K* (``LIVE_GAINS_SCHEMA``)."""
    return f"live/{deputy}/gains"


@functools.cache
def _bus_schema(name: str) -> dict[str, Any]:
    """The recording's JSON schema of a bus message type, built once."""
    return message_json_schema(SCHEMAS[name])


def reference_gains(dep: Deployment) -> dict[str, tuple[list[float], list[float]]]:
    """Deputy -> (K*, L*) flattened, empty for a deputy whose truth has no optimal gains."""
    from services.model import reference_gains as optimal

    out: dict[str, tuple[list[float], list[float]]] = {}
    for d in dep.deputy:
        K, L = optimal(dep, d)
        flat = K is not None and L is not None
        out[d.name] = (K.ravel().tolist(), L.ravel().tolist()) if flat else ([], [])
    return out


class LiveServer:
    """A Foxglove WebSocket server of one run's messages (see the module's docstring)."""

    def __init__(
        self,
        address: LiveAddress,
        name: str,
        advertise: dict[str, tuple[str, dict[str, Any]]],
        references: dict[str, tuple[list[float], list[float]]],
    ) -> None:
        """Listen on ``address`` and advertise ``advertise`` (topic -> (schema name, JSON
        schema)) at once; other topics are advertised when their first message comes."""
        import foxglove
        from foxglove.websocket import Capability

        self._foxglove = foxglove
        self._context = foxglove.Context()
        self._channels: dict[str, Any] = {}
        self._schema_names: dict[str, str] = {}  # topic -> its channel's schema name
        self.references = references  # deputy -> (K*, L*), flattened
        self._time = -1
        self.counters = {"served": 0, "errors": 0, "unserved": 0}
        for topic, (schema_name, schema) in advertise.items():
            self._channel(topic, schema_name, schema)
        self._server = foxglove.start_server(
            name=name,
            host=address.host,
            port=address.port,
            capabilities=[Capability.Time],
            context=self._context,
            message_backlog_size=BACKLOG,
        )

    def _channel(self, topic: str, schema_name: str, schema: dict[str, Any]) -> Any:
        channel = self._channels.get(topic)
        if channel is None:
            data = json.dumps(schema).encode()  # the recording's schema bytes
            channel = self._channels[topic] = self._foxglove.Channel(
                topic,
                schema=self._foxglove.Schema(name=schema_name, encoding="jsonschema", data=data),
                message_encoding="json",
                context=self._context,
            )
            self._schema_names[topic] = schema_name
        return channel

    def _send(
        self, topic: str, schema_name: str, schema: dict[str, Any], data: Any, t: int
    ) -> None:
        channel = self._channel(topic, schema_name, schema)
        if self._schema_names[topic] != schema_name:  # one channel a topic: a stray schema
            self.counters["unserved"] += 1
        elif channel.has_sinks():  # nobody subscribed: not even encoded
            channel.log(orjson.dumps(data, option=orjson.OPT_SERIALIZE_NUMPY), log_time=t)
            self.counters["served"] += 1

    def _failed(self, what: str) -> None:
        n = self.counters["errors"] = self.counters["errors"] + 1
        if worth_saying(n):
            log.exception("live view: could not serve %s (#%d)", what, n)

    def message(self, topic: str, msg: Message) -> None:
        """Serve a decoded bus message at its simulation time; the time master's clock moves
        the server's time."""
        try:
            t = ns(msg.t)
            if msg.schema == "clock" and msg.src == TIME_MASTER and t > self._time:
                self._time = t
                self._server.broadcast_time(t)
            schema = _bus_schema(msg.schema)
            self._send(topic, f"ddvi.{msg.schema}", schema, message_record(msg), t)
            if msg.schema == "gains":
                self._gains(topic.split("/")[1], msg)  # the topic's deputy, not the body's
        except Exception:
            self._failed(topic)

    def _gains(self, sc: str, msg: Message) -> None:
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
        topic = live_gains_topic(sc)
        self._send(topic, "ddvi.live_gains", LIVE_GAINS_SCHEMA, data, ns(msg.t))

    def rejected(self, topic: str, key: str, payload: bytes, err: MessageError, t: float) -> None:
        """Serve a payload that did not decode, as the recording has it, at simulation time t."""
        try:
            data = rejected_record(key, payload, err)
            self._send(f"rejected/{topic}", "ddvi.rejected", REJECTED_SCHEMA, data, ns(t))
        except Exception:
            self._failed(f"rejected/{topic}")

    def alive(self, service: str, alive: bool, t: float) -> None:
        """Serve a liveliness change, as the recording has it, at simulation time t."""
        try:
            data = {"service": service, "alive": alive}
            self._send(topics.alive_topic(service), "ddvi.alive", ALIVE_SCHEMA, data, ns(t))
        except Exception:
            self._failed(topics.alive_topic(service))

    def subscribed(self, topic: str) -> bool:
        """Whether a client subscribes to ``topic`` now."""
        channel = self._channels.get(topic)
        return channel is not None and channel.has_sinks()

    def close(self) -> None:
        """Stop serving (clients see the connection close); idempotent."""
        try:
            self._server.stop()
        except Exception:
            log.exception("live view: could not stop the server")
        log.info("live view closed: %s", self.counters)


def live_server(
    address: LiveAddress, dep: Deployment, run: str, liveliness: bool = True
) -> LiveServer:
    """A LiveServer of ``run`` advertising every topic of ``dep`` (with its liveliness topics:
    ``liveliness``) and each deputy's gains against K*.  K* is solved on a thread of its own
    (a second of imports and Riccati solves, which must not hold the caller up): the live
    gains carry an empty K* until it is known."""
    advertise = {t: (f"ddvi.{s}", _bus_schema(s)) for t, s in dep.topics().items()}
    for d in dep.deputy:
        advertise[live_gains_topic(d.name)] = ("ddvi.live_gains", LIVE_GAINS_SCHEMA)
    if liveliness:
        for service in dep.services:
            advertise[topics.alive_topic(service)] = ("ddvi.alive", ALIVE_SCHEMA)
    server = LiveServer(address, f"ddvi {run}", advertise, {})

    def solve() -> None:
        try:
            server.references = reference_gains(dep)
        except Exception:
            log.exception("live view: no K* (its gains are served without)")

    threading.Thread(target=solve, name="live-k-star", daemon=True).start()
    return server
