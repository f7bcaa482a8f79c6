"""One pattern language (``services.interface.keys``): Zenoh's key expressions, for service
names and topics alike, matched without a session; what Zenoh itself matches, where the
pattern is in Zenoh's own syntax."""

from __future__ import annotations

import re

import pytest
import zenoh

from services.interface.keys import PatternError, check_pattern, key_matches, zenoh_spelling

CASES = [
    ("*", "nav-lqr", True),
    ("nav-*", "nav-lqr", True),
    ("nav-*", "ctrl-lqr", False),
    ("nav-$*", "nav-lqr", True),
    ("*-lqr", "nav-lqr", True),
    ("*", "cmd/lqr/att", False),  # one chunk: not fnmatch's '*'
    ("**", "cmd/lqr/att", True),
    ("**", "clock", True),
    ("cmd/*/att", "cmd/lqr/att", True),
    ("cmd/*/att", "cmd/a/b/att", False),
    ("cmd/**/att", "cmd/a/b/att", True),
    ("cmd/**", "cmd", True),  # '**' takes no chunk too
    ("nav/*/state", "exo/state", False),
    ("ctrl-lq?", "ctrl-lqr", None),  # not a key expression
]


@pytest.mark.parametrize(("pattern", "key", "matches"), CASES)
def test_patterns_match_as_zenoh_matches(pattern: str, key: str, matches: bool | None) -> None:
    if matches is None:
        with pytest.raises(PatternError, match="not part of a key expression"):
            key_matches(pattern, key)
        return
    assert key_matches(pattern, key) is matches
    # what a subscription is made with (ddvi monitor): zenoh matches the same keys
    assert zenoh.KeyExpr(zenoh_spelling(pattern)).intersects(zenoh.KeyExpr(key)) is matches


@pytest.mark.parametrize(
    ("pattern", "said"),
    [
        ("", "expected a key expression"),
        ("a//b", "an empty chunk"),
        ("nav/", "an empty chunk"),
        ("nav**", "'**' stands for whole chunks only"),
        ("[ab]", "not part of a key expression"),
    ],
)
def test_a_pattern_that_is_no_key_expression_is_refused_saying_why(pattern: str, said: str) -> None:
    with pytest.raises(PatternError, match=re.escape(said)):
        check_pattern(pattern)
