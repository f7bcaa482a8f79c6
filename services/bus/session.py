"""Zenoh sessions: a deployment's ``[bus]`` settings, the zenoh configuration they make, and the
names that become key chunks.

Endpoint convention (docs/design.md, "The bus")
-----------------------------------------------
Peer mode on loopback, multicast scouting OFF, explicit endpoints. One designated process, the
*hub* (the launcher, or a Python process in router mode), listens on the rendezvous endpoint
``tcp/127.0.0.1:7447`` (``DEFAULT_HUB``; a deployment picks another port in its ``[bus]``
table). Every service ``connect``s to the hub and also listens on an ephemeral loopback port
(``tcp/127.0.0.1:0``). Zenoh 1.x peers do not relay for each other, so the mesh is formed by gossip
scouting (on by default): each peer learns the others' listening endpoints through the hub and
connects to them directly. A service started before the hub keeps retrying its connect.
``BusSettings.hub()`` turns a service's settings into the hub's. Client mode (services connect to a
router, which relays) is the option for multi-host deployments.

That peer mesh is the insecure bus (``[bus] security = false``). A secure run (the default;
``services.bus.security``, docs/security.md) is client mode on a router that authenticates each
session (``user``/``password``, the router's ``dictionary``) and enforces ``access_control``;
links to other hosts are TLS (``tls``).

Keys are ``ddvi/<run>/<topic>`` (``key_prefix(run)`` + a topic of ``services.interface.topics``).
"""

from __future__ import annotations

import json
import re
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any

import zenoh

MODES = ("peer", "client", "router")
DEFAULT_PORT = 7447
DEFAULT_HUB = f"tcp/127.0.0.1:{DEFAULT_PORT}"
EPHEMERAL_LOOPBACK = "tcp/127.0.0.1:0"

_ENDPOINT = re.compile(r"^[a-z][a-z0-9-]*/\S+$")
_NAME = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_.-]*$")


@dataclass
class BusSettings:
    """A deployment's ``[bus]`` table: zenoh mode and explicit endpoints.

    Defaults are a service's side of the convention above: peer mode, listen on an ephemeral
    loopback port, connect to ``DEFAULT_HUB``. Invalid values raise ValueError naming the key.
    """

    mode: str = "peer"
    listen: list[str] = field(default_factory=lambda: [EPHEMERAL_LOOPBACK])
    connect: list[str] = field(default_factory=lambda: [DEFAULT_HUB])
    # authentication (services.bus.security): this session's user and password; a router's
    # ``dictionary`` file of every user's; its ``access_control`` block; TLS files by key
    user: str = ""
    password: str = field(default="", repr=False)
    dictionary: str = ""
    access_control: dict[str, Any] | None = field(default=None, repr=False)
    tls: dict[str, Any] = field(default_factory=dict)
    # ms without a word from this session before its peers drop it (its liveliness tokens go);
    # 0: zenoh's default.  A service's outlasts the run's hang timeout: a frozen service is
    # waited for (and named), not taken for gone while it may still come back
    lease_ms: int = 0

    def __post_init__(self) -> None:
        if self.mode not in MODES:
            raise ValueError(f"bus.mode: expected one of {'|'.join(MODES)}, got {self.mode!r}")
        for key in ("listen", "connect"):
            endpoints = getattr(self, key)
            if isinstance(endpoints, str) or not isinstance(endpoints, list | tuple):
                raise ValueError(f"bus.{key}: expected a list of endpoints, got {endpoints!r}")
            for i, endpoint in enumerate(endpoints):
                if not isinstance(endpoint, str) or not _ENDPOINT.match(endpoint):
                    raise ValueError(
                        f"bus.{key}[{i}]: expected an endpoint '<proto>/<address>', "
                        f"got {endpoint!r}"
                    )
            setattr(self, key, list(endpoints))
        if self.mode == "client" and not self.connect:
            raise ValueError("bus.connect: client mode needs at least one router endpoint")
        if self.mode in ("peer", "router") and not self.listen:
            raise ValueError(
                f"bus.listen: {self.mode} mode needs an endpoint to listen on "
                f"(peers do not relay; use '{EPHEMERAL_LOOPBACK}' for an ephemeral port)"
            )

    def hub(self, mode: str = "peer") -> BusSettings:
        """Settings for the one process that listens where every service connects."""
        return BusSettings(mode=mode, listen=list(self.connect), connect=[])


SERVICE_ZENOH_RUNTIME = "(rx: (worker_threads: 1))"
"""A service's ``ZENOH_RUNTIME``: one receive worker instead of two. A service reads one or a few
links, so a second worker adds thread wake-ups that compete with the services for the cores
without adding throughput (zenoh reads the variable when a session opens; one already set wins).
Not the launcher's, which as the hub (or router) reads every service's link."""


def zenoh_config(settings: BusSettings) -> zenoh.Config:
    """The zenoh configuration for ``settings``: explicit endpoints, no multicast scouting."""
    config = zenoh.Config()
    config.insert_json5("mode", json.dumps(settings.mode))
    config.insert_json5("listen/endpoints", json.dumps(settings.listen))
    config.insert_json5("connect/endpoints", json.dumps(settings.connect))
    config.insert_json5("scouting/multicast/enabled", "false")
    config.insert_json5("scouting/gossip/enabled", "true")
    if settings.mode == "router":
        # a router's open() otherwise waits scouting's 0.5 s for peers to scout; with no
        # multicast scouting and every service connecting to it, there is nothing to wait for
        config.insert_json5("scouting/delay", "0")
    # Shared memory only pays for payloads of kilobytes (zenoh's threshold is 3 KB); every
    # message here is smaller, and the segments and their threads cost each process 10-20 MB.
    config.insert_json5("transport/shared_memory/enabled", "false")
    # Retry a not-yet-listening hub quickly, so start-up order does not matter.
    retry = {"period_init_ms": 100, "period_max_ms": 1000, "period_increase_factor": 2.0}
    config.insert_json5("connect/retry", json.dumps(retry))
    if settings.user:
        usrpwd = {"user": settings.user, "password": settings.password}
        if settings.dictionary:
            usrpwd["dictionary_file"] = settings.dictionary
        config.insert_json5("transport/auth/usrpwd", json.dumps(usrpwd))
    if settings.access_control is not None:
        config.insert_json5("access_control", json.dumps(settings.access_control))
    if settings.tls:
        config.insert_json5("transport/link/tls", json.dumps(settings.tls))
    if settings.lease_ms > 0:
        config.insert_json5("transport/link/tx/lease", str(int(settings.lease_ms)))
    return config


@contextmanager
def open_session(settings: BusSettings) -> Iterator[zenoh.Session]:
    """Open a zenoh session and always close it (an open session can hang interpreter exit)."""
    session = zenoh.open(zenoh_config(settings))
    try:
        yield session
    finally:
        session.close()


_RUST_SOURCE = re.compile(r"\s*\bat /\S+\.rs:\d+\.?")


def error_text(exc: BaseException) -> str:
    """A zenoh error (or any) as one line for a user: its first line, without the Rust source
    path zenoh appends (`` at /root/.cargo/.../orchestrator.rs:447.``)."""
    first = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
    return _RUST_SOURCE.sub("", first).strip() or type(exc).__name__


def check_name(what: str, name: str) -> str:
    """Validate a run or service name (one key-expression chunk, no wildcards)."""
    if not isinstance(name, str) or not _NAME.match(name):
        raise ValueError(f"{what}: expected [A-Za-z0-9_.-]+ (no '/'), got {name!r}")
    return name


def key_prefix(run: str) -> str:
    """``ddvi/<run>/``: what every key of ``run`` starts with (``run`` checked by
    ``check_name``)."""
    return f"ddvi/{check_name('run', run)}/"
