"""One scoring of a deputy (``services.ground.analysis.scoring.deputy_metrics``): the same outcome
is scored alike by the run report, both sweep paths and both campaign paths, and a learner that
flies no learned gain has no gain error in any of them."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

import services.flight.inprocess
from services.config import deployment_from_table, read_table
from services.ground.analysis import report, scoring
from services.ground.analysis.rundata import GainRecord, RunData
from services.ground.analysis.scoring import (
    AS_GOOD_AS_LQR,
    LEARNED_WITHIN_10_PERCENT,
    NOT_LEARNED_TEXT,
    final_error_below,
)
from services.ground.campaign import run as campaign_run
from services.ground.campaign.dispersions import spec_from_table
from services.ground.campaign.report import stats_table
from services.ground.sweeps.sweep import inprocess_rows, summary_rows
from services.ground.sweeps.sweep_table import markdown_table
from services.interface.topics import log_topic
from services.model import lqr_gains, orbit_period

K0 = np.array([[-0.023, 0.0, 0.0, -10.0]])
L0 = np.zeros((1, 5))
LOG = "learning refused at t = 5400 s: the fit's residual is 3 times the noise"
COMPARED = (
    "final_along_track_error_m",
    "max_along_track_error_last_orbit_m",
    "learned",
    "learned_at_orbits",
    "fallback_at_orbits",
    "gain_error",
    "gain_error_vs_lqr",
    "can_hold",
    "note",
)
CAMPAIGN = {  # campaign column -> metric
    "final_error_m": "final_along_track_error_m",
    "last_orbit_max_error_m": "max_along_track_error_last_orbit_m",
    "learned": "learned",
    "learned_at_orbits": "learned_at_orbits",
    "fallback_at_orbits": "fallback_at_orbits",
    "gain_error": "gain_error",
    "gain_error_vs_lqr": "gain_error_vs_lqr",
    "can_hold": "can_hold",
    "note": "note",
}


def _flight(table: dict, history: str) -> dict[str, dict]:
    """Per deputy of the default mission: three orbits of along-track error that grows, the
    gain records it flew and its controller's last log line.  ``history`` of the learner:
    "learned" (K0, then 1.02 x LQR from orbit 1.5), "never" (K0 to the end), "fallback"
    (learned at orbit 1.5, its re-learning fallen back to the old gains at orbit 2.5), "lqr"
    (K0, then no gain validated: the LQR fallback from orbit 2.5)."""
    dep = deployment_from_table(table)
    period = orbit_period(dep)
    t = np.linspace(0.0, 3 * period, 301)
    flights = {}
    for i, d in enumerate(dep.deputy):
        hill = np.zeros((len(t), 6))
        hill[:, 1] = d.y_ref + (i + 1) * 0.5 * np.sin(t / 700.0) * (1 + t / period)
        K, L = (np.asarray(g) for g in lqr_gains(dep, d))
        if d.controller == "lqr":
            gains = [GainRecord(0.0, K.tolist(), L.tolist(), "lqr", 0, True)]
        else:
            gains = [GainRecord(0.0, K0.tolist(), L0.tolist(), "initial", 0, False)]
            learned = GainRecord(1.5 * period, (1.02 * K).tolist(), L.tolist(), "ddvi", 9, True)
            if history in ("learned", "fallback"):
                gains.append(learned)
            if history == "fallback":
                gains.append(GainRecord(2.5 * period, learned.K, learned.L, "fallback", 9, True))
            if history == "lqr":
                gains.append(GainRecord(2.5 * period, K.tolist(), L.tolist(), "lqr", 0, True))
        flights[d.name] = {"t": t, "hill": hill, "gains": gains, "log": LOG}
    return flights


def _report_summary(tmp_path: Path, table: dict, flights: dict, monkeypatch) -> dict:
    """The run report's summary.json of the flights."""
    dep = deployment_from_table(table)
    data = RunData(dep, "scored")
    data.sim_t = data.duration  # the mission completed
    for name, f in flights.items():
        data.sc(name).gains.extend(f["gains"])
        data.last_log[log_topic(f"ctrl-{name}")] = f["log"]
    monkeypatch.setattr(
        RunData, "hill", lambda self, name: (flights[name]["t"], flights[name]["hill"])
    )
    monkeypatch.setattr(report, "write_figures", lambda *args: [])  # not what is scored
    return report.write_report(tmp_path, data, completed=True, monitor_counters={})


def _fake_in_process(flights: dict, monkeypatch: pytest.MonkeyPatch):
    """``run_in_process`` that returns the flights as its records (controller: the last gains
    flown, their source and every switch to learned gains), their Hill states as the truth
    (the frame's transformation is not what is compared: the report's is faked alike)."""
    monkeypatch.setattr(scoring, "truth_hill", lambda dep, chief, deputy: deputy)

    def run(dep, timing=None):
        out = {}
        for d in dep.deputy:
            f = flights[d.name]
            last = f["gains"][-1]
            switches = [g.t for g in f["gains"] if g.source == "ddvi"]
            fallback = [g.t for g in f["gains"][1:] if g.source == "lqr"]
            x = f["hill"]
            learning = SimpleNamespace(learned_at=switches, fallback_at=fallback)
            ctrl = SimpleNamespace(K=np.asarray(last.K), source=last.source, learning=learning)
            out[d.name] = {
                "t": f["t"],
                "x": x,
                "truth_t": f["t"],
                "chief_rv": np.zeros_like(x),
                "rv": x,
                "links": {},
                "environment": {},
                "u": np.zeros(len(f["t"])),
                "log": [f["log"]],
                "controller": ctrl,
            }
        return out

    return run


@pytest.mark.parametrize("history", ["learned", "never", "fallback", "lqr"])
def test_the_report_sweeps_and_campaigns_score_a_deputy_alike(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, history: str
) -> None:
    table = read_table(None)
    dep = deployment_from_table(table)
    flights = _flight(table, history)
    summary = _report_summary(tmp_path / "run", table, flights, monkeypatch)
    fake = _fake_in_process(flights, monkeypatch)
    monkeypatch.setattr(services.flight.inprocess, "run_in_process", fake)

    def fake_ddvi_run(cmd, **kwargs):  # `ddvi run` in a campaign's folder: the same report
        folder = Path(cmd[cmd.index("run") + 1]).parent / "runs" / "scored"
        folder.mkdir(parents=True)
        (folder / "summary.json").write_text(json.dumps(summary))
        return subprocess.CompletedProcess(cmd, 0, "", "")

    monkeypatch.setattr(campaign_run.subprocess, "run", fake_ddvi_run)
    task = {"run": 0, "seed": 1, "table": table}
    in_process, _ = campaign_run.execute({**task, "mode": "inprocess"})
    distributed, _ = campaign_run.execute(
        {**task, "mode": "distributed", "keep": str(tmp_path / "campaign")}
    )
    assert in_process["completed"] and distributed["completed"], distributed["error"]
    sweep_launched = {r["deputy"]: r for r in summary_rows({"noise": 0.0}, summary)}
    sweep_in_process = {r["deputy"]: r for r in inprocess_rows({"noise": 0.0}, dep)}

    for d in dep.deputy:
        s = summary["deputies"][d.name]
        scored = {k: s[k] for k in COMPARED if k != "gain_error"}
        scored["gain_error"] = s["gain_error_vs_true_optimum"]
        for row in (sweep_launched[d.name], sweep_in_process[d.name]):
            assert {k: row[k] for k in COMPARED} == scored
        for row in (in_process, distributed):
            assert {m: row[f"{d.name}.{c}"] for c, m in CAMPAIGN.items()} == scored
        assert scored["can_hold"] is True
        if d.controller == "lqr":
            assert scored["learned"] is None and scored["gain_error"] == 0.0
            continue
        learned = history == "learned"
        assert scored["learned"] is learned
        ever = history in ("learned", "fallback")
        assert scored["learned_at_orbits"] == (pytest.approx(1.5) if ever else None)
        fell_back = scored["fallback_at_orbits"]
        assert fell_back == (pytest.approx(2.5) if history == "lqr" else None)
        if learned:
            assert scored["gain_error"] == pytest.approx(0.02)
            assert scored["gain_error_vs_lqr"] == pytest.approx(0.02)
            assert scored["note"] is None
        elif history == "lqr":  # the fallback's error against K*: the nominal LQR's, 0 here
            assert scored["gain_error"] == 0.0 and scored["gain_error_vs_lqr"] is None
            assert scored["note"] == LOG
        else:  # not K0's error (0.1435 from the nominal K*): no gain error at all
            assert scored["gain_error"] is None and scored["gain_error_vs_lqr"] is None
            assert scored["note"] == LOG
    if history == "lqr":  # said in the run's report and counted in the campaign's table
        learner = next(d.name for d in dep.deputy if d.controller != "lqr")
        run_md = (tmp_path / "run" / "report.md").read_text()
        (line,) = [x for x in run_md.splitlines() if x.startswith(f"| {learner} |")]
        assert "| fallback (LQR) at 2.50 |" in line
        campaign = {"campaign": {"deployment": "rendezvous", "runs": 1}}
        spec = spec_from_table(campaign, read_table, "c.toml")
        (row,) = [x for x in stats_table(spec, [in_process]) if x.startswith("| ddvi")]
        assert row.split(" | ")[-2:] == ["1/1", "- |"]  # fell back; can hold its slot
    if history in ("never", "fallback"):
        learner = next(d.name for d in dep.deputy if d.controller != "lqr")
        sweep_md = markdown_table("noise", list(sweep_in_process.values()))
        (line,) = [x for x in sweep_md.splitlines() if f"| {learner} |" in x]
        assert line.count(f"| {NOT_LEARNED_TEXT} |") == 1 and f"{NOT_LEARNED_TEXT} |" in line
        run_md = (tmp_path / "run" / "report.md").read_text()
        (line,) = [x for x in run_md.splitlines() if x.startswith(f"| {learner} |")]
        assert line.count(NOT_LEARNED_TEXT) == 2
        campaign = {"campaign": {"deployment": "rendezvous", "runs": 1}}
        spec = spec_from_table(campaign, read_table, "c.toml")
        campaign_md = "\n".join(stats_table(spec, [in_process]))
        assert "| 0/1 |" in campaign_md  # learned: not counted, no gain error percentile


def test_a_deputy_that_cannot_hold_its_slot_is_noted_by_every_path(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    table = read_table(None)
    name = table["deputy"][0]["name"]
    table["deputy"][0]["area_factor"] = 0.5
    flights = _flight(table, "learned")
    summary = _report_summary(tmp_path, table, flights, monkeypatch)
    fake = _fake_in_process(flights, monkeypatch)
    monkeypatch.setattr(services.flight.inprocess, "run_in_process", fake)
    row, _ = campaign_run.execute({"run": 0, "seed": 1, "table": table, "mode": "inprocess"})
    (swept,) = [r for r in summary_rows({"noise": 0.0}, summary) if r["deputy"] == name]
    for can_hold, note in (
        (summary["deputies"][name]["can_hold"], summary["deputies"][name]["note"]),
        (row[f"{name}.can_hold"], row[f"{name}.note"]),
        (swept["can_hold"], swept["note"]),
    ):
        assert can_hold is False and note.startswith(f"deputy {name!r} cannot hold a slot")
    others = [d for d in summary["deputies"] if d != name]
    assert all(summary["deputies"][d]["can_hold"] for d in others)


def test_each_tables_success_is_one_named_rule_of_the_deputys_figures() -> None:
    learned = LEARNED_WITHIN_10_PERCENT
    assert learned.met(completed=True, learned=True, gain_error=0.05)
    assert not learned.met(completed=True, learned=True, gain_error=0.1)  # strictly below
    assert not learned.met(completed=True, learned=False, gain_error=0.01)  # K0 is not learned
    assert not learned.met(completed=False, learned=True, gain_error=0.01)
    assert not learned.met(completed=True, learned=None, gain_error=0.01)  # an LQR deputy
    campaign = final_error_below(100.0)
    assert campaign.name == "final error < 100 m"
    assert campaign.met(completed=True, final_m=99.9) and not campaign.met(completed=True)
    assert not campaign.met(completed=True, final_m=100.0)
    twin = AS_GOOD_AS_LQR
    assert twin.met(completed=True, final_m=9.0, lqr_final_m=1.0)  # the 10 m floor
    assert twin.met(completed=True, final_m=40.0, lqr_final_m=20.0)
    assert not twin.met(completed=True, final_m=41.0, lqr_final_m=20.0)
    assert not twin.met(completed=True, final_m=float("nan"), lqr_final_m=20.0)
    row = {
        "completed": True,
        "final_along_track_error_m": 3.0,
        "learned": True,
        "gain_error": 0.02,
    }
    assert learned.row_met(row) and not learned.row_met({**row, "gain_error": None})
