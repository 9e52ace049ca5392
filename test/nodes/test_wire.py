"""The nodes' serialized I/O (nodes/wire.py) against rclpy's own (de)serialization.

rclpy.serialization is the oracle: every fast read must give the fields rclpy's message
holds, and every byte string written must deserialize to the message the rclpy path would
publish, bit for bit (NaN and signed zeros included).
"""

from __future__ import annotations

import math
import struct

import numpy as np
import pytest

pytest.importorskip('rclpy')

from geometry_msgs.msg import PoseArray  # noqa: E402
from nav_msgs.msg import Odometry  # noqa: E402
from rclpy.serialization import deserialize_message, serialize_message  # noqa: E402
from sensor_msgs.msg import Imu, LaserScan  # noqa: E402
from std_msgs.msg import Header  # noqa: E402

from gyro_ekf.core.event_records import Estimate  # noqa: E402
from gyro_ekf.errors import GyroEkfError  # noqa: E402
from gyro_ekf.nodes import conversions, wire  # noqa: E402

FRAMES = ('', 'a', 'imu', 'base', 'laser', 'imu_link', 'frame_ab', 'ünïcode_frame')


def _bits(value):
    """Comparable form of a message: floats by their bits, so NaN and -0.0 count."""
    if hasattr(value, 'get_fields_and_field_types'):
        return {name: _bits(getattr(value, name))
                for name in value.get_fields_and_field_types()}
    if isinstance(value, float):
        return struct.pack('<d', value)
    if isinstance(value, (list, tuple, np.ndarray)) or type(value).__name__ == 'array':
        return [_bits(float(v) if isinstance(v, (float, np.floating)) else v) for v in value]
    return value


def _same(a, b) -> bool:
    return _bits(a) == _bits(b)


def _imu(rng, frame: str) -> Imu:
    message = Imu(header=Header(frame_id=frame))
    message.header.stamp.sec = int(rng.integers(0, 2**31 - 1))
    message.header.stamp.nanosec = int(rng.integers(0, 10**9))
    message.orientation.x, message.orientation.w = rng.standard_normal(2).tolist()
    v = rng.standard_normal(3).tolist()
    message.angular_velocity.x, message.angular_velocity.y, message.angular_velocity.z = v
    message.angular_velocity_covariance = rng.standard_normal(9)
    message.linear_acceleration.y = float(rng.standard_normal())
    message.linear_acceleration_covariance = rng.standard_normal(9)
    return message


@pytest.mark.parametrize('frame', FRAMES)
def test_imu_fields_are_rclpys(frame):
    rng = np.random.default_rng(len(frame))
    for _ in range(20):
        message = _imu(rng, frame)
        sample = wire.decode_imu(serialize_message(message))
        assert sample.stamp == (message.header.stamp.sec, message.header.stamp.nanosec)
        assert sample.frame_id == frame
        assert sample.rates == conversions.imu_rates(message)
        covariance = message.angular_velocity_covariance
        assert sample.covariance == (covariance[0], covariance[4], covariance[8])


def _imu_to_correct(rng, frame, unknown):
    """An IMU message whose covariance is unknown (-1) or has an odd yaw entry, x = -0.0."""
    message = _imu(rng, frame)
    if unknown:
        message.angular_velocity_covariance[0] = -1.0
    message.angular_velocity_covariance[8] = float(rng.choice([-2.0, 0.0, 3e-5]))
    message.angular_velocity.x = -0.0
    return message


@pytest.mark.parametrize('frame', FRAMES)
@pytest.mark.parametrize('unknown', [False, True])
def test_corrected_imu_bytes_are_the_rclpy_paths_message(frame, unknown):
    rng = np.random.default_rng(7)
    for _ in range(10):
        message = _imu_to_correct(rng, frame, unknown)
        sample = wire.decode_imu(serialize_message(message))
        bias = rng.standard_normal(3).tolist()
        got = deserialize_message(wire.corrected_imu(sample, bias), Imu)
        assert _same(got, conversions.corrected_imu(message, bias))
        variance = float(rng.random()) * 1e-6
        got = deserialize_message(wire.corrected_imu(sample, (0.0, 0.0, bias[2]), variance),
                                  Imu)
        assert _same(got, conversions.online_corrected_imu(message, bias[2], variance))


@pytest.mark.parametrize('frame', FRAMES)
def test_imu_rates_and_yaw_are_rclpys(frame):
    rng = np.random.default_rng(len(frame) + 100)
    for _ in range(20):
        message = _imu(rng, frame)
        data = serialize_message(message)
        read, sec, nanosec, at, x, y, z = wire.imu_rates(data)
        stamp = message.header.stamp
        assert read is data and (sec, nanosec) == (stamp.sec, stamp.nanosec)
        assert (x, y, z) == conversions.imu_rates(message) == wire.decode_imu(data).rates
        assert at == wire.decode_imu(data).rates_at
        read, sec, nanosec, frame_id, at_yaw, z, cov0, cov8 = wire.imu_yaw(data)
        covariance = message.angular_velocity_covariance
        assert (read, frame_id, at_yaw) == (data, frame, at)
        assert (sec, nanosec) == (message.header.stamp.sec, message.header.stamp.nanosec)
        assert (z, cov0, cov8) == (message.angular_velocity.z, covariance[0], covariance[8])


@pytest.mark.parametrize('frame', FRAMES)
@pytest.mark.parametrize('unknown', [False, True])
def test_patched_imu_bytes_are_the_rclpy_paths_message(frame, unknown):
    """The nodes' corrected IMU copies (rates patched in the input's bytes) are rclpy's."""
    rng = np.random.default_rng(8)
    for _ in range(10):
        message = _imu_to_correct(rng, frame, unknown)
        data = serialize_message(message)
        bias = rng.standard_normal(3).tolist()
        # calibration_node: imu/corrected
        data, _, _, at, x, y, z = wire.imu_rates(data)
        patched = wire.patched_imu(data, at, x - bias[0], y - bias[1], z - bias[2])
        assert len(patched) == len(data)
        got = deserialize_message(bytes(patched), Imu)
        assert _same(got, conversions.corrected_imu(message, bias))
        # ekf_node: ekf/imu, the yaw rate corrected and the bias variance added
        variance = float(rng.random()) * 1e-6
        _, _, _, _, at, z, cov0, cov8 = wire.imu_yaw(data)
        patched = wire.patched_yaw_rate(data, at, z - bias[2],
                                        wire.online_variance(cov0, cov8, variance))
        got = deserialize_message(bytes(patched), Imu)
        assert _same(got, conversions.online_corrected_imu(message, bias[2], variance))
        assert (wire.online_variance(cov0, cov8, variance) is None) == unknown


@pytest.mark.parametrize('frame', FRAMES)
@pytest.mark.parametrize('child', ['', 'base_link', 'b'])
def test_odometry_fields_are_rclpys(frame, child):
    rng = np.random.default_rng(3)
    message = Odometry(header=Header(frame_id=frame), child_frame_id=child)
    message.header.stamp.sec, message.header.stamp.nanosec = 1_700_000_000, 123_456_789
    pose = message.pose.pose
    pose.position.x, pose.position.y, pose.position.z = rng.standard_normal(3).tolist()
    o = rng.standard_normal(4).tolist()
    pose.orientation.x, pose.orientation.y, pose.orientation.z, pose.orientation.w = o
    message.pose.covariance = rng.standard_normal(36)
    message.twist.twist.linear.x = float(rng.standard_normal())
    message.twist.twist.angular.z = float(rng.standard_normal())
    message.twist.covariance = rng.standard_normal(36)
    sample = wire.decode_odometry(serialize_message(message))
    assert sample.stamp == (1_700_000_000, 123_456_789)
    assert sample.speed_m_s == conversions.odometry_speed(message)
    assert sample.speed_variance == message.twist.covariance[0]
    assert sample.pose == (pose.position.x, pose.position.y, pose.position.z, *o)


def _scan(rng, frame: str, n: int, intensities: bool) -> LaserScan:
    message = LaserScan(header=Header(frame_id=frame))
    message.header.stamp.sec, message.header.stamp.nanosec = 42, 7
    message.angle_min, message.angle_max = -math.pi / 2, math.pi / 2
    message.angle_increment = math.pi / max(n - 1, 1)
    message.range_min, message.range_max = 0.1, 80.0
    ranges = rng.uniform(0.0, 90.0, n).astype(np.float32)
    ranges[::17] = np.inf
    ranges[5::23] = np.nan
    message.ranges = ranges.tolist()
    if intensities:
        message.intensities = rng.uniform(0, 255, n).astype(np.float32).tolist()
    return message


@pytest.mark.parametrize('frame', FRAMES)
@pytest.mark.parametrize('n, intensities', [(361, True), (361, False), (0, False), (7, True)])
def test_scan_fields_are_rclpys(frame, n, intensities):
    data = serialize_message(_scan(np.random.default_rng(n), frame, n, intensities))
    message = deserialize_message(data, LaserScan)  # as a subscriber gets it: float32 angles
    sample = wire.decode_scan(data)
    assert sample.stamp == (42, 7)
    for name in ('angle_min', 'angle_max', 'angle_increment', 'range_min', 'range_max'):
        assert getattr(sample, name) == getattr(message, name), name
    ranges, _, expected_intensities = conversions.scan_arrays(message)
    assert sample.ranges.dtype == np.float32
    np.testing.assert_array_equal(sample.ranges, ranges)
    if expected_intensities is None:
        assert len(sample.intensities) in (0, len(message.intensities))
    else:
        np.testing.assert_array_equal(sample.intensities, expected_intensities)


@pytest.mark.parametrize('frame', FRAMES)
@pytest.mark.parametrize('k', [0, 1, 4])
def test_points_bytes_are_the_rclpy_paths_pose_array(frame, k):
    message = _scan(np.random.default_rng(1), frame, 5, False)
    sample = wire.decode_scan(serialize_message(message))
    points = np.random.default_rng(k).standard_normal((k, 2))
    data = wire.points_bytes(sample.header, points)
    expected = conversions.points_message(message.header, points)
    assert _same(deserialize_message(data, PoseArray), expected)
    assert len(data) == len(serialize_message(expected))
    stamp, got_frame, got = wire.pose_array_points(data)
    assert (stamp, got_frame) == ((42, 7), frame)
    np.testing.assert_array_equal(got, conversions.points_of(expected))


@pytest.mark.parametrize('map_frame, base_frame', [('map', 'base_link'), ('', 'b'),
                                                   ('world_frame', '')])
def test_estimate_bytes_are_the_rclpy_paths_messages(map_frame, base_frame):
    rng = np.random.default_rng(5)
    plain = conversions.EstimateMessages(map_frame, base_frame, 0.05, 0.002)
    fast = wire.EstimateWire(map_frame, base_frame, 0.05, 0.002)
    for step in range(20):
        if step == 10:  # the IMU's frame becomes the bias frame
            plain.bias_frame = fast.bias_frame = 'imu_link'
        a = rng.standard_normal((4, 4))
        estimate = Estimate(stamp_s=0.0, state=rng.standard_normal(4), covariance=a @ a.T,
                            speed_m_s=float(rng.standard_normal()),
                            yaw_rate_rad_s=float(rng.standard_normal()),
                            gyro_error_rad_s=0.0, gyro_error_variance=0.0)
        ns = int(rng.integers(1, 2**31 * 10**9))
        filled = fast.fill(estimate, ns)
        for data, message in zip(filled, plain.fill(estimate, ns)):
            assert len(data) == len(serialize_message(message))
            assert _same(deserialize_message(data, type(message)), message)
        # write() gives the same bytes, in the reused buffers
        assert [bytes(data) for data in fast.write(estimate, ns)] == list(filled)
    assert fast.bias_frame == plain.bias_frame == 'imu_link'


def test_big_endian_and_padded_bytes_take_the_rclpy_path():
    from rosbags.typesys import get_typestore, Stores

    store = get_typestore(Stores.ROS2_JAZZY)
    message = _imu(np.random.default_rng(2), 'imu')
    little = serialize_message(message)
    imu_type = store.types['sensor_msgs/msg/Imu']
    decoded = store.deserialize_cdr(little, 'sensor_msgs/msg/Imu')
    assert isinstance(decoded, imu_type)
    big = bytes(store.serialize_cdr(decoded, 'sensor_msgs/msg/Imu', little_endian=False))
    assert big[:2] == b'\x00\x00'
    for data in (big, little + b'\x00' * 3):
        sample = wire.decode_imu(data)
        assert sample.rates == conversions.imu_rates(message)
        assert sample.stamp == (message.header.stamp.sec, message.header.stamp.nanosec)
        got = deserialize_message(wire.corrected_imu(sample, (0.1, 0.2, 0.3)), Imu)
        assert _same(got, conversions.corrected_imu(message, (0.1, 0.2, 0.3)))
        # the lean reads work on (and hand back) the canonical copy
        read, _, _, at, x, y, z = wire.imu_rates(data)
        assert read[:2] == b'\x00\x01' and (x, y, z) == conversions.imu_rates(message)
        got = deserialize_message(bytes(wire.patched_imu(read, at, x - 0.1, y - 0.2,
                                                         z - 0.3)), Imu)
        assert _same(got, conversions.corrected_imu(message, (0.1, 0.2, 0.3)))
        assert wire.imu_yaw(data)[3] == 'imu'


@pytest.mark.parametrize('decode', [wire.decode_imu, wire.decode_odometry, wire.decode_scan,
                                    wire.pose_array_points, wire.imu_rates, wire.imu_yaw])
def test_bytes_that_are_no_message_raise_wire_error(decode):
    good = serialize_message(_imu(np.random.default_rng(0), 'imu'))
    for data in (b'', b'\x00\x01\x00\x00', b'\x00\x01\x00\x00' + b'\xff' * 40, good[:30]):
        with pytest.raises(wire.WireError, match='bytes are not a'):
            decode(data)


def test_node_io_switch(monkeypatch):
    monkeypatch.delenv(wire.NODE_IO_VARIABLE, raising=False)
    assert wire.node_io() == 'serialized' and wire.serialized_io()
    monkeypatch.setenv(wire.NODE_IO_VARIABLE, 'rclpy')
    assert not wire.serialized_io()
    assert wire.executor() is None
    monkeypatch.setenv(wire.NODE_IO_VARIABLE, 'fast')
    with pytest.raises(GyroEkfError, match="GYRO_EKF_NODE_IO='fast': expected one of"):
        wire.node_io()
