"""Mission benchmarks: the distributed run against the single-process run, and swarm scaling.

Throughput: the default deployment through ``ddvi run`` (every service its own process on
Zenoh, start-up and report included) against ``services.flight.inprocess.run_in_process`` (the
same truth, navigation and controller code stepped in one process, no bus), in wall time and
in the CPU of all processes (which a loaded machine does not inflate); the start-up (launch to
the first clock).  Then the loops alone (the first to the last clock message the monitor
recorded; the one-process loop) and the lock-step floors (``benchmarks.floor``): the same
processes and messages, each process spending its share of the one-process run's work, on
plain zenoh peers, on the mission's topology (authenticated clients of one router with the
run's access control, every message recorded to MCAP) and on the project's Bus, which split
the distributed loop's cost into the topology's, the bus layer's and the services' own.

Swarm scaling: 1, 4, 16 and 32 LQR deputies and 8 learning ones holding along-track slots
1 km apart, each with its own navigation and controller process; the loop (first to last
clock) per simulated orbit and per deputy-orbit, the peak memory of every process of the run
together (sampled by psutil every second, sooner at first) and the messages recorded a
second.  The baselines are the one-deputy run of the same sweep (the four-deputy run for the
loop per deputy-orbit) and the same swarm stepped in one process.

Memory is the proportional set size (PSS) summed over the processes: each page counted once,
a shared one split among the processes that map it.  A sum of resident sizes (RSS) would count
the interpreter's and every extension's shared pages once per process, and grow with the
number of processes far faster than the memory the run holds.  Reading a process's PSS makes
the kernel walk its page tables, hence one sample a second: the sampling must not load the
cores the run is measured on.
"""

from __future__ import annotations

import contextlib
import copy
import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import psutil
from mcap.reader import make_reader

from benchmarks.floor import run_floor
from benchmarks.process_tree import ProcessTreeSampler
from services.config import Deployment, load_deployment, read_table, write_deployment
from services.flight.inprocess import run_in_process
from services.ground.storage.recording import RECORDING
from services.interface.topics import CLOCK
from services.model import duration


class _PeakMemory(ProcessTreeSampler):
    """Peak of the summed proportional set size (PSS) of a process and all its descendants."""

    def __init__(self, pid: int, period: float = 1.0) -> None:
        self.peak = 0
        super().__init__(pid, period)

    def read(self, processes: list[psutil.Process]) -> None:
        total = 0
        for p in processes:
            with contextlib.suppress(psutil.Error):  # it may just have exited
                total += p.memory_full_info().pss
        self.peak = max(self.peak, total)

    def stop(self) -> int:
        self._end()
        return self.peak


def run_distributed(path: Path) -> dict[str, Any]:
    """``ddvi run path --quiet`` as a new user runs it; wall time, peak PSS, summary."""
    t0, launched_ns, cpu0 = time.perf_counter(), time.time_ns(), _children_cpu()
    proc = subprocess.Popen(
        [sys.executable, "-m", "services.cli", "run", str(path), "--quiet"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    memory = _PeakMemory(proc.pid)
    out, err = proc.communicate()
    wall, cpu = time.perf_counter() - t0, _children_cpu() - cpu0
    peak = memory.stop()
    if proc.returncode != 0:
        raise RuntimeError(f"ddvi run {path} failed ({proc.returncode}): {err[-2000:]}")
    folder = Path(out.strip().splitlines()[-1])
    summary = json.loads((folder / "summary.json").read_text())
    first, last = _clock_span(folder / RECORDING)
    return {
        "wall_s": wall,
        "mission_wall_s": summary["wall_s"],
        "loop_s": (last - first) / 1e9,
        "startup_s": (first - launched_ns) / 1e9,
        "cpu_s": cpu,
        "pss_bytes": peak,
        "summary": summary,
    }


def _children_cpu() -> float:
    """CPU seconds (user and system) of this process's children waited for so far, and of
    theirs: a run's processes, which its launcher waits for.  Unlike wall time, it does not
    grow with what else the machine runs."""
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def _clock_span(path: Path) -> tuple[int, int]:
    """Receive times (ns since the epoch) of the first and the last clock message the monitor
    recorded: the lock-step loop lies between, without the services' start-up and final
    stats."""
    with path.open("rb") as f:
        # publish_time: the monitor's receive wall time (services.ground.storage.recording)
        stamps = [m.publish_time for _, _, m in make_reader(f).iter_messages(topics=[CLOCK])]
    return min(stamps), max(stamps)


def _row(
    metric: str,
    unit: str,
    project: float,
    baseline: float,
    baseline_name: str,
    ratio: float,
    target: str = "",
    bench: str = "mission",
) -> dict[str, Any]:
    return {
        "benchmark": bench,
        "metric": metric,
        "unit": unit,
        "project": project,
        "baseline": baseline,
        "baseline_name": baseline_name,
        "cost_ratio": ratio,
        "target": target,
    }


def skipped_row(bench: str, why: str) -> dict[str, Any]:
    """The row of a benchmark that cannot run here, ``why`` said in it (``skipped``: what
    ``ddvi bench`` lists at the end)."""
    nan = float("nan")
    row = _row(f"skipped: {why}", "", nan, nan, "-", nan, bench=bench)
    row["skipped"] = why
    return row


def run_single(path: Path) -> dict[str, Any]:
    """The same deployment stepped in one fresh process (imports included), no bus; with the
    loop's wall time and each service's share of it (``run_in_process``'s timing)."""
    t0, cpu0 = time.perf_counter(), _children_cpu()
    proc = subprocess.Popen(
        [sys.executable, "-m", "benchmarks.mission", str(path)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    memory = _PeakMemory(proc.pid)
    out, err = proc.communicate()
    wall, cpu = time.perf_counter() - t0, _children_cpu() - cpu0
    peak = memory.stop()
    if proc.returncode != 0:
        raise RuntimeError(f"in-process run of {path} failed: {err[-2000:]}")
    return {
        "wall_s": wall,
        "cpu_s": cpu,
        "pss_bytes": peak,
        **json.loads(out.strip().splitlines()[-1]),
    }


def run_single_loop(path: str) -> dict[str, Any]:
    """What ``python -m benchmarks.mission DEPLOYMENT`` prints: the one-process run's loop
    (``loop_s``) and its ``timing``."""
    timing: dict[str, float] = {}
    t0 = time.perf_counter()
    run_in_process(load_deployment(path), timing=timing)
    return {"loop_s": time.perf_counter() - t0, "timing": timing}


def bench_mission(quick: bool = False) -> list[dict[str, Any]]:
    """The default mission, distributed against in-process (quick: 4 orbits, not 40)."""
    table = read_table(None)
    if quick:
        table["run"]["orbits"] = 4.0
    with tempfile.TemporaryDirectory(prefix="ddvi-bench-") as tmp:
        path = write_deployment(table, Path(tmp), "mission")
        dep = load_deployment(str(path))
        single = run_single(path)
        dist = run_distributed(path)
    timing = single["timing"]
    steps = int(timing.pop("steps"))
    floors = {
        (layer, topology): mission_floor(dep, timing, steps, layer, topology)
        for layer, topology in (("plain", "peer"), ("plain", "routed"), ("bus", "peer"))
    }
    return _whole_run_rows(table["run"]["orbits"], duration(dep), dist, single) + _loop_rows(
        dist["loop_s"], single["loop_s"], floors, timing, steps
    )


def mission_floor(
    dep: Deployment, timing: dict[str, float], steps: int, layer: str, topology: str = "peer"
) -> dict[str, Any]:
    """The lock-step floor's loop (s) for ``dep`` on ``layer`` and ``topology``
    (``benchmarks.floor``): the same processes, messages and work (each service's share of
    the one-process run, ``timing``, over ``steps``) as the distributed run, with services
    and a monitor that cost nothing beyond that work (and, routed, the recording); with the
    CPU its processes spent (``cpu_s``)."""
    return run_floor(
        [d.name for d in dep.deputy],
        steps,
        samples=round(dep.run.fsw_period / dep.run.nav_period),
        dt=dep.run.nav_period,
        spins={name: spent / steps for name, spent in timing.items()},
        layer=layer,
        topology=topology,
    )


def _whole_run_rows(
    orbits: float, sim: float, dist: dict[str, Any], single: dict[str, Any]
) -> list[dict[str, Any]]:
    """Wall time, simulated seconds per wall second and peak memory of the whole run (start-up
    included, ``sim`` simulated seconds), distributed against one process."""
    base = "one process, no bus"
    ratio = dist["wall_s"] / single["wall_s"]
    return [
        _row(
            f"{orbits:g}-orbit mission, wall, start-up included",
            "s",
            dist["wall_s"],
            single["wall_s"],
            base,
            ratio,
            "<= 3x",
        ),
        _row(
            "start-up: launch to first clock",
            "s",
            dist["startup_s"],
            single["wall_s"] - single["loop_s"],
            "one process: launch to its loop",
            dist["startup_s"] / (single["wall_s"] - single["loop_s"]),
            "< 2 s",
        ),
        _row(
            "simulated s per wall s", "x", sim / dist["wall_s"], sim / single["wall_s"], base, ratio
        ),
        _row(
            "CPU of all processes, start-up included (not inflated by a loaded machine)",
            "s",
            dist["cpu_s"],
            single["cpu_s"],
            base,
            dist["cpu_s"] / single["cpu_s"],
        ),
        _row(
            "peak memory (PSS), all processes",
            "MB",
            dist["pss_bytes"] / 1e6,
            single["pss_bytes"] / 1e6,
            base,
            dist["pss_bytes"] / single["pss_bytes"],
            "<= 350 MB",
        ),
    ]


def _loop_rows(
    loop: float,
    single_loop: float,
    floors: dict[tuple[str, str], dict[str, Any]],
    timing: dict[str, float],
    steps: int,
) -> list[dict[str, Any]]:
    """The lock-step loop alone (s), distributed (``loop``) against one process
    (``single_loop``), and split by the floors (by layer and topology) into the topology's,
    the bus layer's and the services' own cost; ``timing``: each service's work (s) over
    ``steps``."""
    base = "one process, no bus: loop"
    shares = ", ".join(f"{name} {1e3 * spent / steps:.2f}" for name, spent in timing.items())
    work = sum(timing.values())
    plain, routed, bus = (
        floors[k]["loop_s"] for k in (("plain", "peer"), ("plain", "routed"), ("bus", "peer"))
    )
    cpu = {k: f["cpu_s"] for k, f in floors.items()}
    return [
        _row(
            f"loop only: first to last clock ({steps:,} lock-step steps)",
            "s",
            loop,
            single_loop,
            base,
            loop / single_loop,
        ),
        _row(
            f"one process's work, ms a step: {shares}",
            "ms",
            1e3 * work / steps,
            1e3 * single_loop / steps,
            base,
            work / single_loop,
        ),
        _row(
            "floor: plain zenoh peers, same processes, messages and work",
            "s",
            plain,
            single_loop,
            base,
            plain / single_loop,
        ),
        _row(
            "floor, mission's topology: authenticated clients of one router, access "
            "control, every message recorded to MCAP",
            "s",
            routed,
            plain,
            "floor: plain zenoh peers",
            routed / plain,
            "<= 1.3x",
        ),
        _row(
            "floor on the mission's topology, CPU of all its processes and its router",
            "s",
            cpu["plain", "routed"],
            cpu["plain", "peer"],
            "floor: plain zenoh peers",
            cpu["plain", "routed"] / cpu["plain", "peer"],
        ),
        _row(
            "floor on the project's Bus (peers)",
            "s",
            bus,
            plain,
            "floor: plain zenoh peers",
            bus / plain,
        ),
        _row(
            "loop only, against the floor on the mission's topology",
            "s",
            loop,
            routed,
            "floor, mission's topology",
            loop / routed,
            "<= 1.3x",
        ),
        _row(
            "loop only, against the plain floor",
            "s",
            loop,
            plain,
            "floor: plain zenoh peers",
            loop / plain,
            "<= 1.7x",
        ),
    ]


def swarm_table(n: int, orbits: float, controller: str = "lqr") -> dict[str, Any]:
    """n deputies on along-track slots 1 km apart about the chief, each starting 240 m above
    the chief's orbit at its slot: LQR ones, or (``controller="ddvi"``) learning ones as the
    default mission's learning deputy."""
    table = read_table(None)
    table["run"].update(name=f"swarm{n}", orbits=orbits)
    template = next(d for d in table["deputy"] if d["controller"] == controller)
    deputies = []
    for k in range(n):
        slot = 1000.0 * (k - (n - 1) / 2)
        d = copy.deepcopy(template)
        d.update(name=f"d{k:02d}", controller=controller, y_ref=slot)
        # the chief's argument of latitude plus the slot's angle
        d["orbit"]["f"] = (
            table["chief"]["f"] + slot / table["chief"]["a"] * 180.0 / 3.141592653589793
        )
        deputies.append(d)
    table["deputy"] = deputies
    return table


SWARMS = ((1, "lqr"), (4, "lqr"), (16, "lqr"), (32, "lqr"), (8, "ddvi"))
"""The swarms ``ddvi bench --only swarm`` flies: (deputies, controller)."""
QUICK_SWARMS = ((1, "lqr"), (4, "lqr"))


def bench_swarm(quick: bool = False) -> list[dict[str, Any]]:
    """Each swarm through ``ddvi run`` against the one-deputy swarm and against itself in one
    process: loop per orbit and per deputy-orbit, memory, messages a second."""
    swarms, orbits = (QUICK_SWARMS, 0.5) if quick else (SWARMS, 2.0)
    results = {}
    with tempfile.TemporaryDirectory(prefix="ddvi-bench-") as tmp:
        for n, controller in swarms:
            table = swarm_table(n, orbits, controller)
            path = write_deployment(table, Path(tmp), f"swarm{n}{controller}")
            results[n, controller] = (run_distributed(path), run_single(path))
    rows = []
    for n, controller in swarms:
        rows += _swarm_rows(n, controller, orbits, results)
    return rows


def _swarm_rows(
    n: int, controller: str, orbits: float, results: dict[tuple[int, str], tuple[dict, dict]]
) -> list[dict[str, Any]]:
    """One swarm's rows: its loop per orbit, per deputy-orbit, PSS and messages a second,
    against the one-deputy swarm's (and, per deputy-orbit, the four-deputy swarm's) and its
    own run in one process."""
    dist, single = results[n, controller]
    one, _ = results[1, "lqr"]
    four, _ = results[4, "lqr"]  # every sweep has it
    name = f"{n:2d} {controller} deput{'y' if n == 1 else 'ies'}"
    per_orbit, one_orbit = dist["loop_s"] / orbits, one["loop_s"] / orbits
    single_orbit = single["loop_s"] / orbits
    rate, one_rate = _message_rate(dist), _message_rate(one)
    pss, one_pss = dist["pss_bytes"] / 1e6, one["pss_bytes"] / 1e6

    def row(
        metric: str, unit: str, project: float, base: float, base_name: str, target: str = ""
    ) -> dict[str, Any]:
        return _row(
            f"{name}: {metric}",
            unit,
            project,
            base,
            base_name,
            project / base,
            target,
            bench="swarm",
        )

    return [
        row("loop per orbit", "s", per_orbit, one_orbit, "1 lqr deputy", f"~{n}x if linear"),
        row(
            "loop per orbit, against one process",
            "s",
            per_orbit,
            single_orbit,
            "the same swarm, one process",
        ),
        row(
            "loop per deputy-orbit",
            "s",
            per_orbit / n,
            four["loop_s"] / orbits / 4,
            "4 lqr deputies",
            "<= 1.2x" if n == 32 else "",
        ),
        row("peak memory (PSS), all processes", "MB", pss, one_pss, "1 lqr deputy"),
        row(
            "peak memory (PSS) per deputy",
            "MB",
            pss / n,
            single["pss_bytes"] / 1e6 / n,
            "the same swarm, one process",
        ),
        row("messages recorded a second", "1/s", rate, one_rate, "1 lqr deputy"),
        row(
            "CPU of the whole run per deputy-orbit",
            "s",
            dist["cpu_s"] / orbits / n,
            four["cpu_s"] / orbits / 4,
            "4 lqr deputies",
        ),
    ]


def _message_rate(dist: dict[str, Any]) -> float:
    """Messages the monitor recorded a wall second of the loop."""
    return dist["summary"]["messages"]["recorded"] / dist["loop_s"]


def bench_basilisk(quick: bool = False) -> list[dict[str, Any]]:
    """The default mission on the Basilisk truth, side by side with the built-in truth: stepped
    in one process (the paper's setting; 40 orbits, quick: 1) and through ``ddvi run`` (4
    orbits, quick: 1).  Only where the optional Basilisk backend is installed."""
    import importlib.util

    if importlib.util.find_spec("Basilisk") is None:
        why = "Basilisk is not installed (pip install -e '.[basilisk]')"
        return [skipped_row("basilisk", why)]
    rows = []
    base = "built-in truth"
    with tempfile.TemporaryDirectory(prefix="ddvi-bench-") as tmp:
        for how, orbits, runner in (
            ("in one process", 1.0 if quick else 40.0, run_single),
            ("through ddvi run", 1.0 if quick else 4.0, run_distributed),
        ):
            table = read_table(None)
            table["run"]["orbits"] = orbits
            table.setdefault("environment", {})["backend"] = "builtin"
            builtin = runner(write_deployment(table, Path(tmp), "builtin"))
            table["environment"]["backend"] = "basilisk"
            bsk = runner(write_deployment(table, Path(tmp), "basilisk"))
            rows += [
                _row(
                    f"{orbits:g}-orbit mission {how}, wall",
                    "s",
                    bsk["wall_s"],
                    builtin["wall_s"],
                    base,
                    bsk["wall_s"] / builtin["wall_s"],
                    bench="basilisk",
                ),
                _row(
                    f"{orbits:g}-orbit mission {how}, peak memory (PSS)",
                    "MB",
                    bsk["pss_bytes"] / 1e6,
                    builtin["pss_bytes"] / 1e6,
                    base,
                    bsk["pss_bytes"] / builtin["pss_bytes"],
                    bench="basilisk",
                ),
            ]
    return rows


if __name__ == "__main__":
    # the single-process baseline, in its own process so its memory is its own
    print(json.dumps(run_single_loop(sys.argv[1])))
