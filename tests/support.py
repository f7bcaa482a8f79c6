"""What several test modules share: polling for an outcome, waiting for a run to fly, and unique
run names."""

from __future__ import annotations

import itertools
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import IO, Any

import psutil

TIMEOUT = 5.0
"""Seconds a test waits for something that happens within milliseconds when all is well."""

_run_numbers = itertools.count()


def wait_until(predicate: Callable[[], bool], timeout: float = TIMEOUT) -> bool:
    """Poll ``predicate`` every 10 ms; True as soon as it holds, False after ``timeout`` s."""
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.01)
    return True


def json_messages(summary: Any) -> int:
    """The messages on a recording's JSON channels, from its mcap summary: the bus's (the 3D
    scene beside them, protobuf, is made from them)."""
    counts = summary.statistics.channel_message_counts
    channels = summary.channels
    return sum(n for c, n in counts.items() if channels[c].message_encoding == "json")


def unique_run_name(prefix: str = "test") -> str:
    """A run name no other test of this session (or another session's process) uses."""
    return f"{prefix}{os.getpid()}x{next(_run_numbers)}"


FLYING = b"services alive"
"""What ``ddvi run`` (not ``--quiet``) says on stderr once every service but the environment is
alive: the environment, started with them, then flies."""


def read_until(stream: IO[bytes], marker: bytes) -> list[bytes]:
    """The lines of ``stream`` up to the first that holds ``marker`` (all of them, to its end,
    if none does)."""
    said = []
    for line in stream:
        said.append(line)
        if marker in line:
            break
    return said


def read_until_flying(stderr: IO[bytes]) -> list[bytes]:
    """The lines of a ``ddvi run``'s stderr up to the one saying its services are alive (all of
    them if it never says so): the caller keeps them, since what follows is read elsewhere."""
    return read_until(stderr, FLYING)


During = Callable[[subprocess.Popen, Path], None]
"""What a test does to a flying run: ``during(launcher process, run folder)``."""


def fly(
    dep: Path, root: Path, during: During | None = None, options: tuple[str, ...] = ()
) -> tuple[int, str, Path]:
    """``ddvi run dep`` into ``root`` with ``options``; ``during(proc, run folder)`` once its
    services are alive (the environment then flies).  Its status, stderr and run folder."""
    cmd = [sys.executable, "-m", "services.cli", "run", str(dep), "--output", str(root), *options]
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1"}
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env)
    said: list[bytes] = []
    try:
        if during is not None:
            assert proc.stderr is not None
            said = read_until_flying(proc.stderr)  # the rest is read by communicate()
            (folder,) = [p.parent for p in root.glob("*/bus.json")]
            during(proc, folder)
        _, err = proc.communicate(timeout=300)
    finally:
        if proc.poll() is None:
            proc.kill()
    (out,) = [p.parent for p in root.glob("*/recording.mcap")]
    return proc.returncode, b"".join([*said, err]).decode(), out


def service_process(proc: subprocess.Popen, name: str) -> psutil.Process:
    """The process of service ``name``, a child of the launcher ``proc``."""
    kids = {" ".join(k.cmdline()): k for k in psutil.Process(proc.pid).children()}
    found = [k for c, k in kids.items() if f"--name {name} " in c]
    assert found, f"{name} is not running: {sorted(kids)}"
    return found[0]


def freeze(name: str, seconds: float, after: float = 1.0) -> During:
    """Stop service ``name`` (``launcher``: the launcher's process, the run's router) with
    SIGSTOP ``after`` s into the flight, for ``seconds``, then continue it."""

    def during(proc: subprocess.Popen, _folder: Path) -> None:
        part = psutil.Process(proc.pid) if name == "launcher" else service_process(proc, name)
        time.sleep(after)  # when the freeze starts: the callers give it in wall seconds of flight
        part.send_signal(signal.SIGSTOP)
        time.sleep(seconds)  # the freeze itself, what the callers test, is a length of time
        if part.is_running():
            part.send_signal(signal.SIGCONT)

    return during
