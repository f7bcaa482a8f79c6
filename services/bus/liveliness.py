"""Liveliness: which services are up. A ``Bus`` declares its service's token
``ddvi/<run>/alive/<service>`` (``services.interface.topics.alive_topic``); the functions here
watch those tokens come and go."""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Iterable
from typing import Any

import zenoh

from services.bus.session import key_prefix
from services.interface.keys import key_matches
from services.interface.topics import alive_topic

log = logging.getLogger("ddvi.bus")


def watch_alive(
    session: zenoh.Session, run: str, pattern: str, on_change: Callable[[str, bool], None]
) -> Any:
    """Call ``on_change(service, alive)`` for every service matching ``pattern`` (a key
    expression, ``ctrl-*``: ``services.interface.keys``) whose liveliness token is there now
    or comes and goes later.  Returns the zenoh subscriber: undeclare it when done.
    ``on_change`` runs on a zenoh thread and must not raise."""
    # a service name is one key chunk, so zenoh's '*' hears every token and the last chunk of
    # a token's key is its service
    key = key_prefix(run) + alive_topic("*")

    def on_sample(sample: zenoh.Sample) -> None:
        try:
            name = str(sample.key_expr).rsplit("/", 1)[-1]
            if key_matches(pattern, name):
                on_change(name, sample.kind == zenoh.SampleKind.PUT)
        except Exception:
            log.exception("liveliness callback failed")

    return session.liveliness().declare_subscriber(key, on_sample, history=True)


def wait_for_alive(
    session: zenoh.Session, run: str, services: Iterable[str], timeout: float
) -> set[str]:
    """Wait until every named service's liveliness token is seen or ``timeout`` s pass.

    Returns the subset of ``services`` alive at return time.
    """
    wanted = set(services)
    alive: set[str] = set()
    changed = threading.Condition()

    def on_change(name: str, up: bool) -> None:
        with changed:
            if up:
                alive.add(name)
            else:
                alive.discard(name)
            changed.notify_all()

    subscriber = watch_alive(session, run, "*", on_change)
    try:
        with changed:
            changed.wait_for(lambda: wanted <= alive, timeout)
            return wanted & alive
    finally:
        subscriber.undeclare()


def alive_services(session: zenoh.Session, run: str, timeout: float = 2.0) -> set[str]:
    """The services of ``run`` whose liveliness token is there now: a liveliness query, which
    the run's router answers at once with every token it holds (``timeout`` s at most)."""
    found: set[str] = set()
    for reply in session.liveliness().get(key_prefix(run) + alive_topic("*"), timeout=timeout):
        if reply.ok is not None:
            found.add(str(reply.ok.key_expr).rsplit("/", 1)[-1])
    return found


def wait_for_gone(session: zenoh.Session, run: str, service: str, timeout: float) -> bool:
    """Wait until ``service``'s liveliness token is gone (or was never there), at most
    ``timeout`` s; whether it is gone."""
    gone = threading.Event()

    def on_change(_name: str, up: bool) -> None:
        if not up:
            gone.set()

    subscriber = watch_alive(session, run, service, on_change)  # before the query: no gap
    try:
        key = key_prefix(run) + alive_topic(service)
        replies = session.liveliness().get(key, timeout=min(timeout, 2.0))
        if not any(reply.ok is not None for reply in replies):
            return True
        return gone.wait(timeout)
    finally:
        subscriber.undeclare()


ROUTER_PROBE = 2.0
"""Wall seconds a service gives the run's router to answer a liveliness query before it takes
the router for frozen."""


def router_answers(
    session: zenoh.Session, run: str, service: str, timeout: float = ROUTER_PROBE
) -> bool:
    """Whether the run's router answers, within ``timeout`` s, a liveliness query for
    ``service``'s token.  A router's answer ends the query at once, whatever it holds; a query
    to a frozen router (stopped, or its host gone) runs until its timeout, with at most the
    asking session's own tokens."""
    start = time.monotonic()
    try:
        for _ in session.liveliness().get(key_prefix(run) + alive_topic(service), timeout=timeout):
            pass
    except Exception:  # a session that cannot even ask has lost its router too
        log.exception("liveliness query for %s failed", service)
        return False
    return time.monotonic() - start < 0.75 * timeout
