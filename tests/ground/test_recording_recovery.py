"""A recording cut short (the monitor killed with -9) is recovered up to its last complete chunk:
mcap's standard reader opens the repaired file and ``ddvi report`` writes the report from it."""

from __future__ import annotations

import contextlib
import json
import shutil
import warnings
from pathlib import Path

import pytest
from mcap.reader import make_reader

from services.cli import main as ddvi
from services.ground.analysis.recover import TRUNCATED, is_complete, recover
from services.ground.storage.recording import RECORDING, Recorder
from services.interface import decode, encode, topics

DEPLOYMENT = """
[run]
name = "cut"
orbits = 1.0
[[deputy]]
name = "lqr"
"""


def _clock(step: int, src: str = "environment", final: bool = False):
    body = {"step": step, "dt": 10.0, "fsw": step % 6 == 0, "mode": "lockstep", "final": final}
    return decode(encode("clock", body, seq=step, t=10.0 * step, src=src), "clock")


def _cut_recording(tmp_path: Path, flushed: int, unflushed: int) -> Path:
    """A run folder whose recording is the file as a kill -9 leaves it: ``flushed`` clock
    messages in complete chunks, then ``unflushed`` more written to a chunk never closed."""
    dep = tmp_path / "cut.toml"
    dep.write_text(DEPLOYMENT)
    live = tmp_path / "live"
    rec = Recorder(live / RECORDING, {"run": "cut-1", "deployment": str(dep)}, attachment=dep)
    for k in range(flushed):
        rec.message(topics.CLOCK, _clock(k), recv_ns=10**18 + k)
        if k % 100 == 99:
            rec.flush()
    rec.flush()
    for k in range(flushed, flushed + unflushed):
        rec.message(topics.CLOCK, _clock(k), recv_ns=10**18 + k)
    rec._file.flush()  # what the OS holds: the open chunk is in the writer's buffer only
    folder = tmp_path / "run"
    folder.mkdir()
    shutil.copy(live / RECORDING, folder / RECORDING)
    # and a torn tail: half a record, as a write interrupted by the kill leaves it
    with (folder / RECORDING).open("ab") as f:
        f.write(b"\x06\xff\xff\x00\x00\x00\x00\x00\x00\x28\xb5")
    rec.close()
    return folder


def _standard_count(path: Path) -> int:
    with path.open("rb") as f:
        return sum(1 for _ in make_reader(f).iter_messages())


def test_a_cut_recording_is_repaired_up_to_its_last_complete_chunk(tmp_path: Path) -> None:
    folder = _cut_recording(tmp_path, flushed=450, unflushed=40)
    assert not is_complete(folder / RECORDING)
    with (folder / RECORDING).open("rb") as f, pytest.raises(Exception):  # noqa: B017
        list(make_reader(f).iter_messages())  # the standard reader refuses the cut file
    got = recover(folder)
    assert got.messages == 450 and not got.complete
    assert _standard_count(folder / RECORDING) == 450  # every flushed message
    assert (folder / TRUNCATED).is_file()
    summary = json.loads((folder / "summary.json").read_text())
    assert summary["recovered"] == {"messages": 450, "complete": False}
    assert summary["completed"] is False and summary["outcome"]["ended_by"] == "stopped"
    assert summary["sim_time_s"] == 4490.0  # the last clock read
    assert "up to its last complete chunk" in (folder / "report.md").read_text()


def test_ddvi_report_recovers_a_cut_recording_once(tmp_path, capsys) -> None:
    folder = _cut_recording(tmp_path, flushed=120, unflushed=0)
    assert ddvi(["report", str(folder)]) == 0
    out = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert out == {"messages": 120, "complete": False}
    # the repaired file is complete: a second report reads it as it is
    assert ddvi(["report", str(folder)]) == 0
    assert json.loads(capsys.readouterr().out.strip())["complete"] is True


def test_a_clock_from_anyone_but_the_environment_is_not_obeyed(tmp_path: Path) -> None:
    dep = tmp_path / "cut.toml"
    dep.write_text(DEPLOYMENT)
    folder = tmp_path / "run"
    rec = Recorder(folder / RECORDING, {"run": "cut-1", "deployment": str(dep)}, attachment=dep)
    for k in range(10):
        rec.message(topics.CLOCK, _clock(k), recv_ns=k)
    rec.message(topics.CLOCK, _clock(10**6, src="intruder", final=True), recv_ns=11)
    rec.close()
    got = recover(folder)
    assert got.complete and got.messages == 11
    out = got.summary["outcome"]
    assert out["refused_clocks"] == 1 and out["ended_by"] == "stopped"
    assert got.summary["sim_time_s"] == 90.0
    assert "1 clock messages refused" in (folder / "report.md").read_text()


def test_ddvi_report_of_no_run_folder_is_one_line_and_exit_2(tmp_path, capsys) -> None:
    assert ddvi(["report", str(tmp_path / "nothing")]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "no run folder" in err


LONG = """
[run]
name = "kill9"
orbits = 60.0
[[deputy]]
name = "lqr"
"""


@pytest.mark.integration
def test_kill_9_of_the_monitor_mid_run_leaves_a_report_and_a_readable_recording(
    tmp_path: Path,
) -> None:
    """The launcher sees the monitor die, stops the run and recovers the report; mcap's
    standard reader then reads every message the cut file held up to its last complete
    chunk."""
    import subprocess
    import sys

    import psutil
    from mcap.reader import NonSeekingReader

    from tests.support import FLYING, read_until_flying, wait_until

    dep = tmp_path / "kill9.toml"
    dep.write_text(LONG)
    cmd = [
        sys.executable,
        "-m",
        "services.cli",
        "run",
        str(dep),
        "--output",
        str(tmp_path / "runs"),
    ]
    launcher = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE)

    def kids() -> list[psutil.Process]:
        return psutil.Process(launcher.pid).children(recursive=True)

    assert launcher.stderr is not None
    said = read_until_flying(launcher.stderr)
    assert FLYING in said[-1], said

    def streamed(path: Path) -> int:
        """Messages a stream reader takes from ``path`` (complete chunks only)."""
        n = 0
        with path.open("rb") as f, contextlib.suppress(Exception):  # its open tail
            for _ in NonSeekingReader(f).iter_messages(log_time_order=False):
                n += 1
        return n

    def flushed() -> int:
        """Messages in complete chunks of the run's recording so far (0 before it is made)."""
        return sum(streamed(path) for path in (tmp_path / "runs").glob(f"*/{RECORDING}"))

    # the monitor has flushed more than 1000 messages: what the recovery must give back
    assert wait_until(lambda: flushed() > 1000, timeout=60), flushed()
    (monitor,) = [p for p in kids() if "services.ground.monitoring.monitor" in p.cmdline()]
    monitor.kill()
    _, rest = launcher.communicate(timeout=120)
    err = b"".join([*said, rest]).decode()
    assert launcher.returncode == 1, err
    assert "monitor exited with status -9" in err and "report recovered" in err, err
    (folder,) = (tmp_path / "runs").iterdir()
    recovered = _standard_count(folder / RECORDING)
    summary = json.loads((folder / "summary.json").read_text())
    # the cut file, read by mcap as a stream
    assert recovered == streamed(folder / TRUNCATED) == summary["recovered"]["messages"] > 1000
    assert summary["completed"] is False and summary["outcome"]["ended_by"] == "stopped"
    assert f"({recovered} messages)" in err


def test_a_regenerated_report_counts_every_record_once(tmp_path: Path) -> None:
    """Liveliness records are recordings too: the report written again says the same number
    of messages recorded as the recording holds (and as ``ddvi report`` reads); its figures,
    without a deputy's data, draw no legend and say no warning."""
    dep = tmp_path / "cut.toml"
    dep.write_text(DEPLOYMENT)
    folder = tmp_path / "run"
    rec = Recorder(folder / RECORDING, {"run": "cut-1", "deployment": str(dep)}, attachment=dep)
    rec.alive("nav-lqr", True, recv_ns=1, t=0.0)
    for k in range(10):
        rec.message(topics.CLOCK, _clock(k), recv_ns=2 + k)
    rec.alive("nav-lqr", False, recv_ns=20, t=90.0)
    rec.close()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        got = recover(folder)
    # a run with no deputy data draws its figures without a legend, and without a warning
    assert not [str(w.message) for w in caught if "legend" in str(w.message)]
    assert got.messages == 12 == _standard_count(folder / RECORDING)
    assert got.summary["messages"]["recorded"] == 12
    assert got.summary["messages"]["services"]["monitor"]["received"] == 10
    assert "Messages: 12 recorded by the monitor" in (folder / "report.md").read_text()
