"""The bus substrate: Zenoh sessions and their settings, the endpoint every service publishes
and subscribes through (sequence numbers, replay guards, batching), link impairment models and
liveliness.

May import: ``services.interface``, zenoh, numpy. Not configuration, models or processes.
"""

from services.bus.endpoint import (
    DEFAULT_HUB,
    EPHEMERAL_LOOPBACK,
    SEQUENCE_REASONS,
    SERVICE_ZENOH_RUNTIME,
    Bus,
    BusSettings,
    SequenceGuard,
    SequenceGuards,
    check_name,
    open_session,
    queue_handler,
    wait_for_alive,
    watch_alive,
    zenoh_config,
)
from services.bus.links import (
    LINK_PARAMETERS,
    LinkModel,
    LinkRule,
    LinkSpec,
    impairs_truth,
    rule_latency,
    select_rule,
)

__all__ = [
    "DEFAULT_HUB",
    "EPHEMERAL_LOOPBACK",
    "LINK_PARAMETERS",
    "SEQUENCE_REASONS",
    "SERVICE_ZENOH_RUNTIME",
    "Bus",
    "BusSettings",
    "LinkModel",
    "LinkRule",
    "LinkSpec",
    "SequenceGuard",
    "SequenceGuards",
    "check_name",
    "impairs_truth",
    "open_session",
    "queue_handler",
    "rule_latency",
    "select_rule",
    "wait_for_alive",
    "watch_alive",
    "zenoh_config",
]
