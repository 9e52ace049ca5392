"""`gyro-ekf replay --ack-timeout-s`: a reliable reader that stops acknowledging ends the replay.

In both tests a node with reliable inputs is frozen with SIGSTOP: it neither takes nor
acknowledges anything after that. The replay must not wait for it forever: it ends with
exit 1 and one line naming the topic and the option, and no traceback.

- While publishing: an ekf_node frozen once it has taken some of a looped replay holds the
  replay back (its keep-all history full).
- At the end: a landmark detector frozen before the replay begins is named by the wait for
  acknowledgements after the last message.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

pytestmark = pytest.mark.ros

REPO = Path(__file__).resolve().parents[2]
BAG = REPO / 'bags' / 'sim_static_start'
SCANS = 901
"""The bag's /scan messages (`gyro-ekf info bags/sim_static_start`)."""


def _reader(ros_processes, executable: str, namespace: str, topic: str
            ) -> subprocess.Popen:
    """Start a node with reliable inputs in the namespace; wait until it reads the topic."""
    processes, probe = ros_processes
    node = processes.node(executable, '-r', f'__ns:={namespace}', '-p',
                          'reliable_inputs:=true', name=f'{namespace[1:]}_{executable}')
    probe.spin_until(lambda: probe.node.count_subscribers(f'{namespace}/{topic}') > 0, 60,
                     executable)
    return node


def _replay(processes, namespace: str, log: Path, *args: str) -> subprocess.Popen:
    """Start `gyro-ekf replay BAG --rate 0 --ack-timeout-s 2 args...` in the namespace."""
    return subprocess.Popen(
        [sys.executable, '-m', 'gyro_ekf.cli.main', 'replay', str(BAG), '--rate', '0',
         '--ack-timeout-s', '2', *args, '--ros-args', '-r', f'__ns:={namespace}'],
        env=processes.env, cwd=REPO, stdout=log.open('w'), stderr=subprocess.STDOUT)


def _stop(replay: subprocess.Popen, frozen: subprocess.Popen | None) -> None:
    """Thaw the frozen node; kill the replay if it is still running."""
    if frozen is not None:
        os.kill(frozen.pid, signal.SIGCONT)
    if replay.poll() is None:
        replay.kill()
        replay.wait()


def _error_line(code: int | None, output: str) -> str:
    """Assert exit 1, no traceback and exactly one error line; return that line."""
    assert code == 1, output
    assert 'Traceback' not in output
    error = [line for line in output.splitlines() if line.startswith('gyro-ekf replay: error:')]
    assert len(error) == 1, output
    return error[0]


def test_a_reader_that_stops_acknowledging_ends_the_replay_with_a_clear_error(
        ros_processes, tmp_path):
    from geometry_msgs.msg import PoseWithCovarianceStamped

    from gyro_ekf.nodes import qos

    processes, probe = ros_processes
    namespace = '/ack_timeout'
    poses = probe.subscribe(PoseWithCovarianceStamped, f'{namespace}/ekf/pose', qos.OUTPUT)
    node = _reader(ros_processes, 'ekf_node', namespace, 'imu')
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
    replay = _replay(processes, namespace, log, '--loop', '--topics', 'imu', 'odom',
                     '--wait-for', 'imu:1', '--wait-for', 'odom:1')
    frozen = None
    try:
        probe.spin_until(lambda: len(poses) >= 1, 60, 'the EKF node taking the replay')
        os.kill(node.pid, signal.SIGSTOP)
        frozen = node
        try:
            # Seconds after the freeze, or never (once the lease has dropped the reader).
            code = replay.wait(timeout=60)
        except subprocess.TimeoutExpired:
            code = None  # still replaying: the check below shows its output
    finally:
        _stop(replay, frozen)
    error = _error_line(code, log.read_text())
    assert '--ack-timeout-s' in error and '/imu' in error, error


def _wait_for_line(log: Path, text: str, process: subprocess.Popen, timeout_s: float) -> None:
    """Wait until the process's output has a line containing text (it is still running)."""
    deadline = time.monotonic() + timeout_s
    while text not in log.read_text():
        assert process.poll() is None, f'the replay ended first:\n{log.read_text()}'
        assert time.monotonic() < deadline, f'no {text!r} in {timeout_s} s:\n{log.read_text()}'
        time.sleep(0.05)


def test_a_reader_that_never_acknowledges_is_named_at_the_end_of_the_replay(
        ros_processes, tmp_path):
    from sensor_msgs.msg import LaserScan

    from gyro_ekf.nodes import qos

    processes, probe = ros_processes
    namespace = '/end_ack_timeout'
    detector = _reader(ros_processes, 'landmark_detector_node', namespace, 'scan')
    log = tmp_path / 'replay.log'
    # The order is fixed by the replay, not by timing: told to wait for two subscribers of
    # /scan, it says so on each change of the count. Once it has matched the first (the
    # detector), that one is frozen; only then does the probe subscribe, the second, and
    # the replay begins. Its 901 scans fit the writer's history (a keep-all history
    # blocks writes at 5000 unacknowledged samples), so all are published: the probe
    # takes and acknowledges every one, the frozen detector none, and the wait after the
    # last one must name /scan.
    replay = _replay(processes, namespace, log, '--topics', 'scan', '--wait-for', 'scan:2')
    frozen = None
    try:
        _wait_for_line(log, '/scan has 1 of 2 subscribers', replay, 120)
        os.kill(detector.pid, signal.SIGSTOP)
        frozen = detector
        scans = probe.subscribe(LaserScan, f'{namespace}/scan', qos.LOSSLESS)
        try:
            code = replay.wait(timeout=120)
        except subprocess.TimeoutExpired:
            code = None  # the check below shows its output
        # Whatever reached the probe's reader before the replay ended is taken now.
        probe.spin_until(lambda: len(scans) >= SCANS, 60, 'every scan at the probe')
    finally:
        _stop(replay, frozen)
    output = log.read_text()
    error = _error_line(code, output)
    assert f'replayed {SCANS} messages' in output, output
    assert '/scan' in error and '--ack-timeout-s 2 s' in error, error
    assert 'did not acknowledge every message' in error, error
    assert len(scans) == SCANS
