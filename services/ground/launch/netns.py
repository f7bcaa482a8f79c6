"""Separate network hosts on one Linux machine: ``ddvi netns up|down DEPLOYMENT``.

Each [[host]] k of a deployment is a network namespace joined to the launcher's namespace by a
veth pair ``ddvi<k>h`` (launcher side, 10.77.<k>.1/24) and ``ddvi<k>n`` (host side,
10.77.<k>.2/24).  The launcher (the run's Zenoh router) listens on 10.77.<k>.1 for host k; the
services there connect to it over the pair, so every message between hosts crosses a real
network interface, where ``tc netem`` can delay and lose it (``--delay S --loss P``: seconds and a
probability, as ``[[link]]``, ``ddvi fault link`` and ``ddvi sweep`` take them; where the kernel
has the netem qdisc).  Needs root (CAP_NET_ADMIN) and the ``ip`` command.
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
from pathlib import Path

from services.config import Deployment, DeploymentError, load_deployment

SUBNET = "10.77"


class NetnsError(RuntimeError):
    """Network namespaces cannot be set up here; the message says why."""


def hub_address(k: int) -> str:
    """The launcher-side address of host k's link."""
    return f"{SUBNET}.{k}.1"


def _ip(*args: str, netns: str | None = None) -> None:
    """Run ``ip ARGS`` (inside ``netns`` if given); NetnsError when it fails."""
    cmd = ["ip", *(["netns", "exec", netns, "ip"] if netns else []), *args]
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode != 0:
        raise NetnsError(f"{' '.join(cmd)}: {r.stderr.strip() or r.returncode}")


def available() -> str | None:
    """None when namespaces can be made here, else why not."""
    if shutil.which("ip") is None:
        return "the ip command (iproute2) is not installed"
    probe = "ddvi-probe"
    r = subprocess.run(["ip", "netns", "add", probe], capture_output=True, text=True)
    if r.returncode != 0:
        return f"ip netns add is not permitted here: {r.stderr.strip()}"
    subprocess.run(["ip", "netns", "del", probe], capture_output=True)
    return None


def exists(netns: str) -> bool:
    """Whether the named network namespace is there."""
    return Path("/var/run/netns", netns).exists()


MAX_DELAY = 60.0  # s: a wall-time delay beyond it stalls the lock-step; surely meant in ms


def netem_problem(delay: float, loss: float) -> str | None:
    """Why a netem delay (s) or loss (probability) cannot be used, in one line, or None."""
    if not 0.0 <= delay <= MAX_DELAY:
        return f"--delay {delay:g}: seconds in [0, {MAX_DELAY:g}] (0.05 for 50 ms)"
    if not 0.0 <= loss <= 1.0:
        return f"--loss {loss:g}: a probability in [0, 1] (0.01 for 1 %)"
    return None


def up(dep: Deployment, delay: float = 0.0, loss: float = 0.0) -> list[str]:
    """Create every [[host]]'s namespace and link (idempotent: an existing one is remade),
    with netem's ``delay`` (s) and ``loss`` (probability) on each link; returns what was done,
    a line each."""
    done = []
    down(dep)
    for k, h in enumerate(dep.host):
        outer, inner = f"ddvi{k}h", f"ddvi{k}n"
        _ip("netns", "add", h.netns)
        _ip("link", "add", outer, "type", "veth", "peer", "name", inner)
        _ip("link", "set", inner, "netns", h.netns)
        _ip("addr", "add", f"{hub_address(k)}/24", "dev", outer)
        _ip("link", "set", outer, "up")
        _ip("addr", "add", f"{SUBNET}.{k}.2/24", "dev", inner, netns=h.netns)
        _ip("link", "set", inner, "up", netns=h.netns)
        _ip("link", "set", "lo", "up", netns=h.netns)
        done.append(f"{h.netns}: {inner} {SUBNET}.{k}.2 <-> {outer} {hub_address(k)}")
        if delay or loss:
            netem = ["tc", "qdisc", "add", "dev", outer, "root", "netem"]
            netem += ["delay", f"{delay * 1e3:g}ms", "loss", f"{loss * 100:g}%"]
            r = subprocess.run(netem, capture_output=True, text=True)
            if r.returncode != 0:
                raise NetnsError(f"{' '.join(netem)}: {r.stderr.strip()}")
            done.append(f"{outer}: netem delay {delay:g} s, loss {loss:g}")
    return done


def down(dep: Deployment) -> None:
    """Remove every [[host]]'s namespace (its veth pair goes with it)."""
    for k, h in enumerate(dep.host):
        subprocess.run(["ip", "link", "del", f"ddvi{k}h"], capture_output=True)
        if exists(h.netns):
            subprocess.run(["ip", "netns", "del", h.netns], capture_output=True)


def add_netns_arguments(p: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """The arguments of ``ddvi netns``, for ``services.cli``."""
    p.add_argument("action", choices=("up", "down"), help="create or remove the namespaces")
    p.add_argument("deployment", help="a deployment with [[host]] tables")
    p.add_argument(
        "--delay", type=float, default=0.0, help="netem delay on each link, s (0.05: 50 ms)"
    )
    p.add_argument(
        "--loss", type=float, default=0.0, help="netem loss on each link, probability in [0, 1]"
    )
    return p


def netns_command(args: argparse.Namespace) -> int:
    """``ddvi netns up|down``: 0 when done, 1 when namespaces cannot be made, 2 on bad input."""
    try:
        dep = load_deployment(args.deployment)
    except DeploymentError as exc:
        print(f"ddvi netns: {exc}", file=sys.stderr)
        return 2
    if not dep.host:
        print(f"ddvi netns: {dep.path} has no [[host]] table", file=sys.stderr)
        return 2
    if args.action == "down":
        down(dep)
        return 0
    if (why := netem_problem(args.delay, args.loss)) is not None:
        print(f"ddvi netns: {why}", file=sys.stderr)
        return 2
    if (why := available()) is not None:
        print(f"ddvi netns: {why}", file=sys.stderr)
        return 1
    try:
        for line in up(dep, args.delay, args.loss):
            print(line)
    except NetnsError as exc:
        print(f"ddvi netns: {exc}", file=sys.stderr)
        return 1
    return 0
