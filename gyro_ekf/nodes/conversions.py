"""Messages <-> core values: the only message-aware code of the nodes.

Stamps: ROS messages carry integer nanoseconds since the epoch; the core works in float
seconds since a time zero. ``TimeOrigin`` subtracts the zero in integers first, exactly as
`gyro_ekf.io.bag_reader` does, so a node and an offline run of the same bag compute the
same seconds (a float near 1.7e9 s would only resolve 0.24 us).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from builtin_interfaces.msg import Time
from geometry_msgs.msg import (Pose, PoseArray, PoseWithCovarianceStamped,
                               Quaternion, Vector3Stamped)
from nav_msgs.msg import Odometry
from sensor_msgs.msg import Imu, LaserScan
from std_msgs.msg import Header

from gyro_ekf.core.angles import quaternion_of_yaw, yaw_of_quaternion
from gyro_ekf.core.config import InputLimits
from gyro_ekf.core.event_records import Estimate
from gyro_ekf.core.stamps import join_ns, seconds_since, split_ns
from gyro_ekf.core.types import FloatArray
from gyro_ekf.core.validation import (coordinate_problem, covariance_problem,
                                      quaternion_problem, scan_geometry_problem)
from gyro_ekf.topics import UNKNOWN_AXIS_VARIANCE

# Row/column of x, y, yaw in a ROS 6x6 pose covariance (x, y, z, roll, pitch, yaw).
_POSE_INDEX = (0, 1, 5)


def stamp_ns(stamp: Time) -> int:
    """Integer nanoseconds of a builtin_interfaces/Time."""
    return join_ns(stamp.sec, stamp.nanosec)


def to_stamp(ns: int) -> Time:
    """builtin_interfaces/Time of integer nanoseconds since the epoch (>= 0)."""
    sec, nanosec = split_ns(ns)
    return Time(sec=sec, nanosec=nanosec)


class TimeOrigin:
    """Float seconds since a time zero, from integer-nanosecond stamps.

    Attributes:
        zero_ns: the time zero, ns since the epoch; None until the first stamp when no zero
            was configured.
    """

    def __init__(self, zero_ns: int = 0):
        """Use zero_ns as the time zero; 0 = take the first stamp converted."""
        self.zero_ns: int | None = zero_ns if zero_ns > 0 else None

    def seconds(self, ns: int) -> float:
        """Seconds since the time zero (negative before it)."""
        if self.zero_ns is None:
            self.zero_ns = ns
        return seconds_since(ns, self.zero_ns)


def finite(*values: float) -> bool:
    """Tell whether every value is a finite number."""
    return all(math.isfinite(v) for v in values)


def drop_reason(problem: str, otherwise: str) -> str:
    """Name the /diagnostics drop reason of a core.validation problem.

    `non_finite` for a NaN or inf (every check says "not finite" then), else `otherwise`.
    """
    return 'non_finite' if 'not finite' in problem else otherwise


def pose_problem(message: PoseWithCovarianceStamped, limits: InputLimits) -> str | None:
    """Why an initial pose is refused (position, quaternion, 6x6 covariance), or None.

    A zero quaternion would read as yaw 0 and a negative variance would make every later
    detection "ambiguous", so both are refused, not repaired.
    """
    pose = message.pose.pose
    q = pose.orientation
    return (coordinate_problem((pose.position.x, pose.position.y), limits)
            or quaternion_problem(q.x, q.y, q.z, q.w, limits)
            or covariance_problem(np.asarray(message.pose.covariance,
                                             dtype=np.float64).reshape(6, 6)))


def scan_problem(message: LaserScan) -> str | None:
    """Why a LaserScan's beam geometry is refused (core.validation's check), or None."""
    return scan_geometry_problem(float(message.angle_min), float(message.angle_max),
                                 float(message.angle_increment), len(message.ranges),
                                 float(message.range_min), float(message.range_max))


def imu_rates(message: Imu) -> tuple[float, float, float]:
    """Angular velocity x, y, z of an Imu message, rad/s."""
    w = message.angular_velocity
    return (float(w.x), float(w.y), float(w.z))


def imu_axes_known(message: Imu) -> tuple[bool, bool, bool]:
    """Which angular-velocity axes an Imu message's covariance marks as measured."""
    covariance = message.angular_velocity_covariance
    return axes_known(covariance[0], covariance[4], covariance[8])


def axes_known(xx: float, yy: float, zz: float) -> tuple[bool, bool, bool]:
    """Which axes the diagonal of an angular_velocity_covariance marks as measured."""
    if xx == -1.0:
        return (False, False, False)
    return tuple(bool(v < UNKNOWN_AXIS_VARIANCE) for v in (xx, yy, zz))


def corrected_imu(message: Imu, bias_rad_s: Sequence[float]) -> Imu:
    """Copy an Imu message with the gyro bias (x, y, z, rad/s) removed from its rates."""
    out = Imu(header=message.header, orientation=message.orientation,
              orientation_covariance=message.orientation_covariance,
              angular_velocity_covariance=message.angular_velocity_covariance,
              linear_acceleration=message.linear_acceleration,
              linear_acceleration_covariance=message.linear_acceleration_covariance)
    out.angular_velocity.x = message.angular_velocity.x - float(bias_rad_s[0])
    out.angular_velocity.y = message.angular_velocity.y - float(bias_rad_s[1])
    out.angular_velocity.z = message.angular_velocity.z - float(bias_rad_s[2])
    return out


def online_corrected_imu(message: Imu, bias_rad_s: float, bias_variance: float) -> Imu:
    """ekf/imu: the input with the EKF's yaw-rate bias removed and its variance added.

    The bias variance goes onto angular_velocity_covariance[8] (the corrected rate is
    uncertain by the sensor noise plus the bias estimate's); a covariance marked unknown
    (element 0 is -1, REP-145) stays so.
    """
    out = corrected_imu(message, (0.0, 0.0, bias_rad_s))
    covariance = np.array(message.angular_velocity_covariance, dtype=np.float64)
    if covariance[0] != -1.0:
        covariance[8] = max(covariance[8], 0.0) + bias_variance
    out.angular_velocity_covariance = covariance
    return out


def odometry_speed(message: Odometry) -> float:
    """Forward speed of an Odometry message (twist.linear.x), m/s."""
    return float(message.twist.twist.linear.x)


def beam_bearings(angle_min_rad: float, angle_increment_rad: float, beams: int) -> FloatArray:
    """Bearing of every beam of a scan, rad, float64 (as ScanSeries.angles_rad has them)."""
    return angle_min_rad + angle_increment_rad * np.arange(beams, dtype=np.float64)


def scan_arrays(message: LaserScan) -> tuple[np.ndarray, FloatArray, np.ndarray | None]:
    """Ranges (float32, m), beam bearings (float64, rad) and intensities (or None) of a scan.

    The bearings are computed exactly as ScanSeries.angles_rad does (angle_min plus
    increment times the beam index, in float64), so detections match an offline run.
    """
    ranges = np.asarray(message.ranges, dtype=np.float32)
    angles = beam_bearings(float(message.angle_min), float(message.angle_increment),
                           ranges.size)
    intensities = None
    if len(message.intensities) == ranges.size and ranges.size:
        intensities = np.asarray(message.intensities, dtype=np.float32)
    return ranges, angles, intensities


def points_message(header: Header, points_m: FloatArray) -> PoseArray:
    """Build a PoseArray of 2-D points (shape (k, 2), m) in the header's frame."""
    message = PoseArray(header=header)
    for x, y in np.asarray(points_m, dtype=np.float64).reshape(-1, 2).tolist():
        pose = Pose()
        pose.position.x = x
        pose.position.y = y
        message.poses.append(pose)
    return message


def points_of(message: PoseArray) -> FloatArray:
    """Get the (x, y) of every pose of a PoseArray, shape (k, 2), m."""
    return np.array([(p.position.x, p.position.y) for p in message.poses],
                    dtype=np.float64).reshape(-1, 2)


def yaw_quaternion(yaw_rad: float) -> Quaternion:
    """Quaternion of a rotation about z by yaw_rad."""
    x, y, z, w = quaternion_of_yaw(yaw_rad)
    return Quaternion(x=x, y=y, z=z, w=w)


def quaternion_yaw(q: Quaternion) -> float:
    """Yaw, rad, of a quaternion (the z rotation of its ZYX Euler angles)."""
    return yaw_of_quaternion(q.x, q.y, q.z, q.w)


def pose_and_covariance(message: PoseWithCovarianceStamped) -> tuple[FloatArray, FloatArray]:
    """(x m, y m, yaw rad) and its 3x3 covariance from a PoseWithCovarianceStamped."""
    pose = message.pose.pose
    values = (pose.position.x, pose.position.y, pose.orientation.x, pose.orientation.y,
              pose.orientation.z, pose.orientation.w)
    if not finite(*values) or not finite(*message.pose.covariance):
        raise ValueError('pose or covariance is not finite')
    full = np.asarray(message.pose.covariance, dtype=np.float64).reshape(6, 6)
    covariance = full[np.ix_(_POSE_INDEX, _POSE_INDEX)].copy()
    return (np.array([pose.position.x, pose.position.y, quaternion_yaw(pose.orientation)]),
            covariance)


class EstimateMessages:
    """Pose, odometry and bias messages of filter estimates, built once and refilled.

    Building rclpy messages field by field costs more than the filter step itself, so the
    three messages are created once and only their values change per estimate (publishing
    serializes them, so reuse is safe).
    """

    def __init__(self, map_frame: str, base_frame: str, speed_sigma_m_s: float,
                 gyro_sigma_rad_s: float):
        """Prepare the messages.

        Args:
            map_frame: frame of the pose (`map`).
            base_frame: child frame of the odometry and frame of the bias (`base_link`).
            speed_sigma_m_s: speed noise; its square is the twist's linear.x variance.
            gyro_sigma_rad_s: gyro noise; its square plus the bias variance is the twist's
                angular.z variance (the rate is corrected by the estimated bias).
        """
        self.pose = PoseWithCovarianceStamped(header=Header(frame_id=map_frame))
        self.odometry = Odometry(header=Header(frame_id=map_frame), child_frame_id=base_frame)
        self.bias = Vector3Stamped(header=Header(frame_id=base_frame))
        self._speed_variance = float(speed_sigma_m_s) ** 2
        self._gyro_variance = float(gyro_sigma_rad_s) ** 2
        self._pose_covariance = np.zeros((6, 6))
        self._twist_covariance = np.zeros(36)
        self._twist_covariance[0] = self._speed_variance

    @property
    def bias_frame(self) -> str:
        """Frame of the bias message (the IMU's)."""
        return self.bias.header.frame_id

    @bias_frame.setter
    def bias_frame(self, frame_id: str) -> None:
        self.bias.header.frame_id = frame_id

    def fill(self, estimate: Estimate, stamp_ns: int
             ) -> tuple[PoseWithCovarianceStamped, Odometry, Vector3Stamped]:
        """Write one estimate into the messages and return them.

        Args:
            estimate: the filter output.
            stamp_ns: stamp to give the messages (the input's own), ns since the epoch.

        Returns:
            PoseWithCovarianceStamped in the map frame, Odometry (pose with covariance; speed
            and bias-corrected yaw rate in the twist) and Vector3Stamped (z = bias, rad/s).
        """
        sec, nanosec = split_ns(stamp_ns)
        x, y, yaw, bias = (float(v) for v in estimate.state)
        self._pose_covariance[np.ix_(_POSE_INDEX, _POSE_INDEX)] = estimate.covariance[:3, :3]
        covariance = self._pose_covariance.ravel()
        self._twist_covariance[35] = self._gyro_variance + float(estimate.covariance[3, 3])
        _, _, qz, qw = quaternion_of_yaw(yaw)
        for target in (self.pose.pose, self.odometry.pose):
            position, orientation = target.pose.position, target.pose.orientation
            position.x, position.y = x, y
            orientation.z, orientation.w = qz, qw
            target.covariance = covariance
        twist = self.odometry.twist
        twist.twist.linear.x = float(estimate.speed_m_s)
        twist.twist.angular.z = float(estimate.yaw_rate_rad_s)
        twist.covariance = self._twist_covariance
        self.bias.vector.z = bias
        for message in (self.pose, self.odometry, self.bias):
            message.header.stamp.sec, message.header.stamp.nanosec = sec, nanosec
        return self.pose, self.odometry, self.bias


def bias_message(stamp: Time, frame_id: str, bias_rad_s: Sequence[float]) -> Vector3Stamped:
    """Vector3Stamped of a per-axis gyro bias, rad/s."""
    message = Vector3Stamped(header=Header(stamp=stamp, frame_id=frame_id))
    message.vector.x, message.vector.y, message.vector.z = (float(v) for v in bias_rad_s)
    return message
