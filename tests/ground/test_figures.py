"""The run report's figures, read through matplotlib's objects (axes, labels, scales, legends,
titles, footers): drawn from a run with known gains, phases and commands, and from a short run
through ``ddvi run``, its report's data read again from its recording."""

from __future__ import annotations

import json
import math
import re
import struct
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from matplotlib.axes import Axes
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Rectangle

from ddvi_core.constants import MU_EARTH
from services.config import load_deployment
from services.ground.analysis.figure_canvas import COMMANDS, FIGURES, GAINS, TRUE_STATE
from services.ground.analysis.figures import ENDGAME_SHARE, draw_figures, exploring_spans
from services.ground.analysis.gain_figure import K_NAMES, K_UNITS, L_NAMES
from services.ground.analysis.report import deputy_series
from services.ground.analysis.rundata import GainRecord, RunData, StatusRecord
from services.model import lqr_gains, true_lqr_gains

RUN = "figures-20260101-000000-1"
STEP = 60.0
LEARN_ORBITS = 2.0  # the learner explores on K0 until then, and flies its learned gain after
CLOSING = 5.0  # a deputy closes on its slot as exp(-CLOSING t / the run)


def _circular(theta: float, a: float, inc: float) -> list[float]:
    """A circular orbit's inertial state [r, v] at argument of latitude ``theta``."""
    c, s = math.cos(theta), math.sin(theta)
    r = a * np.array([c, s * math.cos(inc), s * math.sin(inc)])
    v = math.sqrt(MU_EARTH / a) * np.array([-s, c * math.cos(inc), c * math.sin(inc)])
    return [*r, *v]


def flown(deployment: str, orbits: float, learned_off: float, holding: str = "") -> RunData:
    """A run of ``deployment`` over ``orbits``: the deputies close from 10 km behind the chief
    to their slot (y_ref) on a circular orbit 100 m above, but the one named ``holding``, which
    stays 10 km behind; the LQR deputy flies its gain from the start; the learner explores on
    K0 until ``LEARN_ORBITS``, then flies K* (1 + ``learned_off``), and L*; every step commands
    a sigma3 inside the attitude limit."""
    dep = load_deployment(deployment)
    data = RunData(dep, RUN)
    P = data.period
    a, inc = dep.chief.a, math.radians(dep.chief.i)
    n = math.sqrt(MU_EARTH / a**3)
    end = orbits * P
    for t in np.arange(0.0, end + 1e-6, STEP):
        data.sc("chief").truth.add(t, _circular(n * t, a, inc))
        for d in dep.deputy:
            closing = 1.0 if d.name == holding else math.exp(-CLOSING * t / end)
            behind = (10_000.0 - d.y_ref) * closing + d.y_ref
            data.sc(d.name).truth.add(t, _circular(n * t - behind / a, a + 100.0, inc))
            sigma3 = d.attitude_limit * math.sin(t / 300.0)
            data.sc(d.name).cmd.add(t, [0.0, 0.0, sigma3])
    data.sim_t = end
    for d in dep.deputy:
        craft = data.sc(d.name)
        K, L = lqr_gains(dep, d)
        if d.controller == "lqr":
            craft.gains.append(GainRecord(0.0, K.tolist(), L.tolist(), "lqr", 0, True))
            craft.status.append(StatusRecord(0.0, {"phase": "lqr"}))
            continue
        K_true, L_true = true_lqr_gains(dep, d)
        K0, L0 = [list(d.learning.K0)], np.zeros((1, 5)).tolist()
        craft.gains.append(GainRecord(0.0, K0, L0, "initial", 0, False))
        learned = (K_true * (1.0 + learned_off)).tolist()
        craft.gains.append(GainRecord(LEARN_ORBITS * P, learned, L_true.tolist(), "ddvi", 9, True))
        craft.status.append(StatusRecord(0.0, {"phase": "exploring"}))
        craft.status.append(StatusRecord(LEARN_ORBITS * P, {"phase": "learned"}))
    return data


@pytest.fixture(scope="module")
def mismatched() -> dict[str, Figure]:
    """The figures of mismatch-2x (its K* is not the nominal LQR gain) over 4 orbits, the
    learner 0.3 % off K*."""
    data = flown("mismatch-2x", 4.0, 0.003)
    return draw_figures(data, deputy_series(data))


def legend_texts(ax: Axes | Figure) -> list[str]:
    got = ax.get_legend() if isinstance(ax, Axes) else ax.legends[0]
    assert got is not None
    return [t.get_text() for t in got.get_texts()]


def labelled(ax: Axes, label: str) -> Line2D:
    """The one line of ``ax`` with ``label``."""
    lines = [line for line in ax.get_lines() if line.get_label() == label]
    assert len(lines) == 1, [line.get_label() for line in ax.get_lines()]
    return lines[0]


def check_titles_and_footers(figures: dict[str, Figure], run: str) -> None:
    """Every figure: its short title (no run name in it), the run in the footer beside what it
    plots, true state or commands or gains."""
    assert set(figures) == set(FIGURES)
    for name, fig in figures.items():
        assert fig._suptitle is not None
        title = fig._suptitle.get_text()
        assert title == FIGURES[name].title and run not in title and len(title) <= 25
        footer = {t.get_gid(): t.get_text() for t in fig.texts}
        assert footer["run"] == f"run {run}", name
        shows = {"sigma3.png": COMMANDS, "gains.png": GAINS}.get(name, TRUE_STATE)
        assert footer["shows"] == shows, name
    assert "true state" in TRUE_STATE and "navigated state" in COMMANDS


def test_every_figure_has_a_short_title_and_its_run_and_state_in_the_footer(
    mismatched: dict[str, Figure],
) -> None:
    check_titles_and_footers(mismatched, RUN)


def test_legends_name_each_deputy_plainly(mismatched: dict[str, Figure]) -> None:
    for name in ("hill_x.png", "hill_xdot.png", "hill_ydot.png", "along_track_error.png"):
        (ax,) = mismatched[name].axes
        assert legend_texts(ax) == ["lqr", "ddvi"], name
        assert ax.get_xlabel() == "time [orbits]"
    (ax,) = mismatched["along_track_error.png"].axes
    assert ax.get_yscale() == "log" and ax.get_ylabel() == "|y - y_ref| [m]"


def test_gains_show_K_and_L_against_the_optimum_and_the_relative_error_on_a_log_scale(
    mismatched: dict[str, Figure],
) -> None:
    fig = mismatched["gains.png"]
    *elements, error = fig.axes
    assert [ax.get_title() for ax in elements] == [
        *(f"K[{n}] [{u}]" for n, u in zip(K_NAMES, K_UNITS, strict=True)),
        *(f"L[{n}] [-]" for n in L_NAMES),
    ]
    # K* (dotted black) and the nominal LQR gain (dashed grey) are two lines a reader tells apart
    assert legend_texts(fig) == ["ddvi", "K*, L* (the truth's)", "nominal LQR"]
    for c, ax in enumerate(elements):
        optimum, nominal = labelled(ax, "K*, L* (the truth's)"), labelled(ax, "nominal LQR")
        assert (optimum.get_linestyle(), nominal.get_linestyle()) == (":", "--")
        assert optimum.get_color() != nominal.get_color()
        flown = labelled(ax, "ddvi").get_ydata()
        # K0 (L = 0) while exploring, then the learned gain: K 0.3 % off K*, L* itself
        off = 1.003 if c < len(K_NAMES) else 1.0
        assert flown[-1] == pytest.approx(optimum.get_ydata()[0] * off, rel=1e-9)
    assert error.get_yscale() == "log" and error.get_xlabel() == "time [orbits]"
    assert error.get_ylabel() == "relative error [-]"
    texts = legend_texts(error)
    assert texts[0] == "ddvi: |K - K*|/|K*|, 0.003 at the end"
    assert texts[1].startswith("ddvi: |L - L*|/|L*|, ")
    # the LQR deputy's nominal gain is as far from K* as the model is wrong
    assert texts[2].startswith("lqr: nominal LQR |K - K*|/|K*|")
    k_error = labelled(error, texts[0])
    assert k_error.get_ydata()[-1] == pytest.approx(0.003, rel=1e-6)
    assert k_error.get_xdata()[1] == pytest.approx(LEARN_ORBITS)
    assert labelled(error, texts[2]).get_ydata()[0] > 0.3


def test_gains_of_a_nominal_truth_draw_one_reference_and_no_zero_relative_L_error() -> None:
    data = flown("rendezvous", 3.0, 0.01)
    fig = draw_figures(data, deputy_series(data))["gains.png"]
    assert legend_texts(fig) == ["ddvi", "K*, L* = nominal LQR"]
    # L* is zero where the truth is nominal: no relative L error, no nominal LQR line
    assert legend_texts(fig.axes[-1]) == ["ddvi: |K - K*|/|K*|, 0.01 at the end"]


def test_sigma3_marks_the_exploration_the_learning_and_the_attitude_limit(
    mismatched: dict[str, Figure],
) -> None:
    (ax,) = mismatched["sigma3.png"].axes
    assert ax.get_ylabel() == "commanded sigma3 [-]"
    assert legend_texts(ax) == ["lqr", "ddvi", "ddvi exploring", "ddvi learned", "attitude limit"]
    (window,) = [p for p in ax.patches if p.get_label() == "ddvi exploring"]
    assert isinstance(window, Rectangle)
    assert window.get_x() == 0.0 and window.get_width() == pytest.approx(LEARN_ORBITS)
    assert labelled(ax, "ddvi learned").get_xdata()[0] == pytest.approx(LEARN_ORBITS)
    limit = load_deployment("mismatch-2x").deputy_named("ddvi").attitude_limit
    limits = [line.get_ydata()[0] for line in ax.get_lines() if line.get_linestyle() == ":"]
    assert sorted(limits) == [-limit, limit]


def test_the_trajectory_marks_the_chief_and_the_slot_and_shows_the_last_orbit(
    mismatched: dict[str, Figure],
) -> None:
    whole, last = mismatched["hill_xy.png"].axes
    assert (whole.get_title(), last.get_title()) == ("whole run", "last orbit")
    for ax in (whole, last):
        assert ax.get_xlabel() == "y (along-track) [m]" and ax.get_ylabel() == "x (radial) [m]"
        assert list(labelled(ax, "chief").get_xydata()[0]) == [0.0, 0.0]
        assert list(labelled(ax, "slot").get_xydata()[0]) == [0.0, 0.0]  # y_ref = 0
    assert legend_texts(whole) == ["lqr", "ddvi", "slot", "chief"]
    data_whole, data_last = (labelled(ax, "ddvi").get_xdata() for ax in (whole, last))
    period = RunData(load_deployment("mismatch-2x"), RUN).period
    assert len(data_last) == sum(t >= 4.0 * period - period for t in np.arange(0, 4 * period, STEP))
    # the whole run starts 10 km behind; its last orbit ends 67 m behind
    assert data_whole[0] == pytest.approx(-10_000.0, rel=0.01)
    assert data_last[-1] == pytest.approx(-10_000.0 * math.exp(-CLOSING), rel=0.01)


def test_the_along_track_position_has_an_end_game_panel(mismatched: dict[str, Figure]) -> None:
    whole, end = mismatched["hill_y.png"].axes
    assert whole.get_ylabel() == "y [m]" and end.get_ylabel() == "y - y_ref [m]"
    shown = max(ENDGAME_SHARE * 4.0, 1.0)  # at least an orbit
    assert end.get_title() == f"end game: the last {shown:.3g} orbits"
    assert legend_texts(whole) == ["lqr", "ddvi", "slot", "end game (below)"]
    t = labelled(end, "ddvi").get_xdata()
    step = STEP / RunData(load_deployment("mismatch-2x"), RUN).period
    assert 4.0 - shown <= t[0] <= 4.0 - shown + step and t[-1] == pytest.approx(4.0, abs=step)


def test_a_deputy_far_from_its_slot_does_not_hide_the_others_end_game() -> None:
    """The end game and the last orbit scale to the deputies near their slots; the learner
    still 10 km behind is drawn beyond that view and named in it."""
    data = flown("rendezvous", 4.0, 0.01, holding="ddvi")
    figures = draw_figures(data, deputy_series(data))
    _, end = figures["hill_y.png"].axes
    _, last = figures["hill_xy.png"].axes
    for ax, limits in ((end, end.get_ylim()), (last, last.get_xlim())):
        # the LQR deputy closes from 235 m to 67 m behind in the view; the learner stays far
        assert -300.0 < limits[0] < -200.0 and limits[1] < 100.0, limits
        (note,) = ax.texts
        assert note.get_text() == "beyond this view: ddvi (10 km from its slot)"
    assert list(labelled(last, "chief").get_xydata()[0]) == [0.0, 0.0]


DOCS = Path(__file__).resolve().parents[2] / "docs"


def test_the_documented_figures_are_every_figure_of_both_missions(
    mismatched: dict[str, Figure],
) -> None:
    """docs/figures.md shows every figure of the default mission and realistic-nav, each run
    stated with its command and commit, each PNG the size the figure code draws."""
    text = (DOCS / "figures.md").read_text()
    for command in ("`ddvi run` (defaults", "`ddvi run realistic-nav`"):
        assert re.search(re.escape(command) + r"[^\n]* at commit [0-9a-f]{7}\b", text), command
    for mission in ("rendezvous", "realistic-nav"):
        for name, fig in mismatched.items():
            assert f"](figures/{mission}/{name})" in text, (mission, name)
            png = (DOCS / "figures" / mission / name).read_bytes()
            assert png[:8] == b"\x89PNG\r\n\x1a\n"
            width, height = struct.unpack(">II", png[16:24])  # the IHDR chunk's first fields
            drawn = fig.get_size_inches() * fig.dpi
            assert (width, height) == (round(drawn[0]), round(drawn[1])), (mission, name)
    assert "[figures.md](figures.md)" in (DOCS / "results.md").read_text()


def test_a_run_with_no_truth_draws_every_figure_without_lines() -> None:
    data = RunData(load_deployment("rendezvous"), RUN)
    figures = draw_figures(data, deputy_series(data))
    check_titles_and_footers(figures, RUN)
    (ax,) = figures["hill_x.png"].axes
    assert ax.get_legend() is None


SHORT = """
[run]
name = "figs"
orbits = 1.5
command_deadline = 20.0
[[deputy]]
name = "lqr"
controller = "lqr"
[[deputy]]
name = "fit"
controller = "ddvi"
[deputy.learning]
method = "model-fit"
data_from_orbits = 0.1
learn_at_orbits = 1.0
retry_orbits = 0.1
learn_until_orbits = 1.4
interval = 600.0
fit_stride = 10.0
fit_tolerance = 0.15
fit_deadline_orbits = 0.0
validation_orbits = 0.0
feedforward_modes = "static"
feedforward_significance = 0.01
refresh_orbits = 2.0
trim_orbits = 0.0
station_radius = 1000.0
exploration_amplitude = 0.2
K0 = [-0.023, 0.0, 0.0, -10.0]
"""
"""The LQR and the model-fit learner for 1.5 orbits, the learner learning after one (from
0.9 orbits of data: a gain far from K*, which is what its figures must show)."""


@pytest.mark.integration
def test_the_figures_of_a_short_run_from_its_report_data(tmp_path: Path) -> None:
    """`ddvi run` of a 1.5-orbit mission: its report's figures drawn again from the data read
    from its recording, each read through matplotlib, agree with its summary."""
    from services.ground.analysis.recover import run_data

    path = tmp_path / "short.toml"
    path.write_text(SHORT)
    cmd = [sys.executable, "-m", "services.cli", "run", str(path), "--quiet"]
    r = subprocess.run(
        [*cmd, "--output", str(tmp_path / "runs")], capture_output=True, text=True, timeout=120
    )
    assert r.returncode == 0, r.stderr[-3000:]
    folder = Path(r.stdout.strip().splitlines()[-1])
    summary: dict[str, Any] = json.loads((folder / "summary.json").read_text())
    assert set(summary["figures"]) == set(FIGURES)
    fit = summary["deputies"]["fit"]
    assert fit["learned"] is True, fit["note"]
    data = run_data(folder)
    figures = draw_figures(data, deputy_series(data))
    check_titles_and_footers(figures, summary["run"])
    (ax,) = figures["sigma3.png"].axes
    learner = "fit (ddvi model-fit)"
    assert legend_texts(ax) == ["lqr", learner, "fit exploring", "fit learned", "attitude limit"]
    # the learner explores from the start to its learning
    (window,) = [p for p in ax.patches if p.get_label() == "fit exploring"]
    assert window.get_x() == 0.0
    assert window.get_width() == pytest.approx(fit["learned_at_orbits"], rel=1e-9)
    assert labelled(ax, "fit learned").get_xdata()[0] == pytest.approx(fit["learned_at_orbits"])
    # the gain error the figure ends with is the one the report scores
    *_, error = figures["gains.png"].axes
    texts = legend_texts(error)
    said = f"{learner}: |K - K*|/|K*|, {fit['gain_error_vs_true_optimum']:.2g} at the end"
    assert error.get_yscale() == "log" and texts[0] == said
    assert labelled(error, said).get_ydata()[-1] == pytest.approx(
        fit["gain_error_vs_true_optimum"], rel=1e-9
    )
    whole, last = figures["hill_xy.png"].axes
    assert legend_texts(whole) == ["lqr", learner, "slot", "chief"]
    final = summary["deputies"]["lqr"]["final_along_track_error_m"]
    assert abs(labelled(last, "lqr").get_xdata()[-1]) == pytest.approx(final, rel=1e-9)


def test_the_exploring_spans_are_those_of_gains_not_converged_on_k0_or_on_the_fallback() -> None:
    """K0 from 0 to its fallback at 100 s, the fallback explored on from 200 s, a gain learned
    at 300 s: two spans, whatever the gains' source."""
    K, L = [[0.0] * 4], [[0.0] * 5]
    gains = [
        GainRecord(0.0, K, L, "initial", 0, False),
        GainRecord(60.0, K, L, "initial", 0, False),
        GainRecord(100.0, K, L, "lqr", 0, True),
        GainRecord(200.0, K, L, "lqr", 0, False),
        GainRecord(300.0, K, L, "model-fit", 0, True),
        GainRecord(400.0, K, L, "lqr", 0, False),
    ]
    assert exploring_spans(gains, 500.0) == [(0.0, 100.0), (200.0, 300.0), (400.0, 500.0)]
