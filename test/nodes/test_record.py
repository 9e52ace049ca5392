"""`gyro-ekf record` in its own process: what a signal or a kill -9 leaves on disk.

The test publishes its own Vector3Stamped messages (x = 0, 1, 2, ...) on a topic of its
own, waits until the recorder's metadata.yaml (refreshed every --flush-s) counts all of
them, then stops or kills the recorder and reads the bag back.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

pytest.importorskip('rclpy')

from geometry_msgs.msg import Vector3Stamped  # noqa: E402
from rclpy.qos import QoSProfile, ReliabilityPolicy  # noqa: E402

from gyro_ekf.io.bag_info import bag_summary  # noqa: E402
from gyro_ekf.io.bag_reader import iter_bag_messages  # noqa: E402

COUNT = 120
_QOS = QoSProfile(depth=COUNT, reliability=ReliabilityPolicy.RELIABLE)


def _metadata_count(bag: Path) -> int:
    try:
        meta = yaml.safe_load((bag / 'metadata.yaml').read_text())
    except (OSError, yaml.YAMLError):
        return -1
    return int(meta['rosbag2_bagfile_information']['message_count'])


def _publish_and_wait(probe, topic: str, bag: Path, first: int = 0,
                      count: int = COUNT) -> None:
    """Publish count messages once the recorder subscribed; wait until its checkpoint has them."""
    publisher = probe.node.create_publisher(Vector3Stamped, topic, _QOS)
    try:
        probe.spin_until(lambda: publisher.get_subscription_count() > 0, 30.0,
                         f'the recorder to subscribe to {topic}')
        for i in range(first, first + count):
            message = Vector3Stamped()
            message.header.stamp.sec = 1000 + i
            message.vector.x = float(i)
            publisher.publish(message)
        probe.spin_until(lambda: _metadata_count(bag) >= first + count, 30.0,
                         f'metadata.yaml of {bag} to count {first + count} messages')
    finally:
        probe.node.destroy_publisher(publisher)


def _values(bag: Path) -> list[float]:
    return [m.message.vector.x for m in iter_bag_messages(bag)]


def _record_args(topic: str, bag: Path, *extra: str) -> list[str]:
    return ['gyro_ekf.cli.main', 'record', f'{topic}:geometry_msgs/msg/Vector3Stamped',
            '-o', str(bag), '--flush-s', '0.1', *extra]


@pytest.mark.parametrize('signum', [signal.SIGTERM, signal.SIGINT], ids=['term', 'int'])
def test_a_signal_ends_record_with_a_complete_bag(ros_processes, tmp_path, signum):
    processes, probe = ros_processes
    topic = f'/record_signal_{signum.name.lower()}'
    bag = tmp_path / 'signalled'
    name = f'record_{signum.name}'
    recorder = processes.start(name, *_record_args(topic, bag))
    _publish_and_wait(probe, topic, bag)
    recorder.send_signal(signum)
    assert recorder.wait(timeout=30) == 0, processes.log(name)
    output = processes.log(name)
    assert f'recording into {bag / "signalled.mcap"}' in output
    assert 'Traceback' not in output
    assert f'stopped by {signum.name}' in output
    assert sorted(os.listdir(bag)) == ['metadata.yaml', 'signalled.mcap']
    summary = bag_summary(bag)
    assert summary.message_count == COUNT
    assert _values(bag) == [float(i) for i in range(COUNT)]
    # A complete MCAP ends with its footer magic.
    assert (bag / 'signalled.mcap').read_bytes()[-8:] == b'\x89MCAP0\r\n'


def test_sigint_stops_a_record_started_in_the_background(ros_processes, tmp_path):
    """`sh -c 'gyro-ekf record ... &'` starts it with SIGINT ignored; it must still stop."""
    processes, probe = ros_processes
    topic = '/record_background'
    bag = tmp_path / 'background'
    pid_file = tmp_path / 'pid'
    log = tmp_path / 'background.log'
    command = ' '.join([sys.executable, '-m', *_record_args(topic, bag)])
    shell = subprocess.Popen(['sh', '-c', f'{command} >{log} 2>&1 & echo $! >{pid_file}; wait'],
                             env=processes.env, cwd=Path(__file__).resolve().parents[2])
    try:
        probe.spin_until(lambda: pid_file.exists() and pid_file.read_text().strip(), 10.0,
                         'the background pid')
        pid = int(pid_file.read_text())
        ignored = _sigint_ignored_at_start(pid)
        _publish_and_wait(probe, topic, bag)
        os.kill(pid, signal.SIGINT)
        assert shell.wait(timeout=30) == 0, log.read_text()
    finally:
        if shell.poll() is None:
            shell.kill()
    print(f'SIGINT was ignored in the background job before record restored it: {ignored}')
    assert 'stopped by SIGINT' in log.read_text(), log.read_text()
    assert _values(bag) == [float(i) for i in range(COUNT)]


def _sigint_ignored_at_start(pid: int) -> bool | None:
    """Whether the shell gave the job SIGINT ignored (from /proc; None if unreadable)."""
    try:
        status = Path(f'/proc/{pid}/status').read_text()
    except OSError:
        return None
    line = next(x for x in status.splitlines() if x.startswith('SigIgn:'))
    return bool(int(line.split()[1], 16) & (1 << (signal.SIGINT - 1)))


def test_kill_9_leaves_the_bag_readable_up_to_the_last_checkpoint(ros_processes, tmp_path):
    processes, probe = ros_processes
    topic = '/record_killed'
    bag = tmp_path / 'killed'
    recorder = processes.start('record_killed', *_record_args(topic, bag))
    _publish_and_wait(probe, topic, bag)
    recorder.send_signal(signal.SIGKILL)
    recorder.wait(timeout=30)
    assert (bag / 'metadata.yaml').exists()
    assert (bag / 'killed.mcap').exists()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith('.')]
    summary = bag_summary(bag)
    assert summary.message_count == COUNT
    assert [t.name for t in summary.topics] == [topic]
    assert _values(bag) == [float(i) for i in range(COUNT)]


def test_force_replaces_an_old_bag_but_not_a_folder_with_other_files(ros_processes, tmp_path):
    processes, _ = ros_processes
    bag = tmp_path / 'notes'
    bag.mkdir()
    (bag / 'notes.txt').write_text('mine')
    process = processes.start('record_foreign', *_record_args(
        '/record_foreign', bag, '--force', '--duration-s', '1'))
    assert process.wait(timeout=60) == 1
    output = processes.log('record_foreign')
    assert f'{bag / "notes.txt"}: is not part of a bag' in output
    assert 'Traceback' not in output
    assert (bag / 'notes.txt').read_text() == 'mine'


def test_record_stops_after_its_duration_with_a_complete_empty_bag(ros_processes, tmp_path):
    processes, _ = ros_processes
    bag = tmp_path / 'empty'
    processes.run('record_empty', *_record_args('/record_nobody', bag, '--duration-s', '0.5'),
                  timeout_s=60)
    assert bag_summary(bag).message_count == 0
    assert list(iter_bag_messages(bag)) == []


def test_with_sim_time_a_message_before_clock_starts_no_idle_wait(ros_processes):
    # make demo records with --use-sim-time --idle-exit-s 3: a node's /diagnostics report at
    # its start (before the replay's /clock) once started the idle wait, and the recorder
    # exited before the replay's outputs came.
    from rclpy.parameter import Parameter
    from rclpy.time import Time

    from gyro_ekf.nodes.recorder import Recorder

    _, probe = ros_processes
    recorded = []
    recorder = Recorder(['/record_sim_time:geometry_msgs/msg/Vector3Stamped'],
                        lambda *args: recorded.append(args[2]), node_name='sim_time_recorder',
                        context=probe.context,
                        parameter_overrides=[Parameter('use_sim_time', value=True)])
    try:
        topic = recorder.recorded['/record_sim_time']
        recorder._on_message(topic, b'')
        assert recorded == [0] and recorder.last_message is None
        recorder.get_clock().set_ros_time_override(Time(seconds=1000))  # as /clock does
        recorder._on_message(topic, b'')
        assert recorded == [0, 1000 * 10 ** 9] and recorder.last_message is not None
    finally:
        recorder.destroy_node()
