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


class _FakeClock:
    """runtime.time stand-in: monotonic() moves only when a fake call says so; sleeps logged."""

    def __init__(self):
        self.now = 0.0
        self.sleeps: list[float] = []

    def monotonic(self) -> float:
        return self.now

    def sleep(self, seconds: float) -> None:
        self.sleeps.append(seconds)
        self.now += seconds


class _FakeExecutor:
    """Records the spin calls; spin_once 'waits' the given times for its event.

    The context is ok for `rounds` serving calls (spin_until_future_complete).
    """

    def __init__(self, clock: _FakeClock, waits: list[float], rounds: int):
        self.clock, self.waits, self.rounds, self.calls = clock, list(waits), rounds, []
        self.context = self

    def ok(self) -> bool:
        return self.rounds > 0

    def add_node(self, node) -> None:
        pass

    def remove_node(self, node) -> None:
        pass

    def shutdown(self) -> None:
        pass

    def spin_once(self, timeout_sec: float) -> None:
        self.calls.append(('once', timeout_sec))
        self.clock.now += self.waits.pop(0)

    def spin_until_future_complete(self, future, timeout_sec: float) -> None:
        self.calls.append(('serve', timeout_sec))
        self.rounds -= 1


def test_events_are_served_in_batches_unless_a_backlog_waits(monkeypatch):
    """event_batch_s: pause after an event that had to be waited for, none after a ready one."""
    clock = _FakeClock()
    monkeypatch.setattr(runtime, 'time', clock)
    # The first event came after 3 ms (pause), the second was already waiting (no pause).
    executor = _FakeExecutor(clock, [0.003, 0.0], rounds=2)
    runtime._spin_events(object(), executor, batch_s=0.01)
    assert executor.calls == [('once', runtime._SPIN_RETURN_S), ('serve', runtime._DRAIN_S)] * 2
    assert clock.sleeps == [0.01]


def test_without_a_batch_the_events_are_served_as_they_come(monkeypatch):
    clock = _FakeClock()
    monkeypatch.setattr(runtime, 'time', clock)
    executor = _FakeExecutor(clock, [], rounds=2)
    runtime._spin_events(object(), executor)
    assert executor.calls == [('serve', runtime._SPIN_RETURN_S)] * 2 and clock.sleeps == []
