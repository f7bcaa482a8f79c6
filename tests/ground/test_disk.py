"""A run on a full or failing disk (docs/health.md, "A full disk"): on a 2 MB tmpfs the
recording closes itself whole while the report still has room, the mission flies on, the report
is written from every message received and says on its first lines what the recording lacks and
which of its files did not fit, and ``ddvi run`` says it in one line and exits 1, with no
traceback and nothing half-written left.  And, in one process: a recording whose write fails
all the same is cut back to its last whole record, and a report with no room at all is not left
in part.  These tests mount a tmpfs (root, ``mount``); elsewhere they are skipped, saying why."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest
from mcap.reader import make_reader

from benchmarks.flood import DEPLOYMENT
from services.config import deployment_from_table
from services.ground.analysis.report import ReportNotWrittenError, write_report
from services.ground.analysis.rundata import RunData
from services.ground.storage.disk import PART, REPORT_ROOM, space_left
from services.ground.storage.recording import Recorder, read_recording
from tests.support import json_messages

ORBITS = 8.0
SIZE = "2m"


@pytest.fixture
def small_disk(tmp_path: Path) -> Iterator[Path]:
    """A 2 MB tmpfs, unmounted after the test whatever happens."""
    if os.geteuid() != 0:
        pytest.skip("mounting a 2 MB tmpfs needs root")
    if shutil.which("mount") is None or shutil.which("umount") is None:
        pytest.skip("no mount command here")
    where = tmp_path / "disk"
    where.mkdir()
    cmd = ["mount", "-t", "tmpfs", "-o", f"size={SIZE}", "tmpfs", str(where)]
    mounted = subprocess.run(cmd, capture_output=True, text=True)
    if mounted.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {mounted.stderr.strip()}")
    try:
        yield where
    finally:
        if subprocess.run(["umount", str(where)], capture_output=True).returncode != 0:
            subprocess.run(["umount", "-l", str(where)], check=False)  # a process still in it


def _fill(disk: Path, leave: int) -> Path:
    """A file that leaves about ``leave`` bytes free on ``disk``."""
    ballast = disk / "ballast"
    left = space_left(disk)
    assert left is not None
    with ballast.open("wb") as f:
        f.write(b"\0" * max(left - leave, 0))
    return ballast


def _files(folder: Path) -> dict[str, int]:
    """Every file under ``folder`` (relative path: size)."""
    return {str(p.relative_to(folder)): p.stat().st_size for p in folder.rglob("*") if p.is_file()}


@pytest.mark.integration
def test_a_full_disk_keeps_a_whole_recording_and_a_report_that_says_what_it_lacks(
    small_disk: Path, tmp_path: Path
) -> None:
    dep = tmp_path / "disk.toml"
    dep.write_text(DEPLOYMENT.read_text().replace("orbits = 40.0", f"orbits = {ORBITS}", 1))
    cmd = [sys.executable, "-m", "services.cli", "run", str(dep), "--output", str(small_disk)]
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1"}
    r = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=300)
    (out,) = [p.parent for p in small_disk.glob("*/bus.json")]
    assert r.returncode == 1, r.stderr[-3000:]
    said = [line for line in r.stderr.splitlines() if line.startswith("ddvi run: ")]
    assert said[-1].startswith("ddvi run: the recording stopped at t = "), said
    assert f"left on {out}; recording.mcap holds" in said[-1]
    assert "also saved there: report.md, summary.json" in said[-1]
    assert "not written: timeseries.csv" in said[-1]
    log = (out / "logs" / "monitor.log").read_text()
    for text in (r.stderr, log):
        assert "Traceback" not in text and "Logging error" not in text, text[-3000:]

    summary = json.loads((out / "summary.json").read_text())
    stop = summary["outcome"]["record"]["recording"]
    assert stop is not None and stop["footer"] is True
    # the recording is whole, by mcap's own reader, and holds what the report says
    with (out / "recording.mcap").open("rb") as f:
        messages = json_messages(make_reader(f).get_summary())
    assert messages == stop["messages"] == summary["messages"]["recorded"] > 1000
    records, complete = read_recording(out / "recording.mcap")
    assert complete and len(records) == stop["messages"]
    assert max(r.log_time for r in records) / 1e9 == stop["stopped_at_s"]
    # the mission flew on, and the report is from every message received
    assert summary["completed"] is True and stop["stopped_at_s"] < summary["sim_time_s"] / 2
    assert stop["not_recorded"] > stop["messages"]
    assert summary["deputies"]["lqr"]["samples"] == summary["sim_time_s"] / 10.0 + 1
    # what did not fit is named, and not there; what is there is whole
    files = _files(out)
    assert "timeseries.csv" in summary["not_written"]
    assert not set(summary["not_written"]) & set(files)
    assert not [f for f in files if f.endswith((PART, ".tmp"))]
    for figure in summary["figures"]:
        assert (out / figure).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert files["report.md"] > 0 and space_left(small_disk) > 0
    first = (out / "report.md").read_text().splitlines()[:6]
    assert any(line.startswith("- record: **incomplete**: the recording stopped") for line in first)
    assert any(line.startswith("- **not written**: `timeseries.csv`") for line in first)


def test_a_recording_whose_write_fails_is_cut_back_to_its_last_whole_record(
    small_disk: Path,
) -> None:
    path = small_disk / "recording.mcap"
    rec = Recorder(path, {"run": "r"}, None)

    def write(n: int) -> None:  # noise: a chunk takes about its size on the disk
        rec.write("probe", "probe", {}, {"n": n, "noise": os.urandom(2048).hex()}, n * 10**9, n)

    for n in range(100):
        write(n)
    rec.flush()  # a whole chunk of 100 messages
    ballast = _fill(small_disk, 4096)  # then another fills the disk: the recorder cannot know
    assert rec._file is not None
    rec._file.left = None  # as on a disk that cannot tell its space
    n = 100
    while rec.stopped is None:
        write(n)
        n += 1
    stop = rec.stopped
    assert not stop.footer and stop.why == "No space left on device"
    assert stop.messages == 100 and stop.at_t == 99.0
    assert rec.not_recorded == n - 100  # the chunk that failed
    rec.close()  # nothing more to do, and no error
    records, complete = read_recording(path)
    assert not complete and [r.data["n"] for r in records] == list(range(100))
    ballast.unlink()


def test_a_report_with_no_room_at_all_is_not_left_in_part(small_disk: Path) -> None:
    data = RunData(deployment_from_table({"deputy": [{"name": "alpha"}]}), "r")
    _fill(small_disk, 1024)
    with pytest.raises(ReportNotWrittenError) as said:
        write_report(small_disk, data, completed=False, monitor_counters={})
    assert str(said.value).startswith(f"{small_disk / 'report.md'}: no room for its ")
    assert f"left on {small_disk})" in str(said.value)
    assert sorted(_files(small_disk)) == ["ballast"]  # no part of a file, no empty one
    assert REPORT_ROOM > 1024
