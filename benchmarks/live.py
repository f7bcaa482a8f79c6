"""The live view's cost: the default mission through ``ddvi run --live`` with one client
(``benchmarks.foxglove_client``, reading as Foxglove would) subscribed to every channel, and
with one subscribed to the channels ``docs/foxglove-layout.json`` shows (what Foxglove with
that layout subscribes to), against the same mission without ``--live``, alternated, two runs
each (``--rounds N``: N each; ``--quick``: 4 orbits, one run each).  Whole-run wall time,
the lock-step loop (the first to the last clock the monitor recorded, by receive wall time)
and the CPU of the run's processes; the client's CPU and messages; whether the live runs'
final errors are the others' (the live view must not touch the flight); and the floor under
the live view's cost: the same mission without ``--live`` while foxglove-sdk's server alone
(``benchmarks.live_floor``, a process of its own) serves the round's recorded messages to a
client of every channel beside it, the mission's figures and the server's CPU, with what the
live view added to the monitor above it.

    python -m benchmarks.live [--quick] [--rounds N] [--json]
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import json
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import psutil

from benchmarks.foxglove_client import FoxgloveClient
from benchmarks.live_floor import FloorServing
from benchmarks.mission import _clock_span, _row, skipped_row
from benchmarks.process_tree import ProcessTreeSampler
from services.config import read_table, write_deployment
from services.ground.launch.launcher import free_port
from services.ground.monitoring.scene import TRANSFORMS_TOPIC
from services.ground.storage.recording import RECORDING

TARGET = "≤ 1.05"
FLOOR_TARGET = "≤ 0.05"
"""The floor's CPU against the run's: the most the live view may add."""
ADDED_TARGET = "≤ 0.05"
"""The CPU the live view adds to the monitor against the run's: the mission's 1.05, read where
the live view runs (the flight processes' CPU varies more between identical runs)."""


def _loop_s(path: Path) -> float:
    """Wall seconds between the first and the last clock message the monitor received."""
    first, last = _clock_span(path)
    return (last - first) / 1e9


LAYOUT = Path(__file__).resolve().parents[1] / "docs" / "foxglove-layout.json"
EVERY = "every channel"
SHOWN = "the layout's channels"


def layout_topics(path: Path = LAYOUT) -> set[str]:
    """The topics a Foxglove layout's panels read (each message path's topic, and each topic
    a 3D panel shows, with the transforms it places them by)."""
    found: set[str] = set()

    def walk(node: Any) -> None:
        if isinstance(node, dict):
            if "followTf" in node:  # a 3D panel: its topics, in the frames the transforms give
                found.update(node.get("topics", {}))
                found.add(TRANSFORMS_TOPIC)
            for key, value in node.items():
                if key in ("value", "topicPath") and isinstance(value, str):
                    found.add(value.partition(".")[0])
                else:
                    walk(value)
        elif isinstance(node, list):
            for item in node:
                walk(item)

    walk(json.loads(path.read_text())["configById"])
    return found


MONITOR = "services.ground.monitoring.monitor"
"""The module the monitor runs as: the process that serves the live view."""


class ProcessCpu(ProcessTreeSampler):
    """The CPU seconds (user and system) of each process of a tree, by the module it runs
    (``python -m MODULE``), read every ``period`` s while it runs: a process's last read
    counts, so each misses at most its last ``period`` s."""

    def __init__(self, pid: int, period: float = 0.2) -> None:
        self._latest: dict[int, tuple[str, float]] = {}  # pid -> (module, CPU s)
        super().__init__(pid, period)

    @staticmethod
    def _module(p: psutil.Process) -> str:
        args = p.cmdline()
        return args[args.index("-m") + 1] if "-m" in args[:-1] else " ".join(args[:2])

    def read(self, processes: list[psutil.Process]) -> None:
        for p in processes:
            with contextlib.suppress(psutil.Error), p.oneshot():  # it may just have exited
                times = p.cpu_times()
                # an exited process not yet waited for reads an empty command line: it keeps
                # the module it was last seen running
                known = self._latest.get(p.pid)
                module = self._module(p) or (known[0] if known else "")
                self._latest[p.pid] = (module, times.user + times.system)

    def stop(self) -> dict[str, float]:
        """Stop reading; CPU seconds by module."""
        self._end()
        out: dict[str, float] = {}
        for module, cpu in self._latest.values():
            out[module] = out.get(module, 0.0) + cpu
        return out


def run_once(path: Path, out: Path, live: str | None, floor: Path | None = None) -> dict[str, Any]:
    """``ddvi run path --quiet`` (with ``--live`` on a free port and one client reading
    ``live``: EVERY or SHOWN channel): wall time, loop, CPU, summary and what the client
    received.  ``floor``: a recording the floor's server (``benchmarks.live_floor``, a
    process of its own) serves beside the run to this process's client of every channel,
    started with the run; what it took is under "floor"."""
    port = free_port()
    cmd = [sys.executable, "-m", "services.cli", "run", str(path), "--quiet", "--output", str(out)]
    cmd += ["--live", f"127.0.0.1:{port}"] if live else []
    wanted = layout_topics() if live == SHOWN else None
    t0, cpu0, tree0 = time.perf_counter(), time.process_time(), _children_cpu()
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    by_process = ProcessCpu(proc.pid)
    beside = FloorServing(floor) if floor is not None else None
    client = (
        FoxgloveClient(f"ws://127.0.0.1:{port}", timeout=120, keep=False, topics=wanted)
        if live
        else None
    )
    stdout, stderr = proc.communicate()
    modules = by_process.stop()
    wall = time.perf_counter() - t0
    run_cpu = _children_cpu() - tree0  # the launcher and every service (it waits for them)
    if proc.returncode != 0:
        raise RuntimeError(f"ddvi run {path} failed ({proc.returncode}): {stderr[-2000:]}")
    if client is not None:
        client.wait_closed(30)
    floor_result = beside.result() if beside is not None else None  # after the run's CPU
    client_cpu = time.process_time() - cpu0  # this process: the client's reading
    folder = Path(stdout.strip().splitlines()[-1])
    summary = json.loads((folder / "summary.json").read_text())
    return {
        "wall_s": wall,
        "loop_s": _loop_s(folder / RECORDING),
        "errors": {d: s["final_along_track_error_m"] for d, s in summary["deputies"].items()},
        "recorded": summary["messages"]["recorded"],
        "received": sum(client.counts.values()) if client is not None else 0,
        "run_cpu_s": run_cpu,
        "monitor_cpu_s": modules.get(MONITOR, 0.0),
        "others_cpu_s": run_cpu - modules.get(MONITOR, 0.0),
        "client_cpu_s": client_cpu,
        "folder": folder,
        "floor": floor_result,
    }


def _children_cpu() -> float:
    """CPU seconds (user and system) of this process's waited-for descendants so far."""
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


NEEDS = {
    "foxglove": "foxglove-sdk (the live view's server)",
    "websockets": "websockets (the benchmark's Foxglove client)",
}
"""The modules the live benchmark needs beyond a plain installation: the test extra's."""


def missing(needs: dict[str, str] = NEEDS) -> str | None:
    """Why a benchmark needing ``needs`` (module -> what it is; by default the live
    benchmark's) cannot run here (what is not installed, and how to install it), or None."""
    absent = []
    for module, what in needs.items():
        try:
            importlib.import_module(module)
        except ImportError:
            absent.append(what)
    if not absent:
        return None
    verb = "is" if len(absent) == 1 else "are"
    return f"{' and '.join(absent)} {verb} not installed (pip install -e '.[test]')"


def bench_live(quick: bool = False, rounds: int | None = None) -> list[dict[str, Any]]:
    """The default mission with ``--live`` and one client against without, alternated,
    ``rounds`` times (default 2; ``quick``: 1); a skipped row when its server or client is
    not installed."""
    if (why := missing()) is not None:
        return [skipped_row("live", why)]
    table = read_table(None)
    if quick:
        table["run"]["orbits"] = 4.0
    runs: dict[str | None, list[dict[str, Any]]] = {None: [], EVERY: [], SHOWN: []}
    with tempfile.TemporaryDirectory(prefix="ddvi-bench-live-") as tmp:
        path = write_deployment(table, Path(tmp), "mission")
        beside = []  # the mission without --live, the floor serving beside it
        for _ in range(rounds or (1 if quick else 2)):
            for live in runs:
                runs[live].append(run_once(path, Path(tmp) / "runs", live))
            recording = runs[None][-1]["folder"] / RECORDING
            beside.append(run_once(path, Path(tmp) / "runs", None, floor=recording))
    rows = []
    for live in (EVERY, SHOWN):
        rows += _rows(table["run"]["orbits"], live, runs[live], runs[None])
    rows += floor_rows(table["run"]["orbits"], beside, runs[EVERY], runs[None])
    everything = [r for rs in [*runs.values(), beside] for r in rs]
    same = all(r["errors"] == runs[None][0]["errors"] for r in everything)
    rows.append(
        _row(
            f"final along-track errors identical with and without: {same}",
            "m",
            runs[EVERY][-1]["errors"].get("ddvi", float("nan")),
            runs[None][0]["errors"].get("ddvi", float("nan")),
            "without --live",
            1.0,
            bench="live",
        )
    )
    return rows


def monitor_added(live: list[dict[str, Any]], without: list[dict[str, Any]]) -> float:
    """The CPU seconds the live view added to the monitor: its mean with less without."""
    with_live = statistics.mean(r["monitor_cpu_s"] for r in live)
    return with_live - statistics.mean(r["monitor_cpu_s"] for r in without)


def floor_rows(
    orbits: float,
    beside: list[dict[str, Any]],
    live: list[dict[str, Any]],
    without: list[dict[str, Any]],
) -> list[dict[str, Any]]:
    """The floor: each round's mission without ``--live`` while foxglove-sdk's server alone
    serves that round's recording to a client of every channel beside it (``beside``, each
    with its "floor"): the mission's figures against without (what serving and reading the
    messages on the same machine costs the flight, whatever serves them), the floor's CPU
    against the run's, and what the live view with a client of every channel added to the
    monitor above it."""
    floors = [r["floor"] for r in beside]
    run_cpu = statistics.mean(r["run_cpu_s"] for r in without)
    floor_cpu = statistics.mean(f["cpu_s"] for f in floors)
    each = ", ".join(f"{f['cpu_s']:.2f}" for f in floors)
    served = min(f["served"] for f in floors)
    received = min(f["received"] for f in floors)
    # read in the monitor: the other processes' noise is not in it
    above = monitor_added(live, without) - floor_cpu
    rows = [
        alternated_row(
            f"{orbits:g}-orbit mission, {figure}, beside the floor (no --live)",
            key,
            beside,
            without,
            "without --live",
            "",
            "live",
        )
        for key, figure in (
            ("wall_s", "whole run"),
            ("loop_s", "lock-step loop"),
            ("run_cpu_s", "CPU of the run's processes"),
        )
    ]
    return [
        *rows,
        _row(
            "floor: foxglove-sdk's server alone serving each round's recorded messages "
            f"({served:,}; a client of every channel received {received:,}) beside the "
            f"mission, CPU of its process (benchmarks.live_floor; rounds: {each})",
            "s",
            floor_cpu,
            run_cpu,
            "the run's CPU without --live",
            floor_cpu / run_cpu,
            FLOOR_TARGET,
            bench="live",
        ),
        _row(
            "the live view's CPU above the floor, a client of every channel (the monitor's "
            "with --live, less without, less the floor)",
            "s",
            above,
            run_cpu,
            "the run's CPU without --live",
            above / run_cpu,
            bench="live",
        ),
    ]


def alternated_row(
    figure: str,
    key: str,
    runs: list[dict[str, Any]],
    without: list[dict[str, Any]],
    baseline_name: str,
    target: str,
    bench: str,
) -> dict[str, Any]:
    """The mean of the seconds ``key`` over ``runs`` against its mean over ``without`` (the
    runs alternated with them), each run's figure said: ``<figure> (runs: a, b against c, d)``."""
    project = statistics.mean(r[key] for r in runs)
    baseline = statistics.mean(r[key] for r in without)
    each = (
        ", ".join(f"{r[key]:.1f}" for r in runs)
        + " against "
        + ", ".join(f"{r[key]:.1f}" for r in without)
    )
    return _row(
        f"{figure} (runs: {each})",
        "s",
        project,
        baseline,
        baseline_name,
        project / baseline,
        target,
        bench=bench,
    )


def _rows(
    orbits: float, what: str, live: list[dict[str, Any]], without: list[dict[str, Any]]
) -> list[dict[str, Any]]:
    rows = [
        alternated_row(
            f"{orbits:g}-orbit mission, {figure}, --live, a client of {what}",
            key,
            live,
            without,
            "without --live",
            target,
            "live",
        )
        for key, figure, target in (
            ("wall_s", "whole run", TARGET),
            ("loop_s", "lock-step loop", TARGET),
            ("run_cpu_s", "CPU of the run's processes", TARGET),
            ("monitor_cpu_s", "CPU of the monitor (the live view's process)", ""),
            ("others_cpu_s", "CPU of the run's other processes", ""),
        )
    ]
    run_cpu = statistics.mean(r["run_cpu_s"] for r in without)
    added = monitor_added(live, without)
    rows.append(
        _row(
            f"CPU the live view added to the monitor, a client of {what} (with less without)",
            "s",
            added,
            run_cpu,
            "the run's CPU without --live",
            added / run_cpu,
            ADDED_TARGET,
            bench="live",
        )
    )
    client_cpu = statistics.mean(r["client_cpu_s"] for r in live)
    rows.append(
        _row(
            f"CPU of the client of {what} (this process)",
            "s",
            client_cpu,
            run_cpu,
            "the run's CPU without --live",
            client_cpu / run_cpu,
            bench="live",
        )
    )
    last = live[-1]
    rows.append(
        _row(
            f"messages the client of {what} received",
            "count",
            last["received"],
            last["recorded"],
            "messages recorded",
            last["received"] / last["recorded"],
            bench="live",
        )
    )
    return rows


def print_rows(rows: list[dict[str, Any]], as_json: bool) -> None:
    """A benchmark's rows on stdout: as JSON, or one line each with its ratio and target."""
    if as_json:
        print(json.dumps(rows))
        return
    for r in rows:
        print(
            f"{r['metric']}: {r['project']:.4g} {r['unit']} against {r['baseline']:.4g} "
            f"({r['baseline_name']}), ratio {r['cost_ratio']:.3f} {r['target']}"
        )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.live", description=__doc__)
    parser.add_argument("--quick", action="store_true", help="4 orbits, one run each")
    parser.add_argument("--json", action="store_true", help="the rows as JSON on stdout")
    parser.add_argument(
        "--rounds", type=int, default=None, help="alternated rounds (default 2, --quick 1)"
    )
    args = parser.parse_args(argv)
    rows = bench_live(args.quick, args.rounds)
    print_rows(rows, args.json)
    return 0


if __name__ == "__main__":
    sys.exit(main())
