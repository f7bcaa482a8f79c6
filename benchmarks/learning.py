"""Learning benchmark: every built-in scenario and every example system (docs/examples/systems)
by every method, against the Riccati solve timed in the same run.  Run:
``python benchmarks/learning.py`` (``--only builtin|suite``, ``--methods LABEL ...``,
``--json``).  The learning time of a data-driven method leaves out the simulation of its data,
reported apart."""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse
import dataclasses
import json
import time
from pathlib import Path

from ddvi_core.learning import LearningError
from ddvi_core.lqr import NotStabilisingError
from ddvi_core.solve import METHODS, reference_errors, solve
from ddvi_core.systems import BUILTIN_SYSTEMS, System
from services.config.files import load_system

# the gain error the benchmark reports the learner's time and iterations to reach:
# |K - K*|/|K*| below this
K_TOLERANCE = 1e-3
_K_TOLERANCE = f"{K_TOLERANCE:.0e}".replace("e-0", "e-")  # as written: 1e-3


def _timed(fn, repeat: int) -> tuple[float, object]:
    best, out = float("inf"), None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return best, out


def ddvi_after(system: System, iterations: int) -> tuple[float, float]:
    """The data-driven learner stopped after at most ``iterations`` value-iteration steps:
    the wall time of the run (data included) and its |K - K*|/|K*|."""
    cut = dataclasses.replace(system.learning, max_iterations=iterations)
    t, sol = _timed(lambda: solve(dataclasses.replace(system, learning=cut), "ddvi"), 1)
    return t, reference_errors(system, sol)["K_error"]


def iterations_to(
    system: System,
    tolerance: float,
    upper: int,
    resolution: int,
    at_upper: tuple[float, float] | None = None,
) -> tuple[int, float, float]:
    """The fewest value-iteration steps (to within ``resolution``) after which the learner's
    |K - K*|/|K*| < ``tolerance``, with the wall time of that run (data included) and its
    error: a bisection over the learner's ``max_iterations`` between 0 and ``upper``, where
    the error must be below ``tolerance`` (it falls as the iteration converges).
    ``at_upper``: ``ddvi_after(system, upper)`` if already measured."""
    hi = upper
    t_hi, err_hi = ddvi_after(system, hi) if at_upper is None else at_upper
    if not err_hi < tolerance:
        raise ValueError(
            f"|dK|/|K*| = {err_hi:.2e} after {upper} iterations: not below {tolerance:g}"
        )
    lo = 0
    while hi - lo > resolution:
        mid = (lo + hi) // 2
        t_mid, err_mid = ddvi_after(system, mid)
        if err_mid < tolerance:
            hi, t_hi, err_hi = mid, t_mid, err_mid
        else:
            lo = mid
    return hi, t_hi, err_hi


def bench_learning(quick: bool = False) -> list[dict]:
    """Rows for ``ddvi bench``: the data-driven learner on the mission's linear model against
    scipy's Riccati solve of the true model, and the online collector's cost per sample
    against decoding the navigation message that carries the sample."""
    system = BUILTIN_SYSTEMS["rendezvous"]()
    return [*learner_rows(system, quick), collector_row(system)]


def _learning_row(metric: str, t: float, t_ref: float) -> dict:
    """A row of the learner's wall time ``t`` (s) against the Riccati solve's ``t_ref`` (s)."""
    return {
        "benchmark": "learning",
        "metric": metric,
        "unit": "ms",
        "project": 1e3 * t,
        "baseline": 1e3 * t_ref,
        "baseline_name": "scipy Riccati (true model)",
        "cost_ratio": t / t_ref,
        "target": f"|dK|/|K*| < {_K_TOLERANCE}",
    }


EXPLICIT_STEP = {"step": "constant", "step_size": 0.01}
"""Value iteration's explicit step on the mission (its step before the implicit one): the
baseline the mission's implicit steps are measured against in the same run."""


def learner_rows(system: System, quick: bool) -> list[dict]:
    """The learner run to its own stopping rule, then stopped at the fewest iterations that
    reach K_TOLERANCE, each against the Riccati solve (best of 20); and the same learner by
    value iteration's explicit constant step, to its own stopping rule."""
    t_ref, _ = _timed(lambda: solve(system, "lqr"), 20)
    t_ddvi, sol = _timed(lambda: solve(system, "ddvi"), 1 if quick else 3)
    err = reference_errors(system, sol)["K_error"]
    n, t_n, err_n = iterations_to(
        system,
        K_TOLERANCE,
        sol.iterations,
        resolution=max(1, sol.iterations // (16 if quick else 1000)),
        at_upper=(t_ddvi, err),  # the run above stopped by its own rule at sol.iterations
    )
    explicit = dataclasses.replace(
        system, learning=dataclasses.replace(system.learning, **EXPLICIT_STEP)
    )
    t_exp, sol_exp = _timed(lambda: solve(explicit, "ddvi"), 1)
    err_exp = reference_errors(system, sol_exp)["K_error"]
    return [
        _learning_row(
            f"ddvi on the mission: {sol.iterations} iterations, |dK|/|K*| = {err:.1e}",
            t_ddvi,
            t_ref,
        ),
        _learning_row(
            f"ddvi on the mission by the explicit constant step: {sol_exp.iterations} "
            f"iterations, |dK|/|K*| = {err_exp:.1e}",
            t_exp,
            t_ref,
        ),
        _learning_row(
            f"ddvi on the mission to |dK|/|K*| < {_K_TOLERANCE}: {n} iterations "
            f"(|dK|/|K*| = {err_n:.1e})",
            t_n,
            t_ref,
        ),
    ]


def collector_row(system: System) -> dict:
    """The online collector's cost per sample (best of 5 over 20 intervals of samples) against
    decoding the navigation message that would carry each sample."""
    import numpy as np

    from benchmarks.bus import BODY
    from ddvi_core.learning import IntervalCollector
    from ddvi_core.simulate import Exploration, simulate_zoh
    from services.interface import decode, encode

    pr, cfg = system.problem, system.learning
    samples = list(
        simulate_zoh(
            pr.A,
            pr.B,
            pr.D,
            pr.E,
            np.zeros(pr.n),
            np.ones(pr.q),
            K0=cfg.K0_matrix(pr),
            exploration=Exploration(cfg.exploration_amplitude, (1e-3, 3e-3), 0),
            sample_period=cfg.sample_period,
            command_period=cfg.command_period,
            duration=cfg.interval * 20,
        )
    )

    def collect() -> None:
        c = IntervalCollector(pr.n, pr.m, pr.q, cfg.interval)
        for t, x, u, v in samples:
            c.add(t, x, u, v)

    payload = encode("nav", BODY, seq=0, t=0.0, src="bench")

    def decode_all() -> None:
        for _ in samples:
            decode(payload, "nav")

    t_col, _ = _timed(collect, 5)
    t_dec, _ = _timed(decode_all, 5)
    per, per_dec = t_col / len(samples), t_dec / len(samples)
    return {
        "benchmark": "learning",
        "metric": "online collector, per sample",
        "unit": "us",
        "project": 1e6 * per,
        "baseline": 1e6 * per_dec,
        "baseline_name": "decoding its nav message",
        "cost_ratio": per / per_dec,
        "target": "",
    }


SUITE = Path(__file__).resolve().parents[1] / "docs" / "examples" / "systems"

# (row label, solve method, learning overrides): every method, and in place of the derived
# implicit step the Anderson-accelerated explicit (adaptive) step and the paper's eps_k = 1/k,
# for value iteration model-based and from data
EXPLICIT = {"step": "adaptive", "step_size": 0.5}
SUITE_METHODS = (
    ("vi", "vi", {}),
    ("vi explicit", "vi", EXPLICIT),
    ("vi 1/k", "vi", {"step": "harmonic", "step_size": 1.0}),
    ("ddvi", "ddvi", {}),
    ("ddvi explicit", "ddvi", EXPLICIT),
    ("ddvi 1/k", "ddvi", {"step": "harmonic", "step_size": 1.0}),
    ("dpi", "dpi", {}),
    ("hybrid", "hybrid", {}),
)


def _row(name: str, label: str, system: System, method: str, repeat: int, t_ref: float) -> dict:
    """One method on one system: best-of-``repeat`` learning time (the data's simulation
    apart), iterations and the errors against the Riccati / regulator solution."""
    best, sol = float("inf"), None
    for _ in range(repeat):
        t0 = time.perf_counter()
        sol = solve(system, method)
        wall = time.perf_counter() - t0
        best = min(best, sol.details.get("learning_s", wall))
    err = reference_errors(system, sol) if method != "lqr" else {"K_error": 0.0}
    return {
        "system": name,
        "method": label,
        "iterations": sol.iterations,
        "converged": sol.converged,
        "wall_s": best,
        "data_s": sol.details.get("data_s"),
        "riccati_s": t_ref,
        "ratio_to_riccati": best / t_ref,
        "K_error": err.get("K_error"),
        "L_error": err.get("L_error"),
    }


def builtin_rows(repeat: int) -> list[dict]:
    """Every built-in scenario by every method (their tuned tables)."""
    rows = []
    for name, build in BUILTIN_SYSTEMS.items():
        system = build()
        try:
            t_ref, _ = _timed(lambda s=system: solve(s, "lqr"), max(repeat, 20))
        except NotStabilisingError as exc:
            rows.append({"system": name, "method": "-", "note": f"no Riccati solution: {exc}"})
            continue
        for method in METHODS:
            if method in ("dpi", "hybrid"):
                continue  # the scenarios' tables are tuned for value iteration
            rows.append(_row(name, method, system, method, repeat, t_ref))
    return rows


def suite_rows(repeat: int, labels: tuple[str, ...] | None = None) -> list[dict]:
    """Every example system (docs/examples/systems) by every method (those of ``labels``, the
    row labels of SUITE_METHODS, if given), with the settings derived from the system; a
    method that cannot start (policy iteration without a stabilising K0) is a row that says
    why."""
    rows = []
    chosen = [row for row in SUITE_METHODS if labels is None or row[0] in labels]
    for path in sorted(SUITE.glob("*.toml")):
        system = load_system(str(path))
        t_ref, _ = _timed(lambda s=system: solve(s, "lqr"), max(repeat, 20))
        for label, method, overrides in chosen:
            run = dataclasses.replace(
                system, learning=dataclasses.replace(system.learning, **overrides)
            )
            try:
                row = _row(path.stem, label, run, method, repeat, t_ref)
            except LearningError as exc:
                rows.append({"system": path.stem, "method": label, "note": str(exc)})
                continue
            if not row["converged"] and method == "dpi":
                row["note"] = "K0 = 0 does not stabilise: policy iteration cannot start"
            rows.append(row)
    return rows


def _print_table(rows: list[dict]) -> None:
    print(
        f"{'system':<22} {'method':<13} {'iter':>7} {'conv':>5} {'learn ms':>9} {'data ms':>8} "
        f"{'riccati ms':>10} {'ratio':>8} {'|dK|/|K*|':>10} {'|dL|/|L*|':>10}"
    )
    fmt = lambda v: "-" if v is None else f"{v:.2e}"  # noqa: E731
    for r in rows:
        if "iterations" not in r:
            print(f"{r['system']:<22} {r['method']:<13} {r['note']}")
            continue
        data = "-" if r["data_s"] is None else f"{1e3 * r['data_s']:.0f}"
        print(
            f"{r['system']:<22} {r['method']:<13} {r['iterations']:>7} {r['converged']!s:>5} "
            f"{1e3 * r['wall_s']:>9.2f} {data:>8} {1e3 * r['riccati_s']:>10.3f} "
            f"{r['ratio_to_riccati']:>8.1f} {fmt(r['K_error']):>10} {fmt(r['L_error']):>10}"
        )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--json", action="store_true", help="the rows as one JSON list on stdout")
    ap.add_argument("--repeat", type=int, default=3, help="best of N runs per figure")
    ap.add_argument("--only", choices=("builtin", "suite"), default=None)
    ap.add_argument(
        "--methods",
        nargs="+",
        choices=[label for label, _, _ in SUITE_METHODS],
        default=None,
        help="the example systems' rows by these methods only",
    )
    args = ap.parse_args()
    rows = [] if args.only == "suite" else builtin_rows(args.repeat)
    methods = None if args.methods is None else tuple(args.methods)
    rows += [] if args.only == "builtin" else suite_rows(args.repeat, methods)
    if args.json:
        print(json.dumps(rows))
    else:
        _print_table(rows)


if __name__ == "__main__":
    main()
