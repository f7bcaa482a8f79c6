"""Bus security: each participant's credentials, the router's access control generated from
the topology, and the private files that hold them (docs/security.md).

A secure run has one zenoh router, the launcher, that every participant connects to as a client
(listening on nothing) with its own user name and password (zenoh ``usrpwd`` authentication:
the router holds the dictionary; a wrong or missing password is refused at connect).  The
router's access control denies by default and lets each user put only the topics the topology
(``services.interface.topics.TOPOLOGY``) gives its service, plus its own liveliness token:

- every authenticated user may subscribe to the run's keys and its liveliness tokens;
- ``environment`` alone puts clock, exo/state and truth/*; ``nav-X`` alone nav/X/state;
  ``ctrl-X`` alone cmd/X/att, ctrl/X/gains and ctrl/X/status; every service its own stats and
  log; the operator (``ground-operator``, what ``ddvi fault`` uses) alone fault/*;
- the observer (``observer``, what ``ddvi monitor`` uses) puts nothing.

Credentials live in ``<run folder>/security/`` (0700), one file per participant (0600); none of
it goes on the bus, so none of it is in the recording.

Links to other hosts (a deployment's ``[[host]]``) are TLS with both ends authenticated
(``issue_tls``): a certificate authority made for the run, the router's certificate for its
addresses, and a client certificate; the private keys are 0600 files beside the credentials.
"""

from __future__ import annotations

import json
import os
import secrets
import stat
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from services.bus.session import BusSettings, key_prefix
from services.interface.topics import (
    ROS2_GATEWAY,
    alive_topic,
    command_deputy,
    command_topic,
    topics_published_by,
)

OPERATOR = "ground-operator"
"""The operator's user: ``ddvi fault`` connects with it (the ground's ``ground-<pid>`` role)."""
OBSERVER = "observer"
"""A subscribe-only user: ``ddvi monitor`` connects with it."""
ROUTER = "launcher"
"""The router's own user (the launcher)."""
SECURITY_DIR = "security"
"""The run folder's sub-folder that holds the credentials (0700; each file 0600)."""
DICTIONARY = "users.txt"
"""The router's ``user:password`` dictionary, in ``SECURITY_DIR``."""
BUS_FILE = "bus.json"
"""The run folder's description of its bus (hub endpoint, security on or off): what ``ddvi
fault`` and ``ddvi monitor`` read to find a run; no secrets in it."""

_SUBSCRIBE = ["declare_subscriber", "declare_liveliness_subscriber", "liveliness_query"]
_DELIVER = [
    "put",
    "delete",
    "declare_subscriber",
    "declare_liveliness_subscriber",
    "liveliness_token",
    "liveliness_query",
    "reply",
]


@dataclass(frozen=True)
class Credentials:
    """One participant's user name and password (``repr`` hides the password)."""

    user: str
    password: str = field(repr=False)
    tls: dict[str, Any] = field(default_factory=dict, repr=False)  # a client's TLS files

    @staticmethod
    def new(user: str) -> Credentials:
        """Fresh credentials for ``user``: 32 random URL-safe bytes of password."""
        return Credentials(user, secrets.token_urlsafe(32))

    def client(self, connect: list[str], lease_ms: int = 0) -> BusSettings:
        """The settings of a client with these credentials, of ``connect`` (the hub first),
        listening on nothing (``lease_ms`` 0: zenoh's lease)."""
        return BusSettings(
            mode="client",
            listen=[],
            connect=connect,
            user=self.user,
            password=self.password,
            tls=self.tls,
            lease_ms=lease_ms,
        )


_NEW_FILE = os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW | getattr(os, "O_CLOEXEC", 0)


def write_private(path: Path, text: str, mode: int = 0o600) -> None:
    """Write ``text`` to a new file ``path`` with ``mode`` (0600: its owner's only) from its
    first moment.  The file must not exist (``O_EXCL``, FileExistsError) nor be a symbolic link
    (``O_NOFOLLOW``): what another user planted is never written into, or through."""
    fd = os.open(path, _NEW_FILE, mode)
    try:
        os.fchmod(fd, mode)
        os.write(fd, text.encode())
    finally:
        os.close(fd)


def credentials_path(out: Path | str, user: str) -> Path:
    """Where a run folder keeps ``user``'s credentials."""
    return Path(out) / SECURITY_DIR / f"{user}.json"


def load_credentials(path: Path | str) -> Credentials:
    """Read a credentials file written by ``issue_credentials``. Raises ValueError naming the
    file when it is not one (or OSError when it cannot be read)."""
    try:
        data = json.loads(Path(path).read_text())
        return Credentials(str(data["user"]), str(data["password"]), dict(data.get("tls", {})))
    except (ValueError, KeyError, TypeError) as exc:
        raise ValueError(f"{path}: not a credentials file ({exc})") from exc


def _private_folder(out: Path | str) -> Path:
    """``out/security``, made 0700 now, or made so by this user before (TLS first): a folder
    of that name that is anyone else's, wider, or a link is refused (PermissionError)."""
    folder = Path(out) / SECURITY_DIR
    try:
        os.mkdir(folder, 0o700)
        os.chmod(folder, 0o700)  # ours, just made: whatever the umask
    except FileExistsError:
        st = os.lstat(folder)
        if not stat.S_ISDIR(st.st_mode) or st.st_uid != os.getuid() or st.st_mode & 0o077:
            raise PermissionError(
                f"{folder}: exists and is not this user's private folder; credentials are "
                "never written into it"
            ) from None
    return folder


def issue_credentials(
    out: Path | str, users: Iterable[str], tls: dict[str, Any] | None = None
) -> dict[str, Credentials]:
    """Make credentials for every user (and the router), write each to its own 0600 file and
    the router's dictionary to ``security/users.txt`` in the run folder ``out``; ``tls``: the
    client TLS files every user gets (``issue_tls``), for links to other hosts."""
    folder = _private_folder(out)
    issued = {u: Credentials.new(u) for u in dict.fromkeys([*users, ROUTER])}
    issued = {u: Credentials(c.user, c.password, dict(tls or {})) for u, c in issued.items()}
    for user, cred in issued.items():
        body = {"user": cred.user, "password": cred.password, "tls": cred.tls}
        write_private(credentials_path(out, user), json.dumps(body) + "\n")
    lines = "".join(f"{c.user}:{c.password}\n" for c in issued.values())
    write_private(folder / DICTIONARY, lines)
    return issued


def _rule(rule_id: str, flow: str, messages: list[str], keys: list[str]) -> dict[str, Any]:
    return {
        "id": rule_id,
        "permission": "allow",
        "flows": [flow],
        "messages": messages,
        "key_exprs": keys,
    }


def access_control(
    run: str, users: Iterable[str], ros2_deputies: Iterable[str] = ()
) -> dict[str, Any]:
    """The router's ``access_control`` block for ``run``: deny by default; every user may
    subscribe and is delivered what it subscribed; each user puts only the topics its
    service publishes per the topology (``topics_published_by``) and declares only its own
    liveliness token.  ``users`` are service names (``nav-lqr``, ``ground-operator``, ...).
    The ROS 2 gateway, which the topology lets command any deputy, puts the commands of
    ``ros2_deputies`` (the deputies flown from ROS 2) and of no other."""
    prefix = key_prefix(run)
    commands = [command_topic(sc) for sc in ros2_deputies]
    users = list(dict.fromkeys(users))
    rules = [
        _rule("subscribe", "ingress", _SUBSCRIBE, [prefix + "**"]),
        _rule("deliver", "egress", _DELIVER, [prefix + "**"]),
    ]
    subjects = [{"id": "everyone", "usernames": users}]
    policies = [{"id": "everyone", "rules": ["subscribe", "deliver"], "subjects": ["everyone"]}]
    for user in users:
        topics = topics_published_by(user)
        if user == ROS2_GATEWAY:
            topics = tuple(t for t in topics if command_deputy(t) is None) + tuple(commands)
        keys = [prefix + topic for topic in topics]
        own = [f"put {user}"] if keys else []
        if keys:
            rules.append(_rule(own[0], "ingress", ["put"], keys))
        if user != OPERATOR and user != OBSERVER:
            token = [prefix + alive_topic(user)]
            rules.append(_rule(f"alive {user}", "ingress", ["liveliness_token"], token))
            own.append(f"alive {user}")
        if own:
            subjects.append({"id": user, "usernames": [user]})
            policies.append({"id": user, "rules": own, "subjects": [user]})
    return {
        "enabled": True,
        "default_permission": "deny",
        "rules": rules,
        "subjects": subjects,
        "policies": policies,
    }


def issue_tls(out: Path | str, addresses: Iterable[str]) -> tuple[dict[str, Any], dict[str, Any]]:
    """Make the run's TLS material in ``security/``: a certificate authority (valid 30 days),
    the router's certificate for ``addresses`` (IPs) and a client certificate, EC P-256 keys
    in 0600 files.  Returns the router's and a client's zenoh ``transport/link/tls`` settings,
    both requiring the other end's certificate (mutual TLS)."""
    from services.bus.tls import make_authority, make_leaf  # cryptography: only for TLS

    folder = _private_folder(out)
    authority = make_authority("ddvi run authority")
    files = {
        "ca.pem": authority.certificate,
        "router.key": (router := make_leaf(authority, "ddvi router", list(addresses))).key,
        "router.pem": router.certificate,
        "client.key": (client := make_leaf(authority, "ddvi client", [])).key,
        "client.pem": client.certificate,
    }
    for name, pem in files.items():
        write_private(folder / name, pem)
    path = {name: str(folder / name) for name in files}
    router_tls = {
        "root_ca_certificate": path["ca.pem"],
        "listen_private_key": path["router.key"],
        "listen_certificate": path["router.pem"],
        "enable_mtls": True,
    }
    client_tls = {
        "root_ca_certificate": path["ca.pem"],
        "connect_private_key": path["client.key"],
        "connect_certificate": path["client.pem"],
        "enable_mtls": True,
        "verify_name_on_connect": True,
    }
    return router_tls, client_tls
