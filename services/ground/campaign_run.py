"""One campaign run on a worker: the mission of a drawn deployment table, reduced to its row.

What a Dask worker imports (``ddvi-fsw`` installed on it): :func:`execute` takes a plain task
(run index, deployment table, seed, mode) and returns ``(row, timing)``; it never raises, a
failed mission is a row with ``completed`` false and its ``error``.  The mission runs either in
this process (``services.flight.inprocess.run_in_process``, the same services' code, fast) or
as a full ``ddvi run`` (every service its own process on Zenoh) on the worker's host.
"""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
import tempfile
import time
import traceback
from pathlib import Path
from typing import Any

import numpy as np

from services.config import (
    Deployment,
    controller_label,
    deployment_from_table,
    write_deployment,
)
from services.model import orbit_period, true_lqr_gains

MODES = ("inprocess", "distributed")
ROWS_VERSION = 2
"""What a row means beyond its campaign file: raised when the same task gives another row (a
deputy's noise drawn another way, its controller labelled another way), so that ``--resume``
does not mix the two in one table."""
METRICS = (
    "controller",
    "final_error_m",
    "last_orbit_max_error_m",
    "gain_error",
    "learned_at_orbits",
)
"""Each deputy's columns, ``<deputy>.<metric>``: its controller, |y - y_ref| at the end and its
largest value over the last orbit (m), |K - K*| / |K*| of the gains it flies at the end against
the run's true optimal gain K* (``services.model.true_lqr_gains``), and the orbit it first
switched to learned gains at (empty: never)."""


def deputy_columns(names: list[str]) -> list[str]:
    """The per-deputy column names of a deployment's deputies."""
    return [f"{name}.{m}" for name in names for m in METRICS]


def _gain_error(dep: Deployment, name: str, K: Any) -> float | None:
    """|K - K*| / |K*| against the run's true optimal gain (None without K)."""
    if K is None:
        return None
    K_star = true_lqr_gains(dep, dep.deputy_named(name))[0]
    K = np.asarray(K, float)
    if K.shape != K_star.shape:
        return None
    return float(np.linalg.norm(K - K_star) / np.linalg.norm(K_star))


def inprocess_metrics(dep: Deployment) -> dict[str, Any]:
    """Run the mission in this process (its noise from run.seed, the run's seed); each
    deputy's metrics (see :data:`METRICS`)."""
    from services.flight.inprocess import run_in_process

    out = run_in_process(dep)
    period = orbit_period(dep)
    row: dict[str, Any] = {}
    for d in dep.deputy:
        rec = out[d.name]
        c = rec["controller"]
        ey = np.abs(rec["x"][:, 1] - d.y_ref)  # the true state in the navigation frame
        last = rec["t"] >= rec["t"][-1] - period
        row.update(
            {
                f"{d.name}.controller": d.label,
                f"{d.name}.final_error_m": float(ey[-1]),
                f"{d.name}.last_orbit_max_error_m": float(ey[last].max()),
                f"{d.name}.gain_error": _gain_error(dep, d.name, c.K),
                f"{d.name}.learned_at_orbits": c.learned_at[0] / period if c.learned_at else None,
            }
        )
    return row


def distributed_metrics(dep: Deployment, table: dict, folder: Path) -> dict[str, Any]:
    """Run the mission as ``ddvi run`` (processes on Zenoh) with its run under ``folder``;
    each deputy's metrics from the run's summary.json.  RuntimeError when the run made no
    summary or did not complete."""
    path = write_deployment(table, folder, "deployment")
    cmd = [sys.executable, "-m", "services.cli", "run", str(path), "--quiet"]
    done = subprocess.run(cmd, capture_output=True, text=True, check=False)
    found = sorted((folder / "runs").glob("*/summary.json"))
    if not found:
        tail = (done.stderr or done.stdout).strip().splitlines()[-3:]
        raise RuntimeError(
            f"ddvi run exited {done.returncode} with no summary: " + " | ".join(tail)
        )
    summary = json.loads(found[-1].read_text())
    row: dict[str, Any] = {}
    for name, d in summary["deputies"].items():
        gains = d.get("gains") or d.get("lqr_gains") or {}
        row.update(
            {
                f"{name}.controller": controller_label(d["controller"], d.get("learning_method")),
                f"{name}.final_error_m": d["final_along_track_error_m"],
                f"{name}.last_orbit_max_error_m": d["max_along_track_error_last_orbit_m"],
                f"{name}.gain_error": _gain_error(dep, name, gains.get("K")),
                f"{name}.learned_at_orbits": d["learned_at_orbits"],
            }
        )
    if not summary.get("completed"):
        raise _IncompleteError(row, f"ddvi run did not complete (exit {done.returncode})")
    return row


class _IncompleteError(RuntimeError):
    """A distributed run that stopped early: its metrics so far, and why."""

    def __init__(self, row: dict[str, Any], why: str) -> None:
        super().__init__(why)
        self.row = row


def execute(task: dict[str, Any]) -> tuple[dict[str, Any], dict[str, Any]]:
    """Run one task: ``{"run": i, "seed": s, "table": deployment table, "mode": MODES[k],
    "keep": folder or None}`` (``keep``: a distributed run's folder is kept there).

    Returns ``(row, timing)``: row = run, seed, completed, error and the deputies' metrics
    (deterministic: the same task gives the same row); timing = wall_s and the worker's host
    name.  Never raises."""
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    t0 = time.perf_counter()
    row: dict[str, Any] = {
        "run": task["run"],
        "seed": task["seed"],
        "completed": False,
        "error": None,
    }
    try:
        dep = deployment_from_table(task["table"])
        if task["mode"] == "distributed":
            if task.get("keep"):
                row.update(distributed_metrics(dep, task["table"], Path(task["keep"])))
            else:
                with tempfile.TemporaryDirectory(prefix="ddvi-campaign-") as tmp:
                    row.update(distributed_metrics(dep, task["table"], Path(tmp)))
        else:
            row.update(inprocess_metrics(dep))
        row["completed"] = True
    except _IncompleteError as exc:
        row.update(exc.row, error=str(exc))
    except Exception as exc:  # a failed mission is a row, not a failed campaign
        last = traceback.extract_tb(exc.__traceback__)[-1]
        where = f"{Path(last.filename).name}:{last.lineno}"
        row["error"] = f"{type(exc).__name__}: {exc} ({where})"
    timing = {
        "run": task["run"],
        "wall_s": time.perf_counter() - t0,
        "worker": socket.gethostname(),
    }
    return row, timing
