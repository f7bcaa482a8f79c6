"""Where a lock-step step of ``ddvi run`` goes, per service: CPU by thread, and by kind of work.

    python -m benchmarks.step_profile [DEPLOYMENT]            # CPU of every service's threads
    py-spy record --subprocesses --gil --format raw -r 100 -o steps.txt -- \\
        python -m services.cli run --quiet
    python -m benchmarks.step_profile --py-spy steps.txt      # that profile, split by kind

The first form runs the deployment (the default mission without one) through ``ddvi run`` and
reads every process's threads' CPU time from ``/proc`` every half second; it prints the
start-up (launch to the first clock the monitor recorded), the loop (first to last clock) and
each service's CPU by thread (``python``: the main thread and the subscriber callbacks;
``rx``/``tx``/``net``/``app``/``acc``: zenoh's).  The second splits a py-spy profile of the
threads holding the GIL (what the interpreter runs) into kinds of work (``KINDS``), per
service, in ms a step.
"""

from __future__ import annotations

import argparse
import collections
import os
import re
import subprocess
import sys
import time
from pathlib import Path

import psutil
from mcap.reader import make_reader

from services.interface.topics import CLOCK

STEPS = 3620  # lock-step steps of the default mission
KINDS = (  # the first matching frame from the innermost out names the kind
    ("start-up: imports", r"_find_and_load|_handle_fromlist"),
    ("logging", r"logging/__init__"),
    ("stats", r"publish_stats|Bus\.counters"),
    ("recording: JSON and MCAP", r"services/ground/storage/recording|mcap/"),
    (
        "report and its data",
        r"services/ground/(analysis/(report|figures|rundata|scoring)|monitoring/status)",
    ),
    ("serialisation: encode, decode", r"services/interface/|msgpack"),
    ("bus: guards, budget, links, delivery", r"services/bus/"),
    ("zenoh calls", r"zenoh"),
    ("work: truth, navigation, control", r"ddvi_core/|services/model/|services/flight/"),
    ("queues and waits", r"queue\.py|threading\.py"),
)


def _service(stack: str) -> str:
    """The service a py-spy stack is of: its ``--name``, else the launcher."""
    found = re.search(r"--name (\S+)", stack)
    return found.group(1) if found else "launcher"


def split_py_spy(path: Path, rate: float, steps: int) -> dict[str, collections.Counter]:
    """Seconds of samples by service and kind in a raw (collapsed) py-spy profile."""
    split: dict[str, collections.Counter] = collections.defaultdict(collections.Counter)
    for line in path.read_text().splitlines():
        stack, _, count = line.rpartition(" ")
        frames = [f for f in stack.split(";") if not f.startswith("process ")]
        kind = next((k for f in reversed(frames) for k, rx in KINDS if re.search(rx, f)), "other")
        split[_service(stack)][kind] += int(count) / rate
    return split


def _thread_cpu(root: psutil.Process, seen: dict[tuple[str, int], tuple[str, float]]) -> None:
    """Every thread's CPU seconds so far, by (service, thread id): (thread name, seconds)."""
    tick = os.sysconf("SC_CLK_TCK")
    for proc in [root, *root.children(recursive=True)]:
        try:
            found = re.search(r"--name (\S+)", " ".join(proc.cmdline()))
            name = found.group(1) if found else "launcher"
            for tid in os.listdir(f"/proc/{proc.pid}/task"):
                stat = Path(f"/proc/{proc.pid}/task/{tid}/stat").read_text()
                fields = stat[stat.rindex(")") + 2 :].split()
                comm = stat[stat.index("(") + 1 : stat.rindex(")")]
                seen[name, int(tid)] = (comm, (int(fields[11]) + int(fields[12])) / tick)
        except (psutil.Error, OSError, ValueError):
            continue  # it has just exited: its last reading stands


def profile_run(deployment: str | None) -> dict[str, object]:
    """Run ``ddvi run`` and account every service's CPU by thread."""
    launched_ns, t0 = time.time_ns(), time.perf_counter()
    cmd = [sys.executable, "-m", "services.cli", "run", "--quiet"]
    proc = subprocess.Popen(
        cmd + ([deployment] if deployment else []), stdout=subprocess.PIPE, text=True
    )
    root, seen = psutil.Process(proc.pid), {}
    while proc.poll() is None:
        _thread_cpu(root, seen)
        time.sleep(0.5)
    wall = time.perf_counter() - t0
    assert proc.stdout is not None
    folder = Path(proc.stdout.read().strip().splitlines()[-1])
    with (folder / "recording.mcap").open("rb") as f:
        # publish_time: the monitor's receive wall time (log_time is simulation time)
        clocks = [m.publish_time for _, _, m in make_reader(f).iter_messages(topics=[CLOCK])]
    cpu: dict[str, collections.Counter] = collections.defaultdict(collections.Counter)
    for (name, _), (comm, seconds) in seen.items():
        cpu[name][re.sub(r"-\d+$", "", comm)] += seconds
    return {
        "wall_s": wall,
        "startup_s": (min(clocks) - launched_ns) / 1e9,
        "loop_s": (max(clocks) - min(clocks)) / 1e9,
        "steps": len(clocks) - 1,
        "cpu_s": {name: dict(threads) for name, threads in cpu.items()},
        "folder": str(folder),
    }


def _print_split(split: dict[str, collections.Counter], steps: int) -> None:
    every: collections.Counter = collections.Counter()
    for kinds in split.values():
        every.update(kinds)
    ranked = sorted(split.items(), key=lambda kv: -sum(kv[1].values()))
    for name, kinds in [*ranked, ("all services", every)]:
        total = sum(kinds.values())
        print(f"{name}: {total:.2f} s, {1e3 * total / steps:.2f} ms a step")
        for kind, seconds in kinds.most_common():
            print(f"    {kind:40s} {seconds:7.2f} s {1e3 * seconds / steps:6.2f} ms a step")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        prog="python -m benchmarks.step_profile",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    ap.add_argument("deployment", nargs="?", help="a deployment file (default: the mission's)")
    ap.add_argument("--py-spy", type=Path, help="split this raw py-spy profile instead")
    ap.add_argument("--rate", type=float, default=100.0, help="the profile's samples a second")
    ap.add_argument("--steps", type=int, default=STEPS, help="lock-step steps of its run")
    args = ap.parse_args(argv)
    if args.py_spy is not None:
        _print_split(split_py_spy(args.py_spy, args.rate, args.steps), args.steps)
        return 0
    run = profile_run(args.deployment)
    steps = run["steps"]
    print(
        f"start-up {run['startup_s']:.2f} s; loop {run['loop_s']:.2f} s "
        f"({1e3 * run['loop_s'] / steps:.2f} ms a step); wall {run['wall_s']:.2f} s"
    )
    total = 0.0
    for name, threads in sorted(run["cpu_s"].items(), key=lambda kv: -sum(kv[1].values())):
        total += sum(threads.values())
        shown = ", ".join(f"{k} {v:.2f}" for k, v in sorted(threads.items(), key=lambda kv: -kv[1]))
        print(f"{name:14s} {sum(threads.values()):6.2f} s CPU ({shown})")
    print(f"{'all':14s} {total:6.2f} s CPU; run folder {run['folder']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
