"""The live view's cost: the default mission through ``ddvi run --live`` with one client
subscribed to every channel (``benchmarks.foxglove_client``, reading as Foxglove would)
against the same mission without ``--live``, alternated, two runs each (``--quick``: 4 orbits,
one run each).  Whole-run wall time and the lock-step loop (the first to the last clock the
monitor recorded, by receive wall time); the client's messages against the recording's, and
whether the live runs' final errors are the others' (the live view must not touch the flight).

    python -m benchmarks.live [--quick] [--json]
"""

from __future__ import annotations

import argparse
import json
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from benchmarks.foxglove_client import FoxgloveClient
from benchmarks.mission import _clock_span, _row
from services.config import read_table, write_deployment
from services.ground.launcher import free_port
from services.ground.recording import RECORDING

TARGET = "≤ 1.10"


def run_once(path: Path, out: Path, live: bool) -> dict[str, Any]:
    """``ddvi run path --quiet`` (with ``--live`` on a free port and one client reading every
    channel): wall time, loop, summary and what the client received."""
    port = free_port()
    cmd = [sys.executable, "-m", "services.cli", "run", str(path), "--quiet", "--output", str(out)]
    cmd += ["--live", f"127.0.0.1:{port}"] if live else []
    t0, cpu0, tree0 = time.perf_counter(), time.process_time(), _children_cpu()
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    client = FoxgloveClient(f"ws://127.0.0.1:{port}", timeout=120, keep=False) if live else None
    stdout, stderr = proc.communicate()
    wall = time.perf_counter() - t0
    run_cpu = _children_cpu() - tree0  # the launcher and every service (it waits for them)
    if proc.returncode != 0:
        raise RuntimeError(f"ddvi run {path} failed ({proc.returncode}): {stderr[-2000:]}")
    if client is not None:
        client.wait_closed(30)
    client_cpu = time.process_time() - cpu0  # this process: the client's reading
    folder = Path(stdout.strip().splitlines()[-1])
    summary = json.loads((folder / "summary.json").read_text())
    return {
        "wall_s": wall,
        "loop_s": _clock_span(folder / RECORDING),
        "errors": {d: s["final_along_track_error_m"] for d, s in summary["deputies"].items()},
        "recorded": summary["messages"]["recorded"],
        "received": sum(client.counts.values()) if client is not None else 0,
        "run_cpu_s": run_cpu,
        "client_cpu_s": client_cpu,
    }


def _children_cpu() -> float:
    """CPU seconds (user and system) of this process's waited-for descendants so far."""
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def bench_live(quick: bool = False) -> list[dict[str, Any]]:
    """The default mission with ``--live`` and one client against without, alternated."""
    table = read_table(None)
    if quick:
        table["run"]["orbits"] = 4.0
    runs: dict[bool, list[dict[str, Any]]] = {False: [], True: []}
    with tempfile.TemporaryDirectory(prefix="ddvi-bench-live-") as tmp:
        path = write_deployment(table, Path(tmp), "mission")
        for _ in range(1 if quick else 2):
            for live in (False, True):
                runs[live].append(run_once(path, Path(tmp) / "runs", live))
    return _rows(table["run"]["orbits"], runs)


def _rows(orbits: float, runs: dict[bool, list[dict[str, Any]]]) -> list[dict[str, Any]]:
    rows = []
    for key, what in (("wall_s", "whole run"), ("loop_s", "lock-step loop"),
                      ("run_cpu_s", "CPU of the run's processes")):  # fmt: skip
        project = statistics.mean(r[key] for r in runs[True])
        baseline = statistics.mean(r[key] for r in runs[False])
        each = ", ".join(f"{r[key]:.1f}" for r in runs[True] + runs[False])
        rows.append(_row(f"{orbits:g}-orbit mission, {what}, --live and one client (runs: {each})",
                         "s", project, baseline, "without --live", project / baseline,
                         TARGET, bench="live"))  # fmt: skip
    live = runs[True][-1]
    client_cpu = statistics.mean(r["client_cpu_s"] for r in runs[True])
    rows.append(_row("CPU of the client (this process), against the run's without --live", "s",
                     client_cpu, statistics.mean(r["run_cpu_s"] for r in runs[False]),
                     "the run's CPU without --live", client_cpu / statistics.mean(
                         r["run_cpu_s"] for r in runs[False]), bench="live"))  # fmt: skip
    rows.append(_row("messages the client received (live gains included)", "count",
                     live["received"], live["recorded"], "messages recorded",
                     live["received"] / live["recorded"], bench="live"))  # fmt: skip
    same = all(r["errors"] == runs[False][0]["errors"] for r in runs[True] + runs[False])
    rows.append(_row(f"final along-track errors identical with and without: {same}", "m",
                     live["errors"].get("ddvi", float("nan")),
                     runs[False][0]["errors"].get("ddvi", float("nan")), "without --live",
                     1.0, bench="live"))  # fmt: skip
    return rows


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.live", description=__doc__)
    parser.add_argument("--quick", action="store_true", help="4 orbits, one run each")
    parser.add_argument("--json", action="store_true", help="the rows as JSON on stdout")
    args = parser.parse_args(argv)
    rows = bench_live(args.quick)
    if args.json:
        print(json.dumps(rows))
    else:
        for r in rows:
            print(f"{r['metric']}: {r['project']:.4g} {r['unit']} against {r['baseline']:.4g} "
                  f"({r['baseline_name']}), ratio {r['cost_ratio']:.3f} {r['target']}")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
