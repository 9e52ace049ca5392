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

from collections.abc import Iterable
from typing import Any

import numpy as np
from numpy.typing import NDArray
from rosbags.typesys import get_typestore, Stores

from gyro_ekf import topics
from gyro_ekf.core.angles import quaternion_of_yaw, yaw_of_quaternion
from gyro_ekf.core.stamps import join_ns, split_ns
from gyro_ekf.core.types import FloatArray, LandmarkMap, ScanSeries
from gyro_ekf.topics import UNKNOWN_AXIS_VARIANCE

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

_NOT_GIVEN_3x3 = np.array([-1.0] + [0.0] * 8)
_NOT_GIVEN_6x6 = np.array([-1.0] + [0.0] * 35)
_ZERO_3x3 = np.zeros(9)
_ZERO_6x6 = np.zeros(36)
_EMPTY_F32 = np.zeros(0, dtype=np.float32)


def prepare_decoders(msgtypes: Iterable[str]) -> None:
    """Have rosbags build its (de)serialisers of msgtypes now rather than on first use.

    rosbags writes each message type's functions as Python source and imports them the
    first time a message of the type is decoded (some 5 ms a type): a one-time cost of the
    process, like an import. `gyro-ekf run` pays it with its imports, before its clock starts.
    """
    for msgtype in msgtypes:
        TYPESTORE.get_msgdef(msgtype)


def serialize(message: Any) -> bytes:
    """CDR bytes of a message of the Jazzy typestore."""
    return bytes(TYPESTORE.serialize_cdr(message, message.__msgtype__))


def deserialize(data: bytes | memoryview, msgtype: str) -> Any:
    """Decode CDR bytes into a message object."""
    return TYPESTORE.deserialize_cdr(data, msgtype)


def to_time(stamp_ns: int) -> Any:
    """builtin_interfaces/Time of integer nanoseconds since the epoch (>= 0)."""
    sec, nanosec = split_ns(stamp_ns)
    return Time(sec=sec, nanosec=nanosec)


def from_time(stamp: Any) -> int:
    """Integer nanoseconds of a builtin_interfaces/Time."""
    return join_ns(stamp.sec, stamp.nanosec)


def header(stamp_ns: int, frame_id: str) -> Any:
    """std_msgs/Header."""
    return Header(stamp=to_time(stamp_ns), frame_id=frame_id)


def yaw_quaternion(yaw_rad: float) -> Any:
    """Quaternion of a rotation about z by yaw_rad."""
    x, y, z, w = quaternion_of_yaw(yaw_rad)
    return Quaternion(x=x, y=y, z=z, w=w)


def quaternion_yaw(q: Any) -> float:
    """Yaw, rad, of a quaternion (the z rotation of its ZYX Euler angles)."""
    return yaw_of_quaternion(q.x, q.y, q.z, q.w)


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


def axes_known_rows(covariances: NDArray[np.float64]) -> NDArray[np.bool_]:
    """Which axes each Imu.angular_velocity_covariance marks as measured, shape (n, 3).

    An axis is marked not measured by UNKNOWN_AXIS_VARIANCE itself on its diagonal (what
    the bag writer writes), every axis by REP-145's -1 at element 0. Any other value, NaN,
    infinite or huge included, is a covariance, good or bad (core.validation ignores and
    counts a bad one at [8]): its axis counts as measured, so its values are checked.

    Args:
        covariances: row-major 3x3 covariances, shape (n, 9) or (9,).
    """
    rows = np.asarray(covariances, dtype=np.float64).reshape(-1, 9)
    known = rows[:, [0, 4, 8]] != UNKNOWN_AXIS_VARIANCE
    known[rows[:, 0] == -1.0] = False
    return known


def axes_known_of(covariance: NDArray[np.float64]) -> tuple[bool, bool, bool]:
    """Which axes an Imu.angular_velocity_covariance marks as measured (axes_known_rows)."""
    known = axes_known_rows(covariance)[0]
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


# Visual topics (TF, path, markers): what an estimates bag and the EKF node show in
# Foxglove or RViz. Types come from the Jazzy typestore: tf2_msgs does not install from PyPI.
TransformStamped = _T['geometry_msgs/msg/TransformStamped']
Transform = _T['geometry_msgs/msg/Transform']
TFMessage = _T['tf2_msgs/msg/TFMessage']
PoseStamped = _T['geometry_msgs/msg/PoseStamped']
Path = _T['nav_msgs/msg/Path']
Marker = _T['visualization_msgs/msg/Marker']
MarkerArray = _T['visualization_msgs/msg/MarkerArray']
ColorRGBA = _T['std_msgs/msg/ColorRGBA']
Duration = _T['builtin_interfaces/msg/Duration']
_CompressedImage = _T['sensor_msgs/msg/CompressedImage']
_MeshFile = _T['visualization_msgs/msg/MeshFile']
_EMPTY_U8 = np.zeros(0, dtype=np.uint8)

# visualization_msgs/Marker type and action constants.
MARKER_ARROW = 0
MARKER_CYLINDER = 3
MARKER_LINE_LIST = 5
MARKER_SPHERE_LIST = 7
MARKER_ADD = 0

ELLIPSE_SIGMAS = 2.0
"""The covariance ellipse of ekf/markers bounds +-2 sigma (about 86 % of a 2-D Gaussian)."""
ELLIPSE_THICKNESS_M = 0.01
LANDMARK_DIAMETER_M = 0.1
LANDMARK_HEIGHT_M = 1.0

COLOR_ESTIMATE = (0.1, 0.4, 1.0, 1.0)
COLOR_ELLIPSE = (0.1, 0.4, 1.0, 0.35)
COLOR_ASSOCIATED = (0.1, 0.8, 0.2, 1.0)
COLOR_REJECTED = (1.0, 0.2, 0.1, 1.0)
COLOR_LANDMARK = (1.0, 0.75, 0.0, 1.0)


def transform_stamped(stamp_ns: int, parent: str, child: str, x_m: float, y_m: float,
                      yaw_rad: float) -> Any:
    """geometry_msgs/TransformStamped of a planar pose: child's pose in parent."""
    return TransformStamped(
        header=header(stamp_ns, parent), child_frame_id=child,
        transform=Transform(translation=Vector3(x=float(x_m), y=float(y_m), z=0.0),
                            rotation=yaw_quaternion(float(yaw_rad))))


def tf_message(transforms: list[Any]) -> Any:
    """tf2_msgs/TFMessage holding the given TransformStamped (for /tf or /tf_static)."""
    return TFMessage(transforms=list(transforms))


def path_message(stamp_ns: int, stamps_ns: Any, poses: FloatArray, frame_id: str) -> Any:
    """nav_msgs/Path of planar poses (x m, y m, yaw rad per row) stamped stamps_ns."""
    return Path(header=header(stamp_ns, frame_id), poses=[
        PoseStamped(header=header(int(t), frame_id), pose=_pose(*row))
        for t, row in zip(stamps_ns, np.asarray(poses, dtype=np.float64).reshape(-1, 3))])


def _color(rgba: tuple[float, float, float, float]) -> Any:
    return ColorRGBA(r=rgba[0], g=rgba[1], b=rgba[2], a=rgba[3])


def marker(stamp_ns: int, frame_id: str, ns: str, marker_id: int, kind: int, *,
           pose: Any = None, scale: tuple[float, float, float] = (1.0, 1.0, 1.0),
           color: tuple[float, float, float, float] = COLOR_ESTIMATE,
           points: FloatArray | None = None) -> Any:
    """visualization_msgs/Marker (action ADD, no lifetime limit) with Jazzy's empty extras.

    Args:
        points: shape (k, 2) or (k, 3), m, for list and strip kinds (z = 0 when 2-D).
    """
    xyz = np.zeros((0, 3)) if points is None else np.asarray(points, dtype=np.float64)
    if xyz.shape[1] == 2:
        xyz = np.column_stack([xyz, np.zeros(len(xyz))])
    return Marker(
        header=header(stamp_ns, frame_id), ns=ns, id=int(marker_id), type=int(kind),
        action=MARKER_ADD, pose=_IDENTITY_POSE if pose is None else pose,
        scale=Vector3(x=float(scale[0]), y=float(scale[1]), z=float(scale[2])),
        color=_color(color), lifetime=Duration(sec=0, nanosec=0), frame_locked=False,
        points=[Point(x=x, y=y, z=z) for x, y, z in xyz.tolist()], colors=[],
        texture_resource='',
        texture=_CompressedImage(header=header(0, ''), format='', data=_EMPTY_U8),
        uv_coordinates=[], text='', mesh_resource='',
        mesh_file=_MeshFile(filename='', data=_EMPTY_U8), mesh_use_embedded_materials=False)


def covariance_ellipses(covariance_xy: FloatArray, sigmas: float = ELLIPSE_SIGMAS
                        ) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Axes of the sigmas-sigma ellipses of 2x2 covariances, shape (n, 2, 2).

    Returns:
        Per covariance, shape (n,) each: full length along the major axis m, along the
        minor axis m, direction of the major axis rad.
    """
    values, vectors = np.linalg.eigh(np.asarray(covariance_xy, dtype=np.float64))
    # A covariance that rounding made slightly indefinite draws flat, not NaN.
    lengths = 2.0 * sigmas * np.sqrt(np.clip(values, 0.0, None))
    return lengths[:, 1], lengths[:, 0], np.arctan2(vectors[:, 1, 1], vectors[:, 0, 1])


def covariance_ellipse(covariance_xy: FloatArray, sigmas: float = ELLIPSE_SIGMAS
                       ) -> tuple[float, float, float]:
    """covariance_ellipses of one 2x2 covariance, as floats."""
    major, minor, direction = covariance_ellipses(np.asarray(covariance_xy)[None], sigmas)
    return float(major[0]), float(minor[0]), float(direction[0])


def ekf_markers_message(stamp_ns: int, state: FloatArray, covariance: FloatArray,
                        associated_xy: FloatArray | None = None,
                        landmark_xy: FloatArray | None = None,
                        rejected_xy: FloatArray | None = None,
                        frame_id: str = topics.MAP_FRAME) -> Any:
    """visualization_msgs/MarkerArray of one estimate: ellipse, heading, last scan.

    Markers (namespace, id): ('ellipse', 0) the position's ELLIPSE_SIGMAS ellipse;
    drawn as a flat cylinder (a filled ellipse in any viewer, no outline points to send);
    ('heading', 0) an arrow along the yaw; ('associated', 0) the associated detections and
    ('association', 0) a line from each to its landmark; ('rejected', 0) the detections
    not associated. Every id is sent every time (empty lists included), so a viewer
    replaces the previous scan's markers.

    Args:
        state: shape (4,) or (3,): x m, y m, yaw rad[, bias].
        covariance: shape (>=2, >=2); only the x, y block is used.
        associated_xy, landmark_xy: shape (k, 2), m, row i detected and its landmark.
        rejected_xy: shape (r, 2), m.
    """
    x, y, yaw = (float(v) for v in np.asarray(state)[:3])
    major, minor, direction = covariance_ellipse(np.asarray(covariance)[:2, :2])
    none = np.zeros((0, 2))
    detected = none if associated_xy is None else np.asarray(associated_xy).reshape(-1, 2)
    landmark = none if landmark_xy is None else np.asarray(landmark_xy).reshape(-1, 2)
    lines = np.empty((2 * len(detected), 2))
    lines[0::2], lines[1::2] = detected, landmark
    rejected = none if rejected_xy is None else np.asarray(rejected_xy).reshape(-1, 2)
    return MarkerArray(markers=[
        marker(stamp_ns, frame_id, 'ellipse', 0, MARKER_CYLINDER,
               pose=_pose(x, y, direction), scale=(major, minor, ELLIPSE_THICKNESS_M),
               color=COLOR_ELLIPSE),
        marker(stamp_ns, frame_id, 'heading', 0, MARKER_ARROW, pose=_pose(x, y, yaw),
               scale=(0.6, 0.08, 0.08), color=COLOR_ESTIMATE),
        marker(stamp_ns, frame_id, 'associated', 0, MARKER_SPHERE_LIST,
               scale=(0.12, 0.12, 0.12), color=COLOR_ASSOCIATED, points=detected),
        marker(stamp_ns, frame_id, 'association', 0, MARKER_LINE_LIST,
               scale=(0.02, 0.0, 0.0), color=COLOR_ASSOCIATED, points=lines),
        marker(stamp_ns, frame_id, 'rejected', 0, MARKER_SPHERE_LIST,
               scale=(0.12, 0.12, 0.12), color=COLOR_REJECTED, points=rejected)])


def landmark_markers_message(stamp_ns: int, landmarks: LandmarkMap,
                             frame_id: str = topics.MAP_FRAME) -> Any:
    """visualization_msgs/MarkerArray: one cylinder per landmark, standing on z = 0.

    Namespace 'landmarks', id = the landmark's index in the map.
    """
    return MarkerArray(markers=[
        marker(stamp_ns, frame_id, 'landmarks', i, MARKER_CYLINDER,
               pose=Pose(position=Point(x=x, y=y, z=LANDMARK_HEIGHT_M / 2.0),
                         orientation=Quaternion(x=0.0, y=0.0, z=0.0, w=1.0)),
               scale=(LANDMARK_DIAMETER_M, LANDMARK_DIAMETER_M, LANDMARK_HEIGHT_M),
               color=COLOR_LANDMARK)
        for i, (x, y) in enumerate(np.asarray(landmarks.xy_m, dtype=np.float64).tolist())])
