"""The run report's figures: the paper's plots, one line per deputy (matplotlib, Agg backend).

``write_figures`` draws every figure of ``FIGURES`` into the run folder, one function each;
matplotlib is imported when the figures are drawn, not when this module is.
"""

from __future__ import annotations

import io
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from services.ground.analysis.rundata import CraftData, DeputySeries, FloatArray, RunData

K_NAMES = ("x", "y", "xdot", "ydot")  # the in-plane state the gain K acts on (mission.IN_PLANE)
K_UNITS = ("1/m", "1/m", "s/m", "s/m")  # u = sigma3 (an MRP, no unit) per unit of that state
FIGURES = {
    "hill_x.png": "Hill x (radial) position vs orbits",
    "hill_y.png": "Hill y (along-track) position vs orbits",
    "hill_xy.png": "Hill x vs y",
    "hill_xdot.png": "Hill x velocity vs orbits",
    "hill_ydot.png": "Hill y velocity vs orbits",
    "sigma3.png": "Commanded relative MRP sigma3 vs orbits",
    "gains.png": "Learned gain K vs orbits, true optimum K* dotted, nominal LQR gain dashed",
    "along_track_error.png": "|y - y_ref| vs orbits (log scale)",
}
"""Figure file name -> its title (after the run's name) and its line in report.md."""

# fixed margins: a layout engine (tight or constrained) costs about as much as drawing
MARGINS = {"left": 0.12, "right": 0.97, "bottom": 0.11, "top": 0.92}

Curve = Callable[[DeputySeries], tuple[FloatArray, FloatArray]]
"""A deputy's curve: (t (N,) in s, y (N,))."""


Save = Callable[[str, bytes], bool]
"""Writes a figure's PNG bytes under its file name; whether it was written."""


@dataclass
class Canvas:
    """What every figure of a run shares: the folder, the run, its deputies' series, pyplot,
    how a figure is saved, and the files written so far (deputy j draws in colour j of the
    colour cycle)."""

    out: Path
    data: RunData
    series: list[DeputySeries]
    plt: Any
    write: Save
    written: list[str] = field(default_factory=list)

    def color(self, j: int) -> str:
        colors = self.plt.rcParams["axes.prop_cycle"].by_key()["color"]
        return colors[j % len(colors)]

    def title(self, name: str) -> str:
        return f"{self.data.run}: {FIGURES[name]}"

    def save(self, fig: Any, name: str) -> None:
        png = io.BytesIO()  # drawn whole first: on a full disk no part of a figure is left
        fig.savefig(png, dpi=110, format="png")
        self.plt.close(fig)
        if self.write(name, png.getvalue()):
            self.written.append(name)


def legend(ax: Any) -> None:
    """The axes' legend, when it has a labelled line (a run that failed early may have none:
    no legend then, and no matplotlib warning)."""
    if ax.get_legend_handles_labels()[0]:
        ax.legend(loc="best", fontsize="small")


def line_figure(
    canvas: Canvas,
    name: str,
    ylabel: str,
    curve: Curve,
    log_y: bool = False,
    refs: bool = False,
    steps: bool = False,
) -> None:
    """One curve per deputy against time in orbits; ``refs``: each deputy's y_ref dotted;
    ``steps``: drawn as a zero-order hold."""
    # room for log labels like 3.075x10^4 (a span under a decade)
    margins = {**MARGINS, "left": 0.16} if log_y else MARGINS
    fig, ax = canvas.plt.subplots(figsize=(8, 4.5), gridspec_kw=margins)
    P = canvas.data.period
    for j, s in enumerate(canvas.series):
        t, y = curve(s)
        if len(t):
            style = "steps-post" if steps else "default"
            ax.plot(t / P, y, color=canvas.color(j), lw=1.0, label=s.label, ds=style)
            if refs:
                ax.axhline(s.deputy.y_ref, color=canvas.color(j), ls=":", lw=0.8)
    if log_y:
        ax.set_yscale("log")
    ax.set_xlabel("time [orbits]")
    ax.set_ylabel(ylabel)
    ax.set_title(canvas.title(name))
    ax.grid(True, alpha=0.3)
    legend(ax)
    canvas.save(fig, name)


def hill_xy_figure(canvas: Canvas) -> None:
    """Radial against along-track position, a dot at each deputy's last position."""
    fig, ax = canvas.plt.subplots(figsize=(6, 6), gridspec_kw=MARGINS)
    for j, s in enumerate(canvas.series):
        if len(s.t):
            ax.plot(s.hill[:, 1], s.hill[:, 0], color=canvas.color(j), lw=1.0, label=s.label)
            ax.plot(s.hill[-1, 1], s.hill[-1, 0], "o", color=canvas.color(j))
    ax.set_xlabel("y (along-track) [m]")
    ax.set_ylabel("x (radial) [m]")
    ax.set_title(canvas.title("hill_xy.png"))
    ax.grid(True, alpha=0.3)
    legend(ax)
    canvas.save(fig, "hill_xy.png")


def _show_references(ax: Any, values: list[float]) -> None:
    """Widen the y axis to the reference lines' ``values``, with a margin (axhline takes no
    part in autoscaling: a reference just beside the learned gain would sit on the frame)."""
    if not values:
        return
    lo, hi = ax.get_ylim()
    lo, hi = min(lo, *values), max(hi, *values)
    pad = 0.06 * (hi - lo) if hi > lo else 0.06 * abs(hi) or 1.0
    ax.set_ylim(lo - pad, hi + pad)


def gains_figure(canvas: Canvas) -> None:
    """One panel per element of K (1, 4): every learning deputy's flown gain as steps, held to
    the end of the run, its nominal LQR gain dashed and the optimal gain K* of the truth's
    linear model dotted (the reference its gain error is scored against; the two lines are
    one when the truth is nominal)."""
    data = canvas.data
    P = data.period
    fig, axes = canvas.plt.subplots(
        2,
        2,
        figsize=(10, 6.5),
        sharex=True,
        gridspec_kw={**MARGINS, "top": 0.89, "hspace": 0.25, "wspace": 0.32},
    )
    learners = [(j, s) for j, s in enumerate(canvas.series) if s.deputy.controller == "ddvi"]
    for c, ax in enumerate(axes.flat):
        refs: list[float] = []
        for j, s in learners:
            color = canvas.color(j)
            gains = data.craft.get(s.deputy.name, CraftData()).gains
            if gains:
                t = np.array([g.t for g in gains]) / P
                k = np.array([np.ravel(g.K)[c] if np.size(g.K) > c else np.nan for g in gains])
                if data.sim_t > gains[-1].t:  # hold the last gain to the end of the run
                    t, k = np.append(t, data.sim_t / P), np.append(k, k[-1])
                ax.step(t, k, where="post", color=color, lw=1.2, label=f"{s.label} K")
            # the LQR gain wide and pale under K*, thin and dark on top: both stay visible
            # where they coincide (a nominal truth)
            if s.K_lqr.size > c:
                refs.append(float(s.K_lqr.flat[c]))
                ax.axhline(
                    refs[-1],
                    color=color,
                    ls="--",
                    lw=3.0,
                    alpha=0.45,
                    label=f"{s.deputy.name} nominal LQR",
                )
            if s.K_true is not None and s.K_true.size > c:
                same = s.K_lqr.size > c and np.isclose(s.K_true.flat[c], s.K_lqr.flat[c])
                label = f"{s.deputy.name} true K*" + (" (= LQR)" if same else "")
                refs.append(float(s.K_true.flat[c]))
                ax.axhline(refs[-1], color="black", ls=":", lw=1.4, zorder=3, label=label)
        _show_references(ax, refs)
        name = K_NAMES[c] if c < len(K_NAMES) else str(c)
        unit = f" [{K_UNITS[c]}]" if c < len(K_UNITS) else ""
        ax.set_title(f"K[{name}]")
        ax.set_ylabel(f"K[{name}]{unit}")
        ax.grid(True, alpha=0.3)
        if c >= 2:
            ax.set_xlabel("time [orbits]")
    if learners:
        legend(axes.flat[0])
    else:
        axes.flat[0].text(
            0.5, 0.5, "no learning deputy", ha="center", transform=axes.flat[0].transAxes
        )
    fig.suptitle(canvas.title("gains.png"))
    canvas.save(fig, "gains.png")


def commanded_sigma3(data: RunData) -> Curve:
    """A deputy's commanded sigma3 by the time it is for."""

    def curve(s: DeputySeries) -> tuple[FloatArray, FloatArray]:
        t, v = data.craft.get(s.deputy.name, CraftData()).cmd.arrays()
        return t, v[:, 2]

    return curve


def along_track_error(s: DeputySeries) -> tuple[FloatArray, FloatArray]:
    """|y - y_ref|, at least 1 um (a log scale shows no zero)."""
    return s.t, np.maximum(np.abs(s.hill[:, 1] - s.deputy.y_ref), 1e-6)


def write_figures(
    out: Path, data: RunData, series: list[DeputySeries], save: Save | None = None
) -> list[str]:
    """Write the PNG figures, each with ``save`` (default: a file in ``out``); return the file
    names of those written."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    def to_file(name: str, png: bytes) -> bool:
        (out / name).write_bytes(png)
        return True

    canvas = Canvas(out, data, series, plt, save or to_file)
    line_figure(canvas, "hill_x.png", "x [m]", lambda s: (s.t, s.hill[:, 0]))
    line_figure(canvas, "hill_y.png", "y [m]", lambda s: (s.t, s.hill[:, 1]), refs=True)
    line_figure(canvas, "hill_xdot.png", "xdot [m/s]", lambda s: (s.t, s.hill[:, 3]))
    line_figure(canvas, "hill_ydot.png", "ydot [m/s]", lambda s: (s.t, s.hill[:, 4]))
    sigma3 = commanded_sigma3(data)
    line_figure(canvas, "sigma3.png", "commanded sigma3 [-]", sigma3, steps=True)
    line_figure(canvas, "along_track_error.png", "|y - y_ref| [m]", along_track_error, log_y=True)
    hill_xy_figure(canvas)
    gains_figure(canvas)
    return canvas.written
