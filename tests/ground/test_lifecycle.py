"""``ddvi run``'s process lifecycle: every way of stopping it stops every service (checked by
PID) and leaves the partial report; a service that crashes at start-up is reported at once.

Exit statuses (``services.ground.launch.lifecycle``): 128 + N for signal N, 1 for a crash."""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import psutil
import pytest
from mcap.reader import NonSeekingReader

from tests.support import FLYING, read_until, read_until_flying, wait_until

pytestmark = pytest.mark.integration

LONG = """
[run]
name = "lc"
orbits = 60.0
[[deputy]]
name = "lqr"
"""

CRASH_ON_PURPOSE = """
import os, sys
if os.environ.get("DDVI_TEST_CRASH") and os.environ["DDVI_TEST_CRASH"] in sys.orig_argv:
    sys.stderr.write("crash on purpose in " + os.environ["DDVI_TEST_CRASH"] + "\\n")
    sys.stderr.flush()
    os._exit(7)
"""


class Run:
    """``ddvi run`` of a deployment as a process, and the PIDs of the services it started."""

    def __init__(self, tmp: Path, text: str = LONG, env: dict | None = None, **popen) -> None:
        dep = tmp / "dep.toml"
        dep.write_text(text)
        self.runs = tmp / "runs"
        cmd = [sys.executable, "-m", "services.cli", "run", str(dep), "--output", str(self.runs)]
        env = {**os.environ, **(env or {})}
        pipe = subprocess.PIPE
        self.proc = subprocess.Popen(cmd, stdout=pipe, stderr=pipe, env=env, **popen)
        self.pids: set[int] = set()
        self.said: list[bytes] = []  # stderr read before finish()

    def services(self) -> list[psutil.Process]:
        try:
            return psutil.Process(self.proc.pid).children(recursive=True)
        except psutil.NoSuchProcess:
            return []

    def wait_flying(self) -> None:
        """Until the launcher says the services are alive (the environment then flies) and a
        little of the mission has flown; remembers every service's PID."""
        assert self.proc.stderr is not None
        self.said = read_until_flying(self.proc.stderr)
        assert FLYING in self.said[-1], self.finish(5)[1]
        assert wait_until(self.flown, timeout=60), "no clock after t = 0 recorded"
        self.pids |= {p.pid for p in self.services()}
        assert len(self.pids) == 4  # monitor, nav-lqr, ctrl-lqr, environment

    def flown(self) -> bool:
        """Whether the recording holds a clock past the start: the mission has flown a step
        and the monitor recorded it (its complete chunks, read as a stream)."""
        for path in self.runs.glob("*/recording.mcap"):
            with path.open("rb") as f, contextlib.suppress(Exception):  # its open tail
                for _, channel, message in NonSeekingReader(f).iter_messages(log_time_order=False):
                    if channel.topic == "clock" and message.log_time > 0:  # simulation time
                        return True
        return False

    def finish(self, timeout: float = 90) -> tuple[int, str]:
        _, err = self.proc.communicate(timeout=timeout)
        return self.proc.returncode, b"".join([*self.said, err]).decode()

    def folder(self) -> Path:
        (folder,) = self.runs.iterdir()
        return folder


def _left(pids: set[int]) -> list[int]:
    """The PIDs still running (a zombie not reaped by an init that does not reap is gone)."""
    left = []
    for pid in pids:
        try:
            if psutil.Process(pid).status() != psutil.STATUS_ZOMBIE:
                left.append(pid)
        except psutil.NoSuchProcess:
            pass
    return left


@pytest.mark.parametrize(
    ("sig", "status"), [(signal.SIGTERM, 143), (signal.SIGHUP, 129), (signal.SIGINT, 130)]
)
def test_a_stop_signal_stops_every_service_and_writes_the_partial_report(
    tmp_path: Path, sig: signal.Signals, status: int
) -> None:
    run = Run(tmp_path)
    run.wait_flying()
    run.proc.send_signal(sig)
    code, err = run.finish()
    assert code == status, err[-3000:]
    assert _left(run.pids) == []
    assert "Traceback" not in err
    assert f"stopped by {sig.name}" in err and "partial report in" in err
    report = (run.folder() / "report.md").read_text()
    assert "**stopped**" in report and "completed: **no**" in report
    assert (run.folder() / "logs" / "monitor.log").read_text().strip()  # the monitor's log


def test_a_second_sigint_while_stopping_with_sigint_inherited_ignored(tmp_path: Path) -> None:
    """``ddvi run &`` in a script inherits SIGINT ignored; it is still a stop request, and a
    second one while stopping is said, not a traceback."""
    run = Run(tmp_path, preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_IGN))
    run.wait_flying()
    run.proc.send_signal(signal.SIGINT)
    assert run.proc.stderr is not None
    run.said += read_until(run.proc.stderr, b"SIGINT: stopping every service")  # it took it
    run.proc.send_signal(signal.SIGINT)
    code, err = run.finish()
    assert code == 130, err[-3000:]
    assert "SIGINT again: already stopping" in err and "Traceback" not in err
    assert _left(run.pids) == []
    assert (run.folder() / "report.md").is_file()
    assert (run.folder() / "recording.mcap").stat().st_size > 0


def test_the_services_of_a_killed_launcher_stop_by_themselves(tmp_path: Path) -> None:
    run = Run(tmp_path)
    run.wait_flying()
    monitor = {p.pid for p in run.services() if "services.ground.monitoring.monitor" in p.cmdline()}
    run.proc.kill()
    run.finish()
    # the parent-death signal: each service stops as on SIGTERM; the flight services at once,
    # the monitor once it has written its report (seconds of figures on a busy machine)
    assert wait_until(lambda: not _left(run.pids - monitor), timeout=15), _left(run.pids)
    assert wait_until(lambda: not _left(monitor), timeout=60), _left(monitor)
    assert (run.folder() / "report.md").is_file()
    assert "**stopped**" in (run.folder() / "report.md").read_text()


def test_a_service_crashing_at_start_up_is_reported_at_once(tmp_path: Path) -> None:
    site = tmp_path / "site"
    site.mkdir()
    (site / "sitecustomize.py").write_text(CRASH_ON_PURPOSE)
    path = os.pathsep.join([str(site), os.environ.get("PYTHONPATH", "")])
    env = {"DDVI_TEST_CRASH": "services.flight.navigation", "PYTHONPATH": path}
    started = time.monotonic()
    run = Run(tmp_path, env=env)
    pids: set[int] = set()

    def ended() -> bool:  # the launcher's children, as they come and go, until it ends
        pids.update(p.pid for p in run.services())
        return run.proc.poll() is not None

    assert wait_until(ended, timeout=120)
    code, err = run.finish()
    took = time.monotonic() - started
    assert code == 1, err[-3000:]
    assert "nav-lqr exited with status 7 while starting" in err, err[-3000:]
    assert "crash on purpose in services.flight.navigation" in err  # its last log lines
    assert took < 30  # not the 60 s start-up timeout
    assert pids and _left(pids) == []
    assert "Traceback" not in err
