"""services.bus.links: validation, loss statistics, delay, duplication, reordering, determinism."""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import pytest

from ddvi_core.tables import from_table
from services.bus import LinkModel, LinkRule, LinkSpec, select_rule


def run(model: LinkModel, n: int, step: float = 1.0) -> list[int]:
    """Offer items 0..n-1 at t = 0, step, 2 step, ...; then drain; return what came out."""
    out: list[int] = []
    for i in range(n):
        out += model.offer(i, i * step)
    out += model.release(math.inf)
    return out


@pytest.mark.parametrize(
    ("kwargs", "name"),
    [
        ({"delay": -1.0}, "delay"),
        ({"jitter": -0.1}, "jitter"),
        ({"jitter": math.nan}, "jitter"),
        ({"loss": 1.5}, "loss"),
        ({"duplicate": -0.01}, "duplicate"),
        ({"reorder": 2}, "reorder"),
        ({"loss": "0.1"}, "loss"),
    ],
)
def test_spec_validation_names_the_field(kwargs: dict[str, object], name: str) -> None:
    with pytest.raises(ValueError, match=rf"LinkSpec\.{name}:"):
        LinkSpec(**kwargs)  # type: ignore[arg-type]


def test_spec_from_table() -> None:
    """A TOML table reads into a LinkSpec by the one table reader, which reports LinkSpec's
    own checks and unknown keys at the table's key path."""
    assert from_table(LinkSpec, {"delay": 2, "loss": 0.1}) == LinkSpec(delay=2, loss=0.1)
    with pytest.raises(ValueError, match=r"link\.dealy: unknown key \(did you mean 'delay'\?\)"):
        from_table(LinkSpec, {"dealy": 2}, "link")
    with pytest.raises(ValueError, match=r"link\.loss: expected a probability in \[0, 1\]"):
        from_table(LinkSpec, {"loss": 1.5}, "link")
    with pytest.raises(ValueError, match="clock"):
        LinkModel(LinkSpec(), seed=0, clock="gps")


def test_spec_of_a_subclass_is_a_plain_spec() -> None:
    """A subclass adding routing fields (a deployment's [[link]]) checks only the link
    parameters, names itself in its messages, and gives its parameters as a plain LinkSpec."""

    @dataclass(frozen=True)
    class Routed(LinkSpec):
        publisher: str = "*"

    assert Routed(delay=2.0, publisher="nav-*").spec == LinkSpec(delay=2.0)
    with pytest.raises(ValueError, match=r"Routed\.jitter:"):
        Routed(jitter=-1.0)


def test_ideal_link_passes_everything_in_order_immediately() -> None:
    model = LinkModel(LinkSpec(), seed=0)
    for i in range(100):
        assert model.offer(i, float(i)) == [i]
    assert model.counters == {"dropped": 0, "duplicated": 0, "reordered": 0, "delayed": 0}


def test_loss_rate_within_statistical_bounds() -> None:
    n, p = 20_000, 0.2
    model = LinkModel(LinkSpec(loss=p), seed=1)
    out = run(model, n)
    dropped = model.counters["dropped"]
    assert len(out) + dropped == n
    assert abs(dropped - n * p) < 4 * math.sqrt(n * p * (1 - p))  # 4 sigma
    assert out == sorted(out)


def test_delay_holds_until_due() -> None:
    model = LinkModel(LinkSpec(delay=5.0), seed=0)
    assert model.offer("a", 0.0) == []
    assert model.offer("b", 1.0) == []
    assert model.held == 2
    assert model.release(4.999) == []
    assert model.release(5.0) == ["a"]
    assert model.offer("c", 6.0) == ["b"]  # offer also releases what is due
    assert model.release(10.5) == []
    assert model.release(11.0) == ["c"]
    assert model.counters["delayed"] == 3


def test_jitter_keeps_latency_in_range_and_releases_in_due_order() -> None:
    model = LinkModel(LinkSpec(delay=2.0, jitter=3.0), seed=7)
    for i in range(200):
        model.offer(i, 0.0)
    assert model.release(1.999) == []
    out = model.release(3.5)
    assert 0 < len(out) < 200  # some due, some not
    assert sorted(out + model.release(5.0)) == list(range(200))


def test_duplicates_are_delivered_and_counted() -> None:
    model = LinkModel(LinkSpec(duplicate=1.0), seed=0)
    assert model.offer("x", 0.0) == ["x", "x"]
    model = LinkModel(LinkSpec(duplicate=0.3), seed=3)
    out = run(model, 1000)
    assert len(out) == 1000 + model.counters["duplicated"]
    assert 200 < model.counters["duplicated"] < 400


def test_reorder_swaps_adjacent_pairs() -> None:
    model = LinkModel(LinkSpec(reorder=0.3), seed=5)
    out = run(model, 1000)
    inversions = sum(a > b for a, b in itertools.pairwise(out))
    assert model.counters["reordered"] == inversions > 100
    assert len(set(out)) == len(out) == 1000 - model.held  # the last may still wait for a swap


def test_reordered_item_waits_for_its_successor() -> None:
    model = LinkModel(LinkSpec(reorder=1.0), seed=0)
    assert model.offer("a", 0.0) == []  # waits to swap with the next item
    assert model.held == 1
    assert model.offer("b", 1.0) == ["b", "a"]
    assert model.counters["reordered"] == 1


def test_deterministic_for_a_seed() -> None:
    spec = LinkSpec(delay=1.0, jitter=2.0, loss=0.1, duplicate=0.1, reorder=0.1)
    a, b, c = (LinkModel(spec, seed=s) for s in (42, 42, 43))
    out_a, out_b, out_c = run(a, 500), run(b, 500), run(c, 500)
    assert out_a == out_b and a.counters == b.counters
    assert out_a != out_c


def test_latency_runs_from_the_send_time() -> None:
    """A lock-step receiver may be ahead of the sender: the delay counts from the message's
    own time, not from when the receiver saw it."""
    model = LinkModel(LinkSpec(delay=60.0), seed=0)
    assert model.offer("cmd@0", now=60.0, sent=0.0) == ["cmd@0"]  # due at 60: on time
    assert model.offer("cmd@60", now=90.0, sent=60.0) == []
    assert model.release(119.0) == []
    assert model.release(120.0) == ["cmd@60"]


def test_rules_match_publisher_and_topic_but_never_the_clock_nor_the_recorder() -> None:
    rules = [
        LinkRule("nav-*", "nav/*/state", LinkSpec(delay=10.0)),
        LinkRule("environment", "**", LinkSpec(loss=0.1)),  # every topic: '*' is one chunk
        LinkRule("monitor", "**", LinkSpec(delay=1e5)),
    ]
    assert select_rule(rules, "nav-lqr", "nav/lqr/state") == 0
    assert select_rule(rules, "nav-lqr", "stats/nav-lqr") is None
    assert select_rule(rules, "environment", "truth/chief") == 1
    assert select_rule(rules, "environment", "clock") is None  # the time base
    assert select_rule(rules, "ctrl-lqr", "cmd/lqr/att") is None
    assert select_rule(rules, "monitor", "log/monitor") == 2
    assert select_rule(rules, "monitor", "recorded") is None  # lock-step waits on it


def test_jitter_counts_in_the_latency_a_loop_waits_for() -> None:
    """A lock-step loop maps a link to the steps it waits for with delay + jitter, the most a
    message can take; the link never takes longer."""
    model = LinkModel(LinkSpec(delay=60.0, jitter=5.0), seed=3)
    for k in range(50):
        assert model.offer(k, now=60.0 * k + 59.99, sent=60.0 * k) == []  # not before delay
        assert model.release(60.0 * k + 65.0) == [k]  # never after delay + jitter
