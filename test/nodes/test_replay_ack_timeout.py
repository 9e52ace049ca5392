"""`gyro-ekf replay --ack-timeout-s`: a reliable reader that stops acknowledging ends the replay.

The reader is an ekf_node with reliable inputs, frozen with SIGSTOP once it has taken some of
the replay: it neither takes nor acknowledges anything after that. The replay loops, so it is
still publishing at the freeze, and the frozen reader holds it back. The replay must not wait
for it forever: it ends with exit 1 and one line naming the topic and the option.

The same bound at the end of a replay: test_replay_end_ack_timeout.py.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.ros

REPO = Path(__file__).resolve().parents[2]
BAG = REPO / 'bags' / 'sim_static_start'


def test_a_reader_that_stops_acknowledging_ends_the_replay_with_a_clear_error(
        ros_processes, tmp_path):
    from geometry_msgs.msg import PoseWithCovarianceStamped

    from gyro_ekf.nodes import qos

    processes, probe = ros_processes
    namespace = '/ack_timeout'
    node = processes.node('ekf_node', '-r', f'__ns:={namespace}',
                          '-p', 'reliable_inputs:=true', name='ack_timeout_ekf')
    poses = probe.subscribe(PoseWithCovarianceStamped, f'{namespace}/ekf/pose', qos.OUTPUT)
    probe.spin_until(lambda: probe.node.count_subscribers(f'{namespace}/imu') > 0, 60,
                     'the EKF node')
    log = tmp_path / 'replay.log'
    # The replay loops, so it cannot end, all acknowledged, before the freeze however late
    # the first pose reaches the probe (a replay of a few seconds could, on a busy
    # machine, and exit 0). At --rate 0 it publishes as fast as the reader takes (the node
    # is the slower of the two): the keep-all histories fill and stay full, so at the
    # freeze the replay is already held back and gives up --ack-timeout-s later, on /imu
    # (twice /odom's rate, it fills first), whatever CPU the replay gets. That is well
    # within Fast DDS's 20 s participant lease (after it the frozen reader would be
    # dropped as gone, and the replay would go on). A reader that stalls for
    # --ack-timeout-s before the freeze ends the replay the same way.
    replay = subprocess.Popen(
        [sys.executable, '-m', 'gyro_ekf.cli.main', 'replay', str(BAG), '--rate', '0',
         '--loop', '--topics', 'imu', 'odom', '--wait-for', 'imu:1',
         '--wait-for', 'odom:1', '--ack-timeout-s', '2', '--ros-args', '-r',
         f'__ns:={namespace}'], env=processes.env, cwd=REPO, stdout=log.open('w'),
        stderr=subprocess.STDOUT)
    try:
        probe.spin_until(lambda: len(poses) >= 1, 60, 'the EKF node taking the replay')
        os.kill(node.pid, signal.SIGSTOP)
        try:
            # Seconds after the freeze, or never (once the lease has dropped the reader).
            code = replay.wait(timeout=60)
        except subprocess.TimeoutExpired:
            code = None  # still replaying: the check below shows its output
    finally:
        os.kill(node.pid, signal.SIGCONT)
        if replay.poll() is None:
            replay.kill()
            replay.wait()
    output = log.read_text()
    assert code == 1, output
    assert 'Traceback' not in output
    error = [line for line in output.splitlines() if line.startswith('gyro-ekf replay: error:')]
    assert len(error) == 1, output
    assert '--ack-timeout-s' in error[0] and '/imu' in error[0], error
