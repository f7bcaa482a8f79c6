"""The exposed ROS 2 types (``services.ros2.messages``): CDR round trips, Jazzy's RIHS01 hashes
and DDS type names, and the same hashes from a second implementation (zenoh-ros2-sdk) reading
the ``.msg`` definitions the module writes, offline."""

from __future__ import annotations

import struct

import pytest

from services.ros2 import messages
from tests.ros2.samples import plain, sample

JAZZY_HASHES = {
    messages.CLOCK: "RIHS01_692f7a66e93a3c83e71765d033b60349ba68023a8c689a79e48078bcb5c58564",
    messages.ODOMETRY: "RIHS01_3cc97dc7fb7502f8714462c526d369e35b603cfc34d946e3f2eda2766dfec6e0",
    messages.ATTITUDE_COMMAND: (
        "RIHS01_381add86c6c3160644d228ca342182c7fd6c7fab11c7a85ad817a9cc22dbac6e"
    ),
    messages.GAINS: "RIHS01_1025ddc6b9552d191f89ef1a8d2f60f3d373e28b283d8891ddcc974e8c55397f",
    messages.TF: "RIHS01_e369d0f05a23ae52508854b66f6aa0437f3449d652e8cbf22d5abe85d020f087",
    messages.DIAGNOSTICS: (
        "RIHS01_5a8a36efb05fb25070fa0fb3810290c0e6cd4862b54a8fb975a1ee8dc55a333e"
    ),
    messages.ALTITUDE: "RIHS01_4c0296af86e01e562e9e0405d138a01537247580076c58ea38d7923ac1045897",
}
"""The hashes a ROS 2 Jazzy installation reports for these types (``ros2 topic info -v``),
as published by other ROS 2 implementations that pin them."""


@pytest.mark.parametrize("ros_type", messages.EXPOSED_TYPES)
def test_every_exposed_type_round_trips_through_cdr(ros_type: str) -> None:
    original = sample(ros_type)
    payload = messages.serialize(original, ros_type)
    assert payload[:4] == b"\x00\x01\x00\x00"  # encapsulation: CDR, little-endian
    decoded = messages.deserialize(payload, ros_type)
    assert plain(decoded) == plain(original)
    assert messages.serialize(decoded, ros_type) == payload


def test_a_clock_is_two_little_endian_int32_words_after_the_header() -> None:
    payload = messages.serialize(sample(messages.CLOCK), messages.CLOCK)
    assert payload == b"\x00\x01\x00\x00" + struct.pack("<iI", 5432, 123456789)


@pytest.mark.parametrize("ros_type", messages.EXPOSED_TYPES)
def test_the_hashes_are_jazzys(ros_type: str) -> None:
    assert messages.type_hash(ros_type) == JAZZY_HASHES[ros_type]


def test_the_design_documents_example_type_has_its_hash_and_dds_name() -> None:
    # rmw_zenoh docs/design.md: 0/chatter/std_msgs::msg::dds_::String_/RIHS01_df66...
    assert messages.dds_type_name("std_msgs/msg/String") == "std_msgs::msg::dds_::String_"
    assert messages.type_hash("std_msgs/msg/String") == (
        "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18"
    )


@pytest.mark.parametrize(
    ("ros_type", "dds"),
    [
        (messages.CLOCK, "rosgraph_msgs::msg::dds_::Clock_"),
        (messages.ODOMETRY, "nav_msgs::msg::dds_::Odometry_"),
        (messages.ATTITUDE_COMMAND, "geometry_msgs::msg::dds_::QuaternionStamped_"),
        (messages.GAINS, "std_msgs::msg::dds_::Float64MultiArray_"),
        (messages.TF, "tf2_msgs::msg::dds_::TFMessage_"),
        (messages.DIAGNOSTICS, "diagnostic_msgs::msg::dds_::DiagnosticArray_"),
        (messages.ALTITUDE, "geometry_msgs::msg::dds_::PointStamped_"),
    ],
)
def test_dds_type_names(ros_type: str, dds: str) -> None:
    assert messages.dds_type_name(ros_type) == dds


@pytest.mark.parametrize("bad", ["nav_msgs/Odometry", "nav_msgs/msg/Odometryy", "", "a/b/c/d"])
def test_an_unknown_or_malformed_type_is_refused(bad: str) -> None:
    with pytest.raises(ValueError, match=r"nav_msgs/msg/Odometry|not a ROS 2 Jazzy type"):
        messages.type_hash(bad)


def test_the_definitions_name_every_type_used_once() -> None:
    definitions = messages.message_definitions(messages.ODOMETRY)
    assert next(iter(definitions)) == messages.ODOMETRY
    assert set(definitions) == {
        "nav_msgs/msg/Odometry",
        "std_msgs/msg/Header",
        "builtin_interfaces/msg/Time",
        "geometry_msgs/msg/PoseWithCovariance",
        "geometry_msgs/msg/Pose",
        "geometry_msgs/msg/Point",
        "geometry_msgs/msg/Quaternion",
        "geometry_msgs/msg/TwistWithCovariance",
        "geometry_msgs/msg/Twist",
        "geometry_msgs/msg/Vector3",
    }
    assert definitions["builtin_interfaces/msg/Time"].split() == [
        "int32",
        "sec",
        "uint32",
        "nanosec",
    ]


@pytest.mark.parametrize("ros_type", messages.EXPOSED_TYPES)
def test_zenoh_ros2_sdk_computes_the_same_hash_from_the_written_definitions(
    ros_type: str, sdk_registry
) -> None:
    from zenoh_ros2_sdk.utils import get_type_hash, load_dependencies_recursive, ros2_to_dds_type

    path = sdk_registry.get_msg_file_path(ros_type)
    assert path is not None and path.is_relative_to(sdk_registry.messages_dir)
    definition = path.read_text()
    dependencies = load_dependencies_recursive(ros_type, definition, sdk_registry)
    assert set(dependencies) == set(messages.message_definitions(ros_type)) - {ros_type}
    sdk_hash = get_type_hash(ros_type, msg_definition=definition, dependencies=dependencies)
    assert sdk_hash == messages.type_hash(ros_type)
    assert ros2_to_dds_type(ros_type) == messages.dds_type_name(ros_type)
