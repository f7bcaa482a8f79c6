"""The live view's floor: foxglove-sdk's WebSocket server alone, in a process of its own, serving
a run's recorded messages (every channel of its recording: the bus's JSON messages and the
scene) to one client subscribed to every channel, one ``Channel.log`` a message, at the pace
the monitor received them and handed over as the live view hands them (each message queued
when its ``publish_time`` comes, counted from the first; the queue handed over every
``HANDOFF_S``), with the server's backlog and worker threads the monitor's.  No bus, no
decoding, no recording: what serving those messages costs whatever serves them.  Its CPU
(every thread of the serving process, the SDK's WebSocket workers among them, from the first
message logged to two seconds after the last) is the floor under the live view's cost to a
run.

    python -m benchmarks.live_floor RECORDING    # its CPU and the messages the client got
"""

from __future__ import annotations

import json
import os
import resource
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

from benchmarks.foxglove_client import FoxgloveClient
from services.ground.launch.launcher import free_port
from services.ground.monitoring.live import BACKLOG, SERVER_THREADS
from services.ground.monitoring.live_handoff import HANDOFF_S

DRAIN_S = 2.0
"""Seconds the server is given after its last message to send what its queues hold."""


def _cpu() -> float:
    usage = resource.getrusage(resource.RUSAGE_SELF)  # every thread of this process
    return usage.ru_utime + usage.ru_stime


def _recorded(path: Path) -> tuple[list[tuple[str, str, str, bytes, str]], list[Any]]:
    """Every channel of a recording (topic, schema name, schema encoding, schema bytes,
    message encoding), and its messages as (channel index, data, log_time, publish_time), in
    file order."""
    from mcap.reader import make_reader

    channels: dict[int, int] = {}
    described: list[tuple[str, str, str, bytes, str]] = []
    messages = []
    with open(path, "rb") as f:
        for schema, channel, message in make_reader(f).iter_messages(log_time_order=False):
            if channel.id not in channels:
                channels[channel.id] = len(described)
                described.append(
                    (
                        channel.topic,
                        schema.name if schema is not None else "",
                        schema.encoding if schema is not None else "",
                        schema.data if schema is not None else b"",
                        channel.message_encoding,
                    )
                )
            messages.append(
                (channels[channel.id], message.data, message.log_time, message.publish_time)
            )
    return described, messages


def _hand_over(queued: list[tuple[Any, bytes, int]]) -> None:
    """Log each queued (channel, data, log time ns) in order, and empty the queue."""
    for channel, data, log_time in queued:
        channel.log(data, log_time=log_time)
    queued.clear()


def serve(port: int, recording: Path) -> int:
    """The serving process: advertise the recording's channels on 127.0.0.1:``port``, say
    ``ready``, wait for a client to subscribe to every channel, serve every message, and print
    the CPU it took as JSON."""
    import foxglove

    described, messages = _recorded(recording)
    context = foxglove.Context()
    channels = [
        foxglove.Channel(
            topic,
            schema=foxglove.Schema(name=name, encoding=encoding, data=data) if name else None,
            message_encoding=message_encoding,
            context=context,
        )
        for topic, name, encoding, data, message_encoding in described
    ]
    os.environ.setdefault("TOKIO_WORKER_THREADS", SERVER_THREADS)  # the live view's
    server = foxglove.start_server(
        name="ddvi live floor",
        host="127.0.0.1",
        port=port,
        context=context,
        message_backlog_size=BACKLOG,
    )
    try:
        print("ready", flush=True)
        deadline = time.monotonic() + 120
        while not all(c.has_sinks() for c in channels):
            if time.monotonic() > deadline:
                raise RuntimeError("no client subscribed to every channel in 120 s")
            time.sleep(0.05)
        cpu0 = _cpu()
        start, first = time.monotonic(), min(m[3] for m in messages)
        handover, queued = start + HANDOFF_S, []
        for index, data, log_time, publish_time in messages:
            due = start + (publish_time - first) / 1e9
            while due > handover:  # this message is queued after the next handover
                if queued:
                    time.sleep(max(handover - time.monotonic(), 0.0))
                    _hand_over(queued)
                handover += HANDOFF_S
            queued.append((channels[index], data, log_time))
        _hand_over(queued)
        time.sleep(DRAIN_S)
        cpu = _cpu() - cpu0
    finally:
        server.stop()
    print(json.dumps({"cpu_s": cpu, "served": len(messages)}), flush=True)
    return 0


class FloorServing:
    """The floor's serving process, started on ``recording`` with this process's client of
    every channel reading it; ``result`` waits for it.  Until then it is not waited for, so a
    run measured meanwhile by its children's CPU (``resource.RUSAGE_CHILDREN``) does not
    count it."""

    def __init__(self, recording: Path) -> None:
        port = free_port()
        cmd = [sys.executable, "-m", "benchmarks.live_floor", "--serve", str(port), str(recording)]
        self._proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, text=True)
        try:
            assert self._proc.stdout is not None
            if self._proc.stdout.readline().strip() != "ready":
                raise RuntimeError(f"the floor's server did not start ({self._proc.wait(30)})")
            self.client = FoxgloveClient(f"ws://127.0.0.1:{port}", timeout=60, keep=False)
        except BaseException:
            self._stop()
            raise

    def _stop(self) -> None:
        if self._proc.poll() is None:
            self._proc.kill()
            self._proc.wait()

    def result(self) -> dict[str, Any]:
        """The serving process's CPU (s) and the messages it served, once it has served them
        all, and those the client received."""
        try:
            out, _ = self._proc.communicate(timeout=600)
            self.client.close()
        finally:
            self._stop()
        if self._proc.returncode != 0:
            raise RuntimeError(f"the floor's server failed ({self._proc.returncode})")
        result = json.loads(out.strip().splitlines()[-1])
        return {**result, "received": sum(self.client.counts.values())}


def measure_floor(recording: Path) -> dict[str, Any]:
    """The floor of ``recording``: the serving process's CPU (s), the messages it served and
    those the client (this process, every channel) received."""
    return FloorServing(recording).result()


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    if args[:1] == ["--serve"] and len(args) == 3:
        return serve(int(args[1]), Path(args[2]))
    if len(args) != 1:
        print(__doc__.strip().splitlines()[-1].strip(), file=sys.stderr)
        return 2
    print(json.dumps(measure_floor(Path(args[0]))))
    return 0


if __name__ == "__main__":
    sys.exit(main())
