"""The one pattern language of the project: Zenoh's key expressions, over service names and
topics alike, matched without a Zenoh session (the configuration reads them with no zenoh).

A key is chunks separated by ``/`` (a topic below ``ddvi/<run>/``: ``cmd/lqr/att``; a service
name is one chunk: ``nav-lqr``).  In a pattern:

- ``*`` as a whole chunk matches exactly one chunk (``cmd/*/att``);
- ``**`` as a whole chunk matches any number of chunks, none included (``**``: every key;
  ``nav/**``);
- ``$*`` inside a chunk matches any characters of that chunk (``nav-$*``); a ``*`` inside a
  chunk means the same, so that a service pattern reads as it is said (``nav-*``);
- everything else is literal.

For a pattern in Zenoh's own syntax the meaning is Zenoh's, so a pattern given to
``ddvi monitor`` (which Zenoh matches) and one in a ``[[link]]`` mean the same keys.
"""

from __future__ import annotations

import functools
import re

__all__ = ["PatternError", "check_pattern", "key_matches", "zenoh_spelling"]


class PatternError(ValueError):
    """A pattern that is not a key expression: what is wrong and what to write instead."""


def check_pattern(pattern: str) -> str:
    """``pattern`` if it is a key expression; raises PatternError naming what is wrong."""
    if not isinstance(pattern, str) or not pattern:
        raise PatternError(
            f"expected a key expression (e.g. 'nav-*', 'cmd/*/att'), got {pattern!r}"
        )
    if any(not chunk for chunk in pattern.split("/")):
        raise PatternError(
            f"{pattern!r} has an empty chunk (a leading, trailing or doubled '/'); chunks are "
            "separated by one '/'"
        )
    for chunk in pattern.split("/"):
        if "**" in chunk and chunk != "**":
            raise PatternError(
                f"{pattern!r}: '**' stands for whole chunks only ('a/**', not 'a**'); a '*' "
                "inside a chunk matches any characters of it"
            )
    if any(c in pattern for c in "?#[]"):
        raise PatternError(
            f"{pattern!r}: '?', '#', '[' and ']' are not part of a key expression; use '*' for "
            "any characters within a chunk"
        )
    return pattern


def _chunk(chunk: str) -> str:
    """One pattern chunk as a regular expression of one key chunk, led by its '/'."""
    if chunk == "**":
        return "(?:/[^/]+)*"
    if chunk == "*":
        return "/[^/]+"
    literal = chunk.replace("$*", "*").split("*")
    return "/" + "[^/]*".join(re.escape(part) for part in literal)


@functools.lru_cache(maxsize=1024)
def _compiled(pattern: str) -> re.Pattern[str]:
    check_pattern(pattern)
    return re.compile("".join(_chunk(c) for c in pattern.split("/")))


def key_matches(pattern: str, key: str) -> bool:
    """Whether ``key`` (a service name or a topic) is one of the keys ``pattern`` names.
    Raises PatternError for a pattern that is not a key expression."""
    return _compiled(pattern).fullmatch("/" + key) is not None


def zenoh_spelling(pattern: str) -> str:
    """``pattern`` as Zenoh itself takes it (a ``*`` inside a chunk written ``$*``), to
    subscribe with.  Raises PatternError for a pattern that is not a key expression."""
    check_pattern(pattern)
    return "/".join(
        c if c in ("*", "**") else c.replace("$*", "*").replace("*", "$*")
        for c in pattern.split("/")
    )
