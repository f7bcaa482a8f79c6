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

from services.config import (
    Deployment,
    controller_label,
    deployment_from_table,
    write_deployment,
)
from services.ground.analysis.scoring import deputy_metrics, holding_notes, inprocess_outcome

MODES = ("inprocess", "distributed")
ROWS_VERSION = 4
"""What a row means beyond its campaign file: raised when the same task gives another row (a
deputy's noise drawn another way, its controller labelled another way, a deputy scored another
way), so that ``--resume`` does not mix the two in one table."""
COLUMNS = {
    "final_error_m": "final_along_track_error_m",
    "last_orbit_max_error_m": "max_along_track_error_last_orbit_m",
    "gain_error": "gain_error",
    "learned_at_orbits": "learned_at_orbits",
    "fallback_at_orbits": "fallback_at_orbits",
    "learned": "learned",
    "gain_error_vs_lqr": "gain_error_vs_lqr",
    "can_hold": "can_hold",
    "note": "note",
}
"""A campaign column -> the metric of ``services.ground.analysis.scoring.deputy_metrics`` it
holds."""
METRICS = ("controller", *COLUMNS)
"""Each deputy's columns, ``<deputy>.<metric>``: its controller, then its metrics
(``services.ground.analysis.scoring``): |y - y_ref| at the end and its largest value over the last
orbit (m), |K - K*| / |K*| of the gains it flies at the end against the run's true optimal gain
K* (``services.model.true_lqr_gains``; NULL for a learner that flies neither a learned gain nor
its fallback), the orbit it first switched to learned gains at (NULL: never), the orbit it took
to its fallback at (NULL: never), whether it flies learned gains at the end
(NULL for LQR), the gain error against the nominal LQR gain, whether some attitude lets it hold
its slot, and a note (why it cannot, why it flies no learned gain)."""


def deputy_columns(names: list[str]) -> list[str]:
    """The per-deputy column names of a deployment's deputies."""
    return [f"{name}.{m}" for name in names for m in METRICS]


def _columns(name: str, label: str, metrics: dict[str, Any]) -> dict[str, Any]:
    """A deputy's metrics as its campaign columns."""
    row = {f"{name}.controller": label}
    row.update({f"{name}.{col}": metrics[key] for col, key in COLUMNS.items()})
    return row


def inprocess_metrics(dep: Deployment) -> dict[str, Any]:
    """Run the mission in this process (its noise from run.seed, the run's seed); each
    deputy's metrics (see :data:`METRICS`)."""
    from services.flight.inprocess import run_in_process

    out = run_in_process(dep)
    cannot_hold = holding_notes(dep)
    row: dict[str, Any] = {}
    for d in dep.deputy:
        outcome = inprocess_outcome(dep, d, out[d.name])
        metrics = deputy_metrics(dep, d, outcome, cannot_hold=cannot_hold.get(d.name, ""))
        row.update(_columns(d.name, d.label, metrics))
    return row


def distributed_metrics(dep: Deployment, table: dict, folder: Path) -> dict[str, Any]:
    """Run the mission as ``ddvi run`` (processes on Zenoh) with its run under ``folder``;
    each deputy's metrics from the run's summary.json (scored by its report).  RuntimeError
    when the run made no summary or did not complete."""
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
        metrics = {**d, "gain_error": d["gain_error_vs_true_optimum"]}
        label = controller_label(d["controller"], d.get("learning_method"))
        row.update(_columns(name, label, metrics))
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
