"""services.interface.topics: the topic functions, the topic -> schema table and the topology
(who publishes and who subscribes each topic)."""

from __future__ import annotations

import re

import pytest

from services.interface import (
    CLOCK,
    EXOSTATE,
    RECORDED,
    SCHEMAS,
    SERVICES,
    TOPIC_SCHEMAS,
    TOPOLOGY,
    alive_topic,
    command_topic,
    fault_topic,
    gains_topic,
    log_topic,
    nav_state_topic,
    schema_for_topic,
    stats_topic,
    status_topic,
    topics_published_by,
    topics_subscribed_by,
    truth_topic,
)

TOPIC_FUNCTIONS = {
    "clock": lambda name: CLOCK,
    "exo": lambda name: EXOSTATE,
    "truth": truth_topic,
    "nav": nav_state_topic,
    "cmd": command_topic,
    "gains": gains_topic,
    "status": status_topic,
    "fault": fault_topic,
    "stats": stats_topic,
    "log": log_topic,
    "recorded": lambda name: RECORDED,
}


def _example(template: str) -> str:
    """A template with every ``<placeholder>`` filled by a name."""
    return re.sub(r"<([a-z]+)>", lambda m: f"{m.group(1)}1", template)


@pytest.mark.parametrize("schema", sorted(TOPIC_FUNCTIONS))
@pytest.mark.parametrize("name", ["deputy1", "chief", "nav-deputy2", "kill"])
def test_every_topic_function_maps_to_its_schema(schema: str, name: str) -> None:
    topic = TOPIC_FUNCTIONS[schema](name)
    assert "*" not in topic
    assert schema_for_topic(topic) == schema


def test_the_topic_functions_cover_every_schema_and_alive_carries_none() -> None:
    assert set(TOPIC_FUNCTIONS) == set(SCHEMAS) == {s for _, s in TOPIC_SCHEMAS}
    assert schema_for_topic(alive_topic("monitor")) is None  # a liveliness key, no payload
    assert schema_for_topic("nav/deputy1") is None
    assert schema_for_topic("fault") is None
    assert schema_for_topic("fault/a/b") is None  # a fault topic is fault/<kind>
    assert schema_for_topic("cmd/*/att") is None  # a pattern is no topic


def test_every_route_carries_the_schema_of_its_topic() -> None:
    for route in TOPOLOGY:
        assert route.schema in SCHEMAS
        assert schema_for_topic(_example(route.topic)) == route.schema, route.topic
        assert route.rate


def test_every_topic_pattern_has_publishers_and_subscribers() -> None:
    for pattern, schema in TOPIC_SCHEMAS:
        routes = [r for r in TOPOLOGY if r.schema == schema]
        assert routes, f"{pattern}: no route"
        for route in routes:
            assert route.publishers and route.subscribers, route.topic
            assert "monitor" in route.subscribers  # the ground records everything


def test_every_publisher_and_subscriber_is_a_known_participant() -> None:
    names = {s.name for s in SERVICES}
    assert len(names) == len(SERVICES)
    for route in TOPOLOGY:
        assert set(route.publishers) <= names, route.topic
        assert set(route.subscribers) <= names, route.topic
    assert len({r.topic for r in TOPOLOGY}) == len(TOPOLOGY)


def test_topics_published_by_a_service() -> None:
    assert topics_published_by("environment") == (
        CLOCK,
        EXOSTATE,
        truth_topic("*"),
        stats_topic("environment"),
        log_topic("environment"),
    )
    assert topics_published_by("nav-deputy1") == (
        nav_state_topic("deputy1"),
        stats_topic("nav-deputy1"),
        log_topic("nav-deputy1"),
    )
    assert topics_published_by("ctrl-deputy2") == (
        command_topic("deputy2"),
        gains_topic("deputy2"),
        status_topic("deputy2"),
        stats_topic("ctrl-deputy2"),
        log_topic("ctrl-deputy2"),
    )
    assert topics_published_by("launcher") == (stats_topic("launcher"), log_topic("launcher"))
    assert topics_published_by("ground-4242") == tuple(
        fault_topic(k) for k in ("kill", "panel", "bias", "outage", "link")
    )
    assert topics_published_by("intruder") == ()


def test_topics_subscribed_by_a_service() -> None:
    assert topics_subscribed_by("nav-deputy1") == (
        CLOCK,
        truth_topic("*"),
        fault_topic("bias"),
        fault_topic("outage"),
        fault_topic("link"),
    )
    assert topics_subscribed_by("ctrl-deputy1") == (
        CLOCK,
        EXOSTATE,
        nav_state_topic("deputy1"),
        fault_topic("link"),
    )
    assert topics_subscribed_by("environment") == (
        command_topic("*"),
        fault_topic("panel"),
        fault_topic("link"),
        RECORDED,
    )
    assert topics_subscribed_by("launcher") == (CLOCK, fault_topic("kill"))
    monitor = topics_subscribed_by("monitor")
    assert stats_topic("*") in monitor and log_topic("*") in monitor
    assert all(schema_for_topic(_example(k.replace("*", "x"))) for k in monitor)
