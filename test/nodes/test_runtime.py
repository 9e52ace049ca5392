"""The node processes' runtime: the Fast DDS writer profile and the raw publishing path."""

from __future__ import annotations

import xml.etree.ElementTree as ET

import numpy as np
import pytest

pytest.importorskip('rclpy')

from rclpy.serialization import deserialize_message, serialize_message  # noqa: E402
from sensor_msgs.msg import Imu  # noqa: E402

from gyro_ekf.nodes import qos, runtime, wire  # noqa: E402

_NS = '{http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles}'


def test_the_writer_profile_is_used_unless_the_user_configures_fast_dds(tmp_path):
    environ: dict[str, str] = {}
    assert runtime.use_writer_profile(environ, cwd=tmp_path)
    assert environ == {runtime.FASTDDS_PROFILES_VARIABLE: str(runtime.FASTDDS_WRITER_PROFILE)}
    for mine in ({runtime.FASTDDS_PROFILES_VARIABLE: '/etc/my_profiles.xml'},
                 {'RMW_FASTRTPS_USE_QOS_FROM_XML': '1'}):
        before = dict(mine)
        assert not runtime.use_writer_profile(mine, cwd=tmp_path)
        assert mine == before
    (tmp_path / 'DEFAULT_FASTRTPS_PROFILES.xml').write_text('<dds/>')
    environ = {}
    assert not runtime.use_writer_profile(environ, cwd=tmp_path) and environ == {}


def test_the_writer_profile_sets_only_the_nack_suppression():
    """No QoS policy in it: reliability, durability and history stay the nodes' own."""
    root = ET.parse(runtime.FASTDDS_WRITER_PROFILE).getroot()
    writers = root.findall(f'{_NS}profiles/{_NS}data_writer')
    assert len(writers) == 1 and writers[0].get('is_default_profile') == 'true'
    assert [child.tag for child in writers[0]] == [f'{_NS}times']
    times = writers[0].find(f'{_NS}times')
    assert [child.tag for child in times] == [f'{_NS}nackSupressionDuration']
    duration = times.find(f'{_NS}nackSupressionDuration')
    assert (int(duration.find(f'{_NS}sec').text), int(duration.find(f'{_NS}nanosec').text)) \
        == (0, 10_000_000)
    assert len(root.findall(f'{_NS}profiles/*')) == 1  # no participant or reader profile


def test_raw_publisher_sends_bytearrays_as_rclpy_would(ros_processes):
    """wire.raw_publisher's publish takes the nodes' patched bytearrays."""
    _, probe = ros_processes
    received: list[bytes] = []
    probe.node.create_subscription(Imu, 'runtime_test_imu', received.append, qos.LOSSLESS,
                                   raw=True)
    publisher = probe.node.create_publisher(Imu, 'runtime_test_imu', qos.LOSSLESS)
    publish, readers = wire.raw_publisher(publisher)
    probe.spin_until(lambda: readers() == 1, 10.0, 'the subscription to match')
    message = Imu()
    message.header.frame_id = 'imu_link'
    message.header.stamp.sec = 123
    message.angular_velocity.z = 0.25
    data, _, _, at, x, y, z = wire.imu_rates(serialize_message(message))
    publish(wire.patched_imu(data, at, x, y, z - 0.5))
    probe.spin_until(lambda: len(received) == 1, 10.0, 'the patched message')
    got = deserialize_message(received[0], Imu)
    assert got.header.stamp.sec == 123 and got.header.frame_id == 'imu_link'
    assert got.angular_velocity.z == -0.25
    assert np.array_equal(got.angular_velocity_covariance, message.angular_velocity_covariance)
