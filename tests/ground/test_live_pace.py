"""A watchable pace: ``ddvi run --rate R`` flies lock-step no faster than R times real time and
flies the same mission; ``--wait-for-client`` holds the first step until a client of the
live view subscribes; their bad input is one line and exit 2."""

from __future__ import annotations

import json
import queue
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import pytest

from benchmarks.foxglove_client import FoxgloveClient
from services.cli import main as ddvi
from services.ground.storage.recording import read_recording
from tests.ground.test_live import SHORT, free_port

pytest.importorskip("foxglove")

FLOWN = ("truth/", "nav/", "cmd/", "ctrl/")
"""The topics of what the mission flew (a controller's status, which counts wall-time events,
aside)."""


@pytest.mark.parametrize(
    ("argv", "said"),
    [
        (["--rate", "0"], "--rate: expected simulated seconds per wall second"),
        (["--rate", "-3"], "--rate: expected simulated seconds per wall second"),
        (["--rate", "fast"], "--rate: expected simulated seconds per wall second"),
        (["--wait-for-client"], "--wait-for-client waits for a client of the live view"),
    ],
)
def test_a_bad_pace_is_one_line_and_exit_2(
    argv: list[str], said: str, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    try:
        status = ddvi(["run", "--output", str(tmp_path), *argv])
    except SystemExit as exc:  # argparse's own refusal, one line too
        status = exc.code
    assert status == 2
    err = capsys.readouterr().err
    assert said in err and len(err.strip().splitlines()) == 1, err
    assert not list(tmp_path.iterdir())  # nothing launched


def test_a_pace_for_a_real_time_deployment_is_bad_input(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    path = tmp_path / "realtime.toml"
    path.write_text('[run]\nmode = "realtime"\nrate = 50.0\n[[deputy]]\nname = "lqr"\n')
    assert ddvi(["run", str(path), "--output", str(tmp_path / "runs"), "--rate", "10"]) == 2
    err = capsys.readouterr().err
    assert "--rate paces lock-step; this deployment flies in real time at run.rate = 50" in err
    assert not (tmp_path / "runs").exists()


def _run(tmp: Path, *extra: str) -> tuple[Path, float]:
    """``ddvi run`` of the short mission with ``extra``: its folder and wall seconds."""
    tmp.mkdir()
    path = tmp / "short.toml"
    path.write_text(SHORT)
    cmd = [sys.executable, "-m", "services.cli", "run", str(path), "--quiet"]
    cmd += ["--output", str(tmp / "runs"), *extra]
    t0 = time.monotonic()
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-3000:]
    return Path(done.stdout.strip().splitlines()[-1]), time.monotonic() - t0


def _flown(folder: Path) -> dict[str, list[Any]]:
    """What the mission flew, from its recording: each truth, navigation, command and gains
    message's time and body, by topic."""
    records, complete = read_recording(folder / "recording.mcap")
    assert complete
    out: dict[str, list[Any]] = {}
    for r in records:
        if r.topic.startswith(FLOWN) and not r.topic.endswith("/status"):
            out.setdefault(r.topic, []).append((r.data["t"], r.data["body"]))
    return out


def _clock_span(folder: Path) -> float:
    """Wall seconds between the first and the last clock the monitor received."""
    records, _ = read_recording(folder / "recording.mcap")
    stamps = [r.publish_time for r in records if r.topic == "clock"]
    return (max(stamps) - min(stamps)) / 1e9


@pytest.mark.integration
def test_a_paced_mission_is_the_mission_flown_at_full_speed(tmp_path: Path) -> None:
    fast, _ = _run(tmp_path / "fast")
    paced, _ = _run(tmp_path / "paced", "--rate", "2500")
    summary = {f: json.loads((f / "summary.json").read_text()) for f in (fast, paced)}
    sim = summary[paced]["sim_time_s"]
    assert summary[paced]["deputies"] == summary[fast]["deputies"]
    flown = _flown(paced)
    assert flown == _flown(fast) and len(flown["truth/ddvi"]) == sim / 10.0 + 1
    # no faster than 2500 times real time: the flight's clocks span the mission over 2500
    assert _clock_span(paced) >= sim / 2500 - 0.1
    assert _clock_span(fast) < sim / 2500  # which the full-speed flight does not take


def _lines(stream: Any, out: queue.SimpleQueue[str]) -> None:
    for line in stream:
        out.put(line)


def _drained(lines: queue.SimpleQueue[str]) -> list[str]:
    out = []
    while not lines.empty():
        out.append(lines.get())
    return out


@pytest.mark.integration
def test_the_first_step_waits_for_a_client_as_long_as_it_takes(tmp_path: Path) -> None:
    path = tmp_path / "short.toml"
    # a wait longer than any lock-step wait may last: the mission is not flying meanwhile
    paced = "command_deadline = 1.0\nhang_timeout = 2.0"
    path.write_text(SHORT.replace("command_deadline = 20.0", paced))
    port = free_port()
    cmd = [sys.executable, "-m", "services.cli", "run", str(path), "--output", str(tmp_path)]
    cmd += ["--live", f"ws://127.0.0.1:{port}", "--wait-for-client", "--rate", "4000"]
    run = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    said: queue.SimpleQueue[str] = queue.SimpleQueue()
    printed: queue.SimpleQueue[str] = queue.SimpleQueue()
    assert run.stderr is not None and run.stdout is not None
    # one reader per stream, and nothing else reads them: communicate() would take lines from
    # under the readers
    readers = [
        threading.Thread(target=_lines, args=(run.stderr, said), daemon=True),
        threading.Thread(target=_lines, args=(run.stdout, printed), daemon=True),
    ]
    for reader in readers:
        reader.start()
    try:
        seen = []
        while not any("waiting for a client of" in line for line in seen):
            seen.append(said.get(timeout=120))
        assert f"ws://127.0.0.1:{port}: the mission flies once one subscribes" in seen[-1]
        time.sleep(3.0)  # the point: longer than any lock-step wait may last
        assert run.poll() is None  # nobody gave up
        joined = time.time_ns()
        client = FoxgloveClient(f"ws://127.0.0.1:{port}", timeout=10)
        assert run.wait(timeout=300) == 0
        assert client.wait_closed(30)
    finally:
        if run.poll() is None:
            run.kill()
            run.wait()
    for reader in readers:
        reader.join(timeout=30)  # until each stream's end: every line is in its queue
    rest = _drained(said)
    assert any("a client is watching: the mission flies" in line for line in rest), rest
    # the client saw the mission from its first step on, and nothing flew before it came
    clocks = [m.json()["t"] for m in client.messages if m.topic == "clock"]
    assert clocks[0] == 0.0 and clocks[-1] == 8100.0
    folder = Path(_drained(printed)[-1].strip())
    records, _ = read_recording(folder / "recording.mcap")
    first_clock = min(r.publish_time for r in records if r.topic == "clock")
    assert first_clock > joined
    logs = [r.data["body"]["text"] for r in records if r.topic == "log/monitor"]
    assert any(text.startswith("live view: a client subscribed") for text in logs)
