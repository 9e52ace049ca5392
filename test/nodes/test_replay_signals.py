"""`gyro-ekf replay --loop` in its own process: SIGINT and SIGTERM end it cleanly.

The replay runs in a namespace of its own (`-r __ns:=...`), so the probe receives only the
messages this test's replay publishes.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip('rclpy')

from rclpy.qos import QoSProfile, ReliabilityPolicy  # noqa: E402
from sensor_msgs.msg import Imu  # noqa: E402

REPO = Path(__file__).resolve().parents[2]
BAG = REPO / 'bags' / 'sim_static_start'


@pytest.mark.parametrize('signum,background', [(signal.SIGTERM, False), (signal.SIGINT, False),
                                               (signal.SIGINT, True)],
                         ids=['term', 'int', 'int-background'])
def test_a_signal_ends_a_looping_replay_cleanly(ros_processes, tmp_path, signum, background):
    processes, probe = ros_processes
    namespace = f'/replay_{signum.name.lower()}_{"bg" if background else "fg"}'
    received = probe.subscribe(Imu, f'{namespace}/imu',
                               QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE))
    args = [sys.executable, '-m', 'gyro_ekf.cli.main', 'replay', str(BAG), '--loop',
            '--rate', '20', '--topics', 'imu', '--ros-args', '-r', f'__ns:={namespace}']
    log = tmp_path / f'{namespace.strip("/")}.log'
    if background:
        # A shell without job control starts `cmd &` with SIGINT ignored.
        pid_file = tmp_path / 'pid'
        shell = subprocess.Popen(
            ['sh', '-c', f'{" ".join(args)} >{log} 2>&1 & echo $! >{pid_file}; wait'],
            env=processes.env, cwd=REPO)
        probe.spin_until(lambda: pid_file.exists() and pid_file.read_text().strip(), 10.0,
                         'the background pid')
        pid = int(pid_file.read_text())
    else:
        shell = subprocess.Popen(args, env=processes.env, cwd=REPO, stdout=log.open('w'),
                                 stderr=subprocess.STDOUT)
        pid = shell.pid
    try:
        probe.spin_until(lambda: len(received) >= 50, 60.0, f'IMU messages on {namespace}')
        os.kill(pid, signum)
        assert shell.wait(timeout=30) == 0, log.read_text()
    finally:
        if shell.poll() is None:
            shell.kill()
            shell.wait()
    output = log.read_text()
    assert 'Traceback' not in output
    assert f'(stopped by {signum.name})' in output
    assert output.count('replayed ') == 1


def test_loops_n_replays_the_bag_n_times_and_ends(ros_processes):
    processes, _ = ros_processes
    output = processes.run('replay_loops', 'gyro_ekf.cli.main', 'replay', str(BAG), '--loops',
                           '3', '--rate', '0', '--topics', 'odom', '--duration-s', '0.5',
                           '--ros-args', '-r', '__ns:=/replay_loops', timeout_s=60)
    # 0.5 s of 100 Hz odometry from the first message, both ends included: 51 per pass.
    assert 'replayed 153 messages (3 pass(es)' in output, output
