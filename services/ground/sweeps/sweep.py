"""``ddvi sweep``: the mission over a range of link impairments, or of navigation noise and
model mismatch, every deputy of the deployment side by side.

    ddvi sweep delay [DEPLOYMENT] --values 0 60 120 180 300
    ddvi sweep loss  [DEPLOYMENT] --values 0 0.1 0.2 0.3 0.5
    ddvi sweep noise [DEPLOYMENT] --values 0 0.1 1 10 [--mismatch 1 2] [--orbits 40 30]
                     [--filter kalman]
    ddvi sweep KIND ... --in-process

delay, loss: two links impaired, ahead of the deployment's own [[link]] rules: navigation to
controller (``nav-*`` to ``ctrl-*``) and controller to environment (``cmd/*/att``), each with
that delay (s; simulation time in lock-step mode) or that loss probability.

noise: one run per (noise v, mismatch factor f): every deputy's navigation.position_noise = v
(m, 1 sigma per axis) and velocity_noise = ``VELOCITY_NOISE_RATIO`` v (m/s); the truth's
density_factor and every deputy's area_factor f times the deployment's (as
deployments/mismatch-2x.toml does at f = 2); ``--filter`` sets every deputy's
navigation.filter.  ``--orbits`` gives one mission length, or one per mismatch factor (a
denser atmosphere brings the chief down sooner).

Each run goes through the launcher (every service its own process, as ``ddvi run``); with
``--in-process`` through ``services.flight.inprocess.run_in_process`` instead, the services'
components in one process with their links emulated (a 40-orbit mission in seconds; the same
commands and figures as the launcher's in lock-step, unless a link jitters or reorders).

Writes ``<output>/sweep-<kind>-<name>-<stamp>/``: ``sweep.csv`` (one row per run and deputy),
``sweep.md`` (the same table), ``sweep.png`` (``services.ground.sweeps.sweep_table``), the derived
deployments and every launched run's own folder; prints the table.  Every gain error is
against the optimal gain K* of the truth's linear model of that run.
"""

from __future__ import annotations

import argparse
import copy
import datetime
import json
import sys
import textwrap
from pathlib import Path
from typing import Any

from services.config import (
    Deployment,
    DeploymentError,
    controller_label,
    deployment_from_table,
    load_deployment,
    read_table,
    resolve,
    write_deployment,
)
from services.ground.analysis.scoring import (
    LEARNED_WITHIN_10_PERCENT,
    deputy_metrics,
    failed_metrics,
    holding_notes,
    inprocess_outcome,
)
from services.ground.sweeps.sweep_table import (
    POINT,
    UNITS,
    largest_learning_value,
    markdown_table,
    plot,
    write_table,
)
from services.interface import topics
from services.model import holding_problems, reentry_problems

__all__ = [
    "VELOCITY_NOISE_RATIO",
    "impaired_table",
    "infeasible_points",
    "inprocess_rows",
    "largest_learning_value",
    "noisy_table",
    "summary_rows",
    "sweep",
    "unlearned_points",
]

VELOCITY_NOISE_RATIO = 1e-3
"""(m/s) of navigation velocity noise per m of position noise in a noise sweep."""


def impaired_table(table: dict[str, Any], kind: str, value: float) -> dict[str, Any]:
    """The deployment table with the navigation-to-controller and controller-to-environment
    links impaired by ``value`` (a delay in s or a loss probability)."""
    if kind not in ("delay", "loss"):
        raise ValueError(f"sweep kind: expected 'delay' or 'loss', got {kind!r}")
    every_nav, every_cmd = topics.nav_state_topic("*"), topics.command_topic("*")
    rules = [
        {"publisher": "nav-*", "subscriber": "ctrl-*", "topic": every_nav, kind: value},
        {"publisher": "ctrl-*", "subscriber": "environment", "topic": every_cmd, kind: value},
    ]
    out = copy.deepcopy(table)
    out["link"] = rules + out.get("link", [])
    return out


def noisy_table(
    table: dict[str, Any], noise: float, mismatch: float = 1.0, nav_filter: str | None = None
) -> dict[str, Any]:
    """The deployment table with every deputy's navigation noise ``noise`` (m; velocity noise
    ``VELOCITY_NOISE_RATIO`` times it, m/s), the truth's density_factor and every deputy's
    area_factor ``mismatch`` times the table's, and, given ``nav_filter``, every deputy's
    navigation.filter set to it."""
    out = copy.deepcopy(table)
    env = out.setdefault("environment", {})
    env["density_factor"] = env.get("density_factor", 1.0) * mismatch
    for d in out.get("deputy", []):
        d["area_factor"] = d.get("area_factor", 1.0) * mismatch
        nav = d.setdefault("navigation", {})
        nav["position_noise"] = noise
        nav["velocity_noise"] = noise * VELOCITY_NOISE_RATIO
        if nav_filter is not None:
            nav["filter"] = nav_filter
    return out


def _row(point: dict[str, Any], deputy: str, controller: str, **results: Any) -> dict[str, Any]:
    """A row of the table: the point, the deputy, its metrics (``services.ground.analysis.scoring``)
    and any link counters."""
    return {**point, "deputy": deputy, "controller": controller, **results}


def summary_rows(point: dict[str, Any], summary: dict[str, Any]) -> list[dict[str, Any]]:
    """One row per deputy of a launched run's summary.json: the metrics its report scored
    (``services.ground.analysis.scoring.deputy_metrics``) and the link counters."""
    services = summary["messages"]["services"]
    env = services.get("environment", {})
    rows = []
    for name, d in summary["deputies"].items():
        ctrl = services.get(f"ctrl-{name}", {})
        rows.append(
            _row(
                point,
                name,
                controller_label(d["controller"], d.get("learning_method")),
                completed=summary["completed"],
                final_along_track_error_m=d["final_along_track_error_m"],
                max_along_track_error_last_orbit_m=d["max_along_track_error_last_orbit_m"],
                learned=d["learned"],
                learned_at_orbits=d["learned_at_orbits"],
                fallback_at_orbits=d.get("fallback_at_orbits"),
                gain_error=d["gain_error_vs_true_optimum"],
                gain_error_vs_lqr=d["gain_error_vs_lqr"],
                can_hold=d["can_hold"],
                note=d["note"],
                **link_counters(ctrl, env),
            )
        )
    return rows


def link_counters(ctrl: dict[str, Any], env: dict[str, Any]) -> dict[str, int]:
    """A deputy's link columns from its controller's counters and the environment's:
    dropped and delayed by its controller's input links and every command link, late and
    missing commands (all deputies)."""
    return {
        "dropped": ctrl.get("dropped", 0) + env.get("dropped", 0),
        "delayed": ctrl.get("delayed", 0) + env.get("delayed", 0),
        "late": env.get("late_commands", 0),
        "missing": env.get("missing_commands", 0),
    }


def inprocess_rows(point: dict[str, Any], dep: Deployment) -> list[dict[str, Any]]:
    """Run ``dep`` with ``run_in_process`` (navigation noise seeded with run.seed); one row
    per deputy.  A run the truth ends early (a re-entry) gives rows with completed = False
    and the reason as the note."""
    from services.flight.inprocess import run_in_process
    from services.model import ReentryError

    cannot_hold = holding_notes(dep)
    try:
        out = run_in_process(dep)
    except ReentryError as exc:
        return [
            _row(point, d.name, d.label, **failed_metrics(d, str(exc), cannot_hold.get(d.name, "")))
            for d in dep.deputy
        ]
    return [
        _row(
            point,
            d.name,
            d.label,
            **deputy_metrics(
                dep,
                d,
                inprocess_outcome(dep, d, out[d.name]),
                cannot_hold=cannot_hold.get(d.name, ""),
            ),
            **link_counters(out[d.name]["links"], out[d.name]["environment"]),
        )
        for d in dep.deputy
    ]


def infeasible_points(
    runs: list[tuple[dict[str, Any], dict[str, Any], str]],
) -> list[tuple[dict[str, Any], str]]:
    """(point, why) of every deputy of the sweep's runs that cannot hold its slot
    (``services.model.holding_problems``), and of every run whose formation is predicted to
    re-enter before it ends (``services.model.reentry_problems``), in run order."""
    out = []
    for point, table, _ in runs:
        dep = deployment_from_table(table)
        out += [(point, text) for _, text in holding_problems(dep) + reentry_problems(dep)]
    return out


def _point_text(kind: str, point: dict[str, Any]) -> str:
    """A run's point in words: ``delay = 60 s``, ``loss = 0.2 (probability)``, ``noise = 1 m,
    mismatch = 2``."""
    if kind in ("delay", "loss"):
        unit = " s" if kind == "delay" else " (probability)"
        return f"{kind} = {point['value']:g}{unit} on the nav -> ctrl and ctrl -> environment links"
    return f"noise = {point['noise']:g} m, mismatch = {point['mismatch']:g}"


def unlearned_points(
    runs: list[tuple[dict[str, Any], dict[str, Any], str]],
) -> list[tuple[dict[str, Any], str]]:
    """(point, why) of every learning deputy whose run ends before it is scheduled to learn
    (learning.learn_at_orbits at or past run.orbits): its gain error is then unmeasured."""
    out = []
    for point, table, _ in runs:
        dep = deployment_from_table(table)
        for d in dep.deputy:
            at = d.learning.learn_at_orbits
            if d.controller == "ddvi" and at >= dep.run.orbits:
                out.append(
                    (
                        point,
                        f"deputy {d.name!r} learns at orbit {at:g} but the run ends "
                        f"at orbit {dep.run.orbits:g}: it will not learn; give --orbits "
                        f"above {at:g}",
                    )
                )
    return out


def _orbits_per_mismatch(orbits: list[float] | None, mismatches: list[float]) -> list:
    """--orbits as one value per mismatch factor (None: the deployment's)."""
    if not orbits:
        return [None] * len(mismatches)
    if len(orbits) == 1:
        return orbits * len(mismatches)
    if len(orbits) != len(mismatches):
        raise ValueError(
            f"--orbits: give one value, or one per --mismatch factor ({len(mismatches)}), "
            f"not {len(orbits)}"
        )
    return list(orbits)


def sweep_points(
    kind: str,
    table: dict[str, Any],
    values: list[float],
    mismatches: list[float] | None = None,
    orbits: list[float] | None = None,
    nav_filter: str | None = None,
) -> list[tuple[dict[str, Any], dict[str, Any], str]]:
    """(point, deployment table, file stem) of every run, each table checked (raises
    DeploymentError or ValueError before anything runs)."""
    if kind not in UNITS:
        raise ValueError(f"sweep kind: expected one of {list(UNITS)}, got {kind!r}")
    if kind != "noise" and (mismatches or nav_filter or (orbits and len(orbits) > 1)):
        raise ValueError("--mismatch, --filter and several --orbits belong to 'ddvi sweep noise'")
    name = table.get("run", {}).get("name", "run")
    mismatches = mismatches or [1.0]
    runs = []
    for f, n in zip(mismatches, _orbits_per_mismatch(orbits, mismatches), strict=True):
        for v in values:
            if kind == "noise":
                point, t = {"noise": v, "mismatch": f}, noisy_table(table, v, f, nav_filter)
                stem = f"noise-{v:g}-x{f:g}"
            else:
                point, t, stem = {"value": v}, impaired_table(table, kind, v), f"{kind}-{v:g}"
            run = t.setdefault("run", {})
            run["name"] = f"{name}-{stem}".replace(".", "p")
            if n is not None:
                run["orbits"] = n
            deployment_from_table(t)
            runs.append((point, t, stem))
    return runs


def _launch(path: Path, folder: Path, quiet: bool) -> dict[str, Any] | None:
    """Run one derived deployment through the launcher; its summary.json (None: no report)."""
    from services.ground.launch.launcher import Launcher

    launcher = Launcher(load_deployment(str(path)), out_root=str(folder), quiet=quiet)
    status = launcher.execute()
    summary_path = launcher.out / "summary.json"
    if not summary_path.is_file():
        print(
            f"ddvi sweep: {path.stem}: no report (status {status}); see {launcher.out / 'logs'}",
            file=sys.stderr,
        )
        return None
    return json.loads(summary_path.read_text())


def sweep(
    kind: str,
    deployment: str | None,
    values: list[float],
    output: str | None = None,
    orbits: float | list[float] | None = None,
    quiet: bool = True,
    mismatches: list[float] | None = None,
    in_process: bool = False,
    nav_filter: str | None = None,
) -> tuple[Path, list[dict[str, Any]]]:
    """Run the sweep; return its folder and rows.  Raises DeploymentError or ValueError on a
    bad deployment or value (before anything runs)."""
    orbits = [orbits] if isinstance(orbits, int | float) else orbits
    runs = sweep_points(kind, read_table(deployment), values, mismatches, orbits, nav_filter)
    base = load_deployment(str(resolve(deployment)))
    stamp = datetime.datetime.now().strftime("%Y%m%d-%H%M%S")
    folder = Path(output or base.run.output) / f"sweep-{kind}-{base.run.name}-{stamp}"
    if kind == "noise":
        print(
            f"ddvi sweep: noise: each value is the navigation position noise (m, 1 sigma per "
            f"axis); velocity noise {VELOCITY_NOISE_RATIO:g} (m/s)/m times it is added too",
            file=sys.stderr,
            flush=True,
        )
    # up front: which points fly a deputy that no attitude lets hold its slot, a formation
    # predicted to re-enter, or that end before a learner learns
    for point, why in infeasible_points(runs) + unlearned_points(runs):
        print(
            f"ddvi sweep: {_point_text(kind, point)}: warning: {why}", file=sys.stderr, flush=True
        )
    rows: list[dict[str, Any]] = []
    for point, table, stem in runs:
        path = write_deployment(table, folder / "deployments", stem)
        print(f"ddvi sweep: {_point_text(kind, point)} ...", file=sys.stderr, flush=True)
        if in_process:
            rows.extend(inprocess_rows(point, load_deployment(str(path))))
        elif (summary := _launch(path, folder, quiet)) is not None:
            rows.extend(summary_rows(point, summary))
        # after every run: an interrupted sweep keeps its rows
        write_table(kind, rows, folder, VELOCITY_NOISE_RATIO)
    if rows:
        plot(kind, rows, folder / "sweep.png")
    return folder, rows


WRITES = (
    "Writes sweep.csv (a row per run and deputy), sweep.md (the same table) and sweep.png in "
    "<output>/sweep-{kind}-<run name>-<stamp>/, with the derived deployments and each launched "
    "run's folder, and prints the table; every gain error is against K*, the optimal gain of "
    "that run's truth."
)

SWEEPS: dict[str, tuple[str, str, str]] = {
    "delay": (
        "the mission over link delays",
        "The mission once per delay: the navigation -> controller links (nav-* to ctrl-*) and "
        "the controller -> environment links (cmd/*/att) each delayed by it, ahead of the "
        "deployment's own [[link]]s.",
        "delays, s (simulation time in lock-step)",
    ),
    "loss": (
        "the mission over link loss rates",
        "The mission once per loss rate: the navigation -> controller links (nav-* to ctrl-*) "
        "and the controller -> environment links (cmd/*/att) each losing messages with that "
        "probability, ahead of the deployment's own [[link]]s.",
        "loss probabilities in [0, 1]",
    ),
    "noise": (
        "the mission over navigation noise and model mismatch",
        "The mission once per navigation noise v and mismatch factor f: every deputy's "
        "navigation.position_noise = v (m, 1 sigma per axis) and velocity_noise = "
        f"{VELOCITY_NOISE_RATIO:g} (m/s)/m times it; the truth's density_factor and every "
        "deputy's area_factor f times the deployment's (as deployments/mismatch-2x.toml does at "
        "f = 2).",
        "navigation position noise, m (1 sigma per axis; velocity noise "
        f"{VELOCITY_NOISE_RATIO:g} (m/s)/m times it)",
    ),
}
"""Each sweep kind: its line in ``ddvi sweep --help``, its own help's description, and what
its --values are."""

EXAMPLES = {
    "delay": "ddvi sweep delay --values 0 60 120 180 300\n  ddvi sweep delay realistic-nav "
    "--values 0 60 --in-process",
    "loss": "ddvi sweep loss --values 0 0.1 0.2 0.3 0.5",
    "noise": "ddvi sweep noise realistic-nav --values 0 0.1 1 10\n  ddvi sweep noise "
    "--values 1 --mismatch 1 2 --orbits 40 30 --in-process",
}


def add_sweep_arguments(p: argparse.ArgumentParser) -> None:
    """The arguments of ``ddvi sweep``, for ``services.cli``: one parser per kind, each with
    its own help (``ddvi sweep noise --help``)."""
    p.description = (
        "The mission over a range of link delays, loss rates, or navigation noise and model "
        "mismatch, the deployment's deputies side by side."
    )
    kinds = p.add_subparsers(
        dest="kind",
        required=True,
        metavar="KIND",
        help="what to sweep (ddvi sweep KIND --help): "
        + "; ".join(f"{kind}, {summary}" for kind, (summary, _, _) in SWEEPS.items()),
    )
    for kind, (summary, description, values) in SWEEPS.items():
        k = kinds.add_parser(
            kind,
            help=summary,
            description=textwrap.fill(f"{description} {WRITES.format(kind=kind)}", 80),
            epilog=f"examples:\n  {EXAMPLES[kind]}",
            formatter_class=argparse.RawDescriptionHelpFormatter,
        )
        k.add_argument("deployment", nargs="?", default=None, help="default: rendezvous")
        k.add_argument("--values", type=float, nargs="+", required=True, help=values)
        if kind == "noise":
            k.add_argument(
                "--mismatch",
                type=float,
                nargs="+",
                default=None,
                help="factors on the truth's density and facet area (default 1)",
            )
            k.add_argument(
                "--orbits",
                type=float,
                nargs="+",
                help="override run.orbits: one value, or one per --mismatch factor (a denser "
                "atmosphere brings the chief down sooner)",
            )
            k.add_argument(
                "--filter",
                dest="nav_filter",
                choices=("kalman", "none"),
                default=None,
                help="set every deputy's navigation.filter",
            )
        else:
            k.add_argument("--orbits", type=float, help="override run.orbits")
            k.set_defaults(mismatch=None, nav_filter=None)
        k.add_argument(
            "--in-process",
            action="store_true",
            help="run each mission in this process (the services' components, their links "
            "emulated as the buses would; lock-step only)",
        )
        k.add_argument("--output", help="parent folder (default: the deployment's run.output)")


def sweep_command(args: argparse.Namespace) -> int:
    """Run the sweep and print its table; 0 when every run completed, 1 if not, 2 on bad
    input."""
    try:
        folder, rows = sweep(
            args.kind,
            args.deployment,
            args.values,
            args.output,
            args.orbits,
            mismatches=args.mismatch,
            in_process=args.in_process,
            nav_filter=args.nav_filter,
        )
    except (DeploymentError, ValueError) as exc:
        print(f"ddvi sweep: {exc}", file=sys.stderr)
        return 2
    if not rows:
        print(f"ddvi sweep: no run produced a report; see {folder}", file=sys.stderr)
        return 1
    print(markdown_table(args.kind, rows, VELOCITY_NOISE_RATIO))
    if args.kind in ("delay", "loss") and any(r["controller"] != "lqr" for r in rows):
        best = largest_learning_value(rows)
        unit = UNITS[args.kind]
        criterion = LEARNED_WITHIN_10_PERCENT.name
        print(
            f"Every learner {criterion} at every {args.kind} up to {best:g} {unit}"
            if best is not None
            else f"A learner was not {criterion} at the smallest {args.kind}"
        )
    print(folder)
    runs = len({tuple(r[c] for c in POINT[args.kind]) for r in rows})
    expected = len(args.values) * len(args.mismatch or [1.0])
    completed = all(r["completed"] for r in rows) and runs >= expected
    return 0 if completed else 1
