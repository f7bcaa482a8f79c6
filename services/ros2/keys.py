"""rmw_zenoh's wire names (ROS 2 Jazzy): the key a topic's samples travel on, the liveliness
tokens that make a node and its publishers visible to ROS 2 tools, the QoS string inside a
token, the entity GID, and the attachment every sample carries.

Formats as rmw_zenoh defines them (repository ros2/rmw_zenoh):

- ``docs/design.md``, "Topic and Service name mapping to Zenoh key expressions": the data key
  ``<domain_id>/<fully_qualified_name>/<type_name>/<type_hash>``; the fully qualified name
  without its leading ``/`` (``TopicInfo::TopicInfo`` in
  ``rmw_zenoh_cpp/src/detail/liveliness_utils.cpp`` strips it).
- ``docs/design.md``, "Graph Cache": the liveliness tokens
  ``@ros2_lv/<domain_id>/<zid>/<node_id>/<node_id>/NN/<enclave>/<namespace>/<node_name>`` and
  ``@ros2_lv/<domain_id>/<zid>/<node_id>/<entity_id>/<kind>/<enclave>/<namespace>/<node_name>/
  <topic>/<type_name>/<type_hash>/<qos>``, each name mangled (every ``/`` written ``%``)
  (``Entity::Entity``, ``mangle_name`` in ``liveliness_utils.cpp``).
- ``qos_to_keyexpr`` and ``keyexpr_to_qos`` in ``liveliness_utils.cpp``, with the defaults of
  ``QoS::QoS`` in ``rmw_zenoh_cpp/src/detail/qos.cpp``: the QoS string, in which a field equal to
  rmw_zenoh's default is left empty.
- ``Entity::Entity``: an entity's GID is the XXH3-128 hash of its liveliness token, low 64 bits
  then high 64 bits, each little-endian.
- ``docs/design.md``, "Publishers", and ``AttachmentData::serialize_to_zbytes`` in
  ``rmw_zenoh_cpp/src/detail/attachment_helpers.cpp``: the attachment, Zenoh's serialisation of
  (int64 sequence number, int64 source timestamp in ns since the UNIX epoch, the 16-byte GID as
  a length-prefixed sequence), i.e. ``<q`` ``<q`` ``0x10`` and 16 bytes: 33 bytes.
  ``PublisherData`` in ``rmw_publisher_data.cpp`` numbers a publisher's samples from 1.

Every function is pure: strings and bytes in, strings and bytes out; no Zenoh session.
"""

from __future__ import annotations

import re
import struct
from dataclasses import dataclass, field
from enum import IntEnum, StrEnum

import xxhash

__all__ = [
    "ADMIN_SPACE",
    "ATTACHMENT_SIZE",
    "GID_SIZE",
    "INFINITE",
    "Attachment",
    "Durability",
    "Endpoint",
    "EntityKind",
    "History",
    "Liveliness",
    "Node",
    "QoS",
    "Reliability",
    "data_key",
    "decode_attachment",
    "demangle",
    "encode_attachment",
    "endpoint_token",
    "entity_gid",
    "fully_qualified_name",
    "liveliness_pattern",
    "mangle",
    "node_token",
    "parse_qos",
    "parse_token",
    "qos_keyexpr",
]

ADMIN_SPACE = "@ros2_lv"
"""The first chunk of every liveliness token (a hermetic Zenoh namespace: ``**`` skips it)."""

GID_SIZE = 16
"""Bytes of an entity GID (RMW_GID_STORAGE_SIZE in Jazzy)."""


class EntityKind(StrEnum):
    """The kind chunk of a liveliness token."""

    NODE = "NN"
    PUBLISHER = "MP"
    SUBSCRIPTION = "MS"
    SERVICE = "SS"
    CLIENT = "SC"


class Reliability(IntEnum):
    """``rmw_qos_reliability_policy_e`` (ros2/rmw ``include/rmw/types.h``)."""

    RELIABLE = 1
    BEST_EFFORT = 2


class Durability(IntEnum):
    """``rmw_qos_durability_policy_e``."""

    TRANSIENT_LOCAL = 1
    VOLATILE = 2


class History(IntEnum):
    """``rmw_qos_history_policy_e``."""

    KEEP_LAST = 1
    KEEP_ALL = 2


class Liveliness(IntEnum):
    """``rmw_qos_liveliness_policy_e`` (the only kinds a token can carry)."""

    AUTOMATIC = 1
    MANUAL_BY_TOPIC = 3


Duration = tuple[int, int]
"""An ``rmw_time_t``: (seconds, nanoseconds), both non-negative."""

INFINITE: Duration = (9223372036, 854775807)
"""``RMW_DURATION_INFINITE``."""


@dataclass(frozen=True)
class QoS:
    """An entity's QoS as rmw_zenoh encodes it in a token: the profile after rmw_zenoh fills
    in system defaults (``QoS::best_available_qos``), so no field is "system default".

    The field defaults are rmw_zenoh's own (``QoS::QoS``): reliable, volatile, keep last with
    depth 42, infinite deadline, lifespan and lease, automatic liveliness; ``QoS()`` encodes
    to ``"::,:,:,:,,"``.  rclcpp's default profile is ``QoS(depth=10)``.
    """

    reliability: Reliability = Reliability.RELIABLE
    durability: Durability = Durability.VOLATILE
    history: History = History.KEEP_LAST
    depth: int = 42
    deadline: Duration = INFINITE
    lifespan: Duration = INFINITE
    liveliness: Liveliness = Liveliness.AUTOMATIC
    liveliness_lease_duration: Duration = INFINITE

    def __post_init__(self) -> None:
        object.__setattr__(self, "reliability", Reliability(self.reliability))
        object.__setattr__(self, "durability", Durability(self.durability))
        object.__setattr__(self, "history", History(self.history))
        object.__setattr__(self, "liveliness", Liveliness(self.liveliness))
        if not isinstance(self.depth, int) or self.depth < 1:
            raise ValueError(f"QoS depth: expected an int >= 1, got {self.depth!r}")
        for name in ("deadline", "lifespan", "liveliness_lease_duration"):
            value = getattr(self, name)
            if (
                not isinstance(value, tuple)
                or len(value) != 2
                or not all(isinstance(v, int) and v >= 0 for v in value)
            ):
                raise ValueError(f"QoS {name}: expected (sec, nsec) ints >= 0, got {value!r}")


_DEFAULT_QOS = QoS()


def _field(value: int, default: int) -> str:
    """One QoS field as ``qos_to_keyexpr`` writes it: empty when it is rmw_zenoh's default."""
    return "" if value == default else str(int(value))


def qos_keyexpr(qos: QoS) -> str:
    """The QoS chunk of a token:
    ``<reliability>:<durability>:<history>,<depth>:<deadline s>,<ns>:<lifespan s>,<ns>:
    <liveliness>,<lease s>,<lease ns>``, a field equal to rmw_zenoh's default left empty
    (``QoS(depth=10)`` -> ``"::,10:,:,:,,"``)."""
    d = _DEFAULT_QOS
    lease, default_lease = qos.liveliness_lease_duration, d.liveliness_lease_duration
    return ":".join(
        [
            _field(qos.reliability, d.reliability),
            _field(qos.durability, d.durability),
            _field(qos.history, d.history) + "," + _field(qos.depth, d.depth),
            _duration_fields(qos.deadline, d.deadline),
            _duration_fields(qos.lifespan, d.lifespan),
            _field(qos.liveliness, d.liveliness) + "," + _duration_fields(lease, default_lease),
        ]
    )


def _duration_fields(value: Duration, default: Duration) -> str:
    return _field(value[0], default[0]) + "," + _field(value[1], default[1])


def _digits(text: str) -> bool:
    return text.isascii() and text.isdigit()


def _int_field(text: str, default: int, what: str) -> int:
    if text == "":
        return default
    if not _digits(text):
        raise ValueError(f"QoS string: {what} {text!r} is not a non-negative integer")
    return int(text)


def parse_qos(text: str) -> QoS:
    """The QoS of a token's QoS chunk (the inverse of ``qos_keyexpr``); ValueError if it is
    not six ``:``-separated parts of 1, 1, 2, 2, 2 and 3 ``,``-separated fields."""
    parts = text.split(":")
    sizes = (1, 1, 2, 2, 2, 3)
    fields = [p.split(",") for p in parts]
    if len(parts) != len(sizes) or [len(f) for f in fields] != list(sizes):
        raise ValueError(
            f"QoS string {text!r}: expected '<rel>:<dur>:<hist>,<depth>:<s>,<ns>:<s>,<ns>:"
            "<liveliness>,<s>,<ns>'"
        )
    d = _DEFAULT_QOS
    (rel,), (dur,), (hist, depth), deadline, lifespan, (liv, *lease) = fields
    try:
        return QoS(
            reliability=Reliability(_int_field(rel, d.reliability, "reliability")),
            durability=Durability(_int_field(dur, d.durability, "durability")),
            history=History(_int_field(hist, d.history, "history")),
            depth=_int_field(depth, d.depth, "depth"),
            deadline=_duration(deadline, d.deadline, "deadline"),
            lifespan=_duration(lifespan, d.lifespan, "lifespan"),
            liveliness=Liveliness(_int_field(liv, d.liveliness, "liveliness")),
            liveliness_lease_duration=_duration(lease, d.liveliness_lease_duration, "lease"),
        )
    except ValueError as e:
        raise ValueError(f"QoS string {text!r}: {e}") from None


def _duration(texts: list[str], default: Duration, what: str) -> Duration:
    return (
        _int_field(texts[0], default[0], what + " sec"),
        _int_field(texts[1], default[1], what + " nsec"),
    )


# ----------------------------------------------------------------------------------- names

_TOKEN = r"[A-Za-z_][A-Za-z0-9_]*"
_NAMESPACE = re.compile(rf"/|(?:/{_TOKEN})+")
_RELATIVE = re.compile(rf"{_TOKEN}(?:/{_TOKEN})*")
_NODE_NAME = re.compile(_TOKEN)
_ZID = re.compile(r"[0-9a-f]{1,32}")
_TYPE_NAME = re.compile(r"[A-Za-z][A-Za-z0-9_]*::(?:msg|srv|action)::dds_::[A-Za-z][A-Za-z0-9_]*_")
_TYPE_HASH = re.compile(r"RIHS01_[0-9a-f]{64}")


def fully_qualified_name(name: str, namespace: str = "/") -> str:
    """A topic or service name made absolute: ``("chatter", "/robot1")`` -> ``/robot1/chatter``;
    ``("/clock", ...)`` -> ``/clock``.  Private (``~``) and substituted (``{node}``) names are
    refused, as are tokens that are not ``[A-Za-z_][A-Za-z0-9_]*``."""
    if not isinstance(namespace, str) or not _NAMESPACE.fullmatch(namespace):
        raise ValueError(f"namespace: expected '/' or '/a/b', got {namespace!r}")
    relative = name[1:] if isinstance(name, str) and name.startswith("/") else name
    if not isinstance(relative, str) or not _RELATIVE.fullmatch(relative):
        raise ValueError(
            f"expected a topic name of '/'-separated [A-Za-z_][A-Za-z0-9_]* tokens, got {name!r}"
        )
    if name.startswith("/"):
        return name
    return namespace.rstrip("/") + "/" + name


def _absolute(name: str, what: str) -> str:
    if not isinstance(name, str) or not name.startswith("/"):
        raise ValueError(f"{what}: expected a fully qualified name ('/a/b'), got {name!r}")
    return fully_qualified_name(name)


def mangle(name: str) -> str:
    """A name as one key chunk: every ``/`` written ``%`` (``/robot1/chatter`` ->
    ``%robot1%chatter``; the root namespace ``/`` -> ``%``)."""
    return name.replace("/", "%")


def demangle(chunk: str) -> str:
    """The name of a mangled chunk: every ``%`` read as ``/``."""
    return chunk.replace("%", "/")


def _check(pattern: re.Pattern[str], value: object, what: str, example: str) -> str:
    if not isinstance(value, str) or not pattern.fullmatch(value):
        raise ValueError(f"{what}: expected e.g. {example!r}, got {value!r}")
    return value


def _check_id(value: object, what: str) -> int:
    if not isinstance(value, int) or isinstance(value, bool) or value < 0:
        raise ValueError(f"{what}: expected an int >= 0, got {value!r}")
    return value


def data_key(domain_id: int, topic: str, type_name: str, type_hash: str) -> str:
    """The key expression a topic's samples are put on:
    ``<domain_id>/<topic without its leading '/'>/<type_name>/<type_hash>``.

    ``topic`` is fully qualified (``fully_qualified_name``); ``type_name`` the DDS type name
    (``nav_msgs::msg::dds_::Odometry_``), ``type_hash`` the RIHS01 hash.  The same format
    names a service's queryable.
    """
    _check_id(domain_id, "domain_id")
    topic = _absolute(topic, "topic")
    _check(_TYPE_NAME, type_name, "type_name", "nav_msgs::msg::dds_::Odometry_")
    _check(_TYPE_HASH, type_hash, "type_hash", "RIHS01_" + "0" * 64)
    return f"{domain_id}/{topic[1:]}/{type_name}/{type_hash}"


# ------------------------------------------------------------------------------ liveliness


@dataclass(frozen=True)
class Node:
    """A ROS 2 node as its token names it.

    ``zid`` is the Zenoh session's id as Zenoh prints it (``str(session.info.zid())``: up to 32
    lowercase hex digits); ``node_id`` the node's number within its session (a context);
    ``namespace`` and ``enclave`` are ``/`` unless set.
    """

    domain_id: int
    zid: str
    node_id: int
    name: str
    namespace: str = "/"
    enclave: str = "/"

    def __post_init__(self) -> None:
        _check_id(self.domain_id, "domain_id")
        _check(_ZID, self.zid, "zid", "aac3178e146ba6f1fc6e6a4085e77f21")
        _check_id(self.node_id, "node_id")
        _check(_NODE_NAME, self.name, "node name", "ddvi_gateway")
        _check(_NAMESPACE, self.namespace, "namespace", "/robot1")
        _check(_NAMESPACE, self.enclave, "enclave", "/")


@dataclass(frozen=True)
class Endpoint:
    """A publisher, subscription, service server or client of ``node``, as its token names
    it: ``topic`` fully qualified, ``type_name`` the DDS type name, ``type_hash`` RIHS01."""

    node: Node
    entity_id: int
    kind: EntityKind
    topic: str
    type_name: str
    type_hash: str
    qos: QoS = field(default_factory=QoS)

    def __post_init__(self) -> None:
        object.__setattr__(self, "kind", EntityKind(self.kind))
        if self.kind is EntityKind.NODE:
            raise ValueError("an Endpoint's kind is MP, MS, SS or SC; a node is a Node")
        _check_id(self.entity_id, "entity_id")
        _absolute(self.topic, "topic")
        _check(_TYPE_NAME, self.type_name, "type_name", "nav_msgs::msg::dds_::Odometry_")
        _check(_TYPE_HASH, self.type_hash, "type_hash", "RIHS01_" + "0" * 64)


def _node_chunks(node: Node, entity_id: int, kind: EntityKind) -> list[str]:
    return [
        ADMIN_SPACE,
        str(node.domain_id),
        node.zid,
        str(node.node_id),
        str(entity_id),
        kind.value,
        mangle(node.enclave),
        mangle(node.namespace),
        mangle(node.name),
    ]


def node_token(node: Node) -> str:
    """The liveliness token of a node:
    ``@ros2_lv/<domain>/<zid>/<node_id>/<node_id>/NN/<enclave>/<namespace>/<name>``."""
    return "/".join(_node_chunks(node, node.node_id, EntityKind.NODE))


def endpoint_token(endpoint: Endpoint) -> str:
    """The liveliness token of a publisher (``MP``), subscription (``MS``), service (``SS``)
    or client (``SC``): the node's chunks with its own id and kind, then
    ``<mangled topic>/<type_name>/<type_hash>/<qos>``."""
    chunks = _node_chunks(endpoint.node, endpoint.entity_id, endpoint.kind)
    chunks += [
        mangle(endpoint.topic),
        endpoint.type_name,
        endpoint.type_hash,
        qos_keyexpr(endpoint.qos),
    ]
    return "/".join(chunks)


def parse_token(token: str) -> Node | Endpoint:
    """The node or endpoint a liveliness token names (the inverse of ``node_token`` and
    ``endpoint_token``); ValueError if it is not an rmw_zenoh token."""
    chunks = token.split("/")
    if len(chunks) < 9 or chunks[0] != ADMIN_SPACE or any(not c for c in chunks):
        raise ValueError(f"not an rmw_zenoh liveliness token: {token!r}")
    _, domain, zid, node_id, entity_id, kind_text, enclave, namespace, name, *rest = chunks
    try:
        kind = EntityKind(kind_text)
    except ValueError:
        raise ValueError(f"token {token!r}: unknown entity kind {kind_text!r}") from None
    for text, what in ((domain, "domain id"), (node_id, "node id"), (entity_id, "entity id")):
        if not _digits(text):
            raise ValueError(f"token {token!r}: {what} {text!r} is not a non-negative integer")
    node = Node(
        int(domain), zid, int(node_id), demangle(name), demangle(namespace), demangle(enclave)
    )
    if kind is EntityKind.NODE:
        if rest or entity_id != node_id:
            raise ValueError(f"token {token!r}: a node's token ends at its name, ids equal")
        return node
    if len(rest) != 4:
        raise ValueError(f"token {token!r}: an endpoint's token has topic, type, hash and QoS")
    topic, type_name, type_hash, qos = rest
    return Endpoint(
        node, int(entity_id), kind, demangle(topic), type_name, type_hash, parse_qos(qos)
    )


def liveliness_pattern(domain_id: int) -> str:
    """The key expression of every token of a domain: ``@ros2_lv/<domain_id>/**``."""
    return f"{ADMIN_SPACE}/{_check_id(domain_id, 'domain_id')}/**"


def entity_gid(token: str) -> bytes:
    """The 16-byte GID rmw_zenoh gives the entity of a liveliness token: XXH3-128 of the token
    (UTF-8), the low 64 bits then the high 64 bits, each little-endian."""
    return xxhash.xxh3_128_intdigest(token.encode()).to_bytes(GID_SIZE, "little")


# ------------------------------------------------------------------------------ attachment

_INT64 = (-(2**63), 2**63 - 1)
_ATTACHMENT = struct.Struct("<qqB")
ATTACHMENT_SIZE = _ATTACHMENT.size + GID_SIZE
"""Bytes of an attachment: 8 + 8 + 1 + 16."""


@dataclass(frozen=True)
class Attachment:
    """What rmw_zenoh attaches to every sample: the publisher's ``sequence_number`` (int64,
    1 for its first sample), the ``source_timestamp`` (int64 ns since the UNIX epoch, the
    publisher's system clock at publication) and the publisher's 16-byte ``source_gid``."""

    sequence_number: int
    source_timestamp: int
    source_gid: bytes

    def __post_init__(self) -> None:
        for name in ("sequence_number", "source_timestamp"):
            value = getattr(self, name)
            if not isinstance(value, int) or not _INT64[0] <= value <= _INT64[1]:
                raise ValueError(f"attachment {name}: expected an int64, got {value!r}")
        if not isinstance(self.source_gid, bytes) or len(self.source_gid) != GID_SIZE:
            raise ValueError(
                f"attachment source_gid: expected {GID_SIZE} bytes, got {self.source_gid!r}"
            )


def encode_attachment(attachment: Attachment) -> bytes:
    """The 33 attachment bytes: sequence number and timestamp as little-endian int64, then the
    GID as Zenoh serialises a 16-element byte array (its length, 0x10, then the bytes)."""
    head = _ATTACHMENT.pack(attachment.sequence_number, attachment.source_timestamp, GID_SIZE)
    return head + attachment.source_gid


def decode_attachment(data: bytes | bytearray | memoryview) -> Attachment:
    """The attachment of a sample (the inverse of ``encode_attachment``); ValueError if it is
    not 33 bytes with a 16-byte GID."""
    data = bytes(data)
    if len(data) != ATTACHMENT_SIZE:
        raise ValueError(f"attachment: expected {ATTACHMENT_SIZE} bytes, got {len(data)}")
    sequence_number, source_timestamp, size = _ATTACHMENT.unpack_from(data)
    if size != GID_SIZE:
        raise ValueError(f"attachment: expected a {GID_SIZE}-byte GID, its length says {size}")
    return Attachment(sequence_number, source_timestamp, data[_ATTACHMENT.size :])
