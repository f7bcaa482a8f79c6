"""A run folder that holds credentials while its bus.json turns security off (docs/security.md,
"A tampered run folder"): ``ddvi monitor``, its live view and ``ddvi fault`` refuse it, exit 2,
saying why and what to do, and connect to nothing; with ``--insecure`` the user has said so, and
``ddvi monitor`` connects without authentication.  The folder is a secure run's, as the launcher
writes it; its bus.json is edited to name an open hub that serves forged clocks."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import threading
from collections.abc import Iterator
from pathlib import Path

import pytest
import zenoh

from services.bus import BusSettings, open_session
from services.config import deployment_from_table
from services.ground.launch.credentials import hub_settings, write_bus_file
from services.ground.launch.launcher import free_port as find_free_port
from services.interface import encode

pytestmark = pytest.mark.integration

RUN = "tampered-1"
FORGED_T = 4242.0  # the forged clocks' time: no real run says it


@pytest.fixture
def open_hub(free_port: int) -> Iterator[tuple[str, list[str]]]:
    """An open zenoh peer on loopback putting forged clocks of RUN, and recording every fault
    put to RUN: (its endpoint, the faults' keys)."""
    endpoint = f"tcp/127.0.0.1:{free_port}"
    faults: list[str] = []
    stop = threading.Event()
    with open_session(BusSettings(mode="peer", listen=[endpoint], connect=[])) as session:

        def on_fault(sample: zenoh.Sample) -> None:
            faults.append(str(sample.key_expr))

        sub = session.declare_subscriber(f"ddvi/{RUN}/fault/**", on_fault)

        def forge() -> None:
            body = {"step": 1, "dt": 10.0, "fsw": True, "mode": "lockstep", "final": False}
            seq = 0
            while not stop.wait(0.05):
                payload = encode("clock", body, seq=seq, t=FORGED_T, src="environment")
                session.put(f"ddvi/{RUN}/clock", payload)
                seq += 1

        thread = threading.Thread(target=forge, daemon=True)
        thread.start()
        try:
            yield endpoint, faults
        finally:
            stop.set()
            thread.join()
            sub.undeclare()


def _tampered(tmp_path: Path, hub: str) -> Path:
    """A secure run's folder (bus.json and every participant's credentials, as the launcher
    writes them), its bus.json then edited: security off, and another hub."""
    folder = tmp_path / RUN
    folder.mkdir(mode=0o700)
    dep = deployment_from_table({"deputy": [{"name": "lqr"}]})
    write_bus_file(
        folder, RUN, hub_settings(dep, RUN, folder, ["tcp/127.0.0.1:1"], dep.services), True
    )
    info = json.loads((folder / "bus.json").read_text())
    assert info["security"] is True and (folder / "security" / "observer.json").is_file()
    (folder / "bus.json").unlink()
    (folder / "bus.json").write_text(json.dumps({**info, "security": False, "hub": hub}))
    return folder


def _ddvi(*args: str) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1"}
    cmd = [sys.executable, "-m", "services.cli", *args]
    return subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=120)


def _refused(r: subprocess.CompletedProcess[str], folder: Path) -> None:
    assert r.returncode == 2, r.stdout + r.stderr
    said = f"{folder / 'bus.json'} turns security off, but {folder / 'security'} holds the run's"
    assert f"{said} credentials" in r.stderr, r.stderr
    assert '"security": true' in r.stderr and "--insecure" in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1 and "Traceback" not in r.stderr
    assert "clock" not in r.stdout


def test_a_folder_with_credentials_whose_bus_json_turns_security_off_is_refused(
    tmp_path: Path, open_hub: tuple[str, list[str]]
) -> None:
    hub, faults = open_hub
    folder = _tampered(tmp_path, hub)
    _refused(_ddvi("monitor", "--run", str(folder), "--count", "1", "--seconds", "5"), folder)
    _refused(_ddvi("fault", str(folder), "kill", "ctrl-lqr", "--timeout", "3"), folder)
    # naming the hub does not get round it
    via_hub = _ddvi("fault", str(folder), "kill", "ctrl-lqr", "--hub", hub, "--timeout", "3")
    _refused(via_hub, folder)
    live = f"127.0.0.1:{find_free_port()}"  # another port than the hub's, free now
    _refused(_ddvi("monitor", "--run", str(folder), "--live", live, "--seconds", "1"), folder)
    assert faults == []
    # said explicitly, it connects without authentication, and hears what that hub says
    r = _ddvi("monitor", "--run", str(folder), "--insecure", "--count", "1", "--seconds", "20")
    assert r.returncode == 0, r.stderr
    assert f"ddvi/{RUN}/clock clock t={FORGED_T:.3f} src=environment" in r.stdout, r.stdout
