"""How much velocity noise the paper's value iteration tolerates at 1 m of position noise: the
``realistic-nav`` deployment's value-iteration deputy (learning at orbit 15, through the
Kalman filter) alone, over a range of navigation velocity noise and N draws each, in one
process.  Run: ``python -m benchmarks.velocity_noise [--values V ...] [--draws N]``.

Per velocity noise (m/s, 1 sigma per axis): in how many draws the learner learned, when (the
median orbit), its gain error |K - K*| / |K*| at the end (median and largest; K* of the
truth's linear model, nominal here), and its final along-track error (median and largest, m);
a draw that learns nothing flies its fallback, the nominal LQR gains, from
``learn_until_orbits`` on (``services.flight.phases``).  Draw i is run.seed i (1 to N), its
exploration seeded with it too.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse
from concurrent.futures import ProcessPoolExecutor

import numpy as np

from services.config import deployment_from_table, read_table
from services.ground.sweeps.sweep import inprocess_rows

DEPLOYMENT = "realistic-nav"
LEARNER = "ddvi"
"""The deployment's value-iteration deputy."""
POSITION_NOISE = 1.0  # m, 1 sigma per axis
VALUES = (0.0, 1e-6, 1e-5, 3e-5, 1e-4, 3e-4, 1e-3)
"""Velocity noise, m/s: from exact to the deployment's 1e-3."""


def draw(velocity_noise: float, seed: int) -> dict:
    """The learner's row (``services.ground.analysis.scoring.METRICS``) of draw ``seed`` at
    ``velocity_noise`` m/s."""
    table = read_table(DEPLOYMENT)
    table["deputy"] = [d for d in table["deputy"] if d["name"] == LEARNER]
    (deputy,) = table["deputy"]
    deputy["navigation"].update(position_noise=POSITION_NOISE, velocity_noise=velocity_noise)
    deputy["learning"]["seed"] = seed
    table["run"]["seed"] = seed
    (row,) = inprocess_rows({"noise": POSITION_NOISE}, deployment_from_table(table))
    return row


def _median_max(values: list[float]) -> str:
    return f"{np.median(values):.3g} / {max(values):.3g}" if values else "-"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--values", type=float, nargs="+", default=list(VALUES), help="m/s")
    parser.add_argument("--draws", type=int, default=3, help="noise draws (seeds 1 to N)")
    parser.add_argument("--workers", type=int, default=2, help="processes")
    args = parser.parse_args()
    if args.draws < 1 or any(not v >= 0 for v in args.values):
        parser.error("--draws must be at least 1 and every --values at least 0")
    tasks = [(v, seed) for v in args.values for seed in range(1, args.draws + 1)]
    with ProcessPoolExecutor(args.workers) as pool:
        rows = list(pool.map(draw, *zip(*tasks, strict=True)))
    print(
        "| velocity noise (m/s) | learned | learned at orbit (p50) | gain error p50 / max "
        "| final p50 / max (m) | fell back |"
    )
    print("|---|---|---|---|---|---|")
    for v in args.values:
        mine = [r for (value, _), r in zip(tasks, rows, strict=True) if value == v]
        learned = [r for r in mine if r["learned"]]
        at = [r["learned_at_orbits"] for r in learned]
        print(
            f"| {v:g} | {len(learned)}/{len(mine)} | {np.median(at) if at else '-':.4} "
            f"| {_median_max([r['gain_error'] for r in learned])} "
            f"| {_median_max([r['final_along_track_error_m'] for r in mine])} "
            f"| {sum(r['fallback_at_orbits'] is not None for r in mine)}/{len(mine)} |"
        )


if __name__ == "__main__":
    main()
