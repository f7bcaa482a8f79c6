"""The run report scores gains against the optimal gain of the truth's linear model (true K*),
with the nominal LQR gain in its own column."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from services.config import load_deployment
from services.ground.analysis.report import write_report
from services.ground.analysis.rundata import GainRecord, RunData, StatusRecord
from services.model import lqr_gains, true_lqr_gains

# no truth samples: the position figures have no line to label
pytestmark = pytest.mark.filterwarnings("ignore:No artists with labels")


def _flown(deployment: str, learned: np.ndarray) -> RunData:
    """A run of ``deployment`` in which the LQR deputy flew its gain from the start and the
    learning deputy switched from K0 to ``learned`` (1, 4) at orbit 1."""
    dep = load_deployment(deployment)
    data = RunData(dep, "reference")
    K_lqr, L_lqr = lqr_gains(dep, dep.deputy_named("lqr"))
    lqr, ddvi = data.sc("lqr"), data.sc("ddvi")
    lqr.gains.append(GainRecord(0.0, K_lqr.tolist(), L_lqr.tolist(), "lqr", 0, True))
    L0 = np.zeros((1, 5)).tolist()
    ddvi.gains.append(GainRecord(0.0, [[-0.023, 0.0, 0.0, -10.0]], L0, "initial", 0, False))
    ddvi.gains.append(GainRecord(data.period, learned.tolist(), L0, "ddvi", 9, True))
    ddvi.status.append(StatusRecord(data.period, {"phase": "learned"}))
    return data


def _report(tmp_path: Path, data: RunData) -> tuple[dict, str]:
    summary = write_report(tmp_path, data, completed=False, monitor_counters={})
    assert json.loads((tmp_path / "summary.json").read_text())["deputies"].keys() == {
        "lqr",
        "ddvi",
    }
    return summary["deputies"], (tmp_path / "report.md").read_text()


def test_a_learner_that_learns_the_truth_scores_zero_in_a_mismatch_run(tmp_path: Path) -> None:
    dep = load_deployment("mismatch-2x")
    K_true, L_true = true_lqr_gains(dep, dep.deputy_named("ddvi"))
    K_lqr = lqr_gains(dep, dep.deputy_named("ddvi"))[0]
    deputies, markdown = _report(tmp_path, _flown("mismatch-2x", K_true))
    ddvi, lqr = deputies["ddvi"], deputies["lqr"]
    assert ddvi["gain_error_vs_true_optimum"] == pytest.approx(0.0, abs=1e-12)
    # against the nominal gain it would be scored as 40% wrong
    off = np.linalg.norm(K_true - K_lqr) / np.linalg.norm(K_lqr)
    assert ddvi["gain_error_vs_lqr"] == pytest.approx(off) and off > 0.3
    assert ddvi["learned_at_orbits"] == pytest.approx(1.0)
    np.testing.assert_allclose(ddvi["true_optimal_gains"]["K"], K_true)
    np.testing.assert_allclose(ddvi["true_optimal_gains"]["L"], L_true)
    # the LQR deputy flies the nominal gain: 68% off the truth's optimum
    assert lqr["gain_error_vs_true_optimum"] == pytest.approx(0.68, abs=0.02)
    assert lqr["gain_error_vs_lqr"] is None
    assert "optimal gain K* of the truth's linear model" in markdown
    assert "| gain error | gain error vs nominal LQR |" in markdown
    assert (tmp_path / "gains.png").stat().st_size > 0


def test_in_a_nominal_run_both_references_agree(tmp_path: Path) -> None:
    dep = load_deployment("rendezvous")
    K_lqr = lqr_gains(dep, dep.deputy_named("ddvi"))[0]
    deputies, _ = _report(tmp_path, _flown("rendezvous", K_lqr * 1.01))
    ddvi = deputies["ddvi"]
    assert ddvi["gain_error_vs_true_optimum"] == pytest.approx(0.01, rel=1e-9)
    assert ddvi["gain_error_vs_lqr"] == pytest.approx(0.01, rel=1e-9)
    assert deputies["lqr"]["gain_error_vs_true_optimum"] == 0.0
