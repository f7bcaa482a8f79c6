"""The ROS 2 wire format (ROS 2 Jazzy over rmw_zenoh) for the messages the mission exposes:
what a gateway to ROS 2 puts on a Zenoh bus so that ROS 2 nodes and tools see a ROS 2 node.

Modules: ``messages`` (the exposed types, their CDR, RIHS01 hashes and DDS type names, from
the ``rosbags`` Jazzy type store), ``keys`` (rmw_zenoh's data keys, liveliness tokens, QoS
strings, entity GIDs and sample attachments), ``conversions`` (the mission's quantities as
those messages, and back: Hill state, simulation time, MRP attitudes, gains, health).
docs/ros2.md describes the wire format for users.

Pure: no Zenoh session, no I/O.  Needs the ``ros2`` extra (rosbags, xxhash).

May import: the standard library, numpy, rosbags, xxhash, ``ddvi_core``. Nothing else of
``services``; its ``gateway`` package is the service that carries a run to ROS 2 with this
wire format, a layer above it (its own docstring says what it may import).
"""

import os

# the gateway's process loads numpy through this package before its runtime can say so: BLAS
# threads would compete with the services for the cores
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

from services.ros2.conversions import (
    CHIEF_HILL_FRAME,
    Level,
    Status,
    altitude_from_message,
    altitude_message,
    attitude_command,
    attitude_command_mrp,
    base_link_frame,
    clock_message,
    diagnostic_array,
    gains_from_message,
    gains_message,
    hill_frame,
    hill_state_from_odometry,
    hill_transform,
    mrp_to_quaternion,
    odometry_message,
    quaternion_to_mrp,
    seconds_from_time,
    statuses_from_diagnostics,
    tf_message,
    time_from_seconds,
    time_message,
    transform,
)
from services.ros2.keys import (
    Attachment,
    Endpoint,
    EntityKind,
    Node,
    QoS,
    data_key,
    decode_attachment,
    encode_attachment,
    endpoint_token,
    entity_gid,
    fully_qualified_name,
    liveliness_pattern,
    node_token,
    parse_qos,
    parse_token,
    qos_keyexpr,
)
from services.ros2.messages import (
    ALTITUDE,
    ATTITUDE_COMMAND,
    CLOCK,
    DIAGNOSTICS,
    EXPOSED_TYPES,
    GAINS,
    ODOMETRY,
    TF,
    dds_type_name,
    deserialize,
    message_class,
    message_definitions,
    serialize,
    type_hash,
)

__all__ = [
    "ALTITUDE",
    "ATTITUDE_COMMAND",
    "CHIEF_HILL_FRAME",
    "CLOCK",
    "DIAGNOSTICS",
    "EXPOSED_TYPES",
    "GAINS",
    "ODOMETRY",
    "TF",
    "Attachment",
    "Endpoint",
    "EntityKind",
    "Level",
    "Node",
    "QoS",
    "Status",
    "altitude_from_message",
    "altitude_message",
    "attitude_command",
    "attitude_command_mrp",
    "base_link_frame",
    "clock_message",
    "data_key",
    "dds_type_name",
    "decode_attachment",
    "deserialize",
    "diagnostic_array",
    "encode_attachment",
    "endpoint_token",
    "entity_gid",
    "fully_qualified_name",
    "gains_from_message",
    "gains_message",
    "hill_frame",
    "hill_state_from_odometry",
    "hill_transform",
    "liveliness_pattern",
    "message_class",
    "message_definitions",
    "mrp_to_quaternion",
    "node_token",
    "odometry_message",
    "parse_qos",
    "parse_token",
    "qos_keyexpr",
    "quaternion_to_mrp",
    "seconds_from_time",
    "serialize",
    "statuses_from_diagnostics",
    "tf_message",
    "time_from_seconds",
    "time_message",
    "transform",
    "type_hash",
]
