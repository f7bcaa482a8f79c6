"""The mission across network namespaces: navigation and controllers on separate hosts, each
joined to the launcher's Zenoh router by a veth pair (services/ground/launch/netns.py).  Needs root;
where namespaces cannot be made the tests are skipped with the reason (pytest -ra prints it)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from services.config import Deployment, deployment_from_table, read_table, write_deployment
from services.ground.launch import netns

pytestmark = pytest.mark.integration


def _why_not() -> str | None:
    if sys.platform != "linux":
        return f"network namespaces are Linux only (this is {sys.platform})"
    if os.geteuid() != 0:
        return "network namespaces need root (CAP_NET_ADMIN); CI runs as root"
    return netns.available()


@pytest.fixture
def multihost(tmp_path: Path, free_port: int) -> Iterator[tuple[Deployment, Path]]:
    """deployments/multihost.toml, 1 orbit, its own port and namespaces, torn down after."""
    if (why := _why_not()) is not None:
        pytest.skip(f"multi-host test skipped: {why}")
    table = read_table("multihost")
    table["run"]["orbits"] = 1.0
    table["bus"]["port"] = free_port
    for h in table["host"]:
        h["netns"] = h["netns"].replace("ddvi-", "ddvit-")
    path = write_deployment(table, tmp_path, "multihost")
    dep = deployment_from_table(table, str(path))
    try:
        yield dep, path
    finally:
        netns.down(dep)


def _bytes(interface: str) -> int:
    stats = Path("/sys/class/net", interface, "statistics")
    return int((stats / "rx_bytes").read_text()) + int((stats / "tx_bytes").read_text())


def _run(path: Path, out: Path) -> subprocess.CompletedProcess:
    cmd = [sys.executable, "-m", "services.cli", "run", str(path), "--output", str(out)]
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1"}
    return subprocess.run(cmd, capture_output=True, text=True, timeout=300, env=env)


def _completed_summary(path: Path, out: Path) -> dict:
    """Run the deployment, assert it exited 0, and return its summary.json."""
    r = _run(path, out)
    assert r.returncode == 0, r.stderr[-3000:]
    return json.loads((Path(r.stdout.strip().splitlines()[-1]) / "summary.json").read_text())


def test_the_mission_runs_across_network_namespaces(
    multihost: tuple[Deployment, Path], tmp_path: Path
) -> None:
    dep, path = multihost
    r = _run(path, tmp_path / "runs")
    assert r.returncode == 1 and "ddvi netns up" in r.stderr  # no namespaces yet: says how
    netns.up(dep)
    links = [f"ddvi{k}h" for k in range(len(dep.host))]
    before = {i: _bytes(i) for i in links}
    summary = _completed_summary(path, tmp_path / "runs")
    assert summary["completed"] is True
    assert summary["messages"]["totals"]["rejected"] == 0
    # one orbit: 543 navigation samples and 91 commands a deputy (stats count up to the last
    # stats message)
    for name, least in (("nav-lqr", 500), ("nav-ddvi", 500), ("ctrl-lqr", 85), ("ctrl-ddvi", 85)):
        assert summary["messages"]["services"][name]["sent"] >= least, name
    # the navigation and controller traffic crossed the two hosts' links (truth in, navigation
    # out; navigation and exostate in, commands out: hundreds of kB each)
    for i in links:
        assert _bytes(i) - before[i] > 200_000, i


def test_netem_delay_and_loss_on_the_hosts_links(
    multihost: tuple[Deployment, Path], tmp_path: Path
) -> None:
    dep, path = multihost
    try:
        netns.up(dep, delay=0.002, loss=0.01)
    except netns.NetnsError as exc:
        pytest.skip(f"tc netem is not available here: {exc}")
    summary = _completed_summary(path, tmp_path / "runs")
    # TCP retransmits what netem loses: the mission completes with nothing missing
    assert summary["completed"] is True
    assert summary["messages"]["totals"]["missing"] == 0
