"""A campaign's report, from its result table: ``report.md`` and its figures.

- success rate per controller: a deputy succeeds in a run that completed with its final
  along-track error below the campaign's ``success_threshold``;
- percentiles of the final and last-orbit-max along-track errors and of the gain error;
- ``final_error.png``: histograms and empirical CDFs of the final error per controller;
- ``scatter.png``: the final error against each dispersed parameter;
- the worst runs, each with the command that reproduces it bit for bit.
"""

from __future__ import annotations

import shlex
from pathlib import Path
from typing import Any

import numpy as np

from ddvi_core.learning_config import LearningConfig
from services.config import controller_label
from services.ground.analysis.scoring import final_error_below
from services.ground.campaign.dispersions import CampaignSpec

PERCENTILES = (50, 90, 95, 99)
WORST = 5  # runs listed per controller


def outcomes(rows: list[dict[str, Any]], threshold: float) -> list[dict[str, Any]]:
    """One record per run and deputy: run, deputy, controller, final, last (m), gain error,
    learned (None for LQR), learned_at, fallback_at, can_hold, note, completed, success."""
    out = []
    for r in rows:
        for col, controller in r.items():
            if not col.endswith(".controller") or controller is None:
                continue
            name = col.removesuffix(".controller")
            final = r.get(f"{name}.final_error_m")
            learned = r.get(f"{name}.learned")
            can_hold = r.get(f"{name}.can_hold")
            out.append(
                {
                    "run": r["run"],
                    "deputy": name,
                    "controller": controller,
                    "final": final,
                    "last": r.get(f"{name}.last_orbit_max_error_m"),
                    "gain": r.get(f"{name}.gain_error"),
                    "learned": None if learned is None else bool(learned),
                    "learned_at": r.get(f"{name}.learned_at_orbits"),
                    "fallback_at": r.get(f"{name}.fallback_at_orbits"),
                    "can_hold": can_hold is None or bool(can_hold),
                    "note": r.get(f"{name}.note"),
                    "completed": bool(r["completed"]),
                    "success": final_error_below(threshold).met(
                        completed=bool(r["completed"]), final_m=final
                    ),
                }
            )
    return out


def _controllers(rows: list[dict[str, Any]], spec: CampaignSpec) -> list[str]:
    """Every controller of the deployment (a run that failed at start still counts)."""
    names = [
        controller_label(
            d.get("controller", "lqr"), d.get("learning", {}).get("method", LearningConfig.method)
        )
        for d in spec.base.get("deputy", [])
    ]
    return list(dict.fromkeys(names + [o["controller"] for o in outcomes(rows, 1.0)]))


def _pct(values: list[float | None]) -> list[float]:
    v = np.array([x for x in values if x is not None], float)
    return [float(np.percentile(v, p)) for p in PERCENTILES] + [float(v.max())] if v.size else []


def _fmt(x: Any) -> str:
    if x is None:
        return "-"
    return f"{x:.4g}" if isinstance(x, float) else str(x)


def stats_table(spec: CampaignSpec, rows: list[dict[str, Any]]) -> list[str]:
    """The markdown lines of the per-controller table."""
    threshold = spec.campaign.success_threshold
    head = [
        "controller",
        "deputy runs",
        "success",
        "final error p50 / p90 / p95 / p99 / max (m)",
        "last-orbit max p50 / p95 (m)",
        "gain error p50 / p95",
        "learned",
        "learned at orbit p50 / max",
        "fallback (LQR)",
        "cannot hold slot",
    ]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for ctrl in _controllers(rows, spec):
        mine = [o for o in outcomes(rows, threshold) if o["controller"] == ctrl]
        ok = sum(o["success"] for o in mine)
        rate = f"{ok}/{len(mine)} ({ok / len(mine):.1%})" if mine else "-"
        final = " / ".join(_fmt(x) for x in _pct([o["final"] for o in mine])) or "-"
        last = _pct([o["last"] for o in mine])
        gain = _pct([o["gain"] for o in mine])
        learned = sum(bool(o["learned"]) for o in mine) if ctrl != "lqr" else None
        at = _pct([o["learned_at"] for o in mine])
        fell_back = sum(o["fallback_at"] is not None for o in mine)
        infeasible = sum(not o["can_hold"] for o in mine)
        lines.append(
            f"| {ctrl} | {len(mine)} | {rate} | {final} | "
            f"{_fmt(last[0]) if last else '-'} / {_fmt(last[2]) if last else '-'} | "
            f"{_fmt(gain[0]) if gain else '-'} / {_fmt(gain[2]) if gain else '-'} | "
            f"{'-' if learned is None else f'{learned}/{len(mine)}'} | "
            f"{f'{_fmt(at[0])} / {_fmt(at[-1])}' if at else '-'} | "
            f"{'-' if learned is None else f'{fell_back}/{len(mine)}'} | "
            f"{infeasible or '-'} |"
        )
    return lines


def reproduce(spec: CampaignSpec, folder: Path, run: int, mode: str) -> str:
    """The command that runs ``run`` alone, bit for bit, and compares it with the table."""
    cmd = ["ddvi", "campaign", spec.path, "--only-run", str(run), "--output", str(folder)]
    return shlex.join(cmd + (["--distributed"] if mode == "distributed" else []))


def worst_lines(spec: CampaignSpec, folder: Path, rows: list[dict], mode: str) -> list[str]:
    """The markdown lines of the worst runs per controller (failed runs first)."""
    by_run = {r["run"]: r for r in rows}
    keys = [d.key for d in spec.dispersions]
    lines = [
        "| controller | run | deputy | final error (m) | "
        + " | ".join(keys)
        + " | error | reproduce |",
        "|" + "---|" * (6 + len(keys)),
    ]
    for ctrl in _controllers(rows, spec):
        mine = [
            o for o in outcomes(rows, spec.campaign.success_threshold) if o["controller"] == ctrl
        ]
        mine.sort(
            key=lambda o: (o["completed"], -(o["final"] if o["final"] is not None else np.inf))
        )
        for o in mine[:WORST]:
            r = by_run[o["run"]]
            values = " | ".join(_fmt(r.get(k)) for k in keys)
            error = (r["error"] or "").replace("|", "/")[:120]
            lines.append(
                f"| {ctrl} | {o['run']} | {o['deputy']} | {_fmt(o['final'])} | "
                f"{values} | {error or '-'} | `{reproduce(spec, folder, o['run'], mode)}` |"
            )
    return lines


def infeasible_lines(rows: list[dict[str, Any]]) -> list[str]:
    """One markdown line per run and deputy that no attitude lets hold its slot."""
    return [
        f"- run {o['run']}, deputy {o['deputy']} ({o['controller']}): {o['note'] or '-'}"
        for o in outcomes(rows, 0.0)
        if not o["can_hold"]
    ]


def summary_lines(spec: CampaignSpec, rows: list[dict[str, Any]]) -> list[str]:
    """A few lines for the terminal: runs, failures and the success rate per controller."""
    failed = sum(not r["completed"] for r in rows)
    lines = [
        f"campaign {spec.campaign.name}: {len(rows)}/{spec.campaign.runs} runs, {failed} failed"
    ]
    threshold = spec.campaign.success_threshold
    for ctrl in _controllers(rows, spec):
        mine = [o for o in outcomes(rows, threshold) if o["controller"] == ctrl]
        ok = sum(o["success"] for o in mine)
        share = f"{ok / len(mine):.1%}" if mine else "-"
        lines.append(
            f"- {ctrl}: final along-track error < {threshold:g} m in {ok}/{len(mine)} ({share})"
        )
    return lines


def write_report(spec: CampaignSpec, folder: Path, rows: list[dict[str, Any]], mode: str) -> Path:
    """Write report.md and its figures in ``folder``; return report.md's path."""
    from services.ground.campaign.figures import error_figure, scatter_figure

    c = spec.campaign
    failed = [r for r in rows if not r["completed"]]
    lines = [
        f"# Campaign {c.name}",
        "",
        f"Deployment `{c.deployment}`, {len(rows)}/{c.runs} runs ({mode}), campaign seed "
        f"{c.seed}, {len(failed)} failed.  Success: the run completed and the deputy's "
        f"final along-track error is below {c.success_threshold:g} m.  Gain error: "
        "|K - K*| / |K*| of the gains flown at the end against the run's true optimal "
        "gain, for LQR and learned gains (a learner that flies no learned gain at the end is "
        "not learned and has none).  Learned: flies learned gains at the end.  Cannot hold "
        "slot: no attitude within the deputy's limit matches the chief's drag.",
        "",
        *summary_lines(spec, rows)[1:],
        "",
        *stats_table(spec, rows),
        "",
    ]
    figures = []
    if rows and error_figure(outcomes(rows, c.success_threshold), folder / "final_error.png"):
        figures.append("final_error.png")
    keys = [d.key for d in spec.dispersions if d.distribution != "seed"]  # seeds: no axis
    if rows and scatter_figure(rows, keys, folder / "scatter.png"):
        figures.append("scatter.png")
    lines += [f"![{f}]({f})" for f in figures] + ["", "## Worst runs", ""]
    lines += worst_lines(spec, folder, rows, mode)
    if infeasible := infeasible_lines(rows):
        lines += ["", "## Deputies that cannot hold their slot", "", *infeasible]
    if failed:
        lines += ["", "## Failed runs", ""]
        lines += [f"- run {r['run']}: {r['error']}" for r in failed]
    path = folder / "report.md"
    path.write_text("\n".join(lines) + "\n")
    return path
