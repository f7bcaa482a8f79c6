"""A run's bus, as the launcher sets it up and the ground's commands find it.

The launcher writes, on a secure bus (``bus.security``, the default), every participant's
credentials in ``<run folder>/security/`` (``services.bus.security``), opens the hub with them,
and then writes ``<run folder>/bus.json`` (the run's name, its hub endpoint, whether the bus is
secure: no secrets): a run whose bus.json is there has a hub that listens.  ``ddvi fault`` and
``ddvi monitor`` find a run by its name or its folder (``find_run``) and connect with the
operator's or the observer's credentials from there.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

from services.bus import BusSettings
from services.bus.security import (
    BUS_FILE,
    DICTIONARY,
    OBSERVER,
    OPERATOR,
    ROUTER,
    SECURITY_DIR,
    Credentials,
    access_control,
    credentials_path,
    issue_credentials,
    issue_tls,
    load_credentials,
    write_private,
)
from services.config import Deployment


def hub_settings(
    dep: Deployment, run: str, out: Path, listen: list[str], services: list[str]
) -> BusSettings:
    """Write, on a secure bus, the credentials of every service, the operator and the
    observer in the run folder ``out``; return the hub's settings (a router with the
    dictionary and the access control on a secure bus, else what ``bus.mode`` says).
    ``listen``: the loopback endpoint, then one on each other host's link (made TLS on a
    secure bus, with the run's certificates).  ``write_bus_file`` says where the hub is,
    once it listens."""
    secure = dep.bus.security
    hosts = [e.split("/", 1)[1].rsplit(":", 1)[0] for e in listen[1:]]
    if secure and hosts:
        listen = [
            listen[0],
            *(
                host_endpoint(dep, a, e.rsplit(":", 1)[1])
                for a, e in zip(hosts, listen[1:], strict=True)
            ),
        ]
    connect = list(dep.bus.connect)
    if not secure:
        return BusSettings(
            mode="router" if dep.bus.mode == "client" else "peer", listen=listen, connect=connect
        )
    users = [*services, OPERATOR, OBSERVER]
    router_tls, client_tls = issue_tls(out, hosts) if hosts else ({}, {})
    router = issue_credentials(out, users, client_tls)[ROUTER]
    return BusSettings(
        mode="router",
        listen=listen,
        connect=connect,
        user=router.user,
        password=router.password,
        dictionary=str(out / SECURITY_DIR / DICTIONARY),
        access_control=access_control(
            run, users, [d.name for d in dep.deputy if d.controller == "ros2"]
        ),
        tls=router_tls,
    )


def write_bus_file(out: Path, run: str, hub: BusSettings, secure: bool) -> None:
    """Write the run folder's ``bus.json``: the run's name, the endpoints the hub (``hub``,
    from ``hub_settings``) listens on, the first its loopback one, and whether the bus is
    secure.  Written once the hub's session is open, so that a command which finds the run
    finds a hub to connect to."""
    info = {"run": run, "hub": hub.listen[0], "listen": list(hub.listen), "security": secure}
    # new, never through a link: a bus.json another user planted is refused, not followed
    write_private(out / BUS_FILE, json.dumps(info, indent=1) + "\n", mode=0o644)


def host_endpoint(dep: Deployment, address: str, port: int | str) -> str:
    """The hub's endpoint on another host's link: TLS on a secure bus, else TCP."""
    return f"{'tls' if dep.bus.security else 'tcp'}/{address}:{port}"


def service_arguments(dep: Deployment, out: Path, name: str) -> list[str]:
    """The command-line arguments that hand a service its credentials (none when insecure)."""
    return ["--credentials", str(credentials_path(out, name))] if dep.bus.security else []


def client_settings(
    hub: str, credentials: Credentials | None, extra: tuple[str, ...] = ()
) -> BusSettings:
    """A participant's settings: on a secure bus a client of the hub with ``credentials``,
    listening on nothing; else a peer of the hub on an ephemeral loopback port."""
    connect = [hub, *extra]
    if credentials is None:
        return BusSettings(mode="peer", listen=["tcp/127.0.0.1:0"], connect=connect)
    return credentials.client(connect)


@dataclass(frozen=True)
class RunBus:
    """What a ground command needs to reach a running run: its name, its hub and, on a secure
    bus, the credentials of the user it connects as."""

    run: str
    hub: str
    credentials: Credentials | None

    def settings(self) -> BusSettings:
        return client_settings(self.hub, self.credentials)


class RunNotFoundError(ValueError):
    """No run folder (or no readable bus description) for the name given; says where it looked."""


class InsecureRunError(RunNotFoundError):
    """The run folder holds credentials but its bus.json turns security off: the file was
    edited, or the folder is not the run it seems; connecting would send nothing secret but
    trust whatever answers, unauthenticated.  Says what to do."""


def _folder(run: str, output: str) -> Path:
    """The run folder that ``run`` names: a folder path, or a run name under ``output``."""
    as_path = Path(run)
    if (as_path / BUS_FILE).is_file():
        return as_path
    under = Path(output) / run
    if (under / BUS_FILE).is_file():
        return under
    raise RunNotFoundError(
        f"no run {run!r}: neither {as_path / BUS_FILE} nor {under / BUS_FILE} exists (give the "
        "run folder ddvi run printed, or its name with --output ROOT)"
    )


def find_run(run: str, output: str, user: str, insecure: bool = False) -> RunBus:
    """The bus of the run named ``run`` (a run folder, or a run name under ``output``), with
    ``user``'s credentials when it is secure (``OPERATOR``, ``OBSERVER``).  Raises
    ``RunNotFoundError`` with one line saying what is missing, and ``InsecureRunError`` when
    the folder's bus.json turns security off while the folder holds credentials (a secure
    run's folder: the launcher writes credentials only for a secure bus), unless ``insecure``
    (the user said so: ``--insecure``).  Every ground command that reaches a run by its folder
    (``ddvi fault``, ``ddvi monitor``, its live view) loads bus.json here."""
    folder = _folder(run, output)
    bus_file = folder / BUS_FILE
    try:
        info = json.loads(bus_file.read_text())
        name, hub, secure = str(info["run"]), str(info["hub"]), info["security"]
        if not isinstance(secure, bool):
            raise TypeError(f'"security" is {secure!r}, not true or false')
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise RunNotFoundError(f"{bus_file}: not a run's bus description ({exc})") from exc
    if not secure and (folder / SECURITY_DIR).exists() and not insecure:
        raise InsecureRunError(
            f"{bus_file} turns security off, but {folder / SECURITY_DIR} holds the run's "
            "credentials: the file was edited, or this folder is not the run it seems. Restore "
            '"security": true to connect with the credentials, or give --insecure to connect '
            "without authentication anyway (anything on that hub may then answer)"
        )
    if not secure:
        return RunBus(name, hub, None)
    path = credentials_path(folder, user)
    try:
        return RunBus(name, hub, load_credentials(path))
    except OSError as exc:
        raise RunNotFoundError(
            f"cannot read the {user} credentials {path} ({exc.strerror}): run this as the "
            "user who started the run"
        ) from exc
    except ValueError as exc:
        raise RunNotFoundError(str(exc)) from exc


def run_folder(run: str, output: str) -> Path:
    """The run folder ``run`` names (a folder, or a run name under ``output``);
    ``RunNotFoundError`` when there is none."""
    return _folder(run, output)
