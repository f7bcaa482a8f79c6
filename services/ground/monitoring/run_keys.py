"""A run's key expressions from what a user types: a topic pattern (``ctrl/*/status``) or a
full key expression (``ddvi/<run>/ctrl/*/status``), for ``ddvi monitor`` and its live tap."""

from __future__ import annotations

import re

import zenoh

from services.interface import TOPOLOGY
from services.interface.keys import PatternError, zenoh_spelling


def topic_patterns() -> list[str]:
    """Every topic of the topology as a key expression (its placeholders as ``*``)."""
    return [re.sub(r"<[a-z]+>", "*", route.topic) for route in TOPOLOGY]


def run_keyexpr(run: str, pattern: str | None) -> str:
    """The key expression of ``pattern`` on run ``run`` (``*`` for any run): a topic pattern
    (``ctrl/*/status``) is put below ``ddvi/<run>/``; a full one (``ddvi/*/ctrl/*/status``)
    has its run part made ``run``.  ValueError (one line) when it names another run or
    matches no topic of the topology."""
    if not pattern:
        return f"ddvi/{run}/**"
    parts = pattern.strip("/").split("/")
    if parts[0] == "ddvi" and len(parts) > 1:
        named = parts[1]
        if named not in ("*", "**", run) and run != "*":
            raise ValueError(
                f"{pattern!r} names run {named!r}, not this run ({run!r}): give "
                "a topic pattern such as 'ctrl/*/status'"
            )
        if named != "**":
            run = named if run == "*" else run
        parts = (["**"] if named == "**" else []) + parts[2:]
    try:
        topics = zenoh_spelling("/".join(parts) or "**")
        key = zenoh.KeyExpr(topics)
    except (PatternError, zenoh.ZError) as exc:
        raise ValueError(
            f"{pattern!r} is not a key expression ({exc}; chunks separated by /, * for one "
            "chunk or any characters within one, ** for any number: docs/deployments.md, "
            '"Patterns")'
        ) from None
    known = topic_patterns()
    if not any(key.intersects(zenoh.KeyExpr(t)) for t in known):
        raise ValueError(f"{pattern!r} matches no topic; the topics are {', '.join(known)}")
    return f"ddvi/{run}/{topics}"
