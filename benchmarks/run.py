"""``ddvi bench``: every benchmark, each against its baseline measured in the same run.

    ddvi bench            # the full set
    ddvi bench --quick    # short versions, about a minute
    ddvi bench --json     # one JSON list of rows on stdout

Each row gives the project's figure, the baseline's, and the cost ratio (above 1: the project
is slower or bigger than its baseline); a row whose target bounds that ratio (``<= 1.3``,
``<= 2x; ...``) gets a verdict, met or missed.  A benchmark that needs a package this
installation lacks (Basilisk; foxglove-sdk and websockets, the test extra's) gives one row saying
so, and the benchmarks skipped are listed with the reason after the table (``--json``: in
``meta.skipped``).  Benchmarks are not tests: nothing here asserts.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse
import json
import math
import operator
import platform
import re
import sys
import time
from collections.abc import Callable
from typing import Any

from rich.console import Console
from rich.markup import escape
from rich.table import Table

BENCHMARKS: dict[str, str] = {
    "bus": "benchmarks.bus:bench_bus",
    "mission": "benchmarks.mission:bench_mission",
    "learning": "benchmarks.learning:bench_learning",
    "swarm": "benchmarks.mission:bench_swarm",
    "atmosphere": "benchmarks.atmosphere:bench_atmosphere",
    "basilisk": "benchmarks.mission:bench_basilisk",
    "flight": "benchmarks.flight:bench_flight",
    "live": "benchmarks.live:bench_live",
    "ros2": "benchmarks.ros2:bench_ros2",
}


def _load(spec: str) -> Callable[[bool], list[dict[str, Any]]]:
    module, name = spec.split(":")
    return getattr(__import__(module, fromlist=[name]), name)


def _fmt(value: float) -> str:
    if not math.isfinite(value):
        return "-"
    if value == 0 or 0.01 <= abs(value) < 1e5:
        return f"{value:.3g}" if abs(value) < 100 else f"{value:,.0f}"
    return f"{value:.2e}"


_TARGET = re.compile(r"^\s*(<=|<|>=|>)\s*([0-9]*\.?[0-9]+)\s*([A-Za-z/]*)\s*(?:;|$)")
_COMPARE = {"<=": operator.le, "<": operator.lt, ">=": operator.ge, ">": operator.gt}


def verdict(row: dict[str, Any]) -> str | None:
    """ "met" or "missed" when the row's target bounds its cost ratio (it starts ``<= 1.3`` or
    ``<= 2x;``) or its own figure in the row's unit (``< 2 s``, ``<= 350 MB``), "missed" for a
    figure not measured; None when the target bounds something else (a gain error, another
    unit) or there is none."""
    match = _TARGET.match(str(row.get("target", "")))
    if match is None:
        return None
    unit = match.group(3)
    if unit in ("", "x"):
        value = row.get("cost_ratio")
    elif unit == row.get("unit"):
        value = row.get("project")
    else:
        return None
    if not isinstance(value, int | float) or not math.isfinite(value):
        return "missed"
    return "met" if _COMPARE[match.group(1)](value, float(match.group(2))) else "missed"


def plain_json(value: Any) -> Any:
    """``value`` with every non-finite float (a failed benchmark's NaN) as None, numpy
    scalars as Python numbers: what ``json.dumps`` writes as valid JSON."""
    if isinstance(value, dict):
        return {k: plain_json(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [plain_json(v) for v in value]
    if hasattr(value, "item") and not isinstance(value, str):  # a numpy scalar
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def build_parser(parser: argparse.ArgumentParser | None = None) -> argparse.ArgumentParser:
    parser = parser or argparse.ArgumentParser(prog="ddvi bench", description=__doc__)
    parser.add_argument("--quick", action="store_true", help="short versions, about a minute")
    parser.add_argument(
        "--json",
        action="store_true",
        help="one JSON object on stdout: meta, and the rows (a value not measured is null)",
    )
    parser.add_argument(
        "--only", nargs="+", choices=list(BENCHMARKS), help="run only these benchmarks"
    )
    return parser


def run(args: argparse.Namespace) -> int:
    console = Console(stderr=True)
    rows: list[dict[str, Any]] = []
    for name in args.only or list(BENCHMARKS):
        t0 = time.perf_counter()
        console.print(f"[bold]bench[/] {name} ...", highlight=False)
        try:
            got = _load(BENCHMARKS[name])(args.quick)
        except Exception as exc:  # one failing benchmark must not hide the others
            got = [
                {
                    "benchmark": name,
                    "metric": f"FAILED: {exc}",
                    "unit": "",
                    "project": math.nan,
                    "baseline": math.nan,
                    "baseline_name": "",
                    "cost_ratio": math.nan,
                    "target": "",
                }
            ]
        for row in got:
            row["seconds"] = time.perf_counter() - t0
            row["verdict"] = verdict(row)
        rows.extend(got)
    skipped = {r["benchmark"]: r["skipped"] for r in rows if "skipped" in r}
    if args.json:
        meta = {"quick": args.quick, "python": platform.python_version(), "cpus": os.cpu_count()}
        meta["skipped"] = skipped
        print(json.dumps(plain_json({"meta": meta, "rows": rows}), allow_nan=False))
        return 0
    print_table(rows, args.quick)
    print_skipped(skipped)
    return 0


def print_skipped(skipped: dict[str, str]) -> None:
    """What could not run here and why, one line each, after the table."""
    if skipped:
        print(f"skipped {len(skipped)} benchmark{'s' if len(skipped) > 1 else ''}:")
        for name, why in skipped.items():
            print(f"  {name}: {why}")


def print_table(rows: list[dict[str, Any]], quick: bool) -> None:
    """The rows as a table on stdout, every text shown literally (``'.[basilisk]'`` is not
    rich markup)."""
    table = Table(title=f"ddvi bench{' --quick' if quick else ''} ({os.cpu_count()} CPUs)")
    for col in (
        "benchmark",
        "metric",
        "unit",
        "project",
        "baseline",
        "baseline is",
        "ratio",
        "target",
        "verdict",
    ):
        table.add_column(
            col, justify="right" if col in ("project", "baseline", "ratio") else "left"
        )
    for r in rows:
        texts = (
            r["benchmark"],
            r["metric"],
            r["unit"],
            _fmt(r["project"]),
            _fmt(r["baseline"]),
            r["baseline_name"],
            _fmt(r["cost_ratio"]),
            r["target"],
            r.get("verdict") or "",
        )
        table.add_row(*(escape(str(t)) for t in texts))
    Console(width=200).print(table)


def main(argv: list[str] | None = None) -> int:
    return run(build_parser().parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
