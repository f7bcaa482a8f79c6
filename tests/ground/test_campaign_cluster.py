"""``ddvi campaign`` on real Dask clusters: a `dask scheduler` and two `dask worker` processes on
loopback, LocalClusters of one and two workers, a campaign killed and resumed.  Short missions
(one orbit) keep each campaign to seconds."""

from __future__ import annotations

import json
import os
import signal
import sqlite3
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from services.cli import main
from services.ground.campaign import load_campaign
from services.ground.campaign.dispersions import draw_run
from services.ground.campaign.store import read_rows
from tests.support import wait_until

pytestmark = pytest.mark.integration

CAMPAIGN = """
[campaign]
name = "short"
deployment = "rendezvous"
runs = {runs}
seed = 5
success_threshold = 40000.0
[overrides.run]
orbits = 1.0
[[dispersion]]
key = "environment.density_factor"
distribution = "uniform"
low = 0.8
high = 1.25
[[dispersion]]
key = "deputy[*].navigation.position_noise"
distribution = "uniform"
low = 0.0
high = 1.0
[[dispersion]]
key = "deputy[*].initial.along_track"
distribution = "uniform"
low = -31000.0
high = -27000.0
"""


def campaign_file(folder: Path, runs: int) -> Path:
    path = folder / f"campaign-{runs}.toml"
    path.write_text(CAMPAIGN.format(runs=runs))
    return path


def ddvi(*args: str, **kw) -> subprocess.Popen:
    cmd = [sys.executable, "-m", "services.cli", "campaign", *args, "--quiet"]
    return subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, **kw)


def finish(proc: subprocess.Popen, timeout: float = 120.0) -> str:
    out, err = proc.communicate(timeout=timeout)
    assert proc.returncode == 0, err[-2000:]
    return out


def runs_table(path: Path) -> list[dict]:
    return read_rows(path / "results.sqlite")


@pytest.fixture
def dask_cluster(tmp_path: Path) -> Iterator[str]:
    """A `dask scheduler` and two single-threaded `dask worker` processes on 127.0.0.1 (random
    ports); the scheduler's address."""
    dask = str(Path(sys.executable).parent / "dask")
    info = tmp_path / "scheduler.json"
    common = {"cwd": tmp_path, "stdout": subprocess.DEVNULL, "stderr": subprocess.DEVNULL}
    scheduler = ["scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard"]
    procs = [subprocess.Popen([dask, *scheduler, "--scheduler-file", str(info)], **common)]
    try:
        assert wait_until(lambda: info.is_file() and info.stat().st_size > 0, 60.0)
        address = json.loads(info.read_text())["address"]
        worker = ["worker", address, "--nthreads", "1", "--host", "127.0.0.1", "--no-dashboard"]
        env = {**os.environ, "OPENBLAS_NUM_THREADS": "1"}
        for k in range(2):  # no nanny: one process per worker
            procs.append(
                subprocess.Popen(
                    [dask, *worker, "--no-nanny", "--name", f"w{k}"], env=env, **common
                )
            )
        from distributed import Client

        with Client(address, timeout="30s") as client:
            client.wait_for_workers(2, timeout=90)
        yield address
    finally:
        for p in reversed(procs):  # the workers, then the scheduler
            p.terminate()
            try:
                p.wait(timeout=10)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()


def test_a_campaign_runs_on_a_dask_scheduler_and_two_workers(
    tmp_path: Path, dask_cluster: str, capsys: pytest.CaptureFixture
) -> None:
    path = campaign_file(tmp_path, 4)
    out = finish(ddvi(str(path), "--scheduler", dask_cluster, "--output", str(tmp_path / "o")))
    assert "4/4 runs, 0 failed" in out
    rows = runs_table(tmp_path / "o")
    spec = load_campaign(str(path))
    assert [r["run"] for r in rows] == [0, 1, 2, 3]
    for r in rows:
        _, values, seed = draw_run(spec, r["run"])
        assert r["completed"] == 1 and r["error"] is None and r["seed"] == seed
        assert all(r[k] == v for k, v in values.items())
        for name in ("lqr", "ddvi"):  # one orbit: still about the initial gap behind
            assert 25000.0 < r[f"{name}.final_error_m"] < 35000.0
            assert r[f"{name}.last_orbit_max_error_m"] >= r[f"{name}.final_error_m"]
        assert r["lqr.controller"] == "lqr" and r["lqr.gain_error"] is not None
        # one orbit: the learner has not learned, so it has no gain error (not K0's)
        assert r["ddvi.learned_at_orbits"] is None and r["ddvi.learned"] == 0
        assert r["ddvi.gain_error"] is None and r["ddvi.note"]
    # both workers ran runs (the timing table holds each run's wall time and worker, apart)
    timing = read_rows(tmp_path / "o" / "results.sqlite", "timing")
    assert [t["run"] for t in timing] == [0, 1, 2, 3] and all(t["wall_s"] > 0 for t in timing)
    assert len({t["worker"] for t in timing}) == 2
    assert (tmp_path / "o" / "report.md").is_file()
    # a run reproduced alone, here, is the table's row bit for bit
    assert main(["campaign", str(path), "--only-run", "2", "--output", str(tmp_path / "o")]) == 0
    assert "run 2 is identical to the row" in capsys.readouterr().err


@pytest.fixture(scope="module")
def straight(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[dict]]:
    """The 8-run campaign run straight through on a 2-worker LocalCluster: its file, rows."""
    folder = tmp_path_factory.mktemp("straight")
    path = campaign_file(folder, 8)
    finish(ddvi(str(path), "--workers", "2", "--output", str(folder / "o")))
    return path, runs_table(folder / "o")


def test_the_same_campaign_twice_gives_the_same_table(
    straight: tuple[Path, list[dict]], tmp_path: Path
) -> None:
    path, rows = straight
    finish(ddvi(str(path), "--workers", "1", "--output", str(tmp_path / "again")))
    assert len(rows) == 8 and all(r["completed"] for r in rows)
    assert runs_table(tmp_path / "again") == rows
    finals = np.array([r["ddvi.final_error_m"] for r in rows])
    assert np.unique(finals).size == 8  # dispersed runs, not one run eight times


def _count(db: Path) -> int:
    try:
        con = sqlite3.connect(db)
        try:
            return con.execute("SELECT count(*) FROM runs").fetchone()[0]
        finally:
            con.close()
    except sqlite3.Error:
        return 0


def test_a_killed_campaign_resumes_to_the_same_table(
    straight: tuple[Path, list[dict]], tmp_path: Path
) -> None:
    path, rows = straight
    out = tmp_path / "killed"
    proc = ddvi(str(path), "--workers", "1", "--output", str(out), start_new_session=True)
    try:
        assert wait_until(lambda: _count(out / "results.sqlite") >= 2, 90.0)
    finally:
        os.killpg(proc.pid, signal.SIGKILL)  # the campaign and its LocalCluster's workers
        proc.communicate()
    kept = runs_table(out)
    assert 2 <= len(kept) < 8
    assert kept == [r for r in rows if r["run"] in {k["run"] for k in kept}]
    # without --resume the finished runs are not overwritten
    assert main(["campaign", str(path), "--output", str(out)]) == 2
    finish(ddvi(str(path), "--workers", "2", "--output", str(out), "--resume"))
    assert runs_table(out) == rows


def test_sigterm_stops_a_campaign_in_order_and_resume_says_what_it_skips(
    tmp_path: Path,
) -> None:
    """SIGTERM unwinds the campaign as Ctrl-C does: its LocalCluster closed (no semaphore
    leaked), exit 143, the finished rows kept; --resume says how many runs it skips."""
    path, out = campaign_file(tmp_path, 40), tmp_path / "stopped"
    proc = ddvi(str(path), "--workers", "1", "--output", str(out))
    try:
        assert wait_until(lambda: _count(out / "results.sqlite") >= 1, 90.0)
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=60)
    finally:
        proc.kill()
    assert proc.returncode == 128 + signal.SIGTERM, err[-2000:]
    assert "ddvi campaign: stopped by SIGTERM" in err
    assert "leaked" not in err and "Traceback" not in err, err[-2000:]
    kept = len(runs_table(out))
    assert 1 <= kept < 40
    resumed = ddvi(str(path), "--workers", "1", "--output", str(out), "--resume")
    try:
        assert wait_until(lambda: _count(out / "results.sqlite") > kept, 90.0)
    finally:
        resumed.send_signal(signal.SIGTERM)
        _, err = resumed.communicate(timeout=60)
    assert f"resuming: {kept} of 40 runs are in the table already and skipped" in err, err
