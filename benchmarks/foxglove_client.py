"""A minimal client of Foxglove's WebSocket protocol (subprotocol ``foxglove.sdk.v1``), as the
Foxglove app speaks it: it reads the server's info and channel advertisements, subscribes to
every channel, and collects the message data and time frames on a thread of its own.  Used by
the live view's benchmark (``benchmarks.live``) and tests; needs the ``websockets`` package.

Frames (the protocol's spec): text frames are JSON (``serverInfo``, ``advertise``,
``unadvertise``, ``status``); binary ones start with an opcode: 1 message data (u32 LE
subscription id, u64 LE timestamp ns, payload), 2 time (u64 LE timestamp ns).
"""

from __future__ import annotations

import itertools
import json
import struct
import threading
import time
from dataclasses import dataclass
from typing import Any

SUBPROTOCOL = "foxglove.sdk.v1"
_MESSAGE_DATA, _TIME = 1, 2


@dataclass(frozen=True)
class Received:
    """One message data frame: its channel's topic, its timestamp (ns) and payload, and when
    it came (``time.monotonic`` s)."""

    topic: str
    timestamp: int
    payload: bytes
    at: float = 0.0

    def json(self) -> Any:
        return json.loads(self.payload)


class FoxgloveClient:
    """Connects to ``url`` (retrying until ``timeout`` s: the server may not listen yet),
    subscribes to every channel advertised (or those of ``topics``), and reads until the
    server closes or ``close``.  ``keep``: keep every message (else count them)."""

    def __init__(
        self,
        url: str,
        timeout: float = 30.0,
        keep: bool = True,
        topics: set[str] | None = None,
    ) -> None:
        self.keep = keep
        self.topics = topics
        self.info: dict[str, Any] = {}
        self.channels: dict[int, dict[str, Any]] = {}  # channel id -> its advertisement
        self.messages: list[Received] = []
        self.counts: dict[str, int] = {}  # topic -> messages received
        self.times: list[int] = []  # the server's time frames, ns
        self.subscribed: dict[str, float] = {}  # topic -> when it was subscribed (monotonic s)
        self.subprotocol: str | None = None
        self._subscriptions: dict[int, int] = {}  # subscription id -> channel id
        self._ids = itertools.count(1)
        self._lock = threading.Lock()
        self._ws: Any = None
        self._error: BaseException | None = None
        self._connected = threading.Event()
        self.closed = threading.Event()
        self._thread = threading.Thread(
            target=self._run, args=(url, timeout), name="foxglove-client", daemon=True
        )
        self._thread.start()
        self._connected.wait()
        if self._error is not None:
            raise self._error

    def _run(self, url: str, timeout: float) -> None:
        from websockets.sync.client import connect

        deadline = time.monotonic() + timeout
        try:
            while True:
                try:
                    ws = connect(url, subprotocols=[SUBPROTOCOL], max_size=None)  # type: ignore[list-item]
                    break
                except OSError:
                    if time.monotonic() > deadline:
                        raise
                    time.sleep(0.1)
        except BaseException as exc:
            self._error = exc
            self._connected.set()
            self.closed.set()
            return
        with ws:
            self._ws, self.subprotocol = ws, ws.subprotocol
            self._connected.set()
            self._read(ws)

    def _read(self, ws: Any) -> None:
        try:
            for frame in ws:
                if isinstance(frame, str):
                    self._control(json.loads(frame))
                else:
                    self._data(frame)
        except Exception:  # the connection closed, cleanly or not: the server is gone
            pass
        finally:
            self.closed.set()

    def _control(self, msg: dict[str, Any]) -> None:
        if msg["op"] == "serverInfo":
            self.info = msg
        elif msg["op"] == "advertise":
            with self._lock:
                self.channels.update({c["id"]: c for c in msg["channels"]})
            topics = self.topics
            wanted = [c for c in msg["channels"] if topics is None or c["topic"] in topics]
            subs = [{"id": next(self._ids), "channelId": c["id"]} for c in wanted]
            self._subscriptions.update({s["id"]: s["channelId"] for s in subs})
            now = time.monotonic()
            self.subscribed.update({c["topic"]: now for c in wanted})
            self._ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))

    def _data(self, frame: bytes) -> None:
        if frame[0] == _TIME:
            self.times.append(struct.unpack_from("<Q", frame, 1)[0])
        elif frame[0] == _MESSAGE_DATA:
            sub, stamp = struct.unpack_from("<IQ", frame, 1)
            topic = self.channels[self._subscriptions[sub]]["topic"]
            self.counts[topic] = self.counts.get(topic, 0) + 1
            if self.keep:
                self.messages.append(Received(topic, stamp, bytes(frame[13:]), time.monotonic()))

    def advertised(self) -> dict[str, dict[str, Any]]:
        """Topic -> its channel's advertisement, so far."""
        with self._lock:
            return {c["topic"]: c for c in self.channels.values()}

    def wait_closed(self, timeout: float) -> bool:
        """Wait for the server to close the connection; whether it did within ``timeout`` s."""
        return self.closed.wait(timeout)

    def close(self) -> None:
        self._ws.close()
        self._thread.join(timeout=5.0)
