"""The NRLMSIS truth's cost, against the exponential truth, both measured in this run, in this
process, alternately, after a short warm-up of each (the first imports are not timed):

- the whole default mission stepped in one process
  (``services.flight.inprocess.run_in_process``): its wall time (target: within 1.5x), its CPU
  time and the environment's share.  This one also moves with what the controllers do in the
  other atmosphere (a learner that fails to learn tries again, and each attempt costs);
- the mission's truth alone: the built-in backend stepped over the mission's flight-software
  steps under sweeping commands, no controllers.

    OPENBLAS_NUM_THREADS=1 python -m benchmarks.atmosphere [--quick]
"""

from __future__ import annotations

import argparse
import copy
import math
import time
from typing import Any

import numpy as np

from benchmarks.mission import _row
from services.config import deployment_from_table, read_table
from services.flight.inprocess import run_in_process
from services.model import BuiltinTruth, duration, orbit_period

REPEATS = 3
"""Times each mission is flown (alternately); the fastest counts: a machine's load only slows."""


def fly(table: dict[str, Any]) -> dict[str, float]:
    """Wall and CPU seconds of the whole in-process run, and the wall seconds of its
    environment's share."""
    timing: dict[str, float] = {}
    t0, cpu0 = time.perf_counter(), time.process_time()
    run_in_process(deployment_from_table(table), timing=timing)
    return {
        "wall": time.perf_counter() - t0,
        "cpu": time.process_time() - cpu0,
        "environment": timing["environment"],
    }


def fly_truth(table: dict[str, Any]) -> dict[str, float]:
    """Wall seconds of the mission's truth alone: the built-in backend stepped over every
    flight-software step of the mission, each deputy's command a slow sweep of sigma3 within
    its limit, as the controllers' commands are."""
    dep = deployment_from_table(table)
    truth, n = BuiltinTruth(dep), len(dep.deputy)
    rate = 2.0 * math.pi / orbit_period(dep)
    t0, t, end = time.perf_counter(), 0.0, duration(dep)
    while t < end - 1e-6:
        sigma = np.zeros((n, 3))
        sigma[:, 2] = 0.1 * math.sin(rate * t)
        truth.step(t, sigma)
        t += dep.run.fsw_period
    return {"truth": time.perf_counter() - t0}


def bench_atmosphere(quick: bool = False) -> list[dict[str, Any]]:
    """The default mission's truth alone and the whole mission (quick: 4 orbits, not 40),
    NRLMSIS truth against exponential; each flown ``REPEATS`` times alternately (once,
    quick), the fastest of each kept."""
    base = read_table(None)
    if quick:
        base["run"]["orbits"] = 4.0
    msis = copy.deepcopy(base)
    msis.setdefault("atmosphere", {})["model"] = "nrlmsis"
    for table in (base, msis):  # warm: first imports (scipy's integrator, pymsis) not timed
        fly({**table, "run": {**table["run"], "orbits": 0.1}})
    runs: dict[str, list[dict[str, float]]] = {"exp": [], "msis": []}
    for _ in range(1 if quick else REPEATS):
        for key, table in (("exp", base), ("msis", msis)):
            runs[key].append({**fly_truth(table), **fly(table)})
    metrics = ("truth", "wall", "cpu", "environment")
    best = {k: {m: min(r[m] for r in v) for m in metrics} for k, v in runs.items()}
    exp, nrl = best["exp"], best["msis"]
    orbits = base["run"]["orbits"]
    name = "exponential truth, same mission"
    rows = [
        (f"{orbits:g}-orbit mission in process, NRLMSIS truth, wall", "wall", "<= 1.5x"),
        ("its truth alone in process (no controllers), NRLMSIS, wall", "truth", ""),
        ("the mission, CPU of the process (not inflated by a loaded machine)", "cpu", ""),
        ("the mission's environment share (truth and exostate), wall", "environment", ""),
    ]
    return [
        _row(metric, "s", nrl[key], exp[key], name, nrl[key] / exp[key], target, "atmosphere")
        for metric, key, target in rows
    ]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--quick", action="store_true", help="4 orbits, not 40")
    args = parser.parse_args(argv)
    for row in bench_atmosphere(args.quick):
        print(
            f"{row['metric']}: {row['project']:.2f} {row['unit']} against {row['baseline']:.2f} "
            f"({row['baseline_name']}), ratio {row['cost_ratio']:.3f} (target {row['target']})"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
