"""The run report's figures: the paper's plots, one line per deputy (matplotlib's object
interface, drawn by the Agg canvas).

``draw_figures`` draws every figure of ``FIGURES`` (``services.ground.analysis.figure_canvas``)
and returns the matplotlib Figures (what the tests read: axes, labels, scales, legends);
``write_figures`` saves them as PNGs in the run folder.  The positions and velocities are the
true state, the commands sigma3, the gains their own figure (``gain_figure``).  matplotlib is
imported when the figures are drawn, not when this module is.
"""

from __future__ import annotations

import io
from collections.abc import Collection
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from services.ground.analysis.figure_canvas import (
    ERROR_FLOOR,
    MARGINS,
    Canvas,
    Curve,
    Margins,
    Save,
    legend,
    time_axes,
)
from services.ground.analysis.gain_figure import gains_figure
from services.ground.analysis.rundata import (
    CraftData,
    DeputySeries,
    FloatArray,
    GainRecord,
    RunData,
)
from services.ground.analysis.scoring import learned_switches, switches_to

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

ENDGAME_SHARE = 0.2
"""The share of the run (at least one orbit) that hill_y.png's lower panel shows: the end game,
metres from the slot where the upper panel spans tens of kilometres."""
NEAR_SLOT_M = 1_000.0
"""How far from its slot (m, along-track or radial) a deputy may be in the end game or the last
orbit and still set the scale of their views: one farther is drawn beyond the view and named in
it, and does not hide the others' metres."""


def line_figure(
    canvas: Canvas, name: str, ylabel: str, curve: Curve, log_y: bool = False
) -> Figure:
    """One curve per deputy against time in orbits."""
    # room for log labels like 3.075x10^4 (a span under a decade)
    fig = canvas.figure(name, (8, 4.5), Margins(left=1.1) if log_y else MARGINS)
    ax = fig.add_subplot()
    plot_curves(canvas, ax, curve)
    if log_y:
        ax.set_yscale("log")
    time_axes(ax, ylabel)
    legend(ax)
    return fig


def plot_curves(
    canvas: Canvas,
    ax: Axes,
    curve: Curve,
    since: float = -np.inf,
    steps: bool = False,
    unscaled: Collection[str] = (),
) -> None:
    """Each deputy's ``curve`` from time ``since`` (s) on, in orbits; ``steps``: drawn as a
    zero-order hold; the deputies named in ``unscaled`` are drawn last, in the view the others
    set (``fix_view``)."""
    fixed = False
    # the deputies that scale the view first (sorted is stable: in deputy order each)
    for j, s in sorted(enumerate(canvas.series), key=lambda js: js[1].deputy.name in unscaled):
        if s.deputy.name in unscaled and not fixed:
            fix_view(ax)
            fixed = True
        t, y = curve(s)
        keep = t >= since
        if keep.any():
            ax.plot(
                t[keep] / canvas.period,
                y[keep],
                color=canvas.color(j),
                lw=1.0,
                label=s.label,
                drawstyle="steps-post" if steps else "default",
            )


def fix_view(ax: Axes) -> None:
    """Keep the axes' view where what they hold now puts it: what is drawn after does not move
    it."""
    ax.autoscale_view()
    ax.set_autoscale_on(False)


def beyond_view(series: list[DeputySeries], since: float) -> dict[str, float]:
    """The deputies farther than ``NEAR_SLOT_M`` from their slot at some time from ``since``
    (s) on, with that largest distance (m, the larger of |y - y_ref| and |x|), when another
    deputy is not: a view of the end game scales to the deputies near their slots.  Empty when
    every deputy is near, or none is."""
    far: dict[str, float] = {}
    near = 0
    for s in series:
        keep = s.t >= since
        if not keep.any():
            continue
        along, radial = np.abs(s.hill[keep, 1] - s.deputy.y_ref), np.abs(s.hill[keep, 0])
        distance = float(np.maximum(along, radial).max())
        if distance > NEAR_SLOT_M:
            far[s.deputy.name] = distance
        else:
            near += 1
    return far if near else {}


def note_beyond(ax: Axes, far: dict[str, float]) -> None:
    """Name the deputies ``beyond_view`` left out of the view's scale, in the view."""
    if far:
        said = ", ".join(f"{name} ({d / 1000:.3g} km from its slot)" for name, d in far.items())
        ax.text(0.01, 0.02, f"beyond this view: {said}", transform=ax.transAxes, fontsize="small")


def hill_y_figure(canvas: Canvas) -> Figure:
    """The along-track position over the run with each deputy's slot dotted (upper panel),
    and over its last ``ENDGAME_SHARE`` its distance from the slot, y - y_ref (lower)."""
    fig = canvas.figure("hill_y.png", (8, 7))
    whole, end = fig.subplots(2, 1, gridspec_kw={"height_ratios": (3, 2), "hspace": 0.45})
    plot_curves(canvas, whole, lambda s: (s.t, s.hill[:, 1]))
    for y_ref, who in distinct_slots(canvas.series):
        whole.axhline(y_ref, color="black", ls=":", lw=0.9, label=f"slot{who}")
    P, t_end = canvas.period, canvas.data.sim_t
    since = t_end - max(ENDGAME_SHARE * t_end, P)
    far = beyond_view(canvas.series, since)
    error = lambda s: (s.t, s.hill[:, 1] - s.deputy.y_ref)  # noqa: E731
    plot_curves(canvas, end, error, since=since, unscaled=far)
    note_beyond(end, far)
    end.axhline(0.0, color="black", ls=":", lw=0.9)
    if t_end > 0:
        whole.axvspan(since / P, t_end / P, color="0.9", zorder=0, label="end game (below)")
    whole.set_title("whole run", fontsize="medium")
    time_axes(whole, "y [m]")
    end.set_title(f"end game: the last {(t_end - since) / P:.3g} orbits", fontsize="medium")
    time_axes(end, "y - y_ref [m]")
    legend(whole)
    return fig


def distinct_slots(series: list[DeputySeries]) -> list[tuple[float, str]]:
    """Each slot y_ref once, with the deputies at it named when the deputies have more than
    one slot (" of lqr, ddvi"; "" when they share one)."""
    slots: dict[float, list[str]] = {}
    for s in series:
        slots.setdefault(s.deputy.y_ref, []).append(s.deputy.name)
    if len(slots) == 1:
        return [(y, "") for y in slots]
    return [(y, f" of {', '.join(names)}") for y, names in slots.items()]


def hill_xy_figure(canvas: Canvas) -> Figure:
    """Radial against along-track position over the run (left) and over its last orbit
    (right), with the chief at the origin, each slot, and each deputy's last position."""
    fig = canvas.figure("hill_xy.png", (12, 5.5))
    whole, last = fig.subplots(1, 2, gridspec_kw={"width_ratios": (3, 2), "wspace": 0.22})
    since = canvas.data.sim_t - canvas.period
    far = beyond_view(canvas.series, since)
    note_beyond(last, far)
    names = [s.deputy.name for s in canvas.series]
    for ax, start, unscaled in ((whole, -np.inf, {}), (last, since, far)):
        plot_trajectories(canvas, ax, start, [n for n in names if n not in unscaled])
        for y_ref, who in distinct_slots(canvas.series):
            ax.plot(y_ref, 0.0, "s", mfc="none", mec="black", ms=9, ls="none", label=f"slot{who}")
        if ax is last:
            # the chief and the deputies far from their slots do not widen the last orbit's
            # view: they show there only if they are near
            fix_view(ax)
        plot_trajectories(canvas, ax, start, unscaled)
        ax.plot(0.0, 0.0, "*", color="black", ms=11, ls="none", label="chief")
        ax.set_xlabel("y (along-track) [m]")
        ax.set_ylabel("x (radial) [m]")
        ax.grid(True, alpha=0.3)
    whole.set_title("whole run", fontsize="medium")
    last.set_title("last orbit", fontsize="medium")
    legend(whole)
    return fig


def plot_trajectories(canvas: Canvas, ax: Axes, since: float, deputies: Collection[str]) -> None:
    """The Hill x-y trajectory from ``since`` (s) on of each deputy named in ``deputies``,
    with a dot at its last position."""
    for j, s in enumerate(canvas.series):
        keep = s.t >= since
        if keep.any() and s.deputy.name in deputies:
            y, x = s.hill[keep, 1], s.hill[keep, 0]
            ax.plot(y, x, color=canvas.color(j), lw=1.0, label=s.label)
            ax.plot(y[-1], x[-1], "o", color=canvas.color(j), ms=5)


def exploring_spans(gains: list[GainRecord], end: float) -> list[tuple[float, float]]:
    """The times (s) a controller explored, each (from, to): while the gains it flew were not
    converged, those of the exploring phases (K0, or the fallback's gains explored on:
    services.flight.phases.EXPLORING_PHASES), which it sends every step it explores; a span
    still open at the last record ends at ``end``."""
    spans: list[tuple[float, float]] = []
    start: float | None = None
    for r in gains:
        exploring = not r.converged
        if exploring and start is None:
            start = r.t
        elif not exploring and start is not None:
            spans.append((start, r.t))
            start = None
    if start is not None:
        spans.append((start, max(end, start)))
    return spans


def sigma3_figure(canvas: Canvas) -> Figure:
    """Each deputy's commanded sigma3 as flown (a zero-order hold), the times each learner
    explored shaded, each switch to learned gains a vertical line (dashed; to its fallback,
    dotted), and the attitude limits."""
    data, P = canvas.data, canvas.period
    fig = canvas.figure("sigma3.png", (10, 4.8), Margins(right=2.1))  # the legend at the right
    ax = fig.add_subplot()

    def commanded(s: DeputySeries) -> tuple[FloatArray, FloatArray]:
        t, v = data.craft.get(s.deputy.name, CraftData()).cmd.arrays()
        return t, v[:, 2]

    plot_curves(canvas, ax, commanded, steps=True)
    for j, s in enumerate(canvas.series):
        craft = data.craft.get(s.deputy.name, CraftData())
        color, name = canvas.color(j), s.deputy.name
        for k, (t0, t1) in enumerate(exploring_spans(craft.gains, data.sim_t)):
            label = f"{name} exploring" if k == 0 else None
            ax.axvspan(t0 / P, t1 / P, color=color, alpha=0.12, lw=0, label=label)
        for k, t in enumerate(learned_switches(craft.gains)):
            label = f"{name} learned" if k == 0 else None
            ax.axvline(t / P, color=color, ls="--", lw=1.2, label=label)
        if s.deputy.controller == "ddvi":
            for k, t in enumerate(switches_to(craft.gains, "lqr")):
                label = f"{name} fallback (LQR)" if k == 0 else None
                ax.axvline(t / P, color=color, ls=":", lw=1.5, label=label)
    limits = sorted({s.deputy.attitude_limit for s in canvas.series})
    for limit in limits:
        label = "attitude limit" if len(limits) == 1 else f"attitude limit {limit:g}"
        ax.axhline(limit, color="black", ls=":", lw=1.0, label=label)
        ax.axhline(-limit, color="black", ls=":", lw=1.0)
    time_axes(ax, "commanded sigma3 [-]")
    legend(ax, loc="upper left", bbox_to_anchor=(1.02, 1.0))
    return fig


def along_track_error(s: DeputySeries) -> tuple[FloatArray, FloatArray]:
    """|y - y_ref|, at least ``ERROR_FLOOR`` m (a log scale shows no zero)."""
    return s.t, np.maximum(np.abs(s.hill[:, 1] - s.deputy.y_ref), ERROR_FLOOR)


def draw_figures(data: RunData, series: list[DeputySeries]) -> dict[str, Figure]:
    """Every figure of ``FIGURES``, drawn: file name -> matplotlib Figure."""
    import matplotlib

    canvas = Canvas(data, series, matplotlib.rcParams["axes.prop_cycle"].by_key()["color"])
    return {
        "hill_x.png": line_figure(canvas, "hill_x.png", "x [m]", lambda s: (s.t, s.hill[:, 0])),
        "hill_y.png": hill_y_figure(canvas),
        "hill_xdot.png": line_figure(
            canvas, "hill_xdot.png", "xdot [m/s]", lambda s: (s.t, s.hill[:, 3])
        ),
        "hill_ydot.png": line_figure(
            canvas, "hill_ydot.png", "ydot [m/s]", lambda s: (s.t, s.hill[:, 4])
        ),
        "sigma3.png": sigma3_figure(canvas),
        "along_track_error.png": line_figure(
            canvas, "along_track_error.png", "|y - y_ref| [m]", along_track_error, log_y=True
        ),
        "hill_xy.png": hill_xy_figure(canvas),
        "gains.png": gains_figure(canvas),
    }


def write_figures(
    out: Path, data: RunData, series: list[DeputySeries], save: Save | None = None
) -> list[str]:
    """Write the PNG figures, each with ``save`` (default: a file in ``out``); return the file
    names of those written.  Each is drawn whole first: on a full disk no part of a figure is
    left."""

    def to_file(name: str, png: bytes) -> bool:
        (out / name).write_bytes(png)
        return True

    write = save or to_file
    written = []
    for name, fig in draw_figures(data, series).items():
        png = io.BytesIO()
        fig.savefig(png, format="png")
        if write(name, png.getvalue()):
            written.append(name)
    return written
