"""The mission's quantities as ROS 2 messages, and back: pure functions, SI units.

Frames (REP-103 axes, REP-105 roles):

- ``chief_hill``: the chief's Hill frame, origin at the chief, x radial (outward), y
  along-track, z cross-track (orbit normal); it rotates with the chief's orbit.
- ``<sc>/hill``: deputy ``sc``'s own Hill frame, the reference of its commanded attitude.
- ``<sc>/base_link``: deputy ``sc``'s body frame.

Attitudes are modified Rodrigues parameters in ``ddvi_core.orbit``'s convention (Schaub &
Junkins: sigma = e tan(phi/4); ``mrp_to_dcm(sigma_BA)`` is the DCM [BA] taking A-frame
components to B-frame components).  ROS quaternions are Hamilton's (x, y, z, w): the orientation
of a child frame B in its parent A, whose rotation matrix R takes B-frame components to A-frame
components, so R = [BA]^T.

Time is the simulation time t (s, float, t >= 0) written as ``builtin_interfaces/Time``: the
float's exact binary value rounded to the nearest nanosecond.  With ``use_sim_time`` a ROS node
reads the same clock from ``/clock``.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from enum import IntEnum
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ddvi_core.orbit import mrp_to_dcm
from services.ros2.messages import (
    ALTITUDE,
    ATTITUDE_COMMAND,
    CLOCK,
    DIAGNOSTICS,
    GAINS,
    ODOMETRY,
    TF,
    message_class,
)

__all__ = [
    "CHIEF_HILL_FRAME",
    "Level",
    "Status",
    "altitude_from_message",
    "altitude_message",
    "attitude_command",
    "attitude_command_mrp",
    "base_link_frame",
    "clock_message",
    "diagnostic_array",
    "gains_from_message",
    "gains_message",
    "hill_frame",
    "hill_state_from_odometry",
    "hill_transform",
    "mrp_to_quaternion",
    "odometry_message",
    "quaternion_to_mrp",
    "seconds_from_time",
    "statuses_from_diagnostics",
    "tf_message",
    "time_from_seconds",
    "time_message",
    "transform",
]

FloatArray = NDArray[np.float64]

CHIEF_HILL_FRAME = "chief_hill"
"""The frame id of the chief's Hill frame."""

_NS_PER_S = 1_000_000_000
_INT32_MAX = 2**31 - 1


@functools.cache
def _msg(ros_type: str) -> type:
    return message_class(ros_type)


def _vector(value: ArrayLike, shape: tuple[int, ...], what: str) -> FloatArray:
    array = np.asarray(value, dtype=np.float64)
    if array.shape != shape:
        raise ValueError(f"{what}: expected shape {shape}, got {array.shape}")
    if not np.isfinite(array).all():
        raise ValueError(f"{what}: expected finite values, got {array}")
    return array


def _frame_name(sc: str) -> str:
    if not isinstance(sc, str) or not sc or "/" in sc or any(c.isspace() for c in sc):
        raise ValueError(f"expected a spacecraft name without '/' or spaces, got {sc!r}")
    return sc


def base_link_frame(sc: str) -> str:
    """The frame id of deputy ``sc``'s body: ``<sc>/base_link``."""
    return f"{_frame_name(sc)}/base_link"


def hill_frame(sc: str) -> str:
    """The frame id of deputy ``sc``'s own Hill frame: ``<sc>/hill``."""
    return f"{_frame_name(sc)}/hill"


# ------------------------------------------------------------------------------------ time


def time_from_seconds(t: float) -> tuple[int, int]:
    """(sec, nanosec) of the simulation time ``t`` (s): the exact binary value of ``t`` rounded
    to the nearest nanosecond (ties to even), sec >= 0, 0 <= nanosec < 10^9.

    ValueError if ``t`` is negative, not finite or past int32 seconds (2038 of the epoch).
    """
    if not isinstance(t, (int, float, np.floating, np.integer)) or not math.isfinite(t):
        raise ValueError(f"simulation time: expected a finite number of seconds, got {t!r}")
    if t < 0:
        raise ValueError(f"simulation time: expected t >= 0 s, got {t!r}")
    # t = n / d exactly (d a power of two); n 10^9 / d rounded half to even, in integers
    n, d = float(t).as_integer_ratio()
    ns, twice_rest = divmod(n * _NS_PER_S, d)
    twice_rest *= 2
    if twice_rest > d or (twice_rest == d and ns % 2):
        ns += 1
    sec, nanosec = divmod(ns, _NS_PER_S)
    if sec > _INT32_MAX:
        raise ValueError(f"simulation time: {t!r} s does not fit builtin_interfaces/Time (int32)")
    return int(sec), int(nanosec)


def seconds_from_time(sec: int, nanosec: int) -> float:
    """The time (s) of a ``builtin_interfaces/Time``: the float nearest sec + nanosec / 10^9."""
    return (sec * _NS_PER_S + nanosec) / _NS_PER_S  # integer division is correctly rounded


def time_message(t: float) -> Any:
    """``builtin_interfaces/msg/Time`` of the simulation time ``t`` (s)."""
    sec, nanosec = time_from_seconds(t)
    return _msg("builtin_interfaces/msg/Time")(sec=sec, nanosec=nanosec)


def _header(t: float, frame_id: str) -> Any:
    return _msg("std_msgs/msg/Header")(stamp=time_message(t), frame_id=frame_id)


def clock_message(t: float) -> Any:
    """``rosgraph_msgs/msg/Clock`` of the simulation time ``t`` (s), for ``/clock``."""
    return _msg(CLOCK)(clock=time_message(t))


# -------------------------------------------------------------------------------- attitude


def mrp_to_quaternion(sigma: ArrayLike) -> FloatArray:
    """(4,) ROS quaternion [x, y, z, w] (w >= 0, unit norm) of the MRP ``sigma`` (3,) of a
    frame B relative to a frame A: the orientation of B in A, R(q) = mrp_to_dcm(sigma)^T.

    The Euler parameters of sigma are beta0 = (1 - |s|^2) / (1 + |s|^2) and
    beta_i = 2 s_i / (1 + |s|^2) (Schaub & Junkins); q = [beta1, beta2, beta3, beta0], negated
    if beta0 < 0 (the same rotation).
    """
    s = _vector(sigma, (3,), "sigma")
    s2 = float(s @ s)
    q = np.empty(4)
    q[:3] = 2.0 * s
    q[3] = 1.0 - s2
    q /= 1.0 + s2
    return -q if q[3] < 0.0 else q


def quaternion_to_mrp(q: ArrayLike) -> FloatArray:
    """(3,) short-rotation MRP (|sigma| <= 1) of a ROS quaternion [x, y, z, w] (normalised
    here); the inverse of ``mrp_to_quaternion``."""
    v = _vector(q, (4,), "quaternion")
    norm = float(np.linalg.norm(v))
    if norm == 0.0:
        raise ValueError("quaternion: the zero quaternion is no rotation")
    v = v / norm
    if v[3] < 0.0:
        v = -v
    return v[:3] / (1.0 + v[3])


def _quaternion_message(sigma: ArrayLike) -> Any:
    x, y, z, w = mrp_to_quaternion(sigma).tolist()
    return _msg("geometry_msgs/msg/Quaternion")(x=x, y=y, z=z, w=w)


def _quaternion_array(q: Any) -> FloatArray:
    return np.array([q.x, q.y, q.z, q.w], dtype=np.float64)


def attitude_command(t: float, sc: str, sigma: ArrayLike) -> Any:
    """``geometry_msgs/msg/QuaternionStamped``: deputy ``sc``'s commanded attitude at ``t``
    (s), the MRP ``sigma`` (3,) of its commanded body frame relative to its own Hill frame, as
    the orientation of that body in frame ``<sc>/hill``.

    QuaternionStamped is ROS's stamped orientation and nothing else, so every ROS tool reads it
    as one: a PoseStamped would add a position the command does not have, and an MRP in a
    Vector3Stamped would be taken for a vector in ``<sc>/hill`` (tf2 would rotate it as one;
    an MRP does not transform that way).  ``attitude_command_mrp`` recovers sigma.
    """
    return _msg(ATTITUDE_COMMAND)(
        header=_header(t, hill_frame(sc)), quaternion=_quaternion_message(sigma)
    )


def attitude_command_mrp(message: Any) -> FloatArray:
    """(3,) the commanded MRP of an ``attitude_command`` message (short rotation)."""
    return quaternion_to_mrp(_quaternion_array(message.quaternion))


# ------------------------------------------------------------------------------ navigation


def _point(xyz: FloatArray) -> Any:
    x, y, z = xyz.tolist()
    return _msg("geometry_msgs/msg/Point")(x=x, y=y, z=z)


def _vector3(xyz: FloatArray) -> Any:
    x, y, z = xyz.tolist()
    return _msg("geometry_msgs/msg/Vector3")(x=x, y=y, z=z)


def _xyz(v: Any) -> FloatArray:
    return np.array([v.x, v.y, v.z], dtype=np.float64)


def odometry_message(
    t: float,
    sc: str,
    hill_state: ArrayLike,
    *,
    sigma: ArrayLike | None = None,
    covariance: ArrayLike | None = None,
) -> Any:
    """``nav_msgs/msg/Odometry`` of deputy ``sc`` at ``t`` (s) from its relative Hill state.

    Parameters
    ----------
    hill_state : (6,) [x, y, z, xdot, ydot, zdot] (m, m/s): the deputy's position relative to
        the chief and its derivative as seen from the rotating Hill frame, Hill components.
    sigma : (3,) MRP of the deputy body relative to ``chief_hill``; None: zero, the body axes
        taken parallel to the Hill axes.
    covariance : (6, 6) covariance of ``hill_state`` (m^2, m^2/s, m^2/s^2); None: zeros.

    Returns
    -------
    Odometry with ``header.frame_id = "chief_hill"`` and ``child_frame_id = "<sc>/base_link"``.
    As nav_msgs/Odometry defines it, the pose is in ``chief_hill`` (position = [x, y, z],
    orientation = sigma) and the twist in ``<sc>/base_link``: linear = [BH] [xdot, ydot, zdot]
    with [BH] = mrp_to_dcm(sigma); angular zero (not estimated).  Covariances: pose rows and
    columns 0-2 the position block of ``covariance``, twist rows and columns 0-2 the velocity
    block rotated into the body ([BH] P_vv [BH]^T); the rotational blocks are zero.
    """
    state = _vector(hill_state, (6,), "hill_state")
    pose_cov = np.zeros((6, 6))
    twist_cov = np.zeros((6, 6))
    if covariance is not None:
        P = _vector(covariance, (6, 6), "covariance")
        pose_cov[:3, :3] = P[:3, :3]
        twist_cov[:3, :3] = P[3:, 3:]
    linear = state[3:]
    if sigma is None:  # the body axes along the Hill axes: nothing to rotate
        orientation = _msg("geometry_msgs/msg/Quaternion")(x=0.0, y=0.0, z=0.0, w=1.0)
    else:
        s = _vector(sigma, (3,), "sigma")
        BH = mrp_to_dcm(s)
        linear = BH @ linear
        twist_cov[:3, :3] = BH @ twist_cov[:3, :3] @ BH.T
        orientation = _quaternion_message(s)
    vector3 = _msg("geometry_msgs/msg/Vector3")
    pose = _msg("geometry_msgs/msg/Pose")(position=_point(state[:3]), orientation=orientation)
    twist = _msg("geometry_msgs/msg/Twist")(
        linear=_vector3(linear), angular=vector3(x=0.0, y=0.0, z=0.0)
    )
    return _msg(ODOMETRY)(
        header=_header(t, CHIEF_HILL_FRAME),
        child_frame_id=base_link_frame(sc),
        pose=_msg("geometry_msgs/msg/PoseWithCovariance")(
            pose=pose, covariance=pose_cov.reshape(36)
        ),
        twist=_msg("geometry_msgs/msg/TwistWithCovariance")(
            twist=twist, covariance=twist_cov.reshape(36)
        ),
    )


def hill_state_from_odometry(message: Any) -> FloatArray:
    """(6,) [x, y, z, xdot, ydot, zdot] (m, m/s, Hill components) of an Odometry in
    ``chief_hill``: the inverse of ``odometry_message`` (the twist rotated back out of the
    body with the pose's orientation)."""
    if message.header.frame_id != CHIEF_HILL_FRAME:
        raise ValueError(
            f"odometry: expected frame_id {CHIEF_HILL_FRAME!r}, got {message.header.frame_id!r}"
        )
    pose = message.pose.pose
    BH = mrp_to_dcm(quaternion_to_mrp(_quaternion_array(pose.orientation)))
    velocity = BH.T @ _xyz(message.twist.twist.linear)
    return np.concatenate([_xyz(pose.position), velocity])


def altitude_message(t: float, sc: str, altitude: float) -> Any:
    """``geometry_msgs/msg/PointStamped``: deputy ``sc``'s altitude ``altitude`` (m above the
    Earth's reference sphere, R_E) at ``t`` (s), as the point of that sphere below the deputy
    in its own Hill frame ``<sc>/hill`` (x radial outward): [-altitude, 0, 0].

    A ROS message for a stamped altitude, in a standard type every ROS tool reads (a Float64
    has no stamp to pair it with its navigation sample); ``altitude_from_message`` recovers it.
    """
    h = float(_vector([altitude], (1,), "altitude")[0])
    return _msg(ALTITUDE)(header=_header(t, hill_frame(sc)), point=_point(np.array([-h, 0.0, 0.0])))


def altitude_from_message(message: Any) -> float:
    """The altitude (m) of an ``altitude_message``."""
    return -float(message.point.x)


# ---------------------------------------------------------------------------------- frames


def transform(t: float, parent: str, child: str, translation: ArrayLike, sigma: ArrayLike) -> Any:
    """``geometry_msgs/msg/TransformStamped`` at ``t`` (s): frame ``child`` in frame
    ``parent``, its origin at ``translation`` (3,) (m, parent components) and its orientation
    the MRP ``sigma`` (3,) of child relative to parent."""
    if not parent or not child or parent == child:
        raise ValueError(f"transform: expected two distinct frame ids, got {parent!r}, {child!r}")
    return _msg("geometry_msgs/msg/TransformStamped")(
        header=_header(t, parent),
        child_frame_id=child,
        transform=_msg("geometry_msgs/msg/Transform")(
            translation=_vector3(_vector(translation, (3,), "translation")),
            rotation=_quaternion_message(sigma),
        ),
    )


def hill_transform(t: float, sc: str, hill_state: ArrayLike, sigma: ArrayLike | None = None) -> Any:
    """The transform ``chief_hill`` -> ``<sc>/base_link`` at ``t`` (s) that matches
    ``odometry_message``'s pose: origin at [x, y, z] of ``hill_state`` (6,) (m), orientation
    the MRP ``sigma`` (3,) of the body relative to ``chief_hill`` (None: zero)."""
    state = _vector(hill_state, (6,), "hill_state")
    return transform(
        t,
        CHIEF_HILL_FRAME,
        base_link_frame(sc),
        state[:3],
        np.zeros(3) if sigma is None else sigma,
    )


def tf_message(transforms: Iterable[Any]) -> Any:
    """``tf2_msgs/msg/TFMessage`` of TransformStamped messages (``transform``)."""
    return _msg(TF)(transforms=list(transforms))


# ----------------------------------------------------------------------------------- gains


def gains_message(K: ArrayLike, labels: tuple[str, str] = ("input", "state")) -> Any:
    """``std_msgs/msg/Float64MultiArray`` of a gain matrix ``K`` (m, n) (u = -K x in the
    controller's units), row-major as std_msgs/MultiArrayLayout specifies: dim[0] ``labels[0]``
    (size m, stride m n), dim[1] ``labels[1]`` (size n, stride n), data_offset 0."""
    gains = np.asarray(K, dtype=np.float64)
    if gains.ndim != 2 or 0 in gains.shape or not np.isfinite(gains).all():
        raise ValueError(f"gains: expected a finite (m, n) matrix, got shape {gains.shape}")
    m, n = gains.shape
    dim = _msg("std_msgs/msg/MultiArrayDimension")
    layout = _msg("std_msgs/msg/MultiArrayLayout")(
        dim=[dim(label=labels[0], size=m, stride=m * n), dim(label=labels[1], size=n, stride=n)],
        data_offset=0,
    )
    return _msg(GAINS)(layout=layout, data=np.ascontiguousarray(gains).reshape(m * n))


def gains_from_message(message: Any) -> FloatArray:
    """(m, n) the matrix of a ``gains_message``; ValueError if the layout is not a dense
    row-major 2-D one."""
    dims = message.layout.dim
    if len(dims) != 2 or message.layout.data_offset != 0:
        raise ValueError("gains: expected a 2-D layout with data_offset 0")
    m, n = dims[0].size, dims[1].size
    if dims[0].stride != m * n or dims[1].stride != n or len(message.data) != m * n:
        raise ValueError(
            f"gains: layout ({m} x {n}, strides {dims[0].stride}, {dims[1].stride}) does not "
            f"match {len(message.data)} values"
        )
    return np.array(message.data, dtype=np.float64).reshape(m, n)


# ------------------------------------------------------------------------------ diagnostics


class Level(IntEnum):
    """``diagnostic_msgs/DiagnosticStatus`` levels."""

    OK = 0
    WARN = 1
    ERROR = 2
    STALE = 3


@dataclass(frozen=True)
class Status:
    """One component's health: ``name`` (e.g. ``"ddvi/nav-lqr"``), ``level``, a one-line
    ``message``, ``hardware_id`` and key-value ``values`` (a mapping or pairs, kept in order)."""

    name: str
    level: Level
    message: str = ""
    hardware_id: str = ""
    values: tuple[tuple[str, str], ...] | Mapping[str, str] = ()

    def __post_init__(self) -> None:
        object.__setattr__(self, "level", Level(self.level))
        pairs = self.values.items() if isinstance(self.values, Mapping) else self.values
        pairs = tuple((str(k), str(v)) for k, v in pairs)
        object.__setattr__(self, "values", pairs)
        if not self.name:
            raise ValueError("diagnostic status: expected a non-empty name")


def diagnostic_array(t: float, statuses: Sequence[Status]) -> Any:
    """``diagnostic_msgs/msg/DiagnosticArray`` at ``t`` (s) of ``statuses``."""
    status = _msg("diagnostic_msgs/msg/DiagnosticStatus")
    key_value = _msg("diagnostic_msgs/msg/KeyValue")
    return _msg(DIAGNOSTICS)(
        header=_header(t, ""),
        status=[
            status(
                level=int(s.level),
                name=s.name,
                message=s.message,
                hardware_id=s.hardware_id,
                values=[key_value(key=k, value=v) for k, v in s.values],
            )
            for s in statuses
        ],
    )


def statuses_from_diagnostics(message: Any) -> list[Status]:
    """The statuses of a DiagnosticArray (the inverse of ``diagnostic_array``)."""
    return [
        Status(
            s.name,
            Level(s.level),
            s.message,
            s.hardware_id,
            tuple((kv.key, kv.value) for kv in s.values),
        )
        for s in message.status
    ]
