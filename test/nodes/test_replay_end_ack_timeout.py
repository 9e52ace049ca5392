"""`gyro-ekf replay --ack-timeout-s` at the end: a reader that never acknowledges is named.

test_replay_ack_timeout.py covers a reader that holds a replay back while it publishes;
this covers the wait after the last message. The order is fixed by the replay itself, not
by timing: it is told to wait for two subscribers of /scan (`--wait-for scan:2`), and says
so on each change of the count. Once it has matched the first (a landmark detector with
reliable inputs), that reader is frozen with SIGSTOP; only then does the test's own probe
subscribe, the second subscriber, and the replay begins. The bag's 901 scans fit the
writer's history (a keep-all history blocks writes at 5000 unacknowledged samples), so all
of them are published; the probe takes and acknowledges every one, the frozen detector
none. The replay must then end with exit 1 and one line naming /scan and the option, after
its summary line.
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
    detector = processes.node('landmark_detector_node', '-r', f'__ns:={namespace}',
                              '-p', 'reliable_inputs:=true', name='end_ack_detector')
    probe.spin_until(lambda: probe.node.count_subscribers(f'{namespace}/scan') > 0, 60,
                     'the landmark detector')
    log = tmp_path / 'replay.log'
    replay = subprocess.Popen(
        [sys.executable, '-m', 'gyro_ekf.cli.main', 'replay', str(BAG), '--rate', '0',
         '--topics', 'scan', '--wait-for', 'scan:2', '--ack-timeout-s', '2',
         '--ros-args', '-r', f'__ns:={namespace}'],
        env=processes.env, cwd=REPO, stdout=log.open('w'), stderr=subprocess.STDOUT)
    frozen = False
    try:
        _wait_for_line(log, '/scan has 1 of 2 subscribers', replay, 120)
        os.kill(detector.pid, signal.SIGSTOP)
        frozen = True
        scans = probe.subscribe(LaserScan, f'{namespace}/scan', qos.LOSSLESS)
        try:
            code = replay.wait(timeout=120)
        except subprocess.TimeoutExpired:
            code = None  # the check below shows its output
        # Whatever reached the probe's reader before the replay ended is taken now.
        probe.spin_until(lambda: len(scans) >= SCANS, 60, 'every scan at the probe')
    finally:
        if frozen:
            os.kill(detector.pid, signal.SIGCONT)
        if replay.poll() is None:
            replay.kill()
            replay.wait()
    output = log.read_text()
    assert code == 1, output
    assert 'Traceback' not in output
    assert f'replayed {SCANS} messages' in output, output
    error = [line for line in output.splitlines() if line.startswith('gyro-ekf replay: error:')]
    assert len(error) == 1, output
    assert '/scan' in error[0] and '--ack-timeout-s 2 s' in error[0], error
    assert 'did not acknowledge every message' in error[0], error
    assert len(scans) == SCANS
