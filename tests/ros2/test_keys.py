"""rmw_zenoh's wire names (``services.ros2.keys``) against the examples of rmw_zenoh's own
design document (docs/design.md of ros2/rmw_zenoh), the attachment against Zenoh's own
serialiser, and the GID against rmw_zenoh's hashing of a token."""

from __future__ import annotations

import pytest
import zenoh
from hypothesis import given
from hypothesis import strategies as st
from zenoh import ext

from services.ros2 import keys, messages
from services.ros2.keys import (
    Attachment,
    Durability,
    Endpoint,
    EntityKind,
    History,
    Liveliness,
    Node,
    QoS,
    Reliability,
)

STRING = "std_msgs::msg::dds_::String_"
STRING_HASH = "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18"
ADD_TWO_INTS = "example_interfaces::srv::dds_::AddTwoInts_"
ADD_TWO_INTS_HASH = "RIHS01_e118de6bf5eeb66a2491b5bda11202e7b68f198d6f67922cf30364858239c81a"

# docs/design.md, "Topic and Service name mapping to Zenoh key expressions"
DATA_KEYS = [
    ((0, "/chatter", STRING, STRING_HASH), f"0/chatter/{STRING}/{STRING_HASH}"),
    ((0, "/robot1/chatter", STRING, STRING_HASH), f"0/robot1/chatter/{STRING}/{STRING_HASH}"),
    (
        (2, "/add_two_ints", ADD_TWO_INTS, ADD_TWO_INTS_HASH),
        f"2/add_two_ints/{ADD_TWO_INTS}/{ADD_TWO_INTS_HASH}",
    ),
]


@pytest.mark.parametrize(("args", "key"), DATA_KEYS)
def test_data_keys_are_the_design_documents(args: tuple, key: str) -> None:
    assert keys.data_key(*args) == key
    assert zenoh.KeyExpr(key) == zenoh.KeyExpr.autocanonize(key)  # a canonical key expression


def test_a_relative_name_is_made_absolute_in_its_namespace() -> None:
    assert keys.fully_qualified_name("chatter", "/robot1") == "/robot1/chatter"
    assert keys.fully_qualified_name("chatter") == "/chatter"
    assert keys.fully_qualified_name("/clock", "/robot1") == "/clock"
    assert keys.fully_qualified_name("ddvi/lqr/odom", "/") == "/ddvi/lqr/odom"
    for bad in ("~/odom", "{node}/odom", "odom/", "a//b", "1odom", ""):
        with pytest.raises(ValueError, match="topic name"):
            keys.fully_qualified_name(bad)
    with pytest.raises(ValueError, match="namespace"):
        keys.fully_qualified_name("odom", "robot1")


def test_a_data_key_needs_an_absolute_topic_and_well_formed_type() -> None:
    with pytest.raises(ValueError, match="fully qualified"):
        keys.data_key(0, "chatter", STRING, STRING_HASH)
    with pytest.raises(ValueError, match="type_name"):
        keys.data_key(0, "/chatter", "std_msgs/msg/String", STRING_HASH)
    with pytest.raises(ValueError, match="type_hash"):
        keys.data_key(0, "/chatter", STRING, "RIHS01_df66")
    with pytest.raises(ValueError, match="domain_id"):
        keys.data_key(-1, "/chatter", STRING, STRING_HASH)


def _endpoint(zid: str, node: str, kind: EntityKind, topic: str, depth: int, srv: bool) -> Endpoint:
    type_name, type_hash = (ADD_TWO_INTS, ADD_TWO_INTS_HASH) if srv else (STRING, STRING_HASH)
    return Endpoint(Node(2, zid, 0, node), 10, kind, topic, type_name, type_hash, QoS(depth=depth))


# docs/design.md, "Graph Cache": the examples with demo_nodes_cpp
TOKENS = [
    (
        Node(2, "aac3178e146ba6f1fc6e6a4085e77f21", 0, "listener"),
        "@ros2_lv/2/aac3178e146ba6f1fc6e6a4085e77f21/0/0/NN/%/%/listener",
    ),
    (
        _endpoint(
            "aac3178e146ba6f1fc6e6a4085e77f21",
            "listener",
            EntityKind.SUBSCRIPTION,
            "/chatter",
            10,
            False,
        ),
        "@ros2_lv/2/aac3178e146ba6f1fc6e6a4085e77f21/0/10/MS/%/%/listener/%chatter/"
        f"{STRING}/{STRING_HASH}/::,10:,:,:,,",
    ),
    (
        _endpoint(
            "8b20917502ee955ac4476e0266340d5c", "talker", EntityKind.PUBLISHER, "/chatter", 7, False
        ),
        "@ros2_lv/2/8b20917502ee955ac4476e0266340d5c/0/10/MP/%/%/talker/%chatter/"
        f"{STRING}/{STRING_HASH}/::,7:,:,:,,",
    ),
    (
        _endpoint(
            "f9980ee0495eaafb3e38f0d19e2eae12",
            "add_two_ints_server",
            EntityKind.SERVICE,
            "/add_two_ints",
            10,
            True,
        ),
        "@ros2_lv/2/f9980ee0495eaafb3e38f0d19e2eae12/0/10/SS/%/%/add_two_ints_server/"
        f"%add_two_ints/{ADD_TWO_INTS}/{ADD_TWO_INTS_HASH}/::,10:,:,:,,",
    ),
    (
        _endpoint(
            "e1dc8d1b45ae8717fce78689cc655685",
            "add_two_ints_client",
            EntityKind.CLIENT,
            "/add_two_ints",
            10,
            True,
        ),
        "@ros2_lv/2/e1dc8d1b45ae8717fce78689cc655685/0/10/SC/%/%/add_two_ints_client/"
        f"%add_two_ints/{ADD_TWO_INTS}/{ADD_TWO_INTS_HASH}/::,10:,:,:,,",
    ),
]


@pytest.mark.parametrize(("entity", "token"), TOKENS, ids=lambda v: getattr(v, "kind", "NN"))
def test_liveliness_tokens_are_the_design_documents(entity: Node | Endpoint, token: str) -> None:
    made = keys.node_token(entity) if isinstance(entity, Node) else keys.endpoint_token(entity)
    assert made == token
    assert keys.parse_token(token) == entity
    ke = zenoh.KeyExpr(token)
    assert ke.intersects(zenoh.KeyExpr(keys.liveliness_pattern(2)))
    assert not ke.intersects(zenoh.KeyExpr(keys.liveliness_pattern(0)))


def test_a_namespace_and_enclave_are_mangled_and_read_back() -> None:
    node = Node(0, "1f", 3, "gateway", namespace="/ddvi/run1", enclave="/secure")
    endpoint = Endpoint(
        node, 7, EntityKind.PUBLISHER, "/ddvi/run1/lqr/odom", STRING, STRING_HASH, QoS(depth=10)
    )
    token = keys.endpoint_token(endpoint)
    assert token == (
        f"@ros2_lv/0/1f/3/7/MP/%secure/%ddvi%run1/gateway/%ddvi%run1%lqr%odom/{STRING}/"
        f"{STRING_HASH}/::,10:,:,:,,"
    )
    assert keys.parse_token(token) == endpoint
    assert keys.node_token(node) == "@ros2_lv/0/1f/3/3/NN/%secure/%ddvi%run1/gateway"


@pytest.mark.parametrize(
    "token",
    [
        "@ros2_lv/2/aac3/0/0/NN/%/%",  # no node name
        "@ros2_lv/2/aac3/0/1/NN/%/%/listener",  # a node's two ids differ
        "@ros2_lv/2/aac3/0/0/XX/%/%/listener",  # unknown kind
        "ros2_lv/2/aac3/0/0/NN/%/%/listener",  # not the admin space
        f"@ros2_lv/2/aac3/0/10/MP/%/%/talker/%chatter/{STRING}/{STRING_HASH}",  # no QoS
        f"@ros2_lv/2/aac3/0/10/MP/%/%/talker/%chatter/{STRING}/{STRING_HASH}/::10:,:,:,,",
        f"@ros2_lv/2/aac3/0/10/MP/%/%/talker/%chatter/{STRING}/{STRING_HASH}/9::,:,:,:,,",
    ],
)
def test_a_malformed_token_is_refused(token: str) -> None:
    with pytest.raises(ValueError):
        keys.parse_token(token)


def test_rmw_zenohs_default_qos_is_all_empty_fields() -> None:
    assert keys.qos_keyexpr(QoS()) == "::,:,:,:,,"
    assert keys.parse_qos("::,:,:,:,,") == QoS()


def test_every_qos_field_that_differs_from_the_default_is_written() -> None:
    qos = QoS(
        reliability=Reliability.BEST_EFFORT,
        durability=Durability.TRANSIENT_LOCAL,
        history=History.KEEP_ALL,
        depth=5,
        deadline=(1, 500),
        lifespan=(0, 250_000_000),
        liveliness=Liveliness.MANUAL_BY_TOPIC,
        liveliness_lease_duration=(3, 0),
    )
    text = keys.qos_keyexpr(qos)
    assert text == "2:1:2,5:1,500:0,250000000:3,3,0"
    assert keys.parse_qos(text) == qos


@given(
    st.builds(
        QoS,
        reliability=st.sampled_from(Reliability),
        durability=st.sampled_from(Durability),
        history=st.sampled_from(History),
        depth=st.integers(1, 10_000),
        deadline=st.tuples(st.integers(0, 2**40), st.integers(0, 999_999_999)),
        lifespan=st.tuples(st.integers(0, 2**40), st.integers(0, 999_999_999)),
        liveliness=st.sampled_from(Liveliness),
        liveliness_lease_duration=st.tuples(st.integers(0, 2**40), st.integers(0, 999_999_999)),
    )
)
def test_a_qos_string_reads_back_as_its_qos(qos: QoS) -> None:
    text = keys.qos_keyexpr(qos)
    assert text.count(":") == 5 and "/" not in text
    assert keys.parse_qos(text) == qos


def test_the_gid_is_rmw_zenohs_hash_of_the_token() -> None:
    # the talker's publisher token of docs/design.md, hashed by rmw_zenoh's own
    # simplified_XXH3_128bits (rmw_zenoh_cpp/src/detail/simplified_xxhash3.cpp), low64 then high64
    token = TOKENS[2][1]
    assert keys.entity_gid(token).hex() == "ac170f31eadcd9ff0cd86d7a17907d1c"
    assert len(keys.entity_gid(keys.node_token(TOKENS[0][0]))) == keys.GID_SIZE


GID = bytes(range(0xA0, 0xB0))


def test_the_attachment_is_zenohs_serialisation_of_its_three_fields() -> None:
    attachment = Attachment(
        sequence_number=1, source_timestamp=1_700_000_000_123_456_789, source_gid=GID
    )
    data = keys.encode_attachment(attachment)
    assert len(data) == keys.ATTACHMENT_SIZE == 33
    assert data == (
        (1).to_bytes(8, "little")
        + (1_700_000_000_123_456_789).to_bytes(8, "little")
        + bytes([16])
        + GID
    )
    # what rmw_zenoh's AttachmentData writes: zenoh::ext::Serializer of int64, int64 and a
    # 16-byte std::array (a length-prefixed sequence), read here by Zenoh's own deserialiser
    assert ext.z_deserialize(tuple[ext.Int64, ext.Int64, bytes], zenoh.ZBytes(data)) == (
        1,
        1_700_000_000_123_456_789,
        GID,
    )
    theirs = ext.z_serialize((ext.Int64(-5), ext.Int64(42), GID)).to_bytes()
    assert keys.decode_attachment(theirs) == Attachment(-5, 42, GID)


@given(
    st.integers(-(2**63), 2**63 - 1),
    st.integers(-(2**63), 2**63 - 1),
    st.binary(min_size=16, max_size=16),
)
def test_an_attachment_reads_back(seq: int, stamp: int, gid: bytes) -> None:
    attachment = Attachment(seq, stamp, gid)
    assert keys.decode_attachment(keys.encode_attachment(attachment)) == attachment


def test_a_malformed_attachment_is_refused() -> None:
    good = keys.encode_attachment(Attachment(1, 2, GID))
    with pytest.raises(ValueError, match="33 bytes"):
        keys.decode_attachment(good[:-1])
    with pytest.raises(ValueError, match="16-byte GID"):
        keys.decode_attachment(good[:16] + bytes([15]) + GID)
    with pytest.raises(ValueError, match="16 bytes"):
        Attachment(1, 2, GID[:8])
    with pytest.raises(ValueError, match="int64"):
        Attachment(2**63, 2, GID)


def test_the_exposed_types_make_valid_keys_and_tokens() -> None:
    node = Node(0, "9b144b1c5e0ba80d6ecb7a12326ed67c", 0, "ddvi_gateway")
    for i, ros_type in enumerate(messages.EXPOSED_TYPES):
        name, digest = messages.dds_type_name(ros_type), messages.type_hash(ros_type)
        key = keys.data_key(0, "/ddvi/topic", name, digest)
        assert zenoh.KeyExpr(key) == zenoh.KeyExpr.autocanonize(key)
        endpoint = Endpoint(node, i + 1, EntityKind.PUBLISHER, "/ddvi/topic", name, digest)
        token = keys.endpoint_token(endpoint)
        assert zenoh.KeyExpr(token) == zenoh.KeyExpr.autocanonize(token)
        assert keys.parse_token(token) == endpoint
