"""The campaign report's figures (matplotlib, Agg): the final along-track error's histogram and
empirical CDF per controller, and its scatter against each dispersed parameter."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _by_controller(outcomes: list[dict[str, Any]]) -> dict[str, np.ndarray]:
    """Final errors (m) per controller, of the deputies that have one."""
    out: dict[str, list[float]] = {}
    for o in outcomes:
        if o["final"] is not None:
            out.setdefault(o["controller"], []).append(max(o["final"], 1e-6))
    return {k: np.sort(np.array(v)) for k, v in out.items()}


def error_figure(outcomes: list[dict[str, Any]], path: Path) -> bool:
    """Write the histogram (left) and empirical CDF (right) of the final along-track error per
    controller; False (no file) when no deputy has one."""
    errors = _by_controller(outcomes)
    if not errors:
        return False
    plt = _pyplot()
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 4))
    every = np.concatenate(list(errors.values()))
    lo, hi = every.min(), every.max()
    bins = np.geomspace(lo, hi * 1.0001, 30) if hi > lo * 1.01 else 10
    for ctrl, e in errors.items():
        ax1.hist(e, bins=bins, alpha=0.55, label=f"{ctrl} ({e.size})")
        ax2.step(e, np.arange(1, e.size + 1) / e.size, where="post", label=ctrl)
    if hi > lo * 1.01:
        for ax in (ax1, ax2):
            ax.set_xscale("log")
    ax1.set(xlabel="final |y - y_ref| (m)", ylabel="deputy runs", title="final along-track error")
    ax2.set(
        xlabel="final |y - y_ref| (m)", ylabel="fraction of runs at or below", title="empirical CDF"
    )
    for ax in (ax1, ax2):
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return True


def _numeric(rows: list[dict[str, Any]], key: str) -> bool:
    return any(
        isinstance(r.get(key), int | float) and not isinstance(r.get(key), bool) for r in rows
    )


def scatter_figure(rows: list[dict[str, Any]], keys: list[str], path: Path) -> bool:
    """Write the final along-track error of each controller's deputies against each numeric
    dispersed parameter, one panel each; False (no file) when there is none."""
    keys = [k for k in keys if _numeric(rows, k)]
    deputies = [c.removesuffix(".controller") for c in rows[0] if c.endswith(".controller")]
    if not keys or not deputies:
        return False
    plt = _pyplot()
    cols = min(3, len(keys))
    nrows = -(-len(keys) // cols)
    fig, axes = plt.subplots(nrows, cols, figsize=(4.2 * cols, 3.4 * nrows), squeeze=False)
    for ax, key in zip(axes.flat, keys, strict=False):
        for name in deputies:
            pts = [
                (r[key], r[f"{name}.final_error_m"])
                for r in rows
                if r.get(f"{name}.final_error_m") is not None
            ]
            if pts:
                x, y = np.array(pts, float).T
                ax.scatter(
                    x,
                    np.maximum(y, 1e-6),
                    s=12,
                    alpha=0.7,
                    label=f"{name} ({rows[0].get(f'{name}.controller')})",
                )
        ax.set_yscale("log")
        ax.set(xlabel=key, ylabel="final |y - y_ref| (m)")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7)
    for ax in list(axes.flat)[len(keys) :]:
        ax.set_visible(False)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return True
