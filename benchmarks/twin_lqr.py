"""How strict "final error within max(2 x the LQR's, 10 m)" is: the LQR deputy of
``realistic-nav`` (or ``--deployment``'s) flown beside an exact copy of itself that draws its own
navigation noise, over N draws, in one process.  Run: ``python -m benchmarks.twin_lqr
[--deployment NAME] [--noise M ...] [--draws N] [--gains lqr|truth] [--refits] [--deployed]
[--within M]``.

The two deputies fly the same gain from the same state through the same filter; only their
noise differs.  How often the copy misses the criterion against the original (and the other way
round) is the rate at which a learner that held station exactly as well as the LQR would still
miss it: the floor under any "in k of 20 draws" target on the criterion.

A third deputy is a learner that learns perfectly at orbit 6: the deployment's model-fit
deputy (K0 and its exploration from the same state, its first attempt at orbit 6), every
attempt accepted with the LQR's own gain and feedforward in place of the fitted ones, and no
feedforward refits on station.  It is what any learner that explores until orbit 6 can at best
do against the criterion: it starts closing the gap six orbits after the LQR.  With
``--gains truth`` it flies instead the optimal gains of the truth's linear model at the start
(``services.model.true_lqr_gains``: K* and L*, with the truth's density, scale height and
facet areas): in a deployment whose truth is not the model (``msis``, ``storm``) the best any
learner of the truth's linear model can fly.  With ``--refits`` it keeps the deployment's
feedforward refits on station (the fitted model's A and B, its D refitted from the data flown
on the given K).  With ``--deployed`` the same deputy flies as the deployment has it (its own
fits and refits), on the same draws.  ``--within M`` adds a table of each deputy's final
errors: how many within M m, and their p50, p90 and max.

Draw i is run.seed i (1 to N), the navigation noise of ``ddvi sweep noise``
(``services.ground.sweeps.sweep.noisy_table``); the learner's exploration is seeded with it too.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse
import contextlib
import copy
import dataclasses
import math
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any
from unittest import mock

import numpy as np

from services.config import deployment_from_table, read_table, resolve
from services.flight import learners
from services.ground.analysis.scoring import AS_GOOD_AS_LQR
from services.ground.sweeps.sweep import inprocess_rows, noisy_table
from services.model.mission import lqr_gains
from services.model.reference import true_lqr_gains

DEPLOYMENT = "realistic-nav"
TWIN = "lqr_twin"
LEARNER = "fit"
"""The deployment's model-fit deputy, made the perfect learner."""
BY_ORBIT = 6.0
"""The orbit a learner should have learned by."""
NO_REFITS = 1e6
"""refresh_orbits of the perfect learner: its feedforward is the given one, never refitted."""
GAINS = {"lqr": lqr_gains, "truth": true_lqr_gains}
"""The perfect learner's gains: the LQR's (the nominal model's) or the truth's optimal ones."""


@dataclasses.dataclass(frozen=True)
class Draw:
    """One draw: deployment file, noise (m), seed; the learner ``deployed``, or perfect with
    ``gains`` (a key of GAINS) and, if ``refits``, the deployment's feedforward refits."""

    path: Path
    noise: float
    seed: int
    deployed: bool = False
    gains: str = "lqr"
    refits: bool = False


def _perfect_fit(gains: tuple[np.ndarray, np.ndarray]) -> Any:
    """``services.flight.learners.fit_attempt`` that accepts every attempt with ``gains``
    (K (1, n), L (1, q)) in place of the fitted ones: L padded with zeros where the learner's
    exostate is longer (its density ratio)."""
    K, L = gains
    fit = learners.fit_attempt

    def attempt(*args: Any, **kwargs: Any) -> tuple[Any, dict, None]:
        r, info, _ = fit(*args, **kwargs)
        padded = np.zeros_like(r.L)
        padded[:, : L.shape[1]] = L
        return dataclasses.replace(r, K=np.atleast_2d(K), L=padded), info, None

    return attempt


def _draw(draw: Draw) -> tuple[float, float, float, float]:
    """(the LQR's, its twin's, the learner's) final along-track error (m) of ``draw``, and the
    orbit the learner learned at (nan: not learned)."""
    table = read_table(draw.path)
    deputies = {d["name"]: d for d in table["deputy"]}
    twin = copy.deepcopy(deputies["lqr"])
    twin["name"] = TWIN
    learner = deputies[LEARNER]
    learner["learning"]["seed"] = draw.seed
    if not (draw.deployed or draw.refits):
        learner["learning"]["refresh_orbits"] = NO_REFITS
    table["deputy"] = [deputies["lqr"], twin, learner]
    table = noisy_table(table, draw.noise)
    table["run"]["seed"] = draw.seed
    dep = deployment_from_table(table)
    # the LQR's gains from the LQR deputy, the truth's from the learner's (its true area)
    deputy = dep.deputy[2] if draw.gains == "truth" else dep.deputy[0]
    perfect = mock.patch.object(
        learners, "fit_attempt", _perfect_fit(GAINS[draw.gains](dep, deputy))
    )
    with contextlib.nullcontext() if draw.deployed else perfect:
        rows = {r["deputy"]: r for r in inprocess_rows({"noise": draw.noise}, dep)}
    learned_at = rows[LEARNER]["learned_at_orbits"]
    finals = tuple(rows[name]["final_along_track_error_m"] for name in ("lqr", TWIN, LEARNER))
    return (*finals, math.nan if learned_at is None else learned_at)


def within(error: np.ndarray, lqr: np.ndarray) -> np.ndarray:
    """Whether each final error is within max(2 x the LQR's of the same draw, 10 m)
    (``AS_GOOD_AS_LQR``)."""
    return np.array(
        [
            AS_GOOD_AS_LQR.met(completed=True, final_m=float(e), lqr_final_m=float(q))
            for e, q in zip(error, lqr, strict=True)
        ],
        dtype=bool,
    )


def finals_row(error: np.ndarray, radius: float) -> str:
    """How many of the final errors ``error`` (m) are within ``radius`` m, and their p50 / p90
    / max (m): cells of the ``--within`` table."""
    n = int(np.sum(error <= radius))
    p50, p90, worst = np.median(error), np.percentile(error, 90), np.max(error)
    return f"{n}/{len(error)} | {p50:.1f} / {p90:.1f} / {worst:.1f}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--noise",
        type=float,
        nargs="+",
        default=[0.5, 1.0, 3.0],
        help="position noise, m (velocity noise 1e-3 of it, m/s)",
    )
    parser.add_argument("--draws", type=int, default=40, help="noise draws (seeds 1 to N)")
    parser.add_argument("--workers", type=int, default=2, help="processes")
    parser.add_argument("--deployment", default=DEPLOYMENT, help="deployment name or file")
    parser.add_argument(
        "--gains",
        choices=sorted(GAINS),
        default="lqr",
        help="the perfect learner's gains: the LQR's or the truth's optimal ones at the start",
    )
    parser.add_argument(
        "--refits",
        action="store_true",
        help="the perfect learner keeps the deployment's feedforward refits on station",
    )
    parser.add_argument(
        "--deployed", action="store_true", help="the model-fit learner as deployed, not perfect"
    )
    parser.add_argument(
        "--within",
        type=float,
        metavar="M",
        help="also each deputy's final errors: how many within M m, p50 / p90 / max",
    )
    args = parser.parse_args()
    path = resolve(args.deployment)
    if args.deployed:
        label = "model-fit learner"
    else:
        refits = ", refits" if args.refits else ""
        label = f"perfect learner ({args.gains} gains{refits}) at orbit 6"
    print(
        "| noise (m) | draws | twin within max(2x LQR, 10 m) | LQR within max(2x twin, 10 m) "
        f"| {label} within max(2x LQR, 10 m) | {label} learned by orbit {BY_ORBIT:g} "
        "| LQR final p50 / p90 (m) |"
    )
    print("|---|---|---|---|---|---|---|")
    table = []
    with ProcessPoolExecutor(args.workers) as pool:
        for noise in args.noise:
            jobs = [
                Draw(path, noise, seed, args.deployed, args.gains, args.refits)
                for seed in range(1, args.draws + 1)
            ]
            finals = np.array(list(pool.map(_draw, jobs)))
            lqr, twin, learner, learned_at = finals.T
            learned = int(np.sum(learned_at <= BY_ORBIT + 0.05))  # its attempt at 6.01
            print(
                f"| {noise:g} | {args.draws} | {int(within(twin, lqr).sum())} "
                f"| {int(within(lqr, twin).sum())} | {int(within(learner, lqr).sum())} "
                f"| {learned} "
                f"| {np.median(lqr):.2f} / "
                f"{np.percentile(lqr, 90):.2f} |",
                flush=True,
            )
            table.append((noise, lqr, twin, learner))
    if args.within is None:
        return
    print(
        f"\n| noise (m) | deputy | within {args.within:g} m | final p50 / p90 / max (m) |"
        "\n|---|---|---|---|"
    )
    for noise, *errors in table:
        for name, error in zip(("LQR", "LQR twin", label), errors, strict=True):
            print(f"| {noise:g} | {name} | {finals_row(error, args.within)} |")


if __name__ == "__main__":
    main()
