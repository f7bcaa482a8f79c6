"""``ddvi sweep``: the mission over a range of link impairments, LQR against DDVI.

    ddvi sweep delay [DEPLOYMENT] --values 0 60 120 180 300
    ddvi sweep loss  [DEPLOYMENT] --values 0 0.1 0.2 0.3 0.5

For each value the deployment runs through the launcher (every service its own process, as
``ddvi run``) with two links impaired, ahead of the deployment's own [[link]] rules: navigation
to controller (``nav-*`` to ``ctrl-*``) and controller to environment (``cmd/*/att``), each
with that delay (s; simulation time in lock-step mode) or that loss probability.

Writes ``<output>/sweep-<kind>-<stamp>/``: ``sweep.csv`` (one row per run and deputy),
``sweep.md`` (the same table), ``sweep.png`` (final along-track error and learned-gain error
against the value) and every run's own folder; prints the table, and the largest value up to
which every DDVI deputy learned a gain within 10% of the LQR gain (``SUCCESS``).
"""

from __future__ import annotations

import argparse
import copy
import csv
import datetime
import json
import sys
from pathlib import Path
from typing import Any

from services.config import (
    DeploymentError,
    deployment_from_table,
    load_deployment,
    read_table,
    resolve,
    write_deployment,
)
from services.interface import topics

KINDS = {"delay": "s", "loss": "probability"}
COLUMNS = [
    "value",
    "deputy",
    "controller",
    "completed",
    "final_along_track_error_m",
    "max_along_track_error_last_orbit_m",
    "learned",
    "learned_at_orbits",
    "gain_error_vs_lqr",
    "dropped",
    "delayed",
    "late",
    "missing",
]


def impaired_table(table: dict[str, Any], kind: str, value: float) -> dict[str, Any]:
    """The deployment table with the navigation-to-controller and controller-to-environment
    links impaired by ``value`` (a delay in s or a loss probability)."""
    if kind not in KINDS:
        raise ValueError(f"sweep kind: expected one of {list(KINDS)}, got {kind!r}")
    key = "delay" if kind == "delay" else "loss"
    every_nav, every_cmd = topics.nav_state_topic("*"), topics.command_topic("*")
    rules = [
        {"publisher": "nav-*", "subscriber": "ctrl-*", "topic": every_nav, key: value},
        {"publisher": "ctrl-*", "subscriber": "environment", "topic": every_cmd, key: value},
    ]
    out = copy.deepcopy(table)
    out["link"] = rules + out.get("link", [])
    return out


def summary_rows(value: float, summary: dict[str, Any]) -> list[dict[str, Any]]:
    """One row per deputy of a run's summary.json."""
    services = summary["messages"]["services"]
    env = services.get("environment", {})
    rows = []
    for name, d in summary["deputies"].items():
        ctrl = services.get(f"ctrl-{name}", {})
        gains = d.get("gains") or {}
        learned = d["phase"] == "learned" and gains.get("source") != "fallback"
        rows.append(
            {
                "value": value,
                "deputy": name,
                "controller": d["controller"],
                "completed": summary["completed"],
                "final_along_track_error_m": d["final_along_track_error_m"],
                "max_along_track_error_last_orbit_m": d["max_along_track_error_last_orbit_m"],
                # flying gains it learned (not K0, and not old gains a failed re-learning
                # fell back to)
                "learned": learned,
                "learned_at_orbits": d["learned_at_orbits"],
                "gain_error_vs_lqr": d["gain_error_vs_lqr"] if learned else None,
                "dropped": ctrl.get("dropped", 0) + env.get("dropped", 0),
                "delayed": ctrl.get("delayed", 0) + env.get("delayed", 0),
                "late": env.get("late_commands", 0),
                "missing": env.get("missing_commands", 0),
            }
        )
    return rows


SUCCESS = 0.1
"""Learning succeeded: the controller switched to learned gains within 10% of the LQR gain of
the nominal model (|K - K*|/|K*| < SUCCESS); a learner can also converge to a wrong gain."""


def succeeded(row: dict[str, Any]) -> bool:
    """A row whose run completed with learned gains within ``SUCCESS`` of the LQR gain."""
    err = row["gain_error_vs_lqr"]
    return bool(row["learned"] and row["completed"] and err is not None and err < SUCCESS)


def largest_learning_value(rows: list[dict[str, Any]]) -> float | None:
    """The largest value at which learning succeeded for every DDVI deputy, all smaller values
    included (None if it failed at the first)."""
    best = None
    for value in sorted({r["value"] for r in rows}):
        ddvi = [r for r in rows if r["value"] == value and r["controller"] == "ddvi"]
        if not ddvi or not all(succeeded(r) for r in ddvi):
            break
        best = value
    return best


def _fmt(x: Any) -> str:
    if x is None:
        return "-"
    if isinstance(x, bool):
        return "yes" if x else "no"
    if isinstance(x, float):
        return f"{x:.4g}"
    return str(x)


def markdown_table(kind: str, rows: list[dict[str, Any]]) -> str:
    """The rows as a markdown table, with a note on what the columns count."""
    unit = KINDS[kind]
    head = [f"{kind} ({unit})", "deputy", "controller", "completed", "final along-track error (m)",
            "last-orbit max (m)", "learned", "at orbit", "gain error", "dropped", "delayed",
            "late", "missing"]  # fmt: skip
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    lines += ["| " + " | ".join(_fmt(r[c]) for c in COLUMNS) + " |" for r in rows]
    lines += [
        "",
        "learned: the controller switched to learned gains; gain error: |K - K*| / |K*| "
        "against the nominal model's LQR gain K*; along-track error: |y - y_ref|. dropped, "
        "delayed: by this deputy's controller's links and the "
        "environment's command links (all deputies); late, missing: the environment's "
        "commands, all deputies (a learning attempt longer than run.command_deadline also "
        "makes them).",
    ]
    return "\n".join(lines) + "\n"


def plot(kind: str, rows: list[dict[str, Any]], path: Path) -> None:
    """Write sweep.png: final along-track error (left) and learned-gain error (right, a cross
    at 1 where a DDVI deputy did not learn) against the swept value."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 4))
    for name in dict.fromkeys(r["deputy"] for r in rows):
        mine = [r for r in rows if r["deputy"] == name]
        ax1.semilogy([r["value"] for r in mine], [r["final_along_track_error_m"] for r in mine],
                     "o-", label=f"{name} ({mine[0]['controller']})")  # fmt: skip
        learned = [r for r in mine if r["learned"]]
        if mine[0]["controller"] == "ddvi":
            ax2.semilogy(
                [r["value"] for r in learned],
                [r["gain_error_vs_lqr"] for r in learned],
                "o-",
                label=name,
            )
            failed = [r["value"] for r in mine if not r["learned"]]
            if failed:
                ax2.plot(failed, [1.0] * len(failed), "rx", label=f"{name}: not learned")
    unit = KINDS[kind]
    ax1.set(xlabel=f"link {kind} ({unit})", ylabel="final |y - y_ref| (m)",
            title="along-track error at the end")  # fmt: skip
    ax2.set(xlabel=f"link {kind} ({unit})", ylabel="|K - K*| / |K*|",
            title="learned gain against the LQR gain")  # fmt: skip
    for ax in (ax1, ax2):
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def sweep(
    kind: str,
    deployment: str | None,
    values: list[float],
    output: str | None = None,
    orbits: float | None = None,
    quiet: bool = True,
) -> tuple[Path, list[dict[str, Any]]]:
    """Run the sweep; return its folder and rows.  Raises DeploymentError or ValueError on a
    bad deployment or value (before anything runs)."""
    from services.ground.launcher import Launcher

    table = read_table(deployment)
    if orbits is not None:
        table.setdefault("run", {})["orbits"] = orbits
    base = load_deployment(str(resolve(deployment)))
    stamp = datetime.datetime.now().strftime("%Y%m%d-%H%M%S")
    folder = Path(output or base.run.output) / f"sweep-{kind}-{base.run.name}-{stamp}"
    tables = []
    for value in values:  # every deployment checked before the first run
        t = impaired_table(table, kind, value)
        t.setdefault("run", {})["name"] = f"{base.run.name}-{kind}{value:g}".replace(".", "p")
        deployment_from_table(t)
        tables.append(t)
    paths = [
        write_deployment(t, folder / "deployments", f"{kind}-{value:g}")
        for t, value in zip(tables, values, strict=True)
    ]
    rows: list[dict[str, Any]] = []
    for value, path in zip(values, paths, strict=True):
        print(f"ddvi sweep: {kind} = {value:g} ...", file=sys.stderr, flush=True)
        launcher = Launcher(load_deployment(str(path)), out_root=str(folder), quiet=quiet)
        status = launcher.execute()
        summary_path = launcher.out / "summary.json"
        if not summary_path.is_file():
            print(f"ddvi sweep: {kind} = {value:g}: no report (status {status}); see "
                  f"{launcher.out / 'logs'}", file=sys.stderr)  # fmt: skip
            continue
        rows.extend(summary_rows(value, json.loads(summary_path.read_text())))
        _write(kind, rows, folder)  # after every run: an interrupted sweep keeps its rows
    if rows:
        plot(kind, rows, folder / "sweep.png")
    return folder, rows


def _write(kind: str, rows: list[dict[str, Any]], folder: Path) -> None:
    """Write sweep.csv and sweep.md of the rows so far."""
    with open(folder / "sweep.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=COLUMNS)
        w.writeheader()
        w.writerows(rows)
    (folder / "sweep.md").write_text(markdown_table(kind, rows))


def add_sweep_arguments(p: argparse.ArgumentParser) -> None:
    """The arguments of ``ddvi sweep``, for ``services.cli``."""
    p.add_argument("kind", choices=list(KINDS), help="which impairment to sweep")
    p.add_argument("deployment", nargs="?", default=None, help="default: rendezvous")
    p.add_argument("--values", type=float, nargs="+", required=True,
                   help="delays in s, or loss probabilities in [0, 1]")  # fmt: skip
    p.add_argument("--orbits", type=float, help="override run.orbits (a shorter sweep)")
    p.add_argument("--output", help="parent folder (default: the deployment's run.output)")


def sweep_command(args: argparse.Namespace) -> int:
    """Run the sweep and print its table; 0 when every run completed, 1 if not, 2 on bad
    input."""
    try:
        folder, rows = sweep(args.kind, args.deployment, args.values, args.output, args.orbits)
    except (DeploymentError, ValueError) as exc:
        print(f"ddvi sweep: {exc}", file=sys.stderr)
        return 2
    if not rows:
        print(f"ddvi sweep: no run produced a report; see {folder}", file=sys.stderr)
        return 1
    print(markdown_table(args.kind, rows))
    best = largest_learning_value(rows)
    if any(r["controller"] == "ddvi" for r in rows):
        unit = KINDS[args.kind]
        print(
            f"DDVI learned within {SUCCESS:.0%} of the LQR gain at every {args.kind} up to "
            f"{best:g} {unit}"
            if best is not None
            else f"DDVI did not learn within {SUCCESS:.0%} of the LQR gain at the smallest "
            f"{args.kind}"
        )
    print(folder)
    completed = all(r["completed"] for r in rows) and len(rows) >= len(args.values)
    return 0 if completed else 1
