"""Serialized input and output of the nodes: the few fields a callback needs, straight from CDR.

An rclpy subscription turns every message into Python objects (a numpy array per covariance,
an object per vector) and a publication turns them back, which costs more CPU than the
filter step. With ``raw=True`` a callback gets the CDR bytes instead; the functions here read
the fields a node uses with ``struct`` at offsets fixed by the length of the header's
frame_id, and the outputs are CDR templates (serialized once by rclpy) whose numbers are
overwritten per message. The values are the same doubles the rclpy messages would hold.

CDR as rmw_fastrtps sends it (XCDR1): a 4-byte encapsulation header (``00 01`` = little
endian), then the body; each primitive is aligned to its size counted from the body's start;
a string is a uint32 length (including its NUL) and its bytes; a sequence is a uint32 count
and its elements. A message that is not little endian or whose lengths do not add up is
deserialized by rclpy and serialized again (canonical bytes); one rclpy cannot deserialize
raises WireError, which the nodes count as ``malformed``.

`serialized_io()` is the switch: the nodes use this module and rclpy's EventsExecutor unless
the environment variable GYRO_EKF_NODE_IO is ``rclpy`` (rclpy messages and the
SingleThreadedExecutor, as before; `make bench` measures both).
"""

from __future__ import annotations

import os
import struct
from collections.abc import Sequence
from typing import Any, NamedTuple

import numpy as np
from geometry_msgs.msg import PoseArray, Vector3Stamped
from nav_msgs.msg import Odometry
from rclpy.serialization import deserialize_message, serialize_message
from sensor_msgs.msg import Imu, LaserScan

from gyro_ekf.core.angles import quaternion_of_yaw
from gyro_ekf.core.event_records import Estimate
from gyro_ekf.errors import GyroEkfError

NODE_IO_VARIABLE = 'GYRO_EKF_NODE_IO'
NODE_IO_CHOICES = ('serialized', 'rclpy')

_LITTLE_ENDIAN = b'\x00\x01'
_ENCAPSULATION = b'\x00\x01\x00\x00'
_HEADER = struct.Struct('<iII')  # stamp.sec, stamp.nanosec, frame_id length
_U32 = struct.Struct('<I')
_D = struct.Struct('<d')
_2D = struct.Struct('<2d')
_3D = struct.Struct('<3d')
_STAMP = struct.Struct('<iI')
_IMU_RATES = struct.Struct('<12d')  # angular_velocity, angular_velocity_covariance
_SCAN_FIELDS = struct.Struct('<7fI')  # angle_min .. range_max, ranges count
_ODOM_POSE = struct.Struct('<7d')  # position, orientation
_POSE_BYTES = 8 * 43
# Flat indices of x, y, yaw rows and columns in a ROS 6x6 pose covariance.
_POSE_COVARIANCE_INDEX = (0, 1, 5, 6, 7, 11, 30, 31, 35)


def _sparse(count: int, written: tuple[int, ...]) -> struct.Struct:
    """Struct of `count` doubles that writes those at `written` and zero bytes elsewhere.

    The outputs' other covariance entries are always zero, so writing zeros over them
    packs one message with one call instead of building a list of every entry.
    """
    return struct.Struct('<' + ''.join('d' if i in written else '8x' for i in range(count)))


# position, orientation and the x, y, yaw block of the 6x6 pose covariance
_POSE_SPARSE = _sparse(43, tuple(range(7)) + tuple(7 + i for i in _POSE_COVARIANCE_INDEX))
# twist linear.x, angular.z and the covariance's linear.x and angular.z variances
_TWIST_SPARSE = _sparse(42, (0, 5, 6, 41))
_IMU_AV = 8 * 13  # angular_velocity after orientation (4) and its covariance (9)
_IMU_COVARIANCE8 = 8 * 3 + 8 * 8  # angular_velocity_covariance[8] after angular_velocity


def _ends_at(data: bytes, end: int) -> None:
    """Raise _Slow unless the message ends at `end` (up to 3 bytes of padding after it)."""
    if not 0 <= len(data) - end <= 3:
        raise _Slow


class WireError(ValueError):
    """Bytes that are not a message of the expected type (rclpy cannot deserialize them)."""


def node_io() -> str:
    """Return the nodes' message path: 'serialized' (default) or 'rclpy' (GYRO_EKF_NODE_IO).

    Raises:
        GyroEkfError: the variable holds anything else.
    """
    value = os.environ.get(NODE_IO_VARIABLE, '').strip() or 'serialized'
    if value not in NODE_IO_CHOICES:
        raise GyroEkfError(f'environment variable {NODE_IO_VARIABLE}={value!r}: expected one '
                           f'of {", ".join(NODE_IO_CHOICES)}')
    return value


def serialized_io() -> bool:
    """Tell whether the nodes take and give CDR bytes (see the module docstring)."""
    return node_io() == 'serialized'


def executor(context: Any = None) -> Any:
    """Executor of a node process: rclpy's EventsExecutor on the serialized path, else None.

    None lets rclpy.spin use its global SingleThreadedExecutor (the plain path).
    """
    if not serialized_io():
        return None
    from rclpy.experimental import EventsExecutor
    return EventsExecutor(context=context)


def raw_publisher(publisher: Any) -> tuple[Any, Any]:
    """(publish, subscription_count) of an rclpy Publisher, without its Python wrapper.

    Publisher.publish and get_subscription_count enter the handle's context and check the
    type on every call (about a microsecond); these are its C++ methods themselves. publish
    takes bytes or a bytearray of CDR. For a publisher that lives as long as the node (the
    executor is single-threaded, so nothing destroys it during a call).
    """
    handle = publisher.handle
    return handle.publish_raw, handle.get_subscription_count


class Stamp(NamedTuple):
    """A header stamp (builtin_interfaces/Time's two fields, without building one)."""

    sec: int
    nanosec: int


def _align8(at: int) -> int:
    """Absolute offset of the next 8-aligned body position at or after `at`."""
    return 4 + ((at - 4 + 7) & ~7)


def _align4(at: int) -> int:
    return 4 + ((at - 4 + 3) & ~3)


def _header(data: bytes) -> tuple[int, int, int]:
    """Stamp and the offset after the header's frame_id, or raise _Slow."""
    if data[:2] != _LITTLE_ENDIAN or len(data) < 17:
        raise _Slow
    sec, nanosec, length = _HEADER.unpack_from(data, 4)
    end = 16 + length
    if length < 1 or end > len(data) or data[end - 1] != 0:
        raise _Slow
    return sec, nanosec, end


class _Slow(Exception):
    """The bytes are not on the fast path (big endian, or lengths that do not add up)."""


def canonical(data: bytes, msg_type: Any) -> bytes:
    """Deserialize with rclpy and serialize again (little endian, the lengths it wrote).

    Raises:
        WireError: rclpy cannot deserialize the bytes as msg_type.
    """
    try:
        message = deserialize_message(data, msg_type)
    except Exception as err:  # noqa: BLE001 - rclpy raises several kinds on bad bytes
        raise WireError(f'{len(data)} bytes are not a {msg_type.__name__} message: '
                        f'{type(err).__name__}: {err}') from None
    return serialize_message(message)


def _decoded(decode, data: bytes, msg_type: Any):
    try:
        return decode(data)
    except (_Slow, struct.error, UnicodeDecodeError):
        pass
    data = canonical(data, msg_type)
    try:
        return decode(data)
    except (_Slow, struct.error, UnicodeDecodeError):
        raise WireError(f'{msg_type.__name__}: rclpy serialized bytes this module cannot '
                        'read') from None


def _frame(data: bytes, end: int) -> str:
    return data[16:end - 1].decode('utf-8')


class ImuSample(NamedTuple):
    """The Imu fields the nodes use.

    Attributes:
        stamp: header stamp.
        frame_id: header frame.
        rates: angular_velocity x, y, z, rad/s.
        covariance: angular_velocity_covariance[0], [4], [8].
        data: the message's (little-endian) CDR bytes.
        rates_at: byte offset of angular_velocity in data.
    """

    stamp: Stamp
    frame_id: str
    rates: tuple[float, float, float]
    covariance: tuple[float, float, float]
    data: bytes
    rates_at: int


def _imu(data: bytes) -> ImuSample:
    sec, nanosec, end = _header(data)
    at = _align8(end) + _IMU_AV
    _ends_at(data, at + 8 * 24)
    values = _IMU_RATES.unpack_from(data, at)
    return ImuSample(Stamp(sec, nanosec), _frame(data, end), values[:3],
                     (values[3], values[7], values[11]), data, at)


def decode_imu(data: bytes) -> ImuSample:
    """Read a sensor_msgs/Imu (see ImuSample); WireError if the bytes are not one."""
    return _decoded(_imu, data, Imu)


def _imu_rates(data: bytes) -> tuple:
    sec, nanosec, end = _header(data)
    at = _align8(end) + _IMU_AV
    _ends_at(data, at + 8 * 24)
    return (data, sec, nanosec, at, *_3D.unpack_from(data, at))


def imu_rates(data: bytes) -> tuple[bytes, int, int, int, float, float, float]:
    """Read a sensor_msgs/Imu's stamp and angular_velocity, without building objects.

    Returns:
        (data, sec, nanosec, at, x, y, z): data is the bytes read (the canonical copy when
        the given ones are not little endian or not as rclpy lays them out), at the byte
        offset of angular_velocity in them, x, y, z its values (rad/s).

    Raises:
        WireError: the bytes are not an Imu message.
    """
    return _decoded(_imu_rates, data, Imu)


def _imu_yaw(data: bytes) -> tuple:
    sec, nanosec, end = _header(data)
    at = _align8(end) + _IMU_AV
    _ends_at(data, at + 8 * 24)
    values = _IMU_RATES.unpack_from(data, at)
    return (data, sec, nanosec, data[16:end - 1].decode('utf-8'), at, values[2], values[3],
            values[11])


def imu_yaw(data: bytes) -> tuple[bytes, int, int, str, int, float, float, float]:
    """Read what ekf_node uses of a sensor_msgs/Imu, without building objects.

    Returns:
        (data, sec, nanosec, frame_id, at, z, covariance0, covariance8): data and at as
        imu_rates returns them; z = angular_velocity.z, covariance0 and covariance8 =
        angular_velocity_covariance[0] and [8].

    Raises:
        WireError: the bytes are not an Imu message.
    """
    return _decoded(_imu_yaw, data, Imu)


def patched_imu(data: bytes, at: int, x: float, y: float, z: float,
                variance: float | None = None) -> bytearray:
    """Copy of Imu bytes with angular_velocity (x, y, z) and, unless None, covariance[8].

    data and at as imu_rates returns them; the rest of the message is the input's, byte for
    byte (what rclpy would serialize from the deserialized message with those fields set).
    """
    out = bytearray(data)
    _3D.pack_into(out, at, x, y, z)
    if variance is not None:
        _D.pack_into(out, at + _IMU_COVARIANCE8, variance)
    return out


def patched_yaw_rate(data: bytes, at: int, z: float, variance: float | None = None
                     ) -> bytearray:
    """patched_imu that keeps angular_velocity x and y (ekf/imu corrects only z)."""
    out = bytearray(data)
    _D.pack_into(out, at + 16, z)
    if variance is not None:
        _D.pack_into(out, at + _IMU_COVARIANCE8, variance)
    return out


def online_variance(covariance0: float, covariance8: float, added_variance: float
                    ) -> float | None:
    """angular_velocity_covariance[8] of ekf/imu (conversions.online_corrected_imu's rule).

    None: the covariance is marked unknown (covariance[0] == -1) and stays as it is.
    """
    if covariance0 == -1.0:
        return None
    return max(covariance8, 0.0) + added_variance


def corrected_imu(sample: ImuSample, bias_rad_s: Sequence[float],
                  added_variance: float | None = None) -> bytes:
    """Copy an Imu message with the bias removed from its rates, as CDR bytes.

    The same values as conversions.corrected_imu (added_variance None) or
    conversions.online_corrected_imu (added_variance = the bias variance, onto
    angular_velocity_covariance[8] unless the covariance is marked unknown).
    """
    out = bytearray(sample.data)
    at = sample.rates_at
    (x, y, z), (bx, by, bz) = sample.rates, bias_rad_s
    _3D.pack_into(out, at, x - float(bx), y - float(by), z - float(bz))
    if added_variance is not None and sample.covariance[0] != -1.0:
        _D.pack_into(out, at + _IMU_COVARIANCE8,
                     max(sample.covariance[2], 0.0) + added_variance)
    return bytes(out)


class OdometrySample(NamedTuple):
    """The Odometry fields the nodes use.

    Attributes:
        stamp: header stamp.
        speed_m_s: twist.twist.linear.x.
        speed_variance: twist.covariance[0].
        pose: pose.pose position x, y, z and orientation x, y, z, w.
    """

    stamp: Stamp
    speed_m_s: float
    speed_variance: float
    pose: tuple[float, ...]


def _odometry(data: bytes) -> OdometrySample:
    sec, nanosec, end = _header(data)
    child = _align4(end)
    if child + 5 > len(data):
        raise _Slow
    length = _U32.unpack_from(data, child)[0]
    end = child + 4 + length
    if length < 1 or end > len(data) or data[end - 1] != 0:
        raise _Slow
    at = _align8(end)
    _ends_at(data, at + 8 * 85)
    pose = _ODOM_POSE.unpack_from(data, at)
    twist = at + _POSE_BYTES
    speed = _D.unpack_from(data, twist)[0]
    variance = _D.unpack_from(data, twist + 48)[0]
    return OdometrySample(Stamp(sec, nanosec), speed, variance, pose)


def decode_odometry(data: bytes) -> OdometrySample:
    """Read a nav_msgs/Odometry (see OdometrySample); WireError if the bytes are not one."""
    return _decoded(_odometry, data, Odometry)


class ScanSample(NamedTuple):
    """The LaserScan fields the detector uses.

    Attributes:
        stamp: header stamp.
        header: the header's CDR bytes (stamp and frame_id, without the encapsulation).
        angle_min, angle_max, angle_increment, range_min, range_max: as float32 values.
        ranges: float32, read-only view of the bytes.
        intensities: float32, read-only view of the bytes (may be empty).
    """

    stamp: Stamp
    header: bytes
    angle_min: float
    angle_max: float
    angle_increment: float
    range_min: float
    range_max: float
    ranges: np.ndarray
    intensities: np.ndarray


def _scan(data: bytes) -> ScanSample:
    sec, nanosec, end = _header(data)
    at = _align4(end)
    if at + _SCAN_FIELDS.size > len(data):
        raise _Slow
    a_min, a_max, a_inc, _, _, r_min, r_max, n = _SCAN_FIELDS.unpack_from(data, at)
    at += _SCAN_FIELDS.size
    if at + 4 * n + 4 > len(data):
        raise _Slow
    ranges = np.frombuffer(data, dtype='<f4', count=n, offset=at)
    at += 4 * n
    m = _U32.unpack_from(data, at)[0]
    at += 4
    _ends_at(data, at + 4 * m)
    intensities = np.frombuffer(data, dtype='<f4', count=m, offset=at)
    return ScanSample(Stamp(sec, nanosec), data[4:end], a_min, a_max, a_inc, r_min, r_max,
                      ranges, intensities)


def decode_scan(data: bytes) -> ScanSample:
    """Read a sensor_msgs/LaserScan (see ScanSample); WireError if the bytes are not one."""
    return _decoded(_scan, data, LaserScan)


def points_bytes(header: bytes, points_m: np.ndarray) -> bytes:
    """geometry_msgs/PoseArray of 2-D points as CDR: one pose (x, y, 0) per row, w = 1.

    Args:
        header: CDR bytes of a header (ScanSample.header: stamp and frame_id).
        points_m: shape (k, 2), m.
    """
    points = np.asarray(points_m, dtype=np.float64).reshape(-1, 2)
    end = 4 + len(header)
    count = _align4(end)
    parts = [_ENCAPSULATION, header, b'\x00' * (count - end), _U32.pack(len(points))]
    if len(points):
        poses = np.zeros((len(points), 7), dtype='<f8')
        poses[:, :2] = points
        poses[:, 6] = 1.0
        parts += [b'\x00' * (_align8(count + 4) - count - 4), poses.tobytes()]
    return b''.join(parts)


class EstimateWire:
    """ekf_node's pose, odometry and bias outputs as CDR bytes (conversions.EstimateMessages).

    Templates are serialized by rclpy from the messages EstimateMessages builds; fill()
    writes the values EstimateMessages.fill would write.
    """

    def __init__(self, map_frame: str, base_frame: str, speed_sigma_m_s: float,
                 gyro_sigma_rad_s: float):
        """Serialize the templates (arguments as for EstimateMessages)."""
        from gyro_ekf.nodes.conversions import EstimateMessages

        messages = EstimateMessages(map_frame, base_frame, speed_sigma_m_s, gyro_sigma_rad_s)
        self._speed_variance = float(speed_sigma_m_s) ** 2
        self._gyro_variance = float(gyro_sigma_rad_s) ** 2
        self._pose = bytearray(serialize_message(messages.pose))
        self._pose_at = _align8(_header(bytes(self._pose))[2])
        self._odometry = bytearray(serialize_message(messages.odometry))
        self._odometry_at = _align8(_align4(_header(bytes(self._odometry))[2]) + 4
                                    + len(base_frame.encode()) + 1)
        self._bias_frame = ''
        self._bias = bytearray()
        self._bias_at = 0
        self.bias_frame = base_frame

    @property
    def bias_frame(self) -> str:
        """Frame of ekf/bias (the IMU's)."""
        return self._bias_frame

    @bias_frame.setter
    def bias_frame(self, frame_id: str) -> None:
        from std_msgs.msg import Header

        self._bias_frame = frame_id
        self._bias = bytearray(serialize_message(Vector3Stamped(
            header=Header(frame_id=frame_id))))
        self._bias_at = _align8(_header(bytes(self._bias))[2])

    def fill(self, estimate: Estimate, stamp_ns: int) -> tuple[bytes, bytes, bytes]:
        """CDR of PoseWithCovarianceStamped, Odometry and Vector3Stamped of one estimate."""
        return tuple(bytes(data) for data in self.write(estimate, stamp_ns))

    def write(self, estimate: Estimate, stamp_ns: int
              ) -> tuple[bytearray, bytearray, bytearray]:
        """Write one estimate into the templates and return them (as fill, without copies).

        The returned buffers are overwritten by the next call: publish them before.
        """
        sec, nanosec = divmod(stamp_ns, 1_000_000_000)  # core.stamps.split_ns
        x, y, yaw, bias = estimate.state.tolist()
        _, _, qz, qw = quaternion_of_yaw(yaw)
        (pxx, pxy, pxt, _), (pyx, pyy, pyt, _), (ptx, pty, ptt, _), (_, _, _, pbb) = \
            estimate.covariance.tolist()
        pose, odometry, bias_bytes = self._pose, self._odometry, self._bias
        _STAMP.pack_into(pose, 4, sec, nanosec)
        _POSE_SPARSE.pack_into(pose, self._pose_at, x, y, 0.0, 0.0, 0.0, qz, qw,
                               pxx, pxy, pxt, pyx, pyy, pyt, ptx, pty, ptt)
        _STAMP.pack_into(odometry, 4, sec, nanosec)
        at = self._odometry_at
        _POSE_SPARSE.pack_into(odometry, at, x, y, 0.0, 0.0, 0.0, qz, qw,
                               pxx, pxy, pxt, pyx, pyy, pyt, ptx, pty, ptt)
        _TWIST_SPARSE.pack_into(odometry, at + _POSE_BYTES, float(estimate.speed_m_s),
                                float(estimate.yaw_rate_rad_s), self._speed_variance,
                                self._gyro_variance + pbb)
        _STAMP.pack_into(bias_bytes, 4, sec, nanosec)
        _D.pack_into(bias_bytes, self._bias_at + 16, bias)
        return pose, odometry, bias_bytes


def pose_array_points(data: bytes) -> tuple[Stamp, str, np.ndarray]:
    """Stamp, frame and (x, y) of every pose of a geometry_msgs/PoseArray, shape (k, 2)."""
    def read(data: bytes) -> tuple[Stamp, str, np.ndarray]:
        sec, nanosec, end = _header(data)
        at = _align4(end)
        if at + 4 > len(data):
            raise _Slow
        n = _U32.unpack_from(data, at)[0]
        at = _align8(at + 4) if n else at + 4
        _ends_at(data, at + 56 * n)
        poses = np.frombuffer(data, dtype='<f8', count=7 * n, offset=at).reshape(n, 7)
        return Stamp(sec, nanosec), _frame(data, end), poses[:, :2].astype(np.float64)
    return _decoded(read, data, PoseArray)


__all__ = ['EstimateWire', 'ImuSample', 'NODE_IO_CHOICES', 'NODE_IO_VARIABLE',
           'OdometrySample', 'ScanSample', 'Stamp', 'WireError', 'canonical',
           'corrected_imu', 'decode_imu', 'decode_odometry', 'decode_scan', 'executor',
           'imu_rates', 'imu_yaw', 'node_io', 'online_variance', 'patched_imu', 'patched_yaw_rate',
           'points_bytes', 'pose_array_points', 'raw_publisher', 'serialized_io']
