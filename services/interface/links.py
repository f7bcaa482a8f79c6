"""Links as a deployment declares them: the impairments of one publisher->subscriber link
(``LinkSpec``) and which messages they apply to at a subscriber (``LinkRule``).  Data only:
the model that applies them to a stream of messages is ``services.bus.links.LinkModel``.

    LinkSpec(delay, jitter, loss, duplicate, reorder)   validated parameters (the one definition
                                     of a link's parameters; a deployment's [[link]] extends it)
    LinkRule(publisher, topic, spec)  which messages a spec applies to (a deployment's [[link]])
    select_rule, rule_latency          the rule that applies to a message, and its latency
    impairs_truth                      whether a link would stand between a sensor and the truth
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

from services.interface.keys import key_matches
from services.interface.topics import CLOCK, RECORDED

UNIMPAIRED = (CLOCK, RECORDED)
"""Topics no link rule applies to (``LinkRule.matches``)."""
LINK_PARAMETERS = ("delay", "jitter", "loss", "duplicate", "reorder")
"""The fields of ``LinkSpec``, in order."""


@dataclass(frozen=True)
class LinkSpec:
    """Impairments of one link. Times in seconds, probabilities in [0, 1]."""

    delay: float = 0.0
    jitter: float = 0.0
    loss: float = 0.0
    duplicate: float = 0.0
    reorder: float = 0.0

    def __post_init__(self) -> None:
        # a subclass (a deployment's [[link]]) adds routing fields: check the parameters only,
        # and name the class the values were given to
        owner = type(self).__name__
        for name in LINK_PARAMETERS:
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise ValueError(f"{owner}.{name}: expected a number, got {value!r}")
            if not math.isfinite(value) or value < 0:
                raise ValueError(f"{owner}.{name}: expected a finite value >= 0, got {value}")
            if name in ("loss", "duplicate", "reorder") and value > 1:
                raise ValueError(f"{owner}.{name}: expected a probability in [0, 1], got {value}")

    @property
    def spec(self) -> LinkSpec:
        """The impairment parameters alone, as a plain LinkSpec."""
        return LinkSpec(*(getattr(self, name) for name in LINK_PARAMETERS))


@dataclass(frozen=True)
class LinkRule:
    """Which messages a LinkSpec applies to, at one subscriber: those whose publishing service
    (the header's ``src``) matches ``publisher`` and whose topic (below ``ddvi/<run>/``) matches
    ``topic``, both key expressions (``services.interface.keys``).  The clock and the
    recorder's acknowledgements are never impaired: the emulator's time base and the ground's
    word on its recording, not flight messages (a lock-step wait on an acknowledgement a link
    held would never end)."""

    publisher: str
    topic: str
    spec: LinkSpec

    def matches(self, publisher: str, topic: str) -> bool:
        return (
            topic not in UNIMPAIRED
            and key_matches(self.publisher, publisher)
            and key_matches(self.topic, topic)
        )


def select_rule(rules: Sequence[LinkRule], publisher: str, topic: str) -> int | None:
    """Index of the first rule matching (publisher, topic), or None."""
    for i, rule in enumerate(rules):
        if rule.matches(publisher, topic):
            return i
    return None


def impairs_truth(publisher: str, subscriber: str) -> bool:
    """Whether a link from ``publisher`` (a pattern) to the service ``subscriber`` would impair
    the environment's truth to a navigation service: it is what a sensor measures, not a
    message a flight link carries (and a lock-step loop could not tell it lost from late)."""
    return subscriber.startswith("nav-") and key_matches(publisher, "environment")


def rule_latency(rules: Sequence[LinkRule], publisher: str, topic: str) -> float:
    """The largest latency (s: delay + jitter) the first matching rule gives a message from
    ``publisher`` on ``topic``; 0 when no rule matches."""
    i = select_rule(rules, publisher, topic)
    return 0.0 if i is None else rules[i].spec.delay + rules[i].spec.jitter
