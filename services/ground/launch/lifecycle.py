"""The launcher's process lifecycle: stop signals, watching children start, and the run's verdict.

Exit statuses of ``ddvi run`` (docs/faults.md, "Stopping a run"):

    0    the mission completed: the environment's final clock at the planned end, every command
         flown (none refused, stale or missing)
    1    it failed: a service died, the mission ended early (a re-entry, a final clock from
         anyone but the environment), the recording stopped (a full or failing disk), or no
         report was written
    2    bad input: the deployment, the output folder or the bus settings (one line says which)
    3    the mission completed, but commands were refused, stale or missing, a publisher flooded
         its receivers, a controller flew the safe attitude, the ground refused messages, a
         service claimed impossible counters, or messages were published and never recorded
         (the report counts them)
    128+N  stopped by signal N (130 SIGINT, 129 SIGHUP, 143 SIGTERM); the partial report is
         written
"""

from __future__ import annotations

import contextlib
import os
import signal
import threading
import time
from collections.abc import Callable, Iterable, Iterator, Mapping
from pathlib import Path
from typing import Any

import zenoh

from services.bus import watch_alive
from services.flight.runtime import STOP_SIGNALS
from services.ground.analysis.outcome import flood_text, impossible_text
from services.ground.storage.disk import size_text, space_left
from services.ground.storage.record import gaps_text, stop_text

EXIT_OK, EXIT_FAILED, EXIT_USAGE, EXIT_DEGRADED = 0, 1, 2, 3
LOG_TAIL = 8  # a crashed service's last log lines the launcher shows
POLL = 0.05  # s between looks at the children while they start

COMMAND_PROBLEMS = ("refused", "stale", "missing", "late")
"""The report's command counters that make a completed mission's exit status 3."""


@contextlib.contextmanager
def handling(signals: Iterable[int], handler: Callable[[int, Any], None]) -> Iterator[None]:
    """``handler`` for ``signals`` while the block runs, the previous handlers restored after;
    it replaces a handler inherited as ignored too (a script's ``&`` ignores SIGINT).  Only
    the main thread may take signals: elsewhere the caller's stay in force."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = {sig: signal.signal(sig, handler) for sig in signals}
    try:
        yield
    finally:
        for sig, old in previous.items():
            signal.signal(sig, old)


def exit_for_signal(signum: int) -> int:
    """The shell's convention: 128 + the signal's number."""
    return 128 + int(signum)


class StopSignals:
    """SIGTERM, SIGHUP and SIGINT (also when inherited as ignored: ``ddvi run &`` in a script)
    request one orderly stop; a second signal while stopping is said, not obeyed (the stop
    writes the partial report).  ``received`` is the first signal's number, or None."""

    def __init__(self, name: str = "ddvi run") -> None:
        self.name = name
        self.received: int | None = None
        self._previous: dict[int, Any] = {}

    def install(self) -> None:
        """Take the stop signals (only the main thread may: elsewhere, e.g. a launcher run on
        a worker thread, the caller keeps its own)."""
        if threading.current_thread() is not threading.main_thread():
            return
        for sig in STOP_SIGNALS:
            self._previous[sig] = signal.signal(sig, self._on_signal)

    def restore(self) -> None:
        for sig, handler in self._previous.items():
            signal.signal(sig, handler)
        self._previous.clear()

    def _on_signal(self, signum: int, _frame: Any) -> None:
        sig = signal.Signals(signum).name
        if self.received is None:
            self.received = signum
            text = f"{self.name}: {sig}: stopping every service; the partial report follows\n"
        else:
            text = f"{self.name}: {sig} again: already stopping, the report is being written\n"
        with contextlib.suppress(OSError):  # not print: it may interrupt a print in progress
            os.write(2, text.encode())


def last_lines(path: Path, n: int = LOG_TAIL, limit: int = 16384) -> list[str]:
    """The last ``n`` non-empty lines of a log file (its last ``limit`` bytes), undecodable
    bytes replaced; [] when the file is missing."""
    try:
        with path.open("rb") as f:
            f.seek(max(f.seek(0, os.SEEK_END) - limit, 0))
            text = f.read().decode("utf-8", "replace")
    except OSError:
        return []
    return [line for line in text.splitlines() if line.strip()][-n:]


def log_reason(path: Path) -> str:
    """Why a service ended, from its log: its last ERROR line's message (without the time and
    the service's name), else its last line; "its log is empty" when there is none."""
    lines = last_lines(path, n=LOG_TAIL * 4)
    errors = [line.split(" ERROR ", 1)[1] for line in lines if " ERROR " in line]
    if errors:
        return errors[-1]
    return lines[-1] if lines else "its log is empty"


def await_client(
    watched: threading.Event,
    exited: Callable[[], tuple[str, int] | None],
    stopping: Callable[[], bool],
) -> tuple[str, Any]:
    """Wait, as long as it takes, until ``watched`` (the live view has a client), watching the
    children: ("watched", None); ("exited", (name, status)) as soon as ``exited()`` names a
    child that ended; ("stopped", None) when ``stopping()``."""
    while not watched.wait(POLL):
        if stopping():
            return "stopped", None
        if (gone := exited()) is not None:
            return "exited", gone
    return "watched", None


def await_alive(
    session: zenoh.Session,
    run: str,
    names: list[str],
    timeout: float,
    exited: Callable[[], tuple[str, int] | None],
    stopping: Callable[[], bool],
) -> tuple[str, Any]:
    """Wait until every named service's liveliness token is seen, watching the children.

    Returns ("alive", None); ("exited", (name, status)) as soon as ``exited()`` names a child
    that ended; ("stopped", None) when ``stopping()``; ("timeout", missing names) after
    ``timeout`` s."""
    alive: set[str] = set()
    lock = threading.Lock()

    def on_change(name: str, up: bool) -> None:
        with lock:
            (alive.add if up else alive.discard)(name)

    sub = watch_alive(session, run, "*", on_change)
    try:
        deadline = time.monotonic() + timeout
        while True:
            with lock:
                missing = sorted(set(names) - alive)
            if not missing:
                return "alive", None
            if stopping():
                return "stopped", None
            if (gone := exited()) is not None:
                return "exited", gone
            if time.monotonic() >= deadline:
                return "timeout", missing
            time.sleep(POLL)
    finally:
        sub.undeclare()


SERVICE_BYTES = 80e6
"""A service process's resident memory, estimated (30 deputies, 62 processes: 4.8 GB)."""


def resources(dep: Any) -> tuple[int, float]:
    """The processes a deployment starts and the memory they take, estimated (bytes)."""
    processes = len(dep.services)
    return processes, processes * SERVICE_BYTES


def resource_problems(dep: Any) -> tuple[list[str], str | None]:
    """Warnings, and the reason not to start at all, for a deployment on this machine: more
    memory than is available is refused; more than half of it, or more processes than eight
    per core, is warned of."""
    import psutil

    processes, need = resources(dep)
    available = psutil.virtual_memory().available
    cores = os.cpu_count() or 1
    said = f"{processes} processes, about {need / 1e9:.1f} GB"
    if need > available:
        return [], (
            f"this deployment needs {said}; {available / 1e9:.1f} GB are available: "
            "run fewer deputies (or split them into several runs)"
        )
    warnings = []
    if need > available / 2:
        warnings.append(f"{said} of the {available / 1e9:.1f} GB available")
    if processes > 8 * cores:
        warnings.append(f"{processes} processes on {cores} cores: lock-step steps will be slow")
    return warnings, None


def command_problems(commands: Mapping[str, Any]) -> dict[str, int]:
    """The outcome's counts of commands refused, stale, missing or late
    (``services.ground.analysis.outcome``), those not zero."""
    found = {k: int(commands.get(k, 0) or 0) for k in COMMAND_PROBLEMS}
    return {k: v for k, v in found.items() if v}


def final_line(summary: Mapping[str, Any], folder: Path, seconds: float) -> tuple[int, str]:
    """The exit status and ``ddvi run``'s last line for a run's summary.json, which took
    ``seconds``, in ``folder``."""
    status, text = verdict(summary)
    if summary.get("outcome", {}).get("record", {}).get("recording") is not None:
        return status, f"{text} ({seconds:.1f} s)"  # it says what is where
    return status, f"{text} in {seconds:.1f} s; report in {folder}"


def no_report(folder: Path, status: int | None) -> str:
    """``ddvi run``'s line when the monitor wrote no report: why (its log's last error), the
    space left on the run folder's disk, and what is saved there."""
    from services.ground.storage.recording import RECORDING  # the recorder's module only here

    why = log_reason(folder / "logs" / "monitor.log").removeprefix("no report: ")
    recording = folder / RECORDING
    saved = "no recording"
    if recording.is_file():
        saved = f"{RECORDING} ({size_text(recording.stat().st_size)})"
    left = size_text(space_left(folder))
    return (
        f"monitor exited with status {status}; no report ({why}); {left} left on {folder}; "
        f"saved there: {saved}"
    )


def verdict(summary: Mapping[str, Any]) -> tuple[int, str]:
    """The exit status and one line for a run's summary.json
    (``services.ground.analysis.report``)."""
    out = summary.get("outcome", {})
    record = out.get("record", {})
    if record.get("recording") is not None:  # the disk failed the run's record
        missing = list(summary.get("not_written", {}))
        figures = summary.get("figures", [])
        written = ["report.md", "summary.json"] + ([f"{len(figures)} figures"] if figures else [])
        said = stop_text(record, written, missing)
        if not summary.get("completed", False):
            said = f"mission INCOMPLETE at {summary.get('orbits', 0.0):.2f} orbits; {said}"
        return EXIT_FAILED, said
    problems = command_problems(out.get("commands", {}))
    said = (
        [f"commands were {', '.join(f'{v} {k}' for k, v in problems.items())}"] if problems else []
    )
    if found := out.get("flooded"):
        said.append(f"flooded by {flood_text(found)}")
    if safe := out.get("health", {}).get("safe_attitude_steps"):
        said.append(
            "safe attitude flown by "
            + ", ".join(f"{name} ({n} steps)" for name, n in sorted(safe.items()))
        )
    if refused := out.get("refused"):
        whom = ", ".join(sorted({f"{r['topic']} from {r['src']}" for r in refused})[:5])
        said.append(f"{sum(r['count'] for r in refused)} messages were refused ({whom})")
    if impossible := out.get("impossible"):
        said.append(f"impossible claims were made ({impossible_text(impossible)})")
    if not record.get("complete", True):
        said.append(f"the record is incomplete: {gaps_text(record)}")
    if not summary.get("completed", False):
        ended_by = out.get("ended_by")
        why = f" (ended by {ended_by})" if ended_by else ""
        tail = f"; {'; '.join(said)}" if said else ""
        return (
            EXIT_FAILED,
            f"mission INCOMPLETE at {summary.get('orbits', 0.0):.2f} orbits{why}{tail}",
        )
    if said:
        return EXIT_DEGRADED, f"mission completed, but {'; '.join(said)} (exit status 3)"
    return EXIT_OK, "mission completed"
