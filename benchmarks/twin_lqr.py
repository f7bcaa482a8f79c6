"""How strict "final error within max(2 x the LQR's, 10 m)" is: the LQR deputy of
``realistic-nav`` flown beside an exact copy of itself that draws its own navigation noise, over
N draws, in one process.  Run: ``python -m benchmarks.twin_lqr [--noise M ...] [--draws N]``.

The two deputies fly the same gain from the same state through the same filter; only their
noise differs.  How often the copy misses the criterion against the original (and the other way
round) is the rate at which a learner that held station exactly as well as the LQR would still
miss it: the floor under any "in k of 20 draws" target on the criterion.  Draw i is run.seed i
(1 to N), the navigation noise of ``ddvi sweep noise`` (``services.ground.sweep.noisy_table``).
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse
import copy
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from services.config import deployment_from_table, read_table, resolve
from services.ground.sweep import inprocess_rows, noisy_table

DEPLOYMENT = "realistic-nav"
TWIN = "lqr_twin"


def _draw(args: tuple[Path, float, int]) -> tuple[float, float]:
    """(the LQR's, its twin's) final along-track error (m) of draw ``seed`` at ``noise`` m."""
    path, noise, seed = args
    table = read_table(path)
    (lqr,) = [d for d in table["deputy"] if d["name"] == "lqr"]
    twin = copy.deepcopy(lqr)
    twin["name"] = TWIN
    table["deputy"] = [lqr, twin]
    table = noisy_table(table, noise)
    table["run"]["seed"] = seed
    rows = {r["deputy"]: r for r in inprocess_rows({"noise": noise}, deployment_from_table(table))}
    return rows["lqr"]["final_along_track_error_m"], rows[TWIN]["final_along_track_error_m"]


def within(error: np.ndarray, lqr: np.ndarray) -> np.ndarray:
    """Whether each final error is within max(2 x the LQR's of the same draw, 10 m)."""
    return error <= np.maximum(2.0 * lqr, 10.0)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--noise", type=float, nargs="+", default=[0.5, 1.0, 3.0],
                        help="position noise, m (velocity noise 1e-3 of it, m/s)")  # fmt: skip
    parser.add_argument("--draws", type=int, default=40, help="noise draws (seeds 1 to N)")
    parser.add_argument("--workers", type=int, default=2, help="processes")
    args = parser.parse_args()
    path = resolve(DEPLOYMENT)
    print("| noise (m) | draws | twin within max(2x LQR, 10 m) | LQR within max(2x twin, 10 m) "
          "| LQR final p50 / p90 (m) |")  # fmt: skip
    print("|---|---|---|---|---|")
    with ProcessPoolExecutor(args.workers) as pool:
        for noise in args.noise:
            jobs = [(path, noise, seed) for seed in range(1, args.draws + 1)]
            finals = np.array(list(pool.map(_draw, jobs)))
            lqr, twin = finals[:, 0], finals[:, 1]
            print(f"| {noise:g} | {args.draws} | {int(within(twin, lqr).sum())} "
                  f"| {int(within(lqr, twin).sum())} | {np.median(lqr):.2f} / "
                  f"{np.percentile(lqr, 90):.2f} |", flush=True)  # fmt: skip


if __name__ == "__main__":
    main()
