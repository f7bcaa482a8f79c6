"""What every figure of the run report shares (``services.ground.analysis.figures``): each
figure's short title, its line in report.md and what it plots, stated in its footer beside the
run's name (the true state, the commands, or the gains flown); the run's data and colours
(``Canvas``); fixed margins; the legend and time axes every panel uses."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from services.ground.analysis.rundata import DeputySeries, FloatArray, RunData

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

TRUE_STATE = "true state: the environment's truth, in the chief's Hill frame"
COMMANDS = "commands the controllers sent (computed from the navigated state)"
GAINS = "gains the controllers flew; K*, L*: the optimal gains of the truth's linear model"
DPI = 110


@dataclass(frozen=True)
class Margins:
    """A figure's margins around its panels, inches: room for the tick and axis labels, the
    title above and the footer below.  Fixed: a layout engine (tight or constrained) costs
    about as much as the drawing, at the end of every run."""

    left: float = 0.85
    right: float = 0.25
    bottom: float = 0.85
    top: float = 0.5


MARGINS = Margins()
ERROR_FLOOR = 1e-6
"""The least relative gain error and along-track error (m) plotted: a log scale shows no zero."""


@dataclass(frozen=True)
class FigureSpec:
    """A figure's short title, its line in report.md, and what it plots (its footer)."""

    title: str
    line: str
    shows: str


FIGURES: dict[str, FigureSpec] = {
    "hill_x.png": FigureSpec("Radial position", "Hill x (radial) position vs orbits", TRUE_STATE),
    "hill_y.png": FigureSpec(
        "Along-track position",
        "Hill y (along-track) position vs orbits, and the end game (y - y_ref)",
        TRUE_STATE,
    ),
    "hill_xy.png": FigureSpec(
        "Relative trajectory",
        "Hill x vs y with the chief and the slots, and the last orbit",
        TRUE_STATE,
    ),
    "hill_xdot.png": FigureSpec("Radial velocity", "Hill x velocity vs orbits", TRUE_STATE),
    "hill_ydot.png": FigureSpec("Along-track velocity", "Hill y velocity vs orbits", TRUE_STATE),
    "sigma3.png": FigureSpec(
        "Commanded attitude",
        "Commanded relative MRP sigma3 vs orbits, with the exploration, the learning and the "
        "attitude limit",
        COMMANDS,
    ),
    "gains.png": FigureSpec(
        "Gains",
        "Flown gains K and L against K*, L* and the nominal LQR gains, and |K - K*|/|K*| "
        "(log scale)",
        GAINS,
    ),
    "along_track_error.png": FigureSpec(
        "Along-track error", "|y - y_ref| vs orbits (log scale)", TRUE_STATE
    ),
}
"""Figure file name -> its title, its line in report.md and what it plots."""

Curve = Callable[[DeputySeries], tuple[FloatArray, FloatArray]]
"""A deputy's curve: (t (N,) in s, y (N,))."""

Save = Callable[[str, bytes], bool]
"""Writes a figure's PNG bytes under its file name; whether it was written."""


@dataclass
class Canvas:
    """What every figure of a run shares: the run, its deputies' series and the colour cycle
    (deputy j draws in colour j)."""

    data: RunData
    series: list[DeputySeries]
    colors: list[str]

    @property
    def period(self) -> float:
        return self.data.period

    def color(self, j: int) -> str:
        return self.colors[j % len(self.colors)]

    def figure(self, name: str, size: tuple[float, float], margins: Margins = MARGINS) -> Figure:
        """A new figure of ``size`` (inches) with ``name``'s title, a footer (the run, and what
        the figure plots) and its panels' area inside ``margins``."""
        from matplotlib.figure import Figure

        w, h = size
        fig = Figure(figsize=size, dpi=DPI)
        fig.subplots_adjust(
            left=margins.left / w,
            right=1 - margins.right / w,
            bottom=margins.bottom / h,
            top=1 - margins.top / h,
        )
        spec = FIGURES[name]
        fig.suptitle(spec.title, y=1 - 0.08 / h, va="top")
        footer = {"va": "bottom", "fontsize": "small", "color": "0.35"}
        fig.text(0.1 / w, 0.08 / h, f"run {self.data.run}", gid="run", **footer)
        fig.text(1 - 0.1 / w, 0.08 / h, spec.shows, ha="right", gid="shows", **footer)
        return fig


def legend(ax: Axes, **kw: Any) -> None:
    """The axes' legend, when it has a labelled artist (a run that failed early may have none:
    no legend then, and no matplotlib warning)."""
    if ax.get_legend_handles_labels()[0]:
        ax.legend(**{"loc": "best", "fontsize": "small", **kw})


def time_axes(ax: Axes, ylabel: str) -> None:
    ax.set_xlabel("time [orbits]")
    ax.set_ylabel(ylabel)
    ax.grid(True, alpha=0.3)
