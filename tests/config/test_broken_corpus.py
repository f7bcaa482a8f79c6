"""A generated corpus of broken deployments and commands: each gets one line on stderr and exit
status 2, no traceback, no folder outside the output root, nothing left running.

The commands run in this process (``services.cli.main``): a deployment that fails its checks
never starts a process.  The few cases that need the launcher's bus (a port in use, an output
folder that cannot be made) open a zenoh session in this process and start nothing; a handful
of cases also run as real processes (integration)."""

from __future__ import annotations

import copy
import math
import os
import socket
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import psutil
import pytest
import tomli_w

from services.cli import main as ddvi

BASE: dict[str, Any] = {"run": {"name": "corpus", "orbits": 1.0}, "deputy": [{"name": "lqr"}]}

NAN, INF = math.nan, math.inf
BAD_VALUES: dict[str, list[Any]] = {
    "run.orbits": [1e-9, 0.0, -1.0, NAN, INF, 1e6],
    "run.nav_period": [0.0, -10.0, NAN, 1e-300],
    "run.fsw_period": [0.0, NAN, 1e9],
    "run.rate": [0.0, INF],
    "run.command_deadline": [0.0, 1e9],
    "run.startup_timeout": [-1.0, 1e9],
    "run.hang_timeout": [0.0, -1.0, NAN, 1e9],
    "run.nav_stale_limit": [-1.0, INF],
    "run.seed": [-1, 2**40],
    "run.status_every": [0, -5],
    "environment.density_factor": [0.0, NAN, 1e300],
    "environment.max_step": [0.0],
    "environment.min_altitude": [-1.0],
    "environment.rtol": [0.0, 1.0],
    "atmosphere.rho0": [1e300, 0.0, -1.0],
    "atmosphere.scale_height": [0.0, INF],
    "atmosphere.h_ref": [-1.0],
    "spacecraft.mass": [0.0, NAN],
    "spacecraft.area": [-1.0],
    "spacecraft.cd": [0.0, 1e9],
    "spacecraft.normal_angle": [0.0, 90.5],
    "chief.a": [1000.0, 6.4e6, 1e12, NAN],
    "chief.e": [1.5, -0.1, 1.0],
    "chief.i": [200.0],
    "chief.area_factor": [0.0, -1.0, NAN, 1e9],
    "deputy.0.orbit.e": [1.5],
    "deputy.0.orbit.a": [1000.0],
    "deputy.0.y_ref": [NAN],
    "deputy.0.area_factor": [0.0, 1e9],
    "deputy.0.navigation.seed": [-1],
    "deputy.0.navigation.position_noise": [-1.0, INF],
    "deputy.0.learning.seed": [-1],
    "deputy.0.learning.max_iterations": [0, -1],
    "deputy.0.learning.tol": [0.0, -1e-6],
    "deputy.0.learning.exploration_frequencies": [[0.0], [-1.0, 1.0]],
    "deputy.0.learning.step_size": [0.0],
    "bus.port": [-1, 70000],
    "bus.connect": [["garbage"], ["tcp/127.0.0.1:99999"], ["tcp/:7447"]],
    "run.name": ["../escape", "a/b", "", ".hidden", "x" * 65, "../../../tmp/x"],
    "ros2.endpoint": ["garbage", "udp/127.0.0.1:7447", "tcp/127.0.0.1:0", "tcp/127.0.0.1"],
    "ros2.domain_id": [-1, 233],
    "ros2.topics": [["odometry"], ["clock", "clock"]],
}


def _set(table: dict[str, Any], dotted: str, value: Any) -> dict[str, Any]:
    """A copy of ``table`` with ``dotted`` (``deputy.0.orbit.e``) set to ``value``."""
    out = copy.deepcopy(table)
    node: Any = out
    *path, last = dotted.split(".")
    for part in path:
        node = node[int(part)] if part.isdigit() else node.setdefault(part, {})
    node[last] = value
    return out


def _leaf(dotted: str) -> str:
    return dotted.rsplit(".", 1)[-1]


Case = tuple[str, Callable[[Path], list[str]], str]
"""(id, argv from the case's folder, a word the one line must hold)."""


def _deployment_case(table: dict[str, Any]) -> Callable[[Path], list[str]]:
    def argv(folder: Path) -> list[str]:
        path = folder / "dep.toml"
        path.write_bytes(tomli_w.dumps(table).encode())
        return ["run", str(path), "--output", str(folder / "runs"), "--quiet"]

    return argv


def _file_case(data: bytes) -> Callable[[Path], list[str]]:
    def argv(folder: Path) -> list[str]:
        path = folder / "dep.toml"
        path.write_bytes(data)
        return ["run", str(path), "--output", str(folder / "runs"), "--quiet"]

    return argv


def _system_case(text: str, *extra: str) -> Callable[[Path], list[str]]:
    def argv(folder: Path) -> list[str]:
        path = folder / "system.toml"
        path.write_text(text)
        return [*extra[:1], str(path), *extra[1:]]

    return argv


HUGE_SYSTEM = """A = [[1e308, 1e308], [0.0, 1e308]]
B = [[0.0], [1.0]]
Q = [[1.0, 0.0], [0.0, 1.0]]
R = [[1.0]]
"""


def _cases() -> list[Case]:
    cases: list[Case] = []
    for key, values in BAD_VALUES.items():
        for k, value in enumerate(values):
            name = f"{key}={value!r}"[:60] + f"#{k}"
            cases.append((name, _deployment_case(_set(BASE, key, value)), _leaf(key)))
    swarm = _set(BASE, "deputy", [{"name": f"d{k}"} for k in range(1000)])
    cases.append(("1000 deputies", _deployment_case(swarm), "deputies"))
    gateway = _set(_set(BASE, "ros2.enabled", True), "deputy.0.name", "1st")
    cases.append(("a deputy no ROS 2 name can hold", _deployment_case(gateway), "deputy[0].name"))
    same_port = _set(_set(BASE, "bus.port", 7447), "ros2.enabled", True)
    cases.append(("ROS 2 on the run's bus port", _deployment_case(same_port), "ros2.endpoint"))
    for bad in ("garbage", "tcp/127.0.0.1:70000"):
        ros2 = _deployment_case(BASE)
        cases.append(
            (f"run --ros2 {bad}", lambda f, ros2=ros2, bad=bad: [*ros2(f), "--ros2", bad], "--ros2")
        )
    link = {"publisher": "ctrl-*", "subscriber": "environment", "delay": 1e9}
    cases.append(("link delay 1e9 s", _deployment_case(_set(BASE, "link", [link])), "link"))
    cases += [
        ("binary file", _file_case(b"\x00\x01\x02\xff\xfe" * 20), "UTF-8"),
        ("latin-1 file", _file_case('[run]\nname = "caf\u00e9"\n'.encode("latin-1")), "UTF-8"),
        ("not TOML", _file_case(b"[run\norbits = = 3\n"), "TOML"),
        ("empty deputies", _file_case(b"[run]\norbits = 1.0\n"), "deputy"),
        ("unknown key", _file_case(b"[run]\norbtis = 1.0\n[[deputy]]\nname='a'\n"), "orbtis"),
        ("no such deployment", lambda f: ["run", str(f / "missing.toml"), "--quiet"], "missing"),
        ("a folder as deployment", lambda f: ["run", str(f), "--quiet"], "is a directory"),
        ("run --output ''", lambda f: ["run", "--output", ""], "--output is empty"),
        ("run --folder-mode 0755", lambda f: ["run", "--folder-mode", "0755"], "others nothing"),
        ("run --folder-mode x", lambda f: ["run", "--folder-mode", "x"], "octal"),
        ("learn --seed -1", lambda f: ["learn", "rendezvous", "--seed", "-1"], "seed"),
        ("learn --seed 2**32", lambda f: ["learn", "rendezvous", "--seed", str(2**32)], "seed"),
        ("learn --seed x", lambda f: ["learn", "rendezvous", "--seed", "x"], "seed"),
        ("check 1e308", _system_case(HUGE_SYSTEM, "check"), "numbers"),
        ("learn 1e308", _system_case(HUGE_SYSTEM, "learn", "--method", "lqr"), "numbers"),
        (
            "fault bias nan",
            lambda f: ["fault", "r", "bias", "lqr", "--position", "nan", "0", "0"],
            "position",
        ),
        (
            "fault bias inf velocity",
            lambda f: [
                "fault",
                "r",
                "bias",
                "lqr",
                "--position",
                "0",
                "0",
                "0",
                "--velocity",
                "inf",
                "0",
                "0",
            ],
            "velocity",
        ),
        (
            "fault link delay nan",
            lambda f: ["fault", "r", "link", "--from", "nav-*", "--to", "ctrl-*", "--delay", "nan"],
            "delay",
        ),
        (
            "fault --hub garbage",
            lambda f: ["fault", "r", "kill", "ctrl-x", "--hub", "garbage"],
            "garbage",
        ),
        ("monitor --hub garbage", lambda f: ["monitor", "--hub", "garbage"], "garbage"),
        ("report of no run", lambda f: ["report", str(f / "nothing")], "run folder"),
        ("unknown command", lambda f: ["frobnicate"], "invalid choice"),
    ]
    return cases


CASES = _cases()


def _tree(root: Path) -> set[str]:
    return {str(p.relative_to(root)) for p in root.rglob("*") if p.is_dir()}


def _check_one_line_exit_2(
    argv: list[str], folder: Path, capsys: pytest.CaptureFixture[str], needle: str
) -> None:
    """Run ``ddvi argv`` here; one line on stderr holding ``needle``, exit 2, no folder made
    but the output root's (which holds no run), no child process left."""
    before = _tree(folder.parent)
    try:
        status = ddvi(argv)
    except SystemExit as exc:  # argparse's usage error
        status = exc.code
    err = capsys.readouterr().err
    assert status == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert "Traceback" not in err and needle.lower() in lines[0].lower(), lines[0]
    made = _tree(folder.parent) - before
    assert made <= {str((folder / "runs").relative_to(folder.parent))}, made
    runs = folder / "runs"
    assert not runs.exists() or not any(runs.iterdir())
    assert psutil.Process().children(recursive=True) == []


def test_the_corpus_is_large() -> None:
    assert len(CASES) >= 50


@pytest.mark.parametrize(("argv", "needle"), [c[1:] for c in CASES], ids=[c[0] for c in CASES])
def test_a_broken_input_is_one_line_and_exit_2(
    argv: Callable[[Path], list[str]], needle: str, tmp_path: Path, capsys, monkeypatch
) -> None:
    folder = tmp_path / "case"
    folder.mkdir()
    monkeypatch.chdir(folder)  # a relative run folder would land here
    _check_one_line_exit_2(argv(folder), folder, capsys, needle)


def test_a_bus_port_in_use_is_one_line_and_exit_2(tmp_path: Path, capsys, monkeypatch) -> None:
    monkeypatch.chdir(tmp_path)
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        table = _set(BASE, "bus.port", s.getsockname()[1])
        argv = _deployment_case(table)(tmp_path)
        _check_one_line_exit_2(argv, tmp_path, capsys, "bus.port in use")


def test_an_output_folder_that_cannot_be_made_is_one_line_and_exit_2(
    tmp_path: Path, capsys, monkeypatch
) -> None:
    monkeypatch.chdir(tmp_path)
    (tmp_path / "a-file").write_text("not a folder")
    argv = _deployment_case(BASE)(tmp_path)
    argv[argv.index("--output") + 1] = str(tmp_path / "a-file" / "runs")
    _check_one_line_exit_2(argv, tmp_path, capsys, "cannot create the run folder")
    # without --quiet too: no progress line before the error
    argv[argv.index("--output") + 1] = str(tmp_path / "a-file")
    argv.remove("--quiet")
    _check_one_line_exit_2(argv, tmp_path, capsys, "a-file: not a folder")


def test_a_deployment_the_machine_cannot_hold_is_refused(tmp_path: Path, capsys, monkeypatch):
    from services.ground.launch import lifecycle

    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(lifecycle, "SERVICE_BYTES", 1e15)  # a petabyte a process
    argv = _deployment_case(BASE)(tmp_path)
    _check_one_line_exit_2(argv, tmp_path, capsys, "GB are available")


@pytest.mark.integration
@pytest.mark.parametrize("case", ["binary file", "run.name='../escape'#0", "1000 deputies"])
def test_as_a_real_process(case: str, tmp_path: Path) -> None:
    (_, argv, needle) = next(c for c in CASES if c[0] == case)
    folder = tmp_path / "case"
    folder.mkdir()
    args = argv(folder)
    r = subprocess.run(
        [sys.executable, "-m", "services.cli", *args],
        capture_output=True,
        text=True,
        timeout=60,
        cwd=folder,
    )
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert "Traceback" not in r.stderr and needle.lower() in r.stderr.lower()
    assert _tree(tmp_path) == {"case"}
    mine = [
        p
        for p in psutil.process_iter(["cmdline"])
        if str(folder) in " ".join(p.info["cmdline"] or [])
    ]
    assert mine == [], [p.pid for p in mine]
    assert os.listdir(folder) == [next(iter(os.listdir(folder)))]  # the deployment alone
