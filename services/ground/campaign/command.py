"""``ddvi campaign``: a Monte Carlo campaign of missions on dask.distributed.

    ddvi campaign FILE                          # a LocalCluster: one worker per core
    ddvi campaign FILE --workers 2
    ddvi campaign FILE --scheduler tcp://HOST:8786   # a running Dask cluster
    ddvi campaign FILE --distributed            # each run a full `ddvi run` on its worker
    ddvi campaign FILE --resume                 # finish a killed campaign
    ddvi campaign FILE --only-run 17            # run 17 alone, here, bit for bit

The campaign file (``services.ground.campaign.dispersions``) names a deployment, the number of
runs, a campaign seed and the dispersions.  Every run's deployment and seed are drawn here, from the
campaign seed and the run's index; the workers run the missions
(``services.ground.campaign.run.execute``) and each row is committed to
``<output>/results.sqlite`` as its run ends (``services.ground.campaign.store``), then the
report (``services.ground.campaign.report``) is written beside it.  docs/campaigns.md.
"""

from __future__ import annotations

import argparse
import difflib
import json
import os
import signal
import sys
import tomllib
import uuid
from contextlib import contextmanager, suppress
from pathlib import Path
from typing import Any

from services.config import DeploymentError, deployment_from_table, read_table
from services.config.files import campaign_file, deployment_dirs
from services.ground.campaign.dispersions import (
    CampaignError,
    CampaignSpec,
    draw_run,
    spec_from_table,
)
from services.ground.campaign.run import MODES, execute
from services.ground.campaign.store import ResultStore, read_meta, read_rows
from services.ground.launch import lifecycle
from services.model import holding_warnings, reentry_warnings

BLAS_THREADS = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


def shipped_campaigns() -> list[str]:
    """The names of the shipped campaign files (deployments/campaigns/), each found by name."""
    return sorted({p.stem for d in deployment_dirs() for p in (d / "campaigns").glob("*.toml")})


def load_campaign(path: str) -> CampaignSpec:
    """A checked campaign file; CampaignError (one line naming the key) if it cannot run.  Its
    deployment is a name, a path from the working directory or one from the file's folder."""
    file = campaign_file(path)
    if file is None:
        shipped = shipped_campaigns()
        near = difflib.get_close_matches(Path(path).name.removesuffix(".toml"), shipped, n=1)
        hint = f" (did you mean '{near[0]}'?)" if near else ""
        raise CampaignError(
            f"{path}: no such campaign file or name{hint}; shipped: "
            + (", ".join(shipped) or "none")
        )
    try:
        table = tomllib.loads(file.read_text())
    except tomllib.TOMLDecodeError as exc:
        raise CampaignError(f"{path}: not valid TOML ({exc})") from None

    def deployment(name: str) -> dict[str, Any]:
        beside = file.parent / name
        try:
            return read_table(str(beside) if beside.is_file() else name)
        except (DeploymentError, tomllib.TOMLDecodeError) as exc:
            raise CampaignError(f"campaign.deployment: {exc}") from None

    try:
        return spec_from_table(table, deployment, str(file))
    except CampaignError as exc:
        raise CampaignError(f"{path}: {exc}") from None


def task(spec: CampaignSpec, index: int, mode: str, keep: str | None = None) -> dict[str, Any]:
    """Run ``index``'s task for :func:`services.ground.campaign.run.execute`, and its dispersed
    values under ``values``."""
    table, values, seed = draw_run(spec, index)
    return {
        "run": index,
        "seed": seed,
        "table": table,
        "mode": mode,
        "keep": keep,
        "values": values,
    }


def holding_lines(spec: CampaignSpec, tasks: dict[int, dict[str, Any]]) -> list[str]:
    """Why deputies cannot hold their slot (``services.model.holding_warnings``), then why the
    formation is predicted to re-enter before the mission ends
    (``services.model.reentry_warnings``): of each, the base deployment's, once, when it has
    one; else each drawn run's that has."""
    base = deployment_from_table(spec.base)
    runs = {i: deployment_from_table(t["table"]) for i, t in tasks.items()}
    lines: list[str] = []
    for warnings in (holding_warnings, reentry_warnings):
        if said := warnings(base):
            lines += [f"the base deployment: {why}" for why in said]
        else:
            lines += [f"run {i}: {why}" for i, dep in runs.items() for why in warnings(dep)]
    return lines


def _say_holding(spec: CampaignSpec, tasks: dict[int, dict[str, Any]]) -> None:
    """Print :func:`holding_lines` to stderr, before anything runs."""
    for line in holding_lines(spec, tasks):
        print(f"ddvi campaign: warning: {line}", file=sys.stderr, flush=True)


def run_one(t: dict[str, Any]) -> tuple[dict[str, Any], dict[str, Any]]:
    """Execute a task (on a worker): its row with the dispersed values, and its timing."""
    row, timing = execute(t)
    try:
        from distributed import get_worker

        timing["worker"] = get_worker().address  # host and port: which worker ran it
    except (ImportError, ValueError):
        pass  # not on a Dask worker: the host name
    return {**row, **t["values"]}, timing


@contextmanager
def dask_client(workers: int | None, scheduler: str | None, dashboard: bool):
    """A Client of the cluster at ``scheduler``, or of a LocalCluster of ``workers`` processes
    (default: one per core), one thread each, BLAS single-threaded, no dashboard unless asked."""
    import logging

    from distributed import Client, LocalCluster

    if scheduler:
        with Client(scheduler, timeout="10s") as client:
            yield client
        return
    for name in BLAS_THREADS:  # inherited by the worker processes
        os.environ[name] = "1"
    cluster = LocalCluster(
        n_workers=workers or os.cpu_count() or 1,
        threads_per_worker=1,
        processes=True,
        dashboard_address=":8787" if dashboard else None,
        silence_logs=logging.ERROR,
    )
    with cluster, Client(cluster) as client:
        if dashboard:
            print(f"ddvi campaign: dashboard at {client.dashboard_link}", file=sys.stderr)
        try:
            yield client
        finally:
            _quiet_shutdown(client)


def _silence_distributed() -> None:
    import logging

    logging.getLogger("distributed").setLevel(logging.CRITICAL)


def _quiet_shutdown(client: Any) -> None:
    """Before the LocalCluster closes: its workers' and nannies' own logs to CRITICAL.  Their
    heartbeats race the scheduler's close, and one that loses logs an ERROR with a traceback
    about a closed connection: noise once the campaign is over or stopped (a task's error
    reaches the client as its exception, not through these logs)."""
    with suppress(Exception):
        client.run(_silence_distributed)
        client.run(_silence_distributed, nanny=True)


def _progress(quiet: bool):
    from rich.console import Console
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )

    return Progress(
        TextColumn("runs"),
        BarColumn(),
        MofNCompleteColumn(),
        TextColumn("failures {task.fields[failures]}"),
        TimeElapsedColumn(),
        TextColumn("ETA"),
        TimeRemainingColumn(),
        console=Console(stderr=True),
        disable=quiet,
    )


def run_campaign(
    spec: CampaignSpec, store: ResultStore, mode: str, client: Any, quiet: bool = False
) -> int:
    """Run every run ``store`` lacks on ``client``'s cluster, writing each row as it ends;
    return the number of runs done here."""
    from distributed import as_completed

    done = store.done()
    todo = [i for i in range(spec.campaign.runs) if i not in done]
    if done:
        print(
            f"ddvi campaign: resuming: {len(done)} of {spec.campaign.runs} runs are in the "
            f"table already and skipped; {len(todo)} to run",
            file=sys.stderr,
        )
    token = uuid.uuid4().hex[:8]
    tasks = {i: task(spec, i, mode) for i in todo}
    _say_holding(spec, tasks)
    futures = {
        client.submit(run_one, t, key=f"ddvi-run-{i}-{token}", pure=False): i
        for i, t in tasks.items()
    }
    failures = store.failed()
    with _progress(quiet) as bar:
        job = bar.add_task("runs", total=spec.campaign.runs, completed=len(done), failures=failures)
        for fut in as_completed(futures):
            t = tasks.pop(futures.pop(fut))
            try:
                row, timing = fut.result()
            except Exception as exc:  # the worker died under the run
                row = {
                    "run": t["run"],
                    "seed": t["seed"],
                    "completed": False,
                    "error": f"{type(exc).__name__}: {exc}",
                    **t["values"],
                }
                timing = {"run": t["run"], "wall_s": None, "worker": None}
            store.write(row, timing)
            failures += not row["completed"]
            bar.update(job, advance=1, failures=failures)
    return len(todo)


def only_run(spec: CampaignSpec, folder: Path, index: int, mode: str) -> int:
    """Run ``index`` alone in this process and print its row; 0 when it equals the row the
    campaign table holds (or the table has none), 1 if not."""
    if not 0 <= index < spec.campaign.runs:
        raise CampaignError(f"--only-run: a run index in [0, {spec.campaign.runs - 1}]")
    keep = str(folder / f"run-{index:04d}") if mode == "distributed" else None
    t = task(spec, index, mode, keep)
    _say_holding(spec, {index: t})
    row, timing = run_one(t)
    print(json.dumps(row, indent=1))
    path = folder / "results.sqlite"
    stored = [r for r in read_rows(path) if r["run"] == index] if path.is_file() else []
    if not stored:
        print(f"ddvi campaign: run {index} in {timing['wall_s']:.1f} s", file=sys.stderr)
        return 0
    same = {k: v for k, v in row.items() if stored[0].get(k) != v}
    verdict = "identical to" if not same else f"differs in {sorted(same)} from"
    print(f"ddvi campaign: run {index} is {verdict} the row in {path}", file=sys.stderr)
    return 0 if not same else 1


def add_campaign_arguments(p: argparse.ArgumentParser) -> None:
    """The arguments of ``ddvi campaign``, for ``services.cli``."""
    p.add_argument(
        "file",
        help="a campaign file (TOML; docs/campaigns.md), or a shipped campaign's name: "
        + ", ".join(shipped_campaigns()),
    )
    p.add_argument(
        "--output",
        help="folder of results.sqlite and the report "
        "(default: <the deployment's run.output>/campaign-<name>)",
    )
    p.add_argument("--resume", action="store_true", help="continue the campaign in --output")
    p.add_argument("--workers", type=int, help="LocalCluster workers (default: one per core)")
    p.add_argument("--scheduler", help="a running Dask scheduler, tcp://HOST:PORT")
    p.add_argument(
        "--distributed",
        action="store_true",
        help="each run a full `ddvi run` (processes on Zenoh) on its worker",
    )
    p.add_argument("--dashboard", action="store_true", help="the LocalCluster's dashboard")
    p.add_argument(
        "--only-run",
        type=int,
        metavar="N",
        help="run N alone in this process, print its row, compare to the table",
    )
    p.add_argument("--report-only", action="store_true", help="rewrite the report, run nothing")
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def output_folder(spec: CampaignSpec, output: str | None) -> Path:
    """``--output``, or ``<run.output>/campaign-<name>``."""
    if output:
        return Path(output)
    return Path(spec.base.get("run", {}).get("output", "runs")) / f"campaign-{spec.campaign.name}"


def _execute(spec: CampaignSpec, folder: Path, mode: str, args: argparse.Namespace) -> None:
    """Open (or resume) the result table and run what it lacks on the cluster."""
    from contextlib import closing

    with closing(ResultStore.open(folder / "results.sqlite", spec, mode, args.resume)) as store:
        if set(range(spec.campaign.runs)) <= store.done():
            print(
                f"ddvi campaign: all {spec.campaign.runs} runs are in {folder} already; "
                "nothing to run (the report is written again)",
                file=sys.stderr,
            )
            return
        try:
            with dask_client(args.workers, args.scheduler, args.dashboard) as client:
                run_campaign(spec, store, mode, client, args.quiet)
        except OSError as exc:  # no scheduler at that address
            raise CampaignError(f"cannot reach the cluster: {exc}") from None


class Stopped(BaseException):  # as KeyboardInterrupt: no `except Exception` takes it
    """SIGTERM or SIGHUP: unwind as Ctrl-C does, so that the cluster's processes and their
    semaphores are closed (not leaked) and the table keeps every finished run."""

    def __init__(self, signum: int) -> None:
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


def _stop(signum: int, _frame: Any) -> None:
    raise Stopped(signum)


def campaign_command(args: argparse.Namespace) -> int:
    """0 when every run completed, 1 if one did not, 2 on bad input, 128 + N when stopped
    by signal N."""
    try:
        with lifecycle.handling((signal.SIGTERM, signal.SIGHUP), _stop):
            return _campaign(args)
    except Stopped as exc:
        end = "" if sys.stderr.isatty() else "\n"  # a plain progress line ends unterminated
        print(
            f"{end}ddvi campaign: stopped by {exc}; its finished runs are in the table: the "
            "same command with --resume continues it",
            file=sys.stderr,
        )
        return 128 + exc.signum


def _campaign(args: argparse.Namespace) -> int:
    from services.ground.campaign.report import summary_lines, write_report

    mode = MODES[1] if args.distributed else MODES[0]
    try:
        if args.workers is not None and args.workers < 1:
            raise CampaignError("--workers: at least 1")
        spec = load_campaign(args.file)
        folder = output_folder(spec, args.output)
        if args.only_run is not None:
            return only_run(spec, folder, args.only_run, mode)
        if not args.report_only:
            _execute(spec, folder, mode, args)
        elif not (folder / "results.sqlite").is_file():
            raise CampaignError(f"{folder / 'results.sqlite'}: no such result table")
    except CampaignError as exc:
        print(f"ddvi campaign: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(
            "ddvi campaign: interrupted; its finished runs are in the table: the same "
            "command with --resume continues it",
            file=sys.stderr,
        )
        return 130
    rows = read_rows(folder / "results.sqlite")
    mode = read_meta(folder / "results.sqlite").get("mode", mode)  # the table's own
    report = write_report(spec, folder, rows, mode)
    print("\n".join(summary_lines(spec, rows)))
    print(report)
    return 0 if rows and all(r["completed"] for r in rows) else 1
