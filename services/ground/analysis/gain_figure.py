"""The run report's gains figure: each element of K and L every learner flew against the
optimal gains of the truth's linear model and the nominal LQR gains, and the relative gain
error on a log scale."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from services.ground.analysis.figure_canvas import (
    ERROR_FLOOR,
    Canvas,
    Margins,
    legend,
    time_axes,
)
from services.ground.analysis.rundata import CraftData, DeputySeries, FloatArray, GainRecord

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

K_NAMES = ("x", "y", "xdot", "ydot")  # the in-plane state the gain K acts on (mission.IN_PLANE)
K_UNITS = ("1/m", "1/m", "s/m", "s/m")  # u = sigma3 (an MRP, no unit) per unit of that state
L_NAMES = ("1", "cos u", "sin u", "cos 2u", "sin 2u")  # the exostate v (services.model.exostate)


def _gain_steps(
    gains: list[GainRecord], which: str, c: int, end: float
) -> tuple[FloatArray, FloatArray]:
    """Element ``c`` of the flown gain ``which`` ("K" or "L") by time, held to ``end``."""
    t = np.array([g.t for g in gains])
    values = [np.ravel(getattr(g, which)) for g in gains]
    v = np.array([row[c] if row.size > c else np.nan for row in values])
    if len(t) and end > t[-1]:  # the last gain is flown to the end of the run
        t, v = np.append(t, end), np.append(v, v[-1])
    return t, v


def _relative_errors(
    gains: list[GainRecord], which: str, reference: FloatArray, end: float
) -> tuple[FloatArray, FloatArray]:
    """|G - G*| / |G*| of each flown gain ``which`` against ``reference``, held to ``end``."""
    t = np.array([g.t for g in gains])
    norm = float(np.linalg.norm(reference))
    e = np.array(
        [
            np.linalg.norm(np.ravel(getattr(g, which)) - np.ravel(reference)) / norm
            if np.size(getattr(g, which)) == reference.size and norm > 0
            else np.nan
            for g in gains
        ]
    )
    if len(t) and end > t[-1]:
        t, e = np.append(t, end), np.append(e, e[-1])
    return t, np.maximum(e, ERROR_FLOOR)


@dataclass(frozen=True)
class Reference:
    """A reference gain drawn across a gain's panels: K* (of the truth's linear model) or the
    nominal LQR gain, or both when they are one."""

    K: FloatArray
    L: FloatArray
    label: str
    style: dict[str, Any]


OPTIMUM_STYLE = {"color": "black", "ls": ":", "lw": 1.6, "zorder": 3}
LQR_STYLE = {"color": "0.55", "ls": "--", "lw": 1.4, "zorder": 2}


def references(series: list[DeputySeries]) -> list[Reference]:
    """The learners' reference gains, each value once: K* dotted black and the nominal LQR
    gain dashed grey, or one line for both where the truth is the nominal model; a deputy
    named only when the learners' references differ."""
    out: list[Reference] = []
    seen: list[tuple[FloatArray, FloatArray]] = []
    learners = [s for s in series if s.deputy.controller == "ddvi"]
    distinct = {
        (tuple(np.round(s.K_lqr.ravel(), 12)), tuple(np.round(_optimum(s)[0].ravel(), 12)))
        for s in learners
    }
    for s in learners:
        who = f" ({s.deputy.name})" if len(distinct) > 1 else ""
        K_opt, L_opt = _optimum(s)
        same = K_opt.shape == s.K_lqr.shape and np.allclose(K_opt, s.K_lqr, rtol=1e-9)
        candidates = (
            [(K_opt, L_opt, f"K*, L* = nominal LQR{who}", OPTIMUM_STYLE)]
            if same
            else [
                (K_opt, L_opt, f"K*, L* (the truth's){who}", OPTIMUM_STYLE),
                (s.K_lqr, s.L_lqr, f"nominal LQR{who}", LQR_STYLE),
            ]
        )
        for K, L, label, style in candidates:
            if any(np.array_equal(K, k) and np.array_equal(L, m) for k, m in seen):
                continue
            seen.append((K, L))
            out.append(Reference(K, L, label, style))
    return out


def _optimum(s: DeputySeries) -> tuple[FloatArray, FloatArray]:
    """K* and L* of the deputy's truth, or its nominal LQR gains when the truth has none."""
    if s.K_true is None or s.L_true is None:
        return s.K_lqr, s.L_lqr
    return s.K_true, s.L_true


def gains_figure(canvas: Canvas) -> Figure:
    """Each element of K (top row, 4) and L (middle, 5) as every learner flew it, as steps held
    to the end of the run, against the reference gains (``references``); below, each learner's
    relative gain errors |K - K*|/|K*| and |L - L*|/|L*| on a log scale, the gap the element
    panels cannot show once a gain is within a per cent of K*.  The LQR deputies fly their
    nominal gain throughout: their error against K* is drawn where the truth is not
    nominal."""
    data = canvas.data
    P, end = canvas.period, data.sim_t
    fig = canvas.figure("gains.png", (14, 10), Margins(left=0.8, top=0.75))
    rows = fig.add_gridspec(3, 1, height_ratios=(1, 1, 1.3), hspace=0.32)
    k_grid = rows[0].subgridspec(1, len(K_NAMES), wspace=0.3)
    l_grid = rows[1].subgridspec(1, len(L_NAMES), wspace=0.4)
    first = fig.add_subplot(k_grid[0])
    k_axes = [first, *(fig.add_subplot(k_grid[c], sharex=first) for c in range(1, len(K_NAMES)))]
    l_axes = [fig.add_subplot(l_grid[c], sharex=first) for c in range(len(L_NAMES))]
    err = fig.add_subplot(rows[2], sharex=first)
    learners = [(j, s) for j, s in enumerate(canvas.series) if s.deputy.controller == "ddvi"]
    refs = references(canvas.series)
    for which, axes, names, units in (
        ("K", k_axes, K_NAMES, K_UNITS),
        ("L", l_axes, L_NAMES, ("-",) * len(L_NAMES)),
    ):
        for c, ax in enumerate(axes):
            for j, s in learners:
                gains = data.craft.get(s.deputy.name, CraftData()).gains
                if gains:
                    t, v = _gain_steps(gains, which, c, end)
                    ax.step(t / P, v, where="post", color=canvas.color(j), lw=1.2, label=s.label)
            values = []
            for r in refs:
                ref = np.ravel(getattr(r, which))
                if ref.size > c:
                    values.append(float(ref[c]))
                    ax.axhline(values[-1], label=r.label, **r.style)
            _show_references(ax, values)
            ax.set_title(f"{which}[{names[c]}] [{units[c]}]", fontsize="medium")
            # small gains as a x10^n offset above the axis, not as long tick labels
            ax.ticklabel_format(axis="y", style="sci", scilimits=(-2, 3), useMathText=True)
            ax.grid(True, alpha=0.3)
    for j, s in learners:
        gains = data.craft.get(s.deputy.name, CraftData()).gains
        K_opt, L_opt = _optimum(s)
        # no relative error against a zero L* (a nominal truth needs no feedforward)
        for which, reference, ls in (("K", K_opt, "-"), ("L", L_opt, "--")):
            if gains and np.linalg.norm(reference) > 0:
                t, e = _relative_errors(gains, which, reference, end)
                label = f"{s.label}: |{which} - {which}*|/|{which}*|, {e[-1]:.2g} at the end"
                err.step(t / P, e, where="post", color=canvas.color(j), ls=ls, lw=1.2, label=label)
    for j, s in enumerate(canvas.series):
        K_opt, _ = _optimum(s)
        if s.deputy.controller == "lqr" and K_opt.shape == s.K_lqr.shape and end > 0:
            e = float(np.linalg.norm(s.K_lqr - K_opt) / np.linalg.norm(K_opt))
            if e > ERROR_FLOOR:
                label = f"{s.label}: nominal LQR |K - K*|/|K*|"
                err.axhline(e, color=canvas.color(j), ls="-.", lw=1.2, label=label)
    err.set_yscale("log")
    err.set_title("relative gain error", fontsize="medium")
    time_axes(err, "relative error [-]")
    if learners:
        handles, labels = k_axes[0].get_legend_handles_labels()
        fig.legend(
            handles,
            labels,
            loc="upper right",
            bbox_to_anchor=(0.99, 0.99),
            ncols=len(labels),
            fontsize="small",
        )
    else:
        err.text(0.5, 0.5, "no learning deputy", ha="center", transform=err.transAxes)
    legend(err, loc="upper right")
    return fig


def _show_references(ax: Axes, values: list[float]) -> None:
    """Widen the y axis to the reference lines' ``values``, with a margin (axhline takes no
    part in autoscaling: a reference just beside the learned gain would sit on the frame)."""
    if not values:
        return
    lo, hi = ax.get_ylim()
    lo, hi = min(lo, *values), max(hi, *values)
    pad = 0.06 * (hi - lo) if hi > lo else 0.06 * abs(hi) or 1.0
    ax.set_ylim(lo - pad, hi + pad)
