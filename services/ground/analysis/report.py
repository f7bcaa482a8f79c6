"""The run report, written by the monitor from its ``RunData`` when the run ends.

``write_report`` writes, in the run folder:

    timeseries.csv   per truth sample time and deputy: t, orbits, the deputy's Hill state from
                     truth (vs the chief), its navigation state at that time (blank if none),
                     the commanded sigma3 in force (zero-order hold on ``for_t``), controller phase
    *.png            the paper's figures (``services.ground.analysis.figures``)
    summary.json     run, completion, errors at the end, gains against the reference,
                     message counters
    report.md        the summary table and the figure list

Each file is written whole or not at all (``services.ground.storage.disk``): on a nearly full disk
the timeseries and the figures take only what is left beyond the room kept for report.md and
summary.json, and whatever did not fit is named in both (``not_written``).  report.md's first
lines say whether the run's record is whole (``services.ground.storage.record``).

Every gain error is |K - K*| / |K*| against K*, the optimal gain of the truth's linear model
of that run (``services.model.true_lqr_gains``: the truth's density, facet area and factors),
which is the nominal LQR gain when the truth is nominal; the error against the nominal LQR
gain is kept beside it (``gain_error_vs_lqr``), since a learner that learns the truth is off
the nominal gain by as much as the model is wrong.
"""

from __future__ import annotations

import csv
import io
import json
import logging
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from services.ground.analysis.figure_canvas import FIGURES
from services.ground.analysis.figures import write_figures
from services.ground.analysis.outcome import outcome, outcome_lines
from services.ground.analysis.rundata import (
    CraftData,
    DeputySeries,
    FloatArray,
    RunData,
)
from services.ground.analysis.scoring import (
    DeputyOutcome,
    deputy_metrics,
    holding_notes,
    learned_switches,
    reference_gains,
    switches_to,
    table_cell,
)
from services.ground.storage.disk import REPORT_ROOM, failure, size_text, space_left, write_whole
from services.ground.storage.record import RecordGaps, record_block, record_line
from services.interface.topics import log_topic
from services.model import lqr_gains

log = logging.getLogger("ddvi.report")

HILL = ("x", "y", "z", "xdot", "ydot", "zdot")


def _hold(t_src: FloatArray, values: Any, t: FloatArray, default: Any) -> list[Any]:
    """Zero-order hold: for each t, the last value whose time is <= t (``default`` before)."""
    if len(t_src) == 0:
        return [default] * len(t)
    k = np.searchsorted(t_src, t, side="right") - 1
    return [values[i] if i >= 0 else default for i in k]


def _last_orbit(t: FloatArray, period: float) -> NDArray[np.bool_]:
    return t >= t[-1] - period


REFERENCE = "the optimal gain K* of the truth's linear model (its density, facet area and factors)"


def _deputy_summary(
    data: RunData, s: DeputySeries, completed: bool, cannot_hold: str
) -> dict[str, Any]:
    d = s.deputy
    craft = data.craft.get(d.name, CraftData())
    last_gains = craft.gains[-1] if craft.gains else None
    outcome = DeputyOutcome(
        t=s.t,
        along_track_error=np.abs(s.hill[:, 1] - d.y_ref),
        K=None if last_gains is None else np.asarray(last_gains.K),
        source=None if last_gains is None else last_gains.source,
        # every switch to learned gains: the first learning, then each re-learning (or, for a
        # restarted controller, its learning from scratch)
        learned_at=learned_switches(craft.gains),
        log=[text] if (text := data.last_log.get(log_topic(f"ctrl-{d.name}"))) else [],
        completed=completed,
        # a learner's switches to the LQR's gains: its fallback (services.flight.phases)
        fallback_at=switches_to(craft.gains, "lqr") if d.controller == "ddvi" else [],
    )
    m = deputy_metrics(
        data.dep, d, outcome, K_true=s.K_true, K_lqr=s.K_lqr, cannot_hold=cannot_hold
    )
    out: dict[str, Any] = {
        "controller": d.controller,
        # a learner's learning.method (None for LQR)
        "learning_method": getattr(d.learning, "method", None) if d.controller == "ddvi" else None,
        "y_ref": d.y_ref,
        "samples": len(s.t),
        "final_along_track_error_m": m["final_along_track_error_m"],
        "max_along_track_error_last_orbit_m": m["max_along_track_error_last_orbit_m"],
        "max_radial_last_orbit_m": None,
        "final_radial_m": None,
        # services.ground.analysis.scoring: None unless an LQR gain or a learned one is flown at
        # the end
        "gain_error_vs_true_optimum": m["gain_error"],
        "gain_error_vs_lqr": m["gain_error_vs_lqr"],
        "learned": m["learned"],
        "learned_at_orbits": m["learned_at_orbits"],
        "fallback_at_orbits": m["fallback_at_orbits"],
        "relearned_at_orbits": [],
        "relearning_abandoned_at_orbits": [],
        "can_hold": m["can_hold"],
        "note": m["note"],
        "gains": None,
        "lqr_gains": {"K": s.K_lqr.tolist(), "L": s.L_lqr.tolist()},
        "true_optimal_gains": None
        if s.K_true is None or s.L_true is None
        else {"K": s.K_true.tolist(), "L": s.L_true.tolist()},
        "phase": craft.status[-1].body["phase"] if craft.status else None,
    }
    if len(s.t):
        ax = np.abs(s.hill[:, 0])
        last = _last_orbit(s.t, data.period)
        out.update(max_radial_last_orbit_m=float(ax[last].max()), final_radial_m=float(ax[-1]))
    if last_gains is not None:
        out["gains"] = {"K": last_gains.K, "L": last_gains.L, "source": last_gains.source}
        if d.controller == "ddvi":
            switches = learned_switches(craft.gains)[1:]
            out["relearned_at_orbits"] = [t / data.period for t in switches]
            # every return to the old gains after re-learning failed (LearningCycle.learning_failed)
            abandoned = switches_to(craft.gains, "fallback")
            out["relearning_abandoned_at_orbits"] = [t / data.period for t in abandoned]
    return out


def _message_summary(data: RunData, monitor: dict[str, int]) -> dict[str, Any]:
    services = dict(data.stats)
    services["monitor"] = dict(monitor)  # the monitor's own counters, final

    def total(key: str) -> int:
        return sum(int(c.get(key, 0)) for c in services.values())

    return {
        "recorded": monitor.get("recorded", 0),
        "rejected": monitor.get("rejected", 0),
        "rejected_by_reason": {
            k.split(".", 1)[1]: v
            for k, v in sorted(monitor.items())
            if k.startswith("rejected.") and v
        },
        "by_schema": dict(sorted(data.counts.items())),
        "unrecorded": dict(sorted(data.unrecorded().items())),
        "services": services,
        "totals": {
            "sent": total("sent"),
            "received": total("received"),
            "dropped": total("dropped"),
            "late": total("late_commands"),
            "missing": total("missing_commands"),
            "rejected": total("rejected"),
            "duplicated": total("duplicated"),
            "reordered": total("reordered"),
            "stale": total("stale_commands"),
            "restarted": total("restarts"),
        },
    }


def timeseries_csv(data: RunData, series: list[DeputySeries]) -> tuple[bytes, int]:
    """timeseries.csv's bytes and its number of data rows.  Empty cells: no navigation sample
    at that time, no command yet, a non-finite value."""
    header = ["t", "orbits", "deputy", "controller", *HILL]
    header += [f"nav_{k}" for k in HILL] + ["nav_valid", "sigma3", "phase"]
    # a row's numbers are formatted in two operations (t and orbits; hill, nav, valid and
    # sigma3); NaN marks an empty cell ("nan" is no other number's text)
    head_format, tail_format = ",".join(["%.10g"] * 2), ",".join(["%.10g"] * 14)
    rows: list[tuple[float, int, str]] = []
    for j, s in enumerate(series):
        craft = data.craft.get(s.deputy.name, CraftData())
        numbers = np.full((len(s.t), 16), np.nan)
        numbers[:, 0], numbers[:, 1], numbers[:, 2:8] = s.t, s.t / data.period, s.hill
        nav_t, nav = craft.nav.arrays()
        if len(nav_t):
            k = np.searchsorted(nav_t, s.t)
            found = k < len(nav_t)
            found[found] = nav_t[k[found]] == s.t[found]
            numbers[found, 8:15] = nav[k[found], :7]
        cmd_t, cmd = craft.cmd.arrays()
        numbers[:, 15] = _hold(cmd_t, cmd[:, 2].tolist(), s.t, np.nan)  # the command in force
        numbers[~np.isfinite(numbers)] = np.nan
        st_t = np.array([r.t for r in craft.status])
        phases = [_csv_cell(r.body["phase"]) for r in craft.status]
        phase = _hold(st_t, phases, s.t, "")
        labels = f"{_csv_cell(s.deputy.name)},{_csv_cell(s.deputy.controller)}"
        for i, v in enumerate(numbers.tolist()):
            tail = (tail_format % tuple(v[2:])).replace("nan", "")
            rows.append((v[0], j, f"{head_format % tuple(v[:2])},{labels},{tail},{phase[i]}"))
    rows.sort(key=lambda r: (r[0], r[1]))
    text = io.StringIO(newline="")
    csv.writer(text).writerow(header)
    text.writelines(r[2] + "\r\n" for r in rows)  # the csv module's line ending
    return text.getvalue().encode(), len(rows)


def _csv_cell(text: str) -> str:
    """One CSV cell as the csv module writes it (quoted only when it must be): the rows are
    written as whole lines, since csv.writer cell by cell costs most of the CSV's time."""
    if any(c in text for c in ',"\r\n'):
        return '"' + text.replace('"', '""') + '"'
    return text


def _num(v: Any, fmt: str = ".3g") -> str:
    return "-" if v is None else format(v, fmt)


def _gain_cell(d: dict[str, Any], key: str) -> str:
    """A gain error of a deputy's summary as the table prints it ("not learned" for a learner
    that flies no learned gain)."""
    value = table_cell("gain_error", {"gain_error": d.get(key), "learned": d.get("learned")})
    return value if isinstance(value, str) else _num(value)


def markdown(summary: dict[str, Any], figures: list[str]) -> str:
    """report.md's text: first what the run is, whether it completed and whether its record
    is whole (and which of the report's files did not fit), then the outcome and the table."""
    out = summary.get("outcome", {})
    lines = [
        f"# Run {summary['run']}",
        "",
        f"- deployment: `{summary['deployment']}`",
        f"- completed: {'yes' if summary['completed'] else '**no** (partial report)'}",
        record_line(out.get("record", {}), summary.get("source", "what was recorded")),
        *not_written_lines(summary.get("not_written", {})),
        f"- simulated: {summary['sim_time_s']:.0f} s = {summary['orbits']:.2f} orbits "
        f"in {summary['wall_s']:.1f} s wall",
        *(outcome_lines(summary["outcome"]) if "outcome" in summary else []),
        "",
        "| deputy | controller | final abs(y - y_ref) [m] | max last orbit [m] | final abs(x) [m] "
        "| max abs(x) last orbit [m] | gain error | gain error vs nominal LQR "
        "| learned at [orbits] | phase | note |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name, d in summary["deputies"].items():
        at = [d["learned_at_orbits"], *d.get("relearned_at_orbits", [])]
        learned = [t for t in at if t is not None]
        abandoned = d.get("relearning_abandoned_at_orbits", [])
        gave_up = [f"old gains again at {t:.2f}" for t in abandoned]
        if (fell_back := d.get("fallback_at_orbits")) is not None:
            gave_up.append(f"fallback (LQR) at {fell_back:.2f}")
        lines.append(
            f"| {name} | {d['controller']} | {_num(d['final_along_track_error_m'])} "
            f"| {_num(d['max_along_track_error_last_orbit_m'])} | {_num(d['final_radial_m'])} "
            f"| {_num(d['max_radial_last_orbit_m'])} "
            f"| {_gain_cell(d, 'gain_error_vs_true_optimum')} "
            f"| {_gain_cell(d, 'gain_error_vs_lqr')} "
            f"| {', '.join([*(_num(t, '.2f') for t in learned), *gave_up]) or '-'} "
            f"| {d['phase'] or '-'} | {(d.get('note') or '-').replace('|', '/')} |"
        )
    lines += [
        "",
        f"Gain error: |K - K*| / |K*| of the gain flown at the end against {REFERENCE}; "
        "vs nominal LQR: against the LQR gain of the nominal model (the two agree when the "
        "truth is nominal).  Scored for an LQR deputy, a learned gain and a learner's "
        "fallback (the nominal model's LQR gains, flown when no gain validated by "
        "learning.learn_until_orbits): a learner that flies no learned gain at the end "
        "(its fallback, or old gains a failed re-learning fell back to) is not learned.  "
        "Note: why a deputy cannot hold its slot, why a learner flies no learned gain.",
    ]
    m = summary["messages"]
    tot = m["totals"]
    reasons = ", ".join(f"{k}: {v}" for k, v in m["rejected_by_reason"].items())
    reasons = f" ({reasons})" if reasons else ""
    lines += [
        "",
        f"Messages: {m['recorded']} recorded by the monitor, {m['rejected']} rejected by it"
        f"{reasons}; all services: sent {tot['sent']}, received "
        f"{tot['received']}, dropped {tot['dropped']}, rejected {tot['rejected']}, late "
        f"commands {tot['late']}, missing commands {tot['missing']}.",
    ]
    if m.get("unrecorded"):
        lost = ", ".join(f"{n} from {s}" for s, n in m["unrecorded"].items())
        lines += [f"Published but never recorded (lost between publisher and monitor): {lost}."]
    lines += [
        "",
        "## Figures",
        "",
    ]
    lines += [f"- [{FIGURES[f].line if f in FIGURES else f}]({f})" for f in figures]
    data = [f"`{f}`" for f in ("timeseries.csv",) if f not in summary.get("not_written", {})]
    data += ["`summary.json`", "recording `recording.mcap`"]
    lines += ["", f"Data: {', '.join(data)}.", ""]
    if summary.get("events"):
        lines += ["## Faults, warnings and errors", ""]
        for e in summary["events"][:50]:
            text = e.get("text") or f"{e.get('kind')} on {e.get('target')} {e.get('params')}"
            lines.append(f"- t = {e['t']:.0f} s `{e['topic']}`: {text}")
        lines.append("")
    if (got := summary.get("recovered")) is not None:
        cut = "" if got["complete"] else " up to its last complete chunk (it was cut short)"
        lines += [
            f"Written by `ddvi report` from the recording: {got['messages']} messages{cut}.",
            "",
        ]
    return "\n".join(lines)


def not_written_lines(not_written: dict[str, str]) -> list[str]:
    """report.md's line on the report's files that did not fit on the disk (none: no line)."""
    if not not_written:
        return []
    said = "; ".join(f"`{name}`: {why}" for name, why in not_written.items())
    return [f"- **not written**: {said}"]


class ReportNotWrittenError(Exception):
    """summary.json or report.md could not be written; the message says which, why, and the
    space left on the disk."""


class ReportFiles:
    """The report's files in its folder, each written whole or not at all
    (``disk.write_whole``): the timeseries and the figures only into what the disk has beyond
    ``disk.REPORT_ROOM``, which stays for summary.json and report.md.  ``not_written``: each
    file that did not fit, and why (an older file of its name is removed: it would belong to
    another report)."""

    def __init__(self, out: Path) -> None:
        self.out = out
        self.not_written: dict[str, str] = {}

    def extra(self, name: str, data: bytes) -> bool:
        """Write ``name`` if it fits beside the report's room; whether it was written."""
        path = self.out / name
        try:
            write_whole(path, data, keep=REPORT_ROOM)
        except OSError as exc:
            self.not_written[name] = exc.strerror or str(exc)
            path.unlink(missing_ok=True)
            return False
        return True

    def say(self) -> None:
        """One line on what was not written, if anything."""
        if self.not_written:
            left = f"{size_text(space_left(self.out))} left on {self.out}"
            said = "; ".join(f"{name}: {why}" for name, why in self.not_written.items())
            log.warning("not written (%s): %s", left, said)

    def essential(self, name: str, data: bytes) -> None:
        """Write ``name``; ReportNotWrittenError when it cannot be."""
        path = self.out / name
        try:
            write_whole(path, data)
        except OSError as exc:
            raise ReportNotWrittenError(failure(path, exc)) from exc


def deputy_series(data: RunData) -> list[DeputySeries]:
    """Each deputy's true Hill states with its nominal LQR gains and the optimal gains of the
    truth's linear model: what the report scores and plots."""
    series = []
    for d in data.dep.deputy:
        t, hill = data.hill(d.name)
        K, L = lqr_gains(data.dep, d)
        K_true, L_true = reference_gains(data.dep, d)
        series.append(DeputySeries(d, t, hill, np.asarray(K), np.asarray(L), K_true, L_true))
    return series


def write_report(
    out: Path,
    data: RunData,
    *,
    completed: bool,
    monitor_counters: dict[str, int],
    gaps: RecordGaps | None = None,
    source: str = "every message the monitor received",
    recovered: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """Write timeseries.csv, the figures, report.md and summary.json to ``out``; return the
    summary.  ``gaps``: what the recorder knows the record lacks; ``source``: what the report
    is from, in words; ``recovered``: how ``ddvi report`` read the recording (messages, and
    whether it was complete).  Each file is written whole or not at all, the timeseries and the
    figures only beyond the room kept for the other two (``ReportFiles``); what did not fit is
    named in both.  Figures that fail are logged and left out.  Raises ReportNotWrittenError when
    report.md or summary.json cannot be written."""
    out.mkdir(parents=True, exist_ok=True)
    series = deputy_series(data)
    files = ReportFiles(out)
    table, rows = timeseries_csv(data, series)
    files.extra("timeseries.csv", table)
    try:
        figures = write_figures(out, data, series, save=files.extra)
    except Exception:
        log.exception("could not draw the figures")
        figures = []
    # completed: the monitor saw the final clock at the planned end (an early final clock,
    # a re-entry say, is a run that ended, not a mission that completed)
    completed = completed and data.sim_t >= data.duration - 1e-6
    cannot_hold = holding_notes(data.dep)
    wall = 0.0
    if data.first_ns is not None and data.last_ns is not None:
        wall = (data.last_ns - data.first_ns) / 1e9
    summary: dict[str, Any] = {
        "run": data.run,
        "deployment": data.dep.path,
        "completed": completed,
        "sim_time_s": data.sim_t,
        "orbits": data.sim_t / data.period,
        "planned_sim_time_s": data.duration,
        "wall_s": wall,
        "csv_rows": rows,
        "deputies": {
            s.deputy.name: _deputy_summary(data, s, completed, cannot_hold.get(s.deputy.name, ""))
            for s in series
        },
        "messages": _message_summary(data, monitor_counters),
        "outcome": _outcome(data, monitor_counters, gaps or RecordGaps()),
        "figures": figures,
        "not_written": files.not_written,
        "source": source,
        "events": data.events,
    }
    if recovered is not None:
        summary["recovered"] = recovered
    files.say()
    files.essential("report.md", markdown(summary, figures).encode())
    files.essential("summary.json", json.dumps(summary, indent=2, default=_json_default).encode())
    return summary


def _outcome(data: RunData, monitor_counters: dict[str, int], gaps: RecordGaps) -> dict[str, Any]:
    """How the run ended and what happened to its commands
    (``services.ground.analysis.outcome``)."""
    return outcome(
        final_seen=data.final_seen,
        sim_t=data.sim_t,
        duration=data.duration,
        period=data.period,
        services=data.stats,
        monitor=monitor_counters,
        refused=data.refusals.summary(),
        impossible=data.claims.impossible(),
        deputies=[d.name for d in data.dep.deputy],
        record=record_block(gaps, data.unrecorded()),
    )


def _json_default(value: Any) -> Any:
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    raise TypeError(f"not JSON serialisable: {type(value).__name__}")
