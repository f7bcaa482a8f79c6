"""The mission's quantities as ROS 2 messages (``services.ros2.conversions``): time to the
nanosecond, MRPs as ROS quaternions (checked against scipy's rotations), the Hill state as
Odometry in the frames ROS expects, gains, transforms and health."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from ddvi_core.orbit import mrp_shadow, mrp_to_dcm
from services.ros2 import conversions as cv
from services.ros2 import messages
from tests.ros2.samples import HILL_STATE, SIGMA, T

# ------------------------------------------------------------------------------------ time


@pytest.mark.parametrize(
    ("t", "stamp"),
    [
        (0.0, (0, 0)),
        (1.5, (1, 500_000_000)),
        (0.1, (0, 100_000_000)),  # 0.1000000000000000055511151231257827 s
        (1e-9, (0, 1)),
        (T, (5432, 123_456_789)),
        (2**-10, (0, 976_562)),  # exactly 976562.5 ns: ties to even
        (3 * 2**-10, (0, 2_929_688)),  # exactly 2929687.5 ns: ties to even
        (86400 * 3 + 0.999999999, (259200, 999_999_999)),
        (2**31 - 1, (2**31 - 1, 0)),
    ],
)
def test_simulation_time_is_rounded_to_the_nearest_nanosecond(
    t: float, stamp: tuple[int, int]
) -> None:
    assert cv.time_from_seconds(t) == stamp
    message = cv.time_message(t)
    assert (message.sec, message.nanosec) == stamp


@pytest.mark.parametrize("t", [-1e-9, math.nan, math.inf, 2.0**31, "1.0"])
def test_a_time_outside_builtin_interfaces_time_is_refused(t: object) -> None:
    with pytest.raises(ValueError, match="simulation time"):
        cv.time_from_seconds(t)  # type: ignore[arg-type]


@given(st.integers(0, 2**21), st.integers(0, 999_999_999))
def test_a_stamp_survives_the_float_of_its_time(sec: int, nanosec: int) -> None:
    # below 2^21 s (24 days) a float resolves well under half a nanosecond
    assert cv.time_from_seconds(cv.seconds_from_time(sec, nanosec)) == (sec, nanosec)


@given(st.floats(0.0, 1e7, allow_nan=False))
def test_a_stamp_is_within_half_a_nanosecond_of_its_time(t: float) -> None:
    sec, nanosec = cv.time_from_seconds(t)
    assert 0 <= nanosec < 1_000_000_000
    assert abs((sec - t) + nanosec * 1e-9) <= 0.5e-9 + 4 * math.ulp(t)


def test_a_clock_message_carries_the_time() -> None:
    clock = cv.clock_message(T)
    assert (clock.clock.sec, clock.clock.nanosec) == (5432, 123_456_789)


# -------------------------------------------------------------------------------- attitude


def test_a_quarter_turn_about_z_is_the_textbook_quaternion() -> None:
    sigma = np.array([0.0, 0.0, math.tan(math.pi / 8)])  # phi = 90 deg, sigma = e tan(phi/4)
    q = cv.mrp_to_quaternion(sigma)
    np.testing.assert_allclose(q, [0.0, 0.0, math.sqrt(0.5), math.sqrt(0.5)], atol=1e-15)


mrps = st.lists(st.floats(-3.0, 3.0, allow_nan=False), min_size=3, max_size=3).map(np.array)


@given(mrps)
def test_the_quaternion_rotates_the_child_frame_into_the_parent(sigma: np.ndarray) -> None:
    q = cv.mrp_to_quaternion(sigma)
    assert q.shape == (4,) and q[3] >= 0.0
    assert abs(np.linalg.norm(q) - 1.0) < 1e-12
    # ROS/scipy quaternion [x, y, z, w]: R takes child (B) components to parent (A) ones = [BA]^T
    R = Rotation.from_quat(q).as_matrix()
    np.testing.assert_allclose(R, mrp_to_dcm(sigma).T, atol=1e-12)


@given(mrps)
def test_the_mrp_comes_back_as_its_short_rotation(sigma: np.ndarray) -> None:
    back = cv.quaternion_to_mrp(cv.mrp_to_quaternion(sigma))
    np.testing.assert_allclose(back, mrp_shadow(sigma), atol=1e-12)
    assert np.linalg.norm(back) <= 1.0 + 1e-12


def test_a_quaternion_of_either_sign_gives_the_same_mrp() -> None:
    q = cv.mrp_to_quaternion(SIGMA)
    np.testing.assert_allclose(cv.quaternion_to_mrp(-3.0 * q), SIGMA, atol=1e-15)
    with pytest.raises(ValueError, match="zero quaternion"):
        cv.quaternion_to_mrp(np.zeros(4))


def test_the_commanded_attitude_is_an_orientation_in_the_deputys_hill_frame() -> None:
    message = cv.attitude_command(T, "ddvi", SIGMA)
    assert message.header.frame_id == "ddvi/hill"
    assert (message.header.stamp.sec, message.header.stamp.nanosec) == (5432, 123_456_789)
    payload = messages.serialize(message, messages.ATTITUDE_COMMAND)
    decoded = messages.deserialize(payload, messages.ATTITUDE_COMMAND)
    np.testing.assert_allclose(cv.attitude_command_mrp(decoded), SIGMA, atol=1e-15)
    for bad in ("", "a/b", "a b"):
        with pytest.raises(ValueError, match="spacecraft name"):
            cv.attitude_command(T, bad, SIGMA)


# ------------------------------------------------------------------------------ navigation


def test_odometry_is_in_the_chiefs_hill_frame_with_the_deputys_body_as_child() -> None:
    message = cv.odometry_message(T, "lqr", HILL_STATE)
    assert message.header.frame_id == "chief_hill"
    assert message.child_frame_id == "lqr/base_link"
    assert (message.header.stamp.sec, message.header.stamp.nanosec) == (5432, 123_456_789)
    pose, twist = message.pose.pose, message.twist.twist
    assert [pose.position.x, pose.position.y, pose.position.z] == HILL_STATE[:3].tolist()
    assert [pose.orientation.x, pose.orientation.y, pose.orientation.z] == [0.0, 0.0, 0.0]
    assert pose.orientation.w == 1.0
    # body axes parallel to Hill's: the twist's components are the Hill velocity's
    assert [twist.linear.x, twist.linear.y, twist.linear.z] == HILL_STATE[3:].tolist()
    assert [twist.angular.x, twist.angular.y, twist.angular.z] == [0.0, 0.0, 0.0]
    assert not message.pose.covariance.any() and not message.twist.covariance.any()


def test_the_twist_is_in_the_body_frame_and_the_covariance_follows_it() -> None:
    P = np.diag([4.0, 9.0, 1.0, 1e-4, 2e-4, 5e-5])
    P[3, 4] = P[4, 3] = 5e-5
    message = cv.odometry_message(T, "lqr", HILL_STATE, sigma=SIGMA, covariance=P)
    BH = mrp_to_dcm(SIGMA)
    twist = message.twist.twist.linear
    np.testing.assert_allclose([twist.x, twist.y, twist.z], BH @ HILL_STATE[3:], atol=1e-15)
    q = message.pose.pose.orientation
    np.testing.assert_allclose([q.x, q.y, q.z, q.w], cv.mrp_to_quaternion(SIGMA))
    pose_cov = message.pose.covariance.reshape(6, 6)
    twist_cov = message.twist.covariance.reshape(6, 6)
    np.testing.assert_array_equal(pose_cov[:3, :3], P[:3, :3])
    np.testing.assert_allclose(twist_cov[:3, :3], BH @ P[3:, 3:] @ BH.T, atol=1e-18)
    assert not pose_cov[3:].any() and not pose_cov[:, 3:].any()
    assert not twist_cov[3:].any() and not twist_cov[:, 3:].any()
    # the speed is the same in either frame
    assert math.isclose(np.linalg.norm([twist.x, twist.y, twist.z]), np.linalg.norm(HILL_STATE[3:]))


def test_the_hill_state_comes_back_from_the_wire() -> None:
    message = cv.odometry_message(T, "lqr", HILL_STATE, sigma=SIGMA)
    decoded = messages.deserialize(
        messages.serialize(message, messages.ODOMETRY), messages.ODOMETRY
    )
    np.testing.assert_allclose(cv.hill_state_from_odometry(decoded), HILL_STATE, rtol=1e-14)


def test_odometry_refuses_what_is_not_a_hill_state() -> None:
    with pytest.raises(ValueError, match="hill_state"):
        cv.odometry_message(T, "lqr", HILL_STATE[:4])
    with pytest.raises(ValueError, match="finite"):
        cv.odometry_message(T, "lqr", np.full(6, np.nan))
    with pytest.raises(ValueError, match="covariance"):
        cv.odometry_message(T, "lqr", HILL_STATE, covariance=np.eye(4))
    other = cv.odometry_message(T, "lqr", HILL_STATE)
    other.header.frame_id = "odom"
    with pytest.raises(ValueError, match="chief_hill"):
        cv.hill_state_from_odometry(other)


# ---------------------------------------------------------------------------------- frames


def test_the_transform_matches_the_odometrys_pose() -> None:
    odometry = cv.odometry_message(T, "lqr", HILL_STATE, sigma=SIGMA)
    stamped = cv.hill_transform(T, "lqr", HILL_STATE, SIGMA)
    assert stamped.header.frame_id == odometry.header.frame_id == "chief_hill"
    assert stamped.child_frame_id == odometry.child_frame_id == "lqr/base_link"
    translation, rotation = stamped.transform.translation, stamped.transform.rotation
    position, orientation = odometry.pose.pose.position, odometry.pose.pose.orientation
    assert (translation.x, translation.y, translation.z) == (position.x, position.y, position.z)
    assert (rotation.x, rotation.y, rotation.z, rotation.w) == (
        orientation.x,
        orientation.y,
        orientation.z,
        orientation.w,
    )
    tf = cv.tf_message([stamped, cv.hill_transform(T, "ddvi", HILL_STATE)])
    assert [t.child_frame_id for t in tf.transforms] == ["lqr/base_link", "ddvi/base_link"]
    with pytest.raises(ValueError, match="distinct"):
        cv.transform(T, "chief_hill", "chief_hill", np.zeros(3), np.zeros(3))


# ----------------------------------------------------------------------------------- gains


def test_gains_are_row_major_with_std_msgs_strides() -> None:
    K = np.array([[1.0, 2.0, 3.0, 4.0], [5.0, 6.0, 7.0, 8.0]])
    message = cv.gains_message(K)
    dims = message.layout.dim
    assert [(d.label, d.size, d.stride) for d in dims] == [("input", 2, 8), ("state", 4, 4)]
    assert message.layout.data_offset == 0
    assert message.data.tolist() == [1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0]
    decoded = messages.deserialize(messages.serialize(message, messages.GAINS), messages.GAINS)
    np.testing.assert_array_equal(cv.gains_from_message(decoded), K)
    np.testing.assert_array_equal(cv.gains_from_message(cv.gains_message(K.T)), K.T)


def test_gains_that_are_not_a_matrix_are_refused() -> None:
    for bad in (np.ones(3), np.ones((0, 2)), [[np.inf]]):
        with pytest.raises(ValueError, match="gains"):
            cv.gains_message(bad)
    message = cv.gains_message(np.ones((2, 3)))
    message.layout.dim[0].stride = 5
    with pytest.raises(ValueError, match="layout"):
        cv.gains_from_message(message)


# ------------------------------------------------------------------------------ diagnostics


def test_health_statuses_come_back_from_the_wire() -> None:
    statuses = [
        cv.Status("ddvi/nav-lqr", cv.Level.OK, "tracking", "lqr", {"rate_hz": "10", "age": "0.1"}),
        cv.Status("ddvi/ctrl-ddvi", cv.Level.STALE, "no input", "ddvi"),
    ]
    message = cv.diagnostic_array(T, statuses)
    assert [s.level for s in message.status] == [0, 3]
    payload = messages.serialize(message, messages.DIAGNOSTICS)
    back = cv.statuses_from_diagnostics(messages.deserialize(payload, messages.DIAGNOSTICS))
    assert back == statuses
    assert back[0].values == (("rate_hz", "10"), ("age", "0.1"))
    with pytest.raises(ValueError):
        cv.Status("x", 7)  # type: ignore[arg-type]


def test_an_altitude_is_the_point_of_the_earths_sphere_below_the_deputy_in_its_hill_frame() -> None:
    message = cv.altitude_message(120.0, "lqr", 301234.5625)
    back = messages.deserialize(messages.serialize(message, messages.ALTITUDE), messages.ALTITUDE)
    assert back.header.frame_id == "lqr/hill" and (
        back.header.stamp.sec,
        back.header.stamp.nanosec,
    ) == (120, 0)
    assert (back.point.x, back.point.y, back.point.z) == (-301234.5625, 0.0, 0.0)
    assert cv.altitude_from_message(back) == 301234.5625
    with pytest.raises(ValueError, match="finite"):
        cv.altitude_message(0.0, "lqr", float("nan"))
