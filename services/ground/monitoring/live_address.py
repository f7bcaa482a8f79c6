"""Where the live view (``services.ground.monitoring.live``) listens: ``--live [HOST:PORT]`` read
and checked before anything is launched (its package there, its port free), and the warning an
address beyond this machine draws."""

from __future__ import annotations

import ipaddress
import socket
from dataclasses import dataclass

LIVE_DEFAULT = "127.0.0.1:8765"
"""Where ``--live`` serves without an address: localhost, Foxglove's default port."""
URL_SCHEME = "ws://"
"""The scheme of the live view's URL (``LiveAddress.url``), also accepted in ``--live``."""
CLIENT_JOINED = "live view: a client subscribed"
"""How the monitor's log says its live view has its first client (what ``ddvi run --live
--wait-for-client`` waits for before the first step)."""
INSTALL = "pip install 'foxglove-sdk>=0.30'"
"""The command that adds the live view's one dependency."""


class LiveError(ValueError):
    """``--live`` cannot serve: one line saying why and what to do."""


@dataclass(frozen=True)
class LiveAddress:
    """Where the live view listens."""

    host: str
    port: int

    @property
    def url(self) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"{URL_SCHEME}{host}:{self.port}"

    def __str__(self) -> str:
        return f"{self.host}:{self.port}"


def parse_address(text: str) -> LiveAddress:
    """``HOST:PORT``, ``PORT`` (on localhost) or the URL ``ws://HOST:PORT`` the live view says
    it serves on, as a LiveAddress; LiveError when it is none of these."""
    bare = text.strip()
    if bare.lower().startswith(URL_SCHEME):  # the URL printed at start, pasted back
        bare = bare[len(URL_SCHEME) :].rstrip("/")
    host, sep, port = bare.rpartition(":")
    host = host.strip("[]") if sep else "127.0.0.1"
    try:
        number = int(port)
    except ValueError:
        number = 0
    if not host or "/" in host or not 1 <= number <= 65535:  # "/": a path, or another scheme
        raise LiveError(
            f"--live {text!r}: give HOST:PORT or ws://HOST:PORT, e.g. {LIVE_DEFAULT} (a "
            "deployment goes before --live)"
        )
    return LiveAddress(host, number)


def foxglove_missing() -> str | None:
    """Why the live view cannot run here (its package is not installed), or None."""
    try:
        import foxglove  # noqa: F401
    except ImportError:
        return f"--live needs the foxglove-sdk package, which is not installed: {INSTALL}"
    return None


def check_live(text: str) -> LiveAddress:
    """The address ``--live`` names, once the package is there and the port is free;
    LiveError (one line) otherwise."""
    if (missing := foxglove_missing()) is not None:
        raise LiveError(missing)
    address = parse_address(text)
    family = socket.AF_INET6 if ":" in address.host else socket.AF_INET
    with socket.socket(family, socket.SOCK_STREAM) as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as the server binds
        try:
            s.bind((address.host, address.port))
        except OSError as exc:
            raise LiveError(
                f"--live {address}: cannot listen there ({exc.strerror}); give another HOST:PORT"
            ) from exc
    return address


def loopback(host: str) -> bool:
    """Whether ``host`` (an address or ``localhost``) is this machine's loopback only."""
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return host == "localhost"


def exposure_warning(address: LiveAddress) -> str | None:
    """A warning when the live view listens beyond this machine (it has no authentication)."""
    if loopback(address.host):
        return None
    return (
        f"the live view on {address} serves every message of the run, unauthenticated, to "
        "anyone who can reach it"
    )
