"""A sweep's results: its rows as a table (CSV and markdown), its plot, and what counts as
learning in it.  ``services.ground.sweeps.sweep`` runs the missions and makes the rows: one per run
(a point of the sweep) and deputy, as dicts keyed by the names of ``columns(kind)``.

Every gain error is |K - K*| / |K*| against K*, the optimal gain of the truth's linear model
of that run (``services.model.true_lqr_gains``), with the error against the nominal model's
LQR gain in its own column; each row's metrics are
``services.ground.analysis.scoring.deputy_metrics``' (in the CSV a learner that flies no learned
gain has empty gain errors and learned false; in the markdown table "not learned").
"""

from __future__ import annotations

import csv
from pathlib import Path
from typing import Any

from services.ground.analysis.scoring import LEARNED_WITHIN_10_PERCENT, METRICS, table_cell

UNITS = {"delay": "s", "loss": "probability", "noise": "m"}
"""Sweep kind -> the unit of its swept value."""

POINT = {"delay": ["value"], "loss": ["value"], "noise": ["noise", "mismatch"]}
"""Sweep kind -> the columns that name a run's point of the sweep (its first column is the
plot's x axis)."""

RESULTS = [
    "deputy",
    "controller",
    "completed",
    "can_hold",
    *(m for m in METRICS if m not in ("completed", "can_hold", "note")),
]
"""A row's deputy and its metrics (``services.ground.analysis.scoring.METRICS``; the note last, in
noise sweeps)."""
LINKS = ["dropped", "delayed", "late", "missing"]

HEADERS = {
    "noise": "nav noise (m)",
    "mismatch": "mismatch",
    "deputy": "deputy",
    "controller": "controller",
    "completed": "completed",
    "can_hold": "can hold slot",
    "final_along_track_error_m": "final along-track error (m)",
    "max_along_track_error_last_orbit_m": "last-orbit max (m)",
    "learned": "learned",
    "learned_at_orbits": "at orbit",
    "fallback_at_orbits": "fallback (LQR) at orbit",
    "gain_error": "gain error vs true K*",
    "gain_error_vs_lqr": "vs nominal LQR",
    "dropped": "dropped",
    "delayed": "delayed",
    "late": "late",
    "missing": "missing",
    "note": "note",
}

NOTES = {
    "links": "dropped, delayed: by this deputy's controller's links and the environment's "
    "command links (all deputies); late, missing: the environment's commands, all deputies.",
    "noise": "nav noise: each deputy's navigation.position_noise (m, 1 sigma per axis), "
    "velocity_noise = {ratio:g} (m/s)/m times it; mismatch f: the truth's density_factor and "
    "every deputy's area_factor f times the deployment's; note: why a deputy cannot hold its "
    "slot, and why a learner flies no learned gain (its controller's last log line).",
}


def columns(kind: str) -> list[str]:
    """The row keys of a sweep of ``kind``, in table order."""
    if kind not in UNITS:
        raise ValueError(f"sweep kind: expected one of {list(UNITS)}, got {kind!r}")
    return POINT[kind] + RESULTS + (["note"] if kind == "noise" else LINKS)


def largest_learning_value(rows: list[dict[str, Any]]) -> float | None:
    """The largest value of a link sweep at which every learning deputy learned within 10 % of
    K* (``LEARNED_WITHIN_10_PERCENT``), all smaller values included (None if it failed at the
    first)."""
    best = None
    for value in sorted({r["value"] for r in rows}):
        learners = [r for r in rows if r["value"] == value and r["controller"] != "lqr"]
        if not learners or not all(LEARNED_WITHIN_10_PERCENT.row_met(r) for r in learners):
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
    return str(x).replace("|", "/")


def markdown_table(kind: str, rows: list[dict[str, Any]], velocity_ratio: float = 0.0) -> str:
    """The rows as a markdown table, with a note on what the columns count."""
    cols = columns(kind)
    head = [HEADERS.get(c, f"{kind} ({UNITS[kind]})") for c in cols]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    lines += ["| " + " | ".join(_fmt(table_cell(c, r)) for c in cols) + " |" for r in rows]
    note = NOTES["noise"].format(ratio=velocity_ratio) if kind == "noise" else NOTES["links"]
    lines += [
        "",
        "learned: the controller flies gains it learned (not K0, not old gains a failed "
        "re-learning fell back to); gain error: |K - K*| / |K*| of the gain flown at the end "
        "(LQR's and learned ones; a learner that flies none is not learned) against K*, the "
        "optimal gain of the truth's linear model of that run (its density, facet area and "
        "factors); vs nominal LQR: against the nominal model's LQR gain; along-track error: "
        "|y - y_ref|; can hold slot: some attitude within the deputy's limit matches the "
        "chief's drag. " + note,
    ]
    return "\n".join(lines) + "\n"


def write_table(
    kind: str, rows: list[dict[str, Any]], folder: Path, velocity_ratio: float = 0.0
) -> None:
    """Write sweep.csv and sweep.md of the rows so far."""
    with open(folder / "sweep.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=columns(kind), extrasaction="ignore")
        w.writeheader()
        w.writerows(rows)
    (folder / "sweep.md").write_text(markdown_table(kind, rows, velocity_ratio))


def _label(kind: str, row: dict[str, Any]) -> str:
    text = f"{row['deputy']} ({row['controller']})"
    return f"{text}, mismatch {row['mismatch']:g}" if kind == "noise" else text


def plot(kind: str, rows: list[dict[str, Any]], path: Path) -> None:
    """Write sweep.png: final along-track error (left) and gain error against the true K*
    (right, a cross at 1 where a learner did not learn; an error of 0, LQR's in a nominal run,
    has no point on the log scale) against the swept value; one line per deputy (and mismatch
    factor), the noise axis symmetric-log (it starts at 0)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    x = POINT[kind][0]
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 4))
    for i, label in enumerate(dict.fromkeys(_label(kind, r) for r in rows)):
        mine, color = [r for r in rows if _label(kind, r) == label], f"C{i % 10}"
        # a log axis has no place for 0 (a nominal LQR's gain error): only positive points
        final = [
            (r[x], r["final_along_track_error_m"])
            for r in mine
            if r["completed"] and r["final_along_track_error_m"] > 0
        ]
        if final:
            ax1.semilogy(*zip(*final, strict=True), "o-", color=color, label=label)
        scored = [(r[x], r["gain_error"]) for r in mine if (r["gain_error"] or 0.0) > 0]
        if scored:
            ax2.semilogy(*zip(*scored, strict=True), "o-", color=color, label=label)
        failed = [r[x] for r in mine if r["controller"] != "lqr" and not r["learned"]]
        if failed:
            ax2.plot(
                failed, [1.0] * len(failed), "x", ms=9, color=color, label=f"{label}: not learned"
            )
    xlabel = "navigation noise (m)" if kind == "noise" else f"link {kind} ({UNITS[kind]})"
    ax1.set(xlabel=xlabel, ylabel="final |y - y_ref| (m)", title="along-track error at the end")
    ax2.set(xlabel=xlabel, ylabel="|K - K*| / |K*|", title="gain against the true optimum K*")
    positive = sorted({r[x] for r in rows if r[x] > 0})
    for ax in (ax1, ax2):
        if kind == "noise" and positive:
            ax.set_xscale("symlog", linthresh=positive[0])
        ax.grid(True, which="both", alpha=0.3)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
