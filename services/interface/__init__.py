"""The flight system's interface: every message type (fields, units, meaning), the topic
each is carried on, which service publishes and which subscribes it, and the codec that puts
them on the wire.

May import: the standard library, numpy, msgpack, msgspec. Nothing else of ``services``.
"""

from services.interface.schema import (
    MAX_BATCH,
    MAX_PAYLOAD,
    REASONS,
    SCHEMAS,
    Array,
    Bool,
    Float,
    Int,
    IntMap,
    Message,
    MessageError,
    ScalarMap,
    Schema,
    Str,
    decode,
    encode,
    pack_batch,
    schema_for_topic,
    unpack_batch,
)

__all__ = [
    "MAX_BATCH",
    "MAX_PAYLOAD",
    "REASONS",
    "SCHEMAS",
    "Array",
    "Bool",
    "Float",
    "Int",
    "IntMap",
    "Message",
    "MessageError",
    "ScalarMap",
    "Schema",
    "Str",
    "decode",
    "encode",
    "pack_batch",
    "schema_for_topic",
    "unpack_batch",
]
