"""Trip samples <-> rosbags message objects of the Jazzy typestore.

Conventions of the messages the bag writer produces (the reader relies on them):

- `/imu` sensor_msgs/Imu, frame `imu_link`: angular velocity in rad/s. An axis the log did not
  measure holds 0 with a variance of UNKNOWN_AXIS_VARIANCE (1e6 (rad/s)^2) on its diagonal, so
  REP-145's element-0 marker keeps its meaning (a -1 at [0] would void the whole vector).
  Measured axes carry the stated gyro variance, or 0 ("not known") when the log states none.
  Linear acceleration in m/s^2 with zero covariance when the log has it, else
  `linear_acceleration_covariance[0] = -1`. Orientation is never known:
  `orientation = (0, 0, 0, 1)`, `orientation_covariance[0] = -1` (REP-145).
- `/odom` nav_msgs/Odometry, frame `odom`, child `base_link`: the speed in
  `twist.twist.linear.x` (variance in `twist.covariance[0]` when stated, else 0); the pose
  is not measured: identity pose with `pose.covariance[0] = -1`.
- `/scan`, `/scan2` sensor_msgs/LaserScan, ROS conventions (0 rad = forward,
  counter-clockwise, m, +inf = no return per REP-117); `time_increment` and `scan_time` are 0
  (not known); `intensities` empty when the sensor gives none.
- `/landmark_map` geometry_msgs/PoseArray, frame `map`: one pose per landmark at (x, y, 0),
  identity orientation.
- `/initialpose` geometry_msgs/PoseWithCovarianceStamped, frame `map`: x, y, yaw; zero
  covariance (the course convention takes the initial pose as exact).
- `/ground_truth` nav_msgs/Odometry, frame `map`, child `base_link`: true x, y, yaw with zero
  pose covariance; the twist is not given (`twist.covariance[0] = -1`).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import NDArray
from rosbags.typesys import get_typestore, Stores

from gyro_ekf import topics
from gyro_ekf.core.types import FloatArray, LandmarkMap, ScanSeries
from gyro_ekf.io.defaults import NS_PER_S

TYPESTORE = get_typestore(Stores.ROS2_JAZZY)
"""The Jazzy message definitions every bag of gyro_ekf is written and read with."""

_T = TYPESTORE.types
Time = _T['builtin_interfaces/msg/Time']
Header = _T['std_msgs/msg/Header']
Vector3 = _T['geometry_msgs/msg/Vector3']
Quaternion = _T['geometry_msgs/msg/Quaternion']
Point = _T['geometry_msgs/msg/Point']
Pose = _T['geometry_msgs/msg/Pose']
PoseWithCovariance = _T['geometry_msgs/msg/PoseWithCovariance']
Twist = _T['geometry_msgs/msg/Twist']
TwistWithCovariance = _T['geometry_msgs/msg/TwistWithCovariance']
Imu = _T[topics.IMU_TYPE]
Odometry = _T[topics.ODOMETRY_TYPE]
LaserScan = _T[topics.LASER_SCAN_TYPE]
PoseArray = _T[topics.POSE_ARRAY_TYPE]
PoseWithCovarianceStamped = _T[topics.POSE_WITH_COVARIANCE_STAMPED_TYPE]

UNKNOWN_AXIS_VARIANCE = 1e6
"""Variance, (rad/s)^2, that marks an angular-velocity axis the log did not measure."""

_NOT_GIVEN_3x3 = np.array([-1.0] + [0.0] * 8)
_NOT_GIVEN_6x6 = np.array([-1.0] + [0.0] * 35)
_ZERO_3x3 = np.zeros(9)
_ZERO_6x6 = np.zeros(36)
_EMPTY_F32 = np.zeros(0, dtype=np.float32)


def serialize(message: Any) -> bytes:
    """CDR bytes of a message of the Jazzy typestore."""
    return bytes(TYPESTORE.serialize_cdr(message, message.__msgtype__))


def deserialize(data: bytes | memoryview, msgtype: str) -> Any:
    """Decode CDR bytes into a message object."""
    return TYPESTORE.deserialize_cdr(data, msgtype)


def to_time(stamp_ns: int) -> Any:
    """builtin_interfaces/Time of integer nanoseconds since the epoch (>= 0)."""
    sec, nanosec = divmod(int(stamp_ns), NS_PER_S)
    return Time(sec=sec, nanosec=nanosec)


def from_time(stamp: Any) -> int:
    """Integer nanoseconds of a builtin_interfaces/Time."""
    return int(stamp.sec) * NS_PER_S + int(stamp.nanosec)


def header(stamp_ns: int, frame_id: str) -> Any:
    """std_msgs/Header."""
    return Header(stamp=to_time(stamp_ns), frame_id=frame_id)


def yaw_quaternion(yaw_rad: float) -> Any:
    """Quaternion of a rotation about z by yaw_rad."""
    return Quaternion(x=0.0, y=0.0, z=math.sin(yaw_rad / 2.0), w=math.cos(yaw_rad / 2.0))


def quaternion_yaw(q: Any) -> float:
    """Yaw, rad, of a quaternion (the z rotation of its ZYX Euler angles)."""
    return math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))


def _pose(x_m: float, y_m: float, yaw_rad: float) -> Any:
    return Pose(position=Point(x=float(x_m), y=float(y_m), z=0.0),
                orientation=yaw_quaternion(float(yaw_rad)))


_IDENTITY_POSE = _pose(0.0, 0.0, 0.0)
_ZERO_TWIST = Twist(linear=Vector3(x=0.0, y=0.0, z=0.0), angular=Vector3(x=0.0, y=0.0, z=0.0))


def angular_velocity_covariance(axes_known: tuple[bool, bool, bool],
                                gyro_sigma_rad_s: float | None) -> FloatArray:
    """Row-major 3x3 covariance for Imu.angular_velocity_covariance, shape (9,), (rad/s)^2.

    Args:
        axes_known: which axes the log measured.
        gyro_sigma_rad_s: stated gyro noise sigma, rad/s, or None (variance 0 = unknown).
    """
    variance = 0.0 if gyro_sigma_rad_s is None else float(gyro_sigma_rad_s) ** 2
    diagonal = [variance if known else UNKNOWN_AXIS_VARIANCE for known in axes_known]
    return np.diag(diagonal).ravel()


def axes_known_of(covariance: NDArray[np.float64]) -> tuple[bool, bool, bool]:
    """Which axes an Imu.angular_velocity_covariance marks as measured."""
    diagonal = np.asarray(covariance, dtype=np.float64)[[0, 4, 8]]
    if diagonal[0] == -1.0:
        return (False, False, False)
    known = diagonal < UNKNOWN_AXIS_VARIANCE
    return (bool(known[0]), bool(known[1]), bool(known[2]))


def imu_message(stamp_ns: int, rate_rad_s: FloatArray, rate_covariance: FloatArray,
                accel_m_s2: FloatArray | None) -> Any:
    """sensor_msgs/Imu of one sample.

    Args:
        stamp_ns: stamp, ns since the epoch.
        rate_rad_s: angular velocity x, y, z, shape (3,), rad/s.
        rate_covariance: from angular_velocity_covariance, shape (9,).
        accel_m_s2: linear acceleration, shape (3,), m/s^2, or None.
    """
    if accel_m_s2 is None:
        accel, accel_cov = Vector3(x=0.0, y=0.0, z=0.0), _NOT_GIVEN_3x3
    else:
        accel = Vector3(x=float(accel_m_s2[0]), y=float(accel_m_s2[1]),
                        z=float(accel_m_s2[2]))
        accel_cov = _ZERO_3x3
    return Imu(
        header=header(stamp_ns, topics.IMU_FRAME),
        orientation=Quaternion(x=0.0, y=0.0, z=0.0, w=1.0),
        orientation_covariance=_NOT_GIVEN_3x3,
        angular_velocity=Vector3(x=float(rate_rad_s[0]), y=float(rate_rad_s[1]),
                                 z=float(rate_rad_s[2])),
        angular_velocity_covariance=rate_covariance,
        linear_acceleration=accel,
        linear_acceleration_covariance=accel_cov)


def speed_covariance(speed_sigma_m_s: float | None) -> FloatArray:
    """Row-major 6x6 twist covariance with the speed variance at [0], shape (36,)."""
    covariance = np.zeros(36)
    if speed_sigma_m_s is not None:
        covariance[0] = float(speed_sigma_m_s) ** 2
    return covariance


def speed_message(stamp_ns: int, speed_m_s: float, twist_covariance: FloatArray) -> Any:
    """nav_msgs/Odometry carrying only the forward speed (pose marked unknown).

    Args:
        stamp_ns: stamp, ns since the epoch.
        speed_m_s: forward speed, m/s.
        twist_covariance: from speed_covariance, shape (36,).
    """
    return Odometry(
        header=header(stamp_ns, topics.ODOM_FRAME),
        child_frame_id=topics.BASE_FRAME,
        pose=PoseWithCovariance(pose=_IDENTITY_POSE, covariance=_NOT_GIVEN_6x6),
        twist=TwistWithCovariance(
            twist=Twist(linear=Vector3(x=float(speed_m_s), y=0.0, z=0.0),
                        angular=Vector3(x=0.0, y=0.0, z=0.0)),
            covariance=twist_covariance))


def ground_truth_message(stamp_ns: int, pose: FloatArray) -> Any:
    """nav_msgs/Odometry with a true pose (x m, y m, yaw rad) in `map`; twist not given."""
    return Odometry(
        header=header(stamp_ns, topics.MAP_FRAME),
        child_frame_id=topics.BASE_FRAME,
        pose=PoseWithCovariance(pose=_pose(pose[0], pose[1], pose[2]), covariance=_ZERO_6x6),
        twist=TwistWithCovariance(twist=_ZERO_TWIST, covariance=_NOT_GIVEN_6x6))


def pose_of(pose: Any) -> tuple[float, float, float]:
    """(x m, y m, yaw rad) of a geometry_msgs/Pose."""
    return (float(pose.position.x), float(pose.position.y), quaternion_yaw(pose.orientation))


def scan_message(stamp_ns: int, series: ScanSeries, index: int) -> Any:
    """sensor_msgs/LaserScan of scan `index` of a series, frame series.frame_id."""
    intensities = _EMPTY_F32 if series.intensities is None else np.ascontiguousarray(
        series.intensities[index], dtype=np.float32)
    beams = series.beam_count
    return LaserScan(
        header=header(stamp_ns, series.frame_id),
        angle_min=float(series.angle_min_rad),
        angle_max=float(series.angle_min_rad + series.angle_increment_rad * (beams - 1)),
        angle_increment=float(series.angle_increment_rad),
        time_increment=0.0,
        scan_time=0.0,
        range_min=float(series.range_min_m),
        range_max=float(series.range_max_m),
        ranges=np.ascontiguousarray(series.ranges_m[index], dtype=np.float32),
        intensities=intensities)


def landmark_map_message(stamp_ns: int, landmarks: LandmarkMap) -> Any:
    """geometry_msgs/PoseArray with one pose per landmark, frame `map`."""
    return PoseArray(header=header(stamp_ns, topics.MAP_FRAME),
                     poses=[_pose(x, y, 0.0) for x, y in np.asarray(landmarks.xy_m)])


def landmarks_of(message: Any) -> LandmarkMap:
    """Get the landmark map of a PoseArray, shape (k, 2), m."""
    xy = np.array([[p.position.x, p.position.y] for p in message.poses], dtype=np.float64)
    return LandmarkMap(xy.reshape(-1, 2))


def initial_pose_message(stamp_ns: int, pose: FloatArray) -> Any:
    """geometry_msgs/PoseWithCovarianceStamped of x m, y m, yaw rad in `map`, exact."""
    return PoseWithCovarianceStamped(
        header=header(stamp_ns, topics.MAP_FRAME),
        pose=PoseWithCovariance(pose=_pose(pose[0], pose[1], pose[2]), covariance=_ZERO_6x6))
