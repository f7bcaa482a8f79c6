"""The flight system's interface: every message type (fields, units, meaning), the topic
each is carried on, which service publishes and which subscribes it, and the codec that puts
them on the wire.

Modules: ``fields`` (field kinds and ``MessageError``), ``messages`` (the catalogue
``SCHEMAS`` and the header), ``codec`` (encode, decode, batches), ``topics`` (topic names,
``TOPIC_SCHEMAS``, the ``TOPOLOGY`` table), ``links`` (a link's impairments and the messages they
apply to, as a deployment declares them), ``reference`` (writes ``docs/interface.md``).

May import: the standard library, numpy, msgpack, msgspec. Nothing else of ``services``.
"""

from services.interface.codec import (
    MAX_BATCH,
    MAX_PAYLOAD,
    check_body,
    decode,
    encode,
    pack_batch,
    unpack_batch,
)
from services.interface.fields import (
    REASONS,
    Array,
    Bool,
    Field,
    Float,
    Int,
    IntMap,
    MessageError,
    ScalarMap,
    Str,
)
from services.interface.messages import HEADER, HEADER_KEYS, SCHEMAS, Message, Schema, upgrade
from services.interface.topics import (
    CLOCK,
    EXOSTATE,
    RECORDED,
    ROS2_GATEWAY,
    SERVICES,
    TOPIC_SCHEMAS,
    TOPOLOGY,
    Route,
    ServiceName,
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

__all__ = [
    "CLOCK",
    "EXOSTATE",
    "HEADER",
    "HEADER_KEYS",
    "MAX_BATCH",
    "MAX_PAYLOAD",
    "REASONS",
    "RECORDED",
    "ROS2_GATEWAY",
    "SCHEMAS",
    "SERVICES",
    "TOPIC_SCHEMAS",
    "TOPOLOGY",
    "Array",
    "Bool",
    "Field",
    "Float",
    "Int",
    "IntMap",
    "Message",
    "MessageError",
    "Route",
    "ScalarMap",
    "Schema",
    "ServiceName",
    "Str",
    "alive_topic",
    "check_body",
    "command_topic",
    "decode",
    "encode",
    "fault_topic",
    "gains_topic",
    "log_topic",
    "nav_state_topic",
    "pack_batch",
    "schema_for_topic",
    "stats_topic",
    "status_topic",
    "topics_published_by",
    "topics_subscribed_by",
    "truth_topic",
    "unpack_batch",
    "upgrade",
]
