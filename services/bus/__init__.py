"""The bus substrate: Zenoh sessions and their settings (``session``), the endpoint every
service publishes and subscribes through (``endpoint``: sequence numbers, batching), its replay
guards (``guards``), per-publisher rate budgets (``budget``), link impairment models
(``links``), liveliness (``liveliness``), and
security: credentials, access control from the topology and TLS material (``security``,
``tls``).

May import: ``services.interface``, zenoh, numpy. Not configuration, models or processes.
"""

from services.bus.budget import RateBudget, budget_for, message_count
from services.bus.endpoint import Bus, queue_handler
from services.bus.guards import SEQUENCE_REASONS, SequenceGuard, SequenceGuards
from services.bus.links import LinkModel
from services.bus.liveliness import (
    alive_services,
    router_answers,
    wait_for_alive,
    wait_for_gone,
    watch_alive,
)
from services.bus.reception import worth_saying
from services.bus.session import (
    DEFAULT_HUB,
    EPHEMERAL_LOOPBACK,
    SERVICE_ZENOH_RUNTIME,
    BusSettings,
    check_name,
    error_text,
    open_session,
    zenoh_config,
)
from services.interface.links import (
    LINK_PARAMETERS,
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
    "RateBudget",
    "SequenceGuard",
    "SequenceGuards",
    "alive_services",
    "budget_for",
    "check_name",
    "error_text",
    "impairs_truth",
    "message_count",
    "open_session",
    "queue_handler",
    "router_answers",
    "rule_latency",
    "select_rule",
    "wait_for_alive",
    "wait_for_gone",
    "watch_alive",
    "worth_saying",
    "zenoh_config",
]
