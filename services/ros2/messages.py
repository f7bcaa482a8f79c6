"""The ROS 2 message types the mission exposes, in ROS 2 Jazzy's definitions: their CDR
encoding, their RIHS01 type hashes and their DDS type names.

Everything comes from the ``rosbags`` type store of ROS 2 Jazzy (``Stores.ROS2_JAZZY``): the
message classes, the CDR serialiser and deserialiser, and the RIHS01 hash (REP-2016: SHA-256
of the type description, as ``rosidl_generator_type_description`` computes it).  Nothing here
writes CDR or a hash by hand.

A CDR payload is what rmw_zenoh puts on the wire: the 4-byte encapsulation header
(``00 01 00 00``: plain CDR, little-endian) followed by the message, exactly the bytes of
``rmw_serialize``.

The exposed types, by role:

============================  =========================================  =====================
role                          ROS type                                   built by
============================  =========================================  =====================
simulation clock              ``rosgraph_msgs/msg/Clock``                ``clock_message``
relative navigation           ``nav_msgs/msg/Odometry``                  ``odometry_message``
commanded attitude            ``geometry_msgs/msg/QuaternionStamped``    ``attitude_command``
controller gains              ``std_msgs/msg/Float64MultiArray``         ``gains_message``
a deputy's altitude           ``geometry_msgs/msg/PointStamped``         ``altitude_message``
frames                        ``tf2_msgs/msg/TFMessage``                 ``tf_message``
health                        ``diagnostic_msgs/msg/DiagnosticArray``    ``diagnostic_array``
============================  =========================================  =====================

(builders in ``services.ros2.conversions``).
"""

from __future__ import annotations

import re
from typing import Any

from rosbags.typesys import Stores, get_typestore

__all__ = [
    "ALTITUDE",
    "ATTITUDE_COMMAND",
    "CLOCK",
    "DIAGNOSTICS",
    "EXPOSED_TYPES",
    "GAINS",
    "ODOMETRY",
    "TF",
    "TYPESTORE",
    "dds_type_name",
    "deserialize",
    "message_class",
    "message_definitions",
    "serialize",
    "type_hash",
]

TYPESTORE = get_typestore(Stores.ROS2_JAZZY)
"""The ROS 2 Jazzy type store: message classes, CDR, RIHS01 hashes."""

CLOCK = "rosgraph_msgs/msg/Clock"
ODOMETRY = "nav_msgs/msg/Odometry"
ATTITUDE_COMMAND = "geometry_msgs/msg/QuaternionStamped"
GAINS = "std_msgs/msg/Float64MultiArray"
TF = "tf2_msgs/msg/TFMessage"
DIAGNOSTICS = "diagnostic_msgs/msg/DiagnosticArray"
ALTITUDE = "geometry_msgs/msg/PointStamped"

EXPOSED_TYPES: tuple[str, ...] = (
    CLOCK,
    ODOMETRY,
    ATTITUDE_COMMAND,
    GAINS,
    TF,
    DIAGNOSTICS,
    ALTITUDE,
)
"""Every message type the mission exposes to ROS 2."""

_TYPE_NAME = re.compile(r"([A-Za-z][A-Za-z0-9_]*)/(msg|srv|action)/([A-Za-z][A-Za-z0-9_]*)")

_CHECKED: set[str] = set()
"""The type names ``_known`` has found in the store."""

_SECTION = "=" * 80 + "\n"
"""What separates one type's definition from the next in a ``generate_msgdef`` text."""


def _known(ros_type: str) -> str:
    """``ros_type`` if the Jazzy store has it; ValueError naming what is wrong otherwise."""
    if isinstance(ros_type, str) and ros_type in _CHECKED:  # every message carried comes here
        return ros_type
    if not isinstance(ros_type, str) or not _TYPE_NAME.fullmatch(ros_type):
        raise ValueError(
            f"expected a ROS type name '<package>/msg/<Name>' (e.g. {ODOMETRY!r}), got {ros_type!r}"
        )
    if ros_type not in TYPESTORE.types:
        raise ValueError(f"{ros_type!r} is not a ROS 2 Jazzy type known to rosbags")
    _CHECKED.add(ros_type)
    return ros_type


def message_class(ros_type: str) -> type:
    """The rosbags dataclass of ``ros_type`` (fields as in the ``.msg`` definition)."""
    return TYPESTORE.types[_known(ros_type)]


def dds_type_name(ros_type: str) -> str:
    """The DDS type name rmw_zenoh puts in keys: ``nav_msgs/msg/Odometry`` ->
    ``nav_msgs::msg::dds_::Odometry_``."""
    package, kind, name = _known(ros_type).split("/")
    return f"{package}::{kind}::dds_::{name}_"


def type_hash(ros_type: str) -> str:
    """The RIHS01 type hash of ``ros_type`` in Jazzy: ``RIHS01_`` + 64 lowercase hex digits."""
    return TYPESTORE.hash_rihs01(_known(ros_type))


def serialize(message: Any, ros_type: str) -> bytes:
    """The CDR payload of ``message`` (a ``message_class(ros_type)`` instance): encapsulation
    header, then the little-endian CDR body."""
    return bytes(TYPESTORE.serialize_cdr(message, _known(ros_type)))


def deserialize(payload: bytes | memoryview, ros_type: str) -> Any:
    """The message of a CDR payload (as ``serialize`` writes it, or rmw_zenoh publishes it)."""
    return TYPESTORE.deserialize_cdr(payload, _known(ros_type))


def message_definitions(ros_type: str) -> dict[str, str]:
    """The ``.msg`` text of ``ros_type`` and of every type it uses, by full type name.

    Returns ``{"nav_msgs/msg/Odometry": "std_msgs/Header header\\n...", "std_msgs/msg/Header":
    ..., ...}``: written to ``<folder>/<package>/msg/<Name>.msg``, they are the definitions a
    tool without ROS installed reads (to compute the same RIHS01 hash, or to decode).
    """
    text, _ = TYPESTORE.generate_msgdef(_known(ros_type), ros_version=2)
    sections = text.split(_SECTION)
    definitions = {ros_type: sections[0]}
    for section in sections[1:]:
        head, _, body = section.partition("\n")
        if not head.startswith("MSG: ") or head.count("/") != 1:
            raise ValueError(f"unexpected section header {head!r} in the definition of {ros_type}")
        package, name = head.removeprefix("MSG: ").split("/")
        definitions[f"{package}/msg/{name}"] = body
    return definitions
