"""``ddvi campaign``'s parts that run no mission: the campaign file and its dispersions, the
per-run seeds, the result table and the report."""

from __future__ import annotations

import copy
import math
from pathlib import Path

import numpy as np
import pytest

from services.cli import main
from services.config import read_table
from services.ground.campaign import load_campaign
from services.ground.campaign import store as campaign_store
from services.ground.campaign.dispersions import (
    CampaignError,
    draw_run,
    run_stream,
    spec_from_table,
)
from services.ground.campaign.report import outcomes, write_report
from services.ground.campaign.store import ResultStore, read_rows

CAMPAIGN = {
    "campaign": {"deployment": "rendezvous", "runs": 50, "seed": 7, "success_threshold": 20.0},
    "overrides": {"run": {"orbits": 2.0}},
    "dispersion": [
        {"key": "environment.density_factor", "distribution": "uniform", "low": 0.8, "high": 1.25},
        {
            "key": "deputy[*].initial.along_track",
            "distribution": "normal",
            "mean": -29000.0,
            "std": 3000.0,
            "low": -31000.0,
            "high": -28000.0,
        },
        {
            "key": "deputy[1].navigation.position_noise",
            "distribution": "choice",
            "values": [0.0, 0.5, 1.0],
        },
        {"key": "deputy[0].y_ref", "distribution": "list", "values": [0.0, 10.0]},
        {"key": "deputy[*].learning.seed", "distribution": "seed"},
    ],
}


def spec(table: dict | None = None):
    return spec_from_table(copy.deepcopy(table or CAMPAIGN), read_table, "c.toml")


def test_draws_follow_their_distributions_and_reach_the_deployment() -> None:
    s = spec()
    draws = [draw_run(s, i) for i in range(s.campaign.runs)]
    for i, (table, values, seed) in enumerate(draws):
        assert 0.8 <= values["environment.density_factor"] <= 1.25
        assert table["environment"]["density_factor"] == values["environment.density_factor"]
        gap = values["deputy[*].initial.along_track"]
        assert -31000.0 <= gap <= -28000.0  # the normal truncated at its bounds
        for d in table["deputy"]:  # one draw for every deputy: the same initial state
            assert math.radians(d["orbit"]["f"] - 20.0) * 6678136.0 == pytest.approx(gap)
            assert "initial" not in d
        assert values["deputy[1].navigation.position_noise"] in (0.0, 0.5, 1.0)
        assert table["deputy"][0]["y_ref"] == [0.0, 10.0][i % 2]
        assert table["deputy"][0]["learning"]["seed"] == table["deputy"][1]["learning"]["seed"]
        assert table["run"]["orbits"] == 2.0 and table["run"]["seed"] == seed
    assert len({v["environment.density_factor"] for _, v, _ in draws}) == len(draws)
    assert len({v["deputy[1].navigation.position_noise"] for _, v, _ in draws}) == 3


def test_a_run_depends_on_the_campaign_seed_and_its_index_alone() -> None:
    children = np.random.SeedSequence(7).spawn(5)
    for i, child in enumerate(children):  # numpy's SeedSequence.spawn, child by child
        assert run_stream(7, i)[0].random() == np.random.default_rng(child).random()
    s, more = spec(), copy.deepcopy(CAMPAIGN)
    more["campaign"]["runs"] = 500
    assert draw_run(s, 3) == draw_run(spec(more), 3)  # more runs: the same first runs
    other = copy.deepcopy(CAMPAIGN)
    other["campaign"]["seed"] = 8
    assert draw_run(s, 3)[1] != draw_run(spec(other), 3)[1]


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"campaign": {"runz": 3}}, "campaign.runz: unknown key (did you mean 'runs'?)"),
        ({"campain": {}}, "campain: unknown key (did you mean 'campaign'?)"),
        ({"overrides": {"run": {"orbitz": 3.0}}}, "run.orbitz: unknown key (did you mean"),
        (
            {
                "dispersion": [
                    {
                        "key": "environment.density_factr",
                        "distribution": "uniform",
                        "low": 0.8,
                        "high": 1.2,
                    }
                ]
            },
            "environment.density_factr: unknown key (did you mean 'density_factor'?)",
        ),
        (
            {
                "dispersion": [
                    {
                        "key": "environment.density_factor",
                        "distribution": "uniform",
                        "lo": 0.8,
                        "high": 1.2,
                    }
                ]
            },
            "dispersion[0].lo: unknown key (did you mean 'low'?)",
        ),
        (
            {"dispersion": [{"key": "environment.density_factor", "distribution": "unifrm"}]},
            "dispersion[0].distribution: expected one of",
        ),
        (
            {"dispersion": [{"key": "deputy[4].y_ref", "distribution": "seed"}]},
            "deputy[4]: the deployment has 2 [[deputy]]",
        ),
        (
            {"dispersion": [{"key": "deputy[*].initial.alongtrack", "distribution": "seed"}]},
            "deputy[0].initial.alongtrack: unknown key",
        ),
        (
            {
                "dispersion": [
                    {
                        "key": "environment.density_factor",
                        "distribution": "uniform",
                        "low": -1.0,
                        "high": 1.2,
                    }
                ]
            },
            "dispersion[0] (environment.density_factor): environment.density_factor: ",
        ),
        (
            {
                "dispersion": [
                    {"key": "run.mode", "distribution": "choice", "values": ["lockstep", "fast"]}
                ]
            },
            "run.mode: expected",
        ),
        (
            {
                "dispersion": [
                    {"key": "environment.density_factor", "distribution": "normal", "mean": 1.0}
                ]
            },
            "dispersion[0].std: required by a normal",
        ),
    ],
)
def test_a_bad_campaign_names_the_key(change: dict, message: str) -> None:
    table = {**copy.deepcopy(CAMPAIGN), **change}
    with pytest.raises(CampaignError) as err:
        spec(table)
    assert message in str(err.value)
    assert "\n" not in str(err.value)


def test_the_cli_refuses_a_bad_campaign_in_one_line(tmp_path: Path, capsys) -> None:
    bad = tmp_path / "c.toml"
    bad.write_text('[campaign]\ndeployment = "rendezvous"\nrunz = 3\n')
    assert main(["campaign", str(bad)]) == 2
    err = capsys.readouterr().err.strip()
    assert err == (
        f"ddvi campaign: {bad}: campaign.runz: unknown key (did you mean 'runs'?); "
        "allowed: deployment, runs, seed, success_threshold, name"
    )


def test_the_shipped_campaign_is_the_default_mission_dispersed() -> None:
    path = Path(__file__).parents[2] / "deployments" / "campaigns" / "rendezvous-200.toml"
    s = load_campaign(str(path))
    assert s.campaign.runs == 200
    assert s.base == read_table("rendezvous")
    keys = {d.key: d for d in s.dispersions}
    assert (keys["environment.density_factor"].low, keys["environment.density_factor"].high) == (
        0.8,
        1.25,
    )
    assert keys["deputy[*].navigation.position_noise"].high == 1.0
    assert "deputy[*].initial.along_track" in keys


def _row(s, i: int, final: float | None, completed: bool = True) -> dict:
    _, values, seed = draw_run(s, i)
    row = {"run": i, "seed": seed, "completed": completed, "error": None if completed else "boom"}
    for name, ctrl in (("lqr", "lqr"), ("ddvi", "ddvi value-iteration")):
        row |= {
            f"{name}.controller": ctrl,
            f"{name}.final_error_m": final,
            f"{name}.last_orbit_max_error_m": final,
            f"{name}.gain_error": 0.01,
            f"{name}.learned_at_orbits": 15.0 if name == "ddvi" else None,
            f"{name}.fallback_at_orbits": None,
            f"{name}.learned": True if name == "ddvi" else None,
            f"{name}.gain_error_vs_lqr": 0.01 if name == "ddvi" else None,
            f"{name}.can_hold": True,
            f"{name}.note": None,
        }
    return row | values


def test_the_table_resumes_only_its_own_campaign(tmp_path: Path) -> None:
    s, path = spec(), tmp_path / "results.sqlite"
    store = ResultStore.open(path, s, "inprocess", resume=False)
    store.write(_row(s, 1, 3.0), {"run": 1, "wall_s": 0.5, "worker": "w"})
    store.close()
    with pytest.raises(CampaignError, match="already holds 1 finished runs: --resume"):
        ResultStore.open(path, s, "inprocess", resume=False)
    with pytest.raises(CampaignError, match="another campaign's runs"):
        ResultStore.open(path, s, "distributed", resume=True)
    with pytest.MonkeyPatch.context() as mp:  # rows that mean something else: not mixed in
        mp.setattr(campaign_store, "ROWS_VERSION", campaign_store.ROWS_VERSION + 1)
        with pytest.raises(CampaignError, match="another campaign's runs"):
            ResultStore.open(path, s, "inprocess", resume=True)
    more = copy.deepcopy(CAMPAIGN)
    more["campaign"]["runs"] = 80  # more runs extend the same campaign
    store = ResultStore.open(path, spec(more), "inprocess", resume=True)
    assert store.done() == {1}
    store.close()
    rows = read_rows(path)
    assert rows == [_row(s, 1, 3.0) | {"completed": 1}]
    assert read_rows(path, "timing") == [{"run": 1, "wall_s": 0.5, "worker": "w"}]


@pytest.mark.integration  # draws every figure of a campaign report
def test_the_report_counts_successes_and_lists_the_worst_runs(tmp_path: Path) -> None:
    s = spec()
    rows = [_row(s, i, float(i)) for i in range(30)] + [_row(s, 30, None, completed=False)]
    oc = outcomes(rows, s.campaign.success_threshold)
    assert sum(o["success"] for o in oc if o["controller"] == "lqr") == 20  # final < 20 m
    report = write_report(s, tmp_path, rows, "inprocess").read_text()
    assert "| lqr | 31 | 20/31 (64.5%) |" in report
    assert "| ddvi value-iteration | 31 | 20/31 (64.5%) |" in report and "| 31/31 |" in report
    assert (tmp_path / "final_error.png").stat().st_size > 10_000
    assert (tmp_path / "scatter.png").stat().st_size > 10_000
    worst = report.split("## Worst runs")[1]
    # the failed run first, then the largest final errors, each with its command
    lines = [x for x in worst.splitlines() if x.startswith("| lqr |")]
    assert [x.split(" | ")[1] for x in lines] == ["30", "29", "28", "27", "26"]
    assert f"`ddvi campaign c.toml --only-run 29 --output {tmp_path}`" in lines[1]
    assert "- run 30: boom" in report


def test_a_failed_mission_is_a_row_with_its_error(monkeypatch: pytest.MonkeyPatch) -> None:
    from services.ground.campaign import run as campaign_run

    def explode(dep):
        raise FloatingPointError("the truth diverged")

    monkeypatch.setattr(campaign_run, "inprocess_metrics", explode)
    table, _, seed = draw_run(spec(), 4)
    row, timing = campaign_run.execute(
        {"run": 4, "seed": seed, "table": table, "mode": "inprocess"}
    )
    assert row == {"run": 4, "seed": seed, "completed": False, "error": row["error"]}
    assert row["error"].startswith("FloatingPointError: the truth diverged (test_campaign.py:")
    assert timing["run"] == 4 and timing["wall_s"] >= 0


def test_a_run_gives_the_same_row_twice() -> None:
    from services.ground.campaign.run import execute

    table, _, seed = draw_run(spec(), 1)
    table["run"]["orbits"] = 0.3
    table["deputy"][1]["navigation"]["position_noise"] = 1.0
    task = {"run": 1, "seed": seed, "table": table, "mode": "inprocess"}
    first, second = execute(task)[0], execute(task)[0]
    assert first == second and first["completed"], first["error"]
    assert first["lqr.gain_error"] > 0  # the truth's density is not the nominal one


def test_a_campaign_tells_the_learners_apart() -> None:
    """Deputies are grouped by controller and learning method: the model-fit learner's runs
    are not counted with the paper's value iteration's."""
    from services.ground.campaign.run import execute

    path = Path(__file__).parents[2] / "deployments" / "campaigns" / "realistic-nav-20.toml"
    s = load_campaign(str(path))
    table, _, seed = draw_run(s, 0)
    table["run"]["orbits"] = 0.2
    row, _ = execute({"run": 0, "seed": seed, "table": table, "mode": "inprocess"})
    labels = [row[f"{name}.controller"] for name in ("lqr", "ddvi", "fit")]
    assert labels == ["lqr", "ddvi value-iteration", "ddvi model-fit"]
    groups = {o["controller"] for o in outcomes([row], s.campaign.success_threshold)}
    assert groups == set(labels)


def test_a_campaign_says_up_front_which_runs_are_predicted_to_reenter() -> None:
    """At five times the nominal density the default mission's chief is predicted to re-enter
    before orbit 40: each drawn run at that density is said, or the base deployment once."""
    from services.ground.campaign import command as campaign

    table = copy.deepcopy(CAMPAIGN)
    table["overrides"] = {"run": {"orbits": 40.0}}
    table["dispersion"] = [
        {"key": "environment.density_factor", "distribution": "choice", "values": [1.0, 5.0]}
    ]
    s = spec(table)
    tasks = {i: campaign.task(s, i, "inprocess") for i in range(6)}
    dense = [i for i, t in tasks.items() if t["values"]["environment.density_factor"] == 5.0]
    lines = campaign.holding_lines(s, tasks)
    assert [int(x.split(":")[0].removeprefix("run ")) for x in lines] == dense and dense
    assert all("the chief is predicted to re-enter" in x for x in lines)
    table["dispersion"] = []
    table["overrides"]["environment"] = {"density_factor": 5.0}
    s_base = spec(table)
    tasks = {i: campaign.task(s_base, i, "inprocess") for i in range(6)}
    (line,) = campaign.holding_lines(s_base, tasks)
    assert line.startswith("the base deployment: the chief is predicted to re-enter")


def test_a_campaign_says_up_front_which_deputies_cannot_hold_their_slot(
    tmp_path: Path, capsys: pytest.CaptureFixture, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A base deployment no attitude can hold is said once; else each drawn run that cannot,
    before it runs."""
    from services.ground.campaign import command as campaign

    table = copy.deepcopy(CAMPAIGN)
    table["dispersion"].append(
        {"key": "deputy[0].area_factor", "distribution": "choice", "values": [1.0, 0.5]}
    )
    s = spec(table)
    tasks = {i: campaign.task(s, i, "inprocess") for i in range(6)}
    halved = [i for i, t in tasks.items() if t["values"]["deputy[0].area_factor"] == 0.5]
    lines = campaign.holding_lines(s, tasks)
    assert [int(x.split(":")[0].removeprefix("run ")) for x in lines] == halved and halved
    assert all("deputy 'lqr' cannot hold a slot" in x for x in lines)
    s_base = spec()
    s_base.base["deputy"][0]["area_factor"] = 0.5  # every run's
    tasks = {i: campaign.task(s_base, i, "inprocess") for i in range(6)}
    (line,) = campaign.holding_lines(s_base, tasks)
    assert line.startswith("the base deployment: deputy 'lqr' cannot hold a slot")

    said = []

    def execute(t):  # what was said before the run ran
        said.append(capsys.readouterr().err)
        return {"run": t["run"], "seed": t["seed"], "completed": True, "error": None}, {
            "run": t["run"],
            "wall_s": 0.0,
            "worker": "w",
        }

    monkeypatch.setattr(campaign, "execute", execute)
    assert campaign.only_run(s, tmp_path, halved[0], "inprocess") == 0
    assert said == [f"ddvi campaign: warning: {lines[0]}\n"]
