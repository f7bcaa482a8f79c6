"""Learning in flight: the model-fit learner against the model-based LQR under navigation noise,
on the nominal model and where the craft's drag is twice the model's.

Each point is ``deployments/realistic-nav.toml`` (or ``realistic-nav-2x.toml``) with every
deputy's navigation noise set (``services.ground.sweeps.sweep.noisy_table``), flown in one process
(``run_in_process``, the services' code) with the LQR and model-fit deputies only; the paper's
value iteration, which learns in none of these points, is measured by ``ddvi sweep noise``
(docs/results.md).  A row's project figure is the model-fit deputy's final along-track error,
its baseline the LQR deputy's in the same mission; the metric names its gain error against
the truth's optimal gain and the orbit it learned at.

    python -m benchmarks.flight [--quick] [--json]
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse
import json
import sys
from typing import Any

from services.config import deployment_from_table, read_table
from services.ground.sweeps.sweep import inprocess_rows, sweep_points

POINTS = {"realistic-nav": (0.0, 0.1, 1.0, 10.0), "realistic-nav-2x": (0.0, 0.1, 1.0, 10.0)}
QUICK_POINTS = {"realistic-nav": (1.0,), "realistic-nav-2x": (1.0,)}
TARGETS = {
    ("realistic-nav", 0.0): "learned by orbit 6, |dK|/|K*| <= 0.02",
    ("realistic-nav", 0.1): "|dK|/|K*| <= 0.02",
    ("realistic-nav", 1.0): "|dK|/|K*| <= 0.05, final <= max(2 x LQR, 10 m)",
    ("realistic-nav", 10.0): "|dK|/|K*| <= 0.15",
    ("realistic-nav-2x", 0.0): "|dK|/|K*| <= 0.02, final <= 50 m",
    ("realistic-nav-2x", 1.0): "|dK|/|K*| <= 0.05, final <= 100 m",
}
"""What the learner is asked for at each point (none where the key is absent)."""


def _learners_only(table: dict[str, Any]) -> dict[str, Any]:
    """The deployment table with its LQR and model-fit deputies only."""
    keep = [
        d
        for d in table["deputy"]
        if d.get("controller", "lqr") == "lqr" or d.get("learning", {}).get("method") == "model-fit"
    ]
    return {**table, "deputy": keep}


def flight_rows(deployment: str, noises: tuple[float, ...]) -> list[dict[str, Any]]:
    """One row per noise value: the model-fit deputy's final along-track error against the
    LQR deputy's, flown side by side."""
    table = _learners_only(read_table(deployment))
    rows = []
    for point, derived, _ in sweep_points("noise", table, list(noises)):
        dep = deployment_from_table(derived)
        by = {r["controller"]: r for r in inprocess_rows(point, dep)}
        fit, lqr = by["ddvi model-fit"], by["lqr"]
        learned = fit["learned_at_orbits"]
        gain = fit["gain_error"]
        where = f"{deployment}, noise {point['noise']:g} m"
        what = (
            f"learned at orbit {learned:.2f}, |dK|/|K*| = {gain:.3g}"
            if learned is not None and gain is not None
            else f"not learned ({fit['note']})"
        )
        project, baseline = fit["final_along_track_error_m"], lqr["final_along_track_error_m"]
        rows.append(
            {
                "benchmark": "flight",
                "metric": f"model-fit final along-track error, {where}: {what}",
                "unit": "m",
                "project": project,
                "baseline": baseline,
                "baseline_name": "LQR, the same mission",
                "cost_ratio": project / baseline if baseline > 0 else float("inf"),
                "target": TARGETS.get((deployment, point["noise"]), ""),
            }
        )
    return rows


def bench_flight(quick: bool = False) -> list[dict[str, Any]]:
    """Rows for ``ddvi bench``: every point of POINTS (QUICK_POINTS with ``quick``)."""
    points = QUICK_POINTS if quick else POINTS
    return [row for name, noises in points.items() for row in flight_rows(name, noises)]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.flight", description=__doc__)
    parser.add_argument("--quick", action="store_true", help="1 m of noise only")
    parser.add_argument("--json", action="store_true", help="the rows as JSON on stdout")
    args = parser.parse_args(argv)
    rows = bench_flight(args.quick)
    if args.json:
        print(json.dumps(rows, default=float))
    else:
        for r in rows:
            print(f"{r['project']:10.3g} m  (LQR {r['baseline']:.3g} m)  {r['metric']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
