"""A run's verdict under the faults it exists to inject, on real runs (docs/health.md,
docs/security.md): one forged sequence number does not stall the mission, a frozen monitor
loses nothing, and a freeze past run.hang_timeout is blamed on the part that froze."""

from __future__ import annotations

import json
import subprocess
import threading
from pathlib import Path
from typing import Any

import psutil
import pytest
import zenoh

from benchmarks.flood import DEPLOYMENT, readable
from services.bus import BusSettings, open_session
from services.bus.security import credentials_path, load_credentials
from services.interface import decode, encode
from tests.support import fly, freeze

pytestmark = pytest.mark.integration

ORBITS = 8.0
ATTACK_T = 20_000.0  # s: the simulation time the forged commands are put at
END_T = ORBITS * 5430.0  # s: about the short mission's last step (inside the mission's window)


def _deployment(tmp: Path, hang_timeout: float = 60.0) -> Path:
    text = DEPLOYMENT.read_text().replace("orbits = 40.0", f"orbits = {ORBITS}", 1)
    text = text.replace(
        "command_deadline = 20.0", f"command_deadline = 2.0\nhang_timeout = {hang_timeout}", 1
    )
    path = tmp / f"trust-{hang_timeout:g}.toml"
    path.write_text(text)
    return path


def _summary(out: Path) -> dict[str, Any]:
    return json.loads((out / "summary.json").read_text())


def _finals(out: Path) -> dict[str, float]:
    return {k: v["final_along_track_error_m"] for k, v in _summary(out)["deputies"].items()}


@pytest.fixture(scope="module")
def clean(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A clean run of the short mission, the figures the others are held to."""
    root = tmp_path_factory.mktemp("clean")
    status, err, out = fly(_deployment(root), root)
    assert status == 0, err
    return out


def _seq_attack(proc: subprocess.Popen, folder: Path) -> None:
    """ctrl-lqr's stolen credential: at the first clock at or past ``ATTACK_T``, the genuine
    body and boot of the newest command, stamped with that clock, once with seq 2^64 - 1 and
    once with 2^62; then the same body for the mission's last step under a boot of its own."""
    info = json.loads((folder / "bus.json").read_text())
    cred = load_credentials(credentials_path(folder, "ctrl-lqr"))
    settings = BusSettings(
        mode="client", listen=[], connect=[info["hub"]], user=cred.user, password=cred.password
    )
    prefix = f"ddvi/{info['run']}/"
    newest: list[Any] = []
    done = threading.Event()
    with open_session(settings) as session:

        def on_command(sample: zenoh.Sample) -> None:
            newest[:] = [decode(sample.payload.to_bytes(), "cmd")]

        def on_clock(sample: zenoh.Sample) -> None:
            clock = decode(sample.payload.to_bytes(), "clock")
            if done.is_set() or clock.t < ATTACK_T or not newest:
                return
            genuine = newest[0]
            for seq in (2**64 - 1, 2**62):
                forged = encode(
                    "cmd", genuine.body, seq=seq, t=clock.t, src="ctrl-lqr", boot=genuine.boot
                )
                session.put(prefix + "cmd/lqr/att", forged)
            # and a boot of its own, taken as a restarted controller's, for the mission's end
            body = {**genuine.body, "for_t": END_T}
            forged = encode("cmd", body, seq=0, t=clock.t, src="ctrl-lqr", boot=genuine.boot + 1)
            session.put(prefix + "cmd/lqr/att", forged)
            done.set()

        subs = [
            session.declare_subscriber(prefix + "cmd/lqr/att", on_command),
            session.declare_subscriber(prefix + "clock", on_clock),
        ]
        try:
            while not done.wait(0.05) and proc.poll() is None:
                pass
        finally:
            for sub in subs:
                sub.undeclare()
    assert done.is_set(), "the mission ended before the attack"


def test_two_forged_sequence_numbers_neither_stall_nor_change_the_mission(
    clean: Path, tmp_path: Path
) -> None:
    status, err, out = fly(_deployment(tmp_path), tmp_path, during=_seq_attack)
    assert status in (0, 3), err
    assert _finals(out) == _finals(clean)
    summary = _summary(out)
    env = summary["messages"]["services"]["environment"]
    assert env["rejected.jump"] == 2, env  # both refused where they act, by that reason
    assert env["bad_commands"] == 1, env  # for a step not clocked: no controller sent it
    assert summary["messages"]["services"]["monitor"]["ignored.jump"] == 2
    assert summary["outcome"]["refused_by_number"] == {"jump": 2}
    assert "refused by their sequence number: 2 jump" in (out / "report.md").read_text()
    assert not summary["messages"]["unrecorded"]  # nothing genuine taken for lost
    commands = _summary(clean)["outcome"]["commands"]
    assert summary["outcome"]["commands"] == {**commands, "refused": 3}
    rows, clean_rows = (d / "timeseries.csv" for d in (out, clean))
    assert rows.read_text() == clean_rows.read_text()  # the command in force, every sample


def test_a_monitor_frozen_for_20_s_loses_nothing(clean: Path, tmp_path: Path) -> None:
    """Lock-step runs at most its lead past what the monitor has recorded: frozen, the monitor
    pauses the mission, and once it goes on the record and every figure are a clean run's."""
    status, err, out = fly(_deployment(tmp_path), tmp_path, during=freeze("monitor", 20.0))
    assert status == 0, err
    summary, reference = _summary(out), _summary(clean)
    paused = summary["outcome"]["health"]["paused_steps"]
    assert paused >= 1
    # every message a clean run records, and the environment's word of each pause
    kinds, clean_kinds = summary["messages"]["by_schema"], reference["messages"]["by_schema"]
    said = {"log": kinds["log"] - paused} if kinds["log"] > paused else {}
    assert {k: v for k, v in kinds.items() if k != "log"} | said == clean_kinds
    assert summary["messages"]["recorded"] == reference["messages"]["recorded"] + paused
    assert not summary["messages"]["unrecorded"]
    assert summary["deputies"] == reference["deputies"]  # finals, learned-at, gains
    assert (
        "acknowledgement of the recording from monitor"
        in (out / "logs" / "environment.log").read_text()
    )
    assert readable(out / "recording.mcap")


@pytest.mark.parametrize(
    ("part", "named"),
    [
        ("environment", "environment is hung"),
        ("launcher", "the run's router (the launcher's process) is hung"),
        ("monitor", "monitor is hung"),
    ],
)
def test_a_freeze_past_the_hang_timeout_is_blamed_on_what_froze(
    part: str, named: str, tmp_path: Path
) -> None:
    """Frozen past run.hang_timeout, the time master, the router or the recorder is named in
    the run's last word, not a service that was only waiting for it."""
    dep = _deployment(tmp_path, hang_timeout=5.0)
    status, err, out = fly(dep, tmp_path, during=freeze(part, 22.0))
    assert status == 1, err
    assert named in err, err
    hung = [line for line in err.splitlines() if " is hung" in line]
    assert all(named in line for line in hung), hung  # nobody else is blamed
    assert (out / "report.md").is_file() and readable(out / "recording.mcap")
    assert not psutil.Process().children(recursive=True)  # every service stopped
