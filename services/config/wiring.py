"""Which services and topics a deployment wires together: the patterns of its ``[[link]]``,
``[[restart]]`` and ``[[host]]`` tables (``services.interface.keys``) must name services of the
run and, for a link, a topic a link carries; a link never impairs the truth to navigation nor
what the monitor records; a kill fault reaches only a service the run can outlive.  The same
checks answer a run-time link or kill fault.  Each raises DeploymentError naming the key.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from ddvi_core.tables import from_table
from services.config.deployment import RESTART_POLICIES, Deployment, DeploymentError, Link
from services.config.ranges import check_link_latency, mission_seconds
from services.interface.keys import PatternError, check_pattern, key_matches
from services.interface.links import UNIMPAIRED, impairs_truth

__all__ = [
    "UNKILLABLE",
    "check_hosts",
    "check_kill",
    "check_link",
    "check_link_fault",
    "check_links",
    "check_restarts",
    "link_from_params",
]


def _pattern(where: str, pattern: str) -> str:
    """``pattern`` if it is a key expression (``services.interface.keys``); else
    DeploymentError at ``where`` saying what is wrong."""
    try:
        return check_pattern(pattern)
    except PatternError as exc:
        raise DeploymentError(f"{where}: {exc}") from None


def _matches_a_service(where: str, pattern: str, services: list[str]) -> list[str]:
    """The services a pattern names; none raises DeploymentError at ``where``."""
    matched = [s for s in services if key_matches(_pattern(where, pattern), s)]
    if not matched:
        raise DeploymentError(
            f"{where}: {pattern!r} matches no service; services: {', '.join(services)}"
        )
    return matched


def check_link(dep: Deployment, w: str, link: Link) -> None:
    """One link's globs: they name services of ``dep``; never the truth to navigation, nor
    the monitor.  (Its numbers are LinkSpec's own checks, its latency the ranges'.)"""
    services = dep.services
    for key in ("publisher", "subscriber"):
        _matches_a_service(f"{w}.{key}", getattr(link, key), services)
    carried = [t for t in dep.topics() if t not in UNIMPAIRED]
    if not any(key_matches(_pattern(f"{w}.topic", link.topic), t) for t in carried):
        raise DeploymentError(
            f"{w}.topic: {link.topic!r} matches no topic a link carries ('*' is one chunk of a "
            "topic, '**' any number of them: every topic is '**'); e.g. 'nav/*/state', "
            "'cmd/*/att', 'exo/state'"
        )
    if any(impairs_truth(link.publisher, s) for s in services if key_matches(link.subscriber, s)):
        raise DeploymentError(
            f"{w}: impairs the environment's truth to navigation "
            f"({link.publisher!r} -> {link.subscriber!r}); impair navigation -> controller "
            '(publisher = "nav-*") or the commands (topic = "cmd/*/att") instead'
        )
    if link.subscriber == "monitor":
        raise DeploymentError(
            f"{w}.subscriber: the monitor records what is published, unimpaired; impair "
            "the links between flight services"
        )


def check_links(dep: Deployment) -> None:
    """[[link]]: globs that name services; never the truth to navigation, nor the monitor.
    (The link parameters are checked when the table is read: LinkSpec's own checks.)"""
    for k, link in enumerate(dep.link):
        check_link(dep, f"link[{k}]", link)


def link_from_params(
    publisher: Any, subscriber: Any, topic: Any, params: Mapping[str, Any]
) -> Link:
    """The link a run-time link fault impairs (``ddvi fault RUN link``: the publisher and
    subscriber globs, the topic glob, ``params`` the LinkSpec's numbers), read as a [[link]]
    table is: a wrong type or a number out of range raises DeploymentError naming the key
    (``link.loss: expected a probability in [0, 1], got 2.0``)."""
    table = {"publisher": publisher, "subscriber": subscriber, "topic": topic, **params}
    return from_table(Link, table, where="link", error=DeploymentError)


def check_link_fault(dep: Deployment, link: Link) -> None:
    """A link impaired at run time, against the run's deployment ``dep``: what a [[link]] of it
    must satisfy (delay + jitter shorter than the mission, globs naming its services, never
    the truth to navigation nor the monitor).  The one check of ``ddvi fault RUN link`` and of
    the fault message each service receives; raises DeploymentError saying what to change."""
    check_link_latency("link", link, mission_seconds(dep))
    check_link(dep, "link", link)


def check_restarts(dep: Deployment) -> None:
    """[[restart]]: a known policy, a count, a glob naming services other than the environment
    and the monitor."""
    for k, r in enumerate(dep.restart):
        w = f"restart[{k}]"
        if r.policy not in RESTART_POLICIES:
            raise DeploymentError(
                f"{w}.policy: expected one of {', '.join(RESTART_POLICIES)}, got {r.policy!r}"
            )
        if r.max_restarts < 0:
            raise DeploymentError(f"{w}.max_restarts: must be >= 0, got {r.max_restarts}")
        matched = _matches_a_service(f"{w}.service", r.service, dep.services)
        if r.policy != "never" and (fixed := {"environment", "monitor"} & set(matched)):
            raise DeploymentError(
                f"{w}.service: {r.service!r} would restart {', '.join(sorted(fixed))}: the "
                "environment is the truth and the time master, the monitor the one recording "
                'of the run; neither can be restarted into it (use service = "ctrl-*" or '
                '"nav-*")'
            )


UNKILLABLE = ("environment", "monitor")
"""Services a kill fault does not reach: the truth and time master, and the one recording;
either would end the run, not test a restart."""


def check_kill(dep: Deployment, service: str) -> None:
    """A kill fault's target (``ddvi fault RUN kill SERVICE``, and the launcher's check of
    the fault message): a service of ``dep`` whose crash the run can outlive, not one of
    :data:`UNKILLABLE`.  Raises DeploymentError naming the services that can be killed."""
    killable = [s for s in dep.services if s not in UNKILLABLE]
    if service in UNKILLABLE:
        raise DeploymentError(
            f"kill: the {service} is not killed by faults (it would end the run); kill one of "
            f"{', '.join(killable)}"
        )
    if service not in dep.services:
        raise DeploymentError(
            f"kill: {service!r} is not a service of this run; kill one of {', '.join(killable)}"
        )


def check_hosts(dep: Deployment) -> None:
    """[[host]]: a client bus on a fixed port; unique namespace names that fit a veth pair's;
    globs naming services other than the monitor."""
    if not dep.host:
        return
    if dep.bus.mode != "client" or dep.bus.port == 0:
        raise DeploymentError(
            "host: services on other hosts reach the hub through a router: set bus.mode = "
            '"client" and a fixed bus.port'
        )
    seen = set()
    for k, h in enumerate(dep.host):
        w = f"host[{k}]"
        if not h.netns or not h.netns.replace("-", "").isalnum() or len(h.netns) > 12:
            raise DeploymentError(
                f"{w}.netns: expected a name of letters, digits and '-' (at most 12, it names "
                f"the veth pair too), got {h.netns!r}"
            )
        if h.netns in seen:
            raise DeploymentError(f"{w}.netns: {h.netns!r} is used twice")
        seen.add(h.netns)
        for pattern in h.services:
            _matches_a_service(f"{w}.services", pattern, dep.services)
        if any(key_matches(p, "monitor") for p in h.services):
            raise DeploymentError(f"{w}.services: the monitor runs beside the launcher")
