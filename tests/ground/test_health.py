"""Flight-software health in a real run (docs/health.md): a navigation service frozen with
SIGSTOP pauses lock-step, and once it continues the mission flies exactly as without the freeze;
frozen past run.hang_timeout, the run ends with status 1 naming it."""

from __future__ import annotations

import json
from pathlib import Path

import psutil
import pytest

from benchmarks.flood import DEPLOYMENT, readable
from services.ground.storage.recording import read_recording
from tests.support import fly, freeze

pytestmark = pytest.mark.integration

ORBITS = 8.0


def _deployment(tmp: Path, command_deadline: float, hang_timeout: float) -> Path:
    text = DEPLOYMENT.read_text().replace("orbits = 40.0", f"orbits = {ORBITS}", 1)
    text = text.replace(
        "command_deadline = 20.0",
        f"command_deadline = {command_deadline}\nhang_timeout = {hang_timeout}",
        1,
    )
    path = tmp / f"health-{hang_timeout:g}.toml"
    path.write_text(text)
    return path


def _fly(dep: Path, root: Path, freeze_nav: float = 0.0) -> tuple[int, str, Path]:
    """``ddvi run dep``; with ``freeze_nav``, nav-lqr is stopped (SIGSTOP) a second after the
    launcher says the services are alive, for ``freeze_nav`` s, then continued."""
    return fly(dep, root, freeze("nav-lqr", freeze_nav) if freeze_nav else None)


def _deputies(out: Path) -> dict:
    return json.loads((out / "summary.json").read_text())["deputies"]


def test_a_frozen_navigation_pauses_the_mission_which_then_flies_as_without_it(
    tmp_path: Path,
) -> None:
    dep = _deployment(tmp_path, command_deadline=1.0, hang_timeout=30.0)
    status, err, clean = _fly(dep, tmp_path / "clean")
    assert status == 0, err
    status, err, frozen = _fly(dep, tmp_path / "frozen", freeze_nav=5.0)
    assert status == 0, err  # no command missing, late or stale: every step waited
    assert _deputies(frozen) == _deputies(clean)
    summary = json.loads((frozen / "summary.json").read_text())
    assert summary["outcome"]["health"]["paused_steps"] >= 1
    said = (frozen / "logs" / "ctrl-lqr.log").read_text()
    assert "lock-step paused" in said and "from nav-lqr" in said
    assert "no command from ctrl-lqr" in (frozen / "logs" / "environment.log").read_text()


def test_a_navigation_frozen_past_the_hang_timeout_ends_the_run_naming_it(
    tmp_path: Path,
) -> None:
    dep = _deployment(tmp_path, command_deadline=1.0, hang_timeout=3.0)
    status, err, out = _fly(dep, tmp_path / "hung", freeze_nav=12.0)
    assert status == 1, err
    assert "nav-lqr is hung" in err and "run.hang_timeout" in err, err
    assert (out / "report.md").is_file() and readable(out / "recording.mcap")
    assert not psutil.Process().children(recursive=True)  # every service stopped


def test_real_time_flies_the_safe_attitude_on_stale_navigation_and_says_so(
    tmp_path: Path,
) -> None:
    """Real time does not wait: with nav-lqr frozen, ctrl-lqr commands the safe attitude (the
    zero relative attitude) once its navigation is older than run.nav_stale_limit, counts the
    steps, and the completed run exits 3 naming it."""
    dep = _deployment(tmp_path, command_deadline=1.0, hang_timeout=30.0)
    text = dep.read_text().replace('mode = "lockstep"', 'mode = "realtime"\nrate = 600.0', 1)
    text = text.replace(f"orbits = {ORBITS}", "orbits = 1.5", 1)
    dep.write_text(text)
    status, err, out = _fly(dep, tmp_path / "rt", freeze_nav=3.0)
    assert status == 3, err
    assert "safe attitude flown by" in err and "ctrl-lqr (" in err
    summary = json.loads((out / "summary.json").read_text())
    safe = summary["outcome"]["health"]["safe_attitude_steps"]
    assert safe["ctrl-lqr"] >= 3, safe  # 3 s frozen: 1800 s
    assert "safe attitude flown" in (out / "report.md").read_text()
    said = (out / "logs" / "ctrl-lqr.log").read_text()
    assert "flying the safe attitude" in said and "navigation is back" in said
    records, _ = read_recording(out / "recording.mcap")
    flown = [r.data["body"]["sigma"] for r in records if r.topic == "cmd/lqr/att"]
    assert sum(sigma == [0.0, 0.0, 0.0] for sigma in flown) >= safe["ctrl-lqr"]
