"""The demo pipeline on a starved machine: CPU hogs on every core, same result as offline.

`gyro-ekf replay bags/sim_static_start --clock` feeds calibration_node, landmark_detector_node
and ekf_node (use_sim_time, the demo's parameters) while busy loops take every core, more
than once over. Staleness and loop detection are judged in the stamps the node received, so
a starved node, whose queues drain one message per executor round while /clock runs ahead,
neither resets nor drops a message as late: with reliable inputs every estimate equals the
offline `gyro-ekf run` of the bag; with the default (sensor data) QoS messages may be lost,
and the final position stays within 1 cm of the offline run's at the same stamp, or the
node's verdict says the inputs it lost.

The hogs stop by themselves after HOG_LIMIT_S and are killed when the test ends.
"""

from __future__ import annotations

import math
import os
from pathlib import Path
import subprocess
import sys

import numpy as np
import pytest

pytestmark = pytest.mark.ros

REPO = Path(__file__).resolve().parents[2]
BAG = REPO / 'bags' / 'sim_static_start'
CONFIG = REPO / 'config' / 'gyro_ekf.yaml'
PUBLISH_EVERY = 4
HOG_LIMIT_S = 900.0
"""Longest a hog runs, s (longer than the slowest pipeline run; killed at the end anyway)."""
RELIABLE_RATE = 20.0
"""Replay speed-up with reliable inputs: more than the starved nodes follow, so their input
queues back up (the staleness rule judged on /clock dropped 13 000 of the 18 001 IMU samples
as late here)."""
LOSSY_RATE = 6.0
"""With the default (lossy) QoS: cli/demo.py's speed-up."""
STAMP_MATCH_S = 1e-6
"""Live and offline stamps of one IMU sample differ by the CSV's rounding at most, s."""


def _cores() -> int:
    return len(os.sched_getaffinity(0))


class Hogs:
    """Busy-loop processes, each ending after HOG_LIMIT_S on its own."""

    def __init__(self, count: int):
        loop = ('import time\nend = time.monotonic() + %r\n'
                'while time.monotonic() < end:\n    pass\n' % HOG_LIMIT_S)
        self.processes = [subprocess.Popen([sys.executable, '-c', loop]) for _ in range(count)]

    def stop(self) -> None:
        for process in self.processes:
            process.kill()
        for process in self.processes:
            process.wait(timeout=30)


@pytest.fixture(scope='module')
def offline(tmp_path_factory) -> np.ndarray:
    """estimates.csv of `gyro-ekf run` on the bag with the demo's config file, shape (n, 12)."""
    out = tmp_path_factory.mktemp('offline')
    subprocess.run([sys.executable, '-m', 'gyro_ekf.cli.main', 'run', str(BAG), '-o',
                    str(out), '--params-file', str(CONFIG), '--no-plots', '--no-bag',
                    '--no-progress', '--force'], check=True, cwd=REPO, timeout=600,
                   capture_output=True)
    return np.loadtxt(out / 'estimates.csv', delimiter=',', skiprows=1, ndmin=2)


def _stamp_s(message) -> float:
    stamp = message.header.stamp
    return (stamp.sec * 10 ** 9 + stamp.nanosec - _START_NS) / 1e9


_START_NS = 1_700_000_000 * 10 ** 9
"""The bag's first stamp (its sidecar's log_time_zero_ns): estimates.csv counts from it."""


def _demo_pipeline(ros_harness, diagnostics_of, tmp_path, reliable: bool, hogs_per_core: int,
                   last_s: float, estimates: int | None = None):
    """Run the demo's nodes on the replayed bag under hogs.

    With `estimates` (reliable inputs: every IMU sample is processed) the node's report is
    awaited until it counts at least that many; without, until it reached last_s - 1 s.

    Returns:
        The probe's ekf/odometry messages, the node's last diagnostics, its log.
    """
    from diagnostic_msgs.msg import DiagnosticArray
    from nav_msgs.msg import Odometry

    from gyro_ekf.nodes import qos

    env = ros_harness.node_env(tmp_path)
    processes = ros_harness.Processes(env, tmp_path)
    probe = ros_harness.Probe(int(env['ROS_DOMAIN_ID']))
    hogs = None

    def values() -> dict[str, str]:
        return diagnostics_of(diagnostics, 'ekf_node: gyro bias EKF') or {}
    try:
        odometry = probe.subscribe(Odometry, 'ekf/odometry', qos.LOSSLESS)
        diagnostics = probe.subscribe(DiagnosticArray, '/diagnostics', qos.LOSSLESS)
        params = ['--params-file', str(CONFIG), '--params-file', f'{BAG}.params.yaml',
                  '-p', 'use_sim_time:=true', '-p', f'reliable_inputs:={str(reliable).lower()}']
        processes.node('calibration_node', *params)
        processes.node('landmark_detector_node', *params)
        # cli/demo.py's ekf_node, without use_calibration: the offline run seeds no bias
        # either (where a seed lands in the stream depends on when gyro_bias arrives).
        processes.node('ekf_node', *params, '-p', f'publish_every_n:={PUBLISH_EVERY}')
        probe.spin_until(lambda: probe.node.count_publishers('/ekf/odometry') > 0
                         and probe.node.count_publishers('/diagnostics') > 0, 60,
                         'the EKF node')
        # The first scans' landmarks are lost if the detector's writer has not matched the
        # EKF node's reader yet (sim time: the detector says so before /clock runs).
        probe.wait_for_landmarks_readers(diagnostics)
        hogs = Hogs(hogs_per_core * _cores())
        rate = RELIABLE_RATE if reliable else LOSSY_RATE
        processes.run(
            'replay', 'gyro_ekf.cli.main', 'replay', str(BAG), '--rate', str(rate), '--clock',
            '--topics', 'imu', 'odom', 'scan', 'landmark_map', 'initialpose',
            '--wait-for', 'imu:2', '--wait-for', 'odom:2', '--wait-for', 'scan:1',
            # Starved, the replay goes as fast as the nodes take it: timeouts say "stuck".
            timeout_s=HOG_LIMIT_S)
        # After the last message the node's idle flush releases what it held and reports:
        # with /clock stopped the periodic report stops too, so only that report has the
        # final counts. A periodic report 1 s short of the end is enough for lossy inputs
        # (their test asserts only counts that stay zero); with reliable ones wait for the
        # count of every sample (the last one is never published, so the odometry wait
        # below does not cover it). Too few shows as a timeout naming the numbers; too many
        # fails the test's own check.
        if estimates is None:
            what = f'the EKF node to process the replayed samples up to {last_s - 1.0} s'

            def done() -> bool:
                return float(values().get('stamp_s') or 0.0) >= last_s - 1.0
        else:
            what = f'the EKF node to report at least {estimates} estimates'

            def done() -> bool:
                return int(values().get('estimates') or 0) >= estimates
        try:
            probe.spin_until(lambda: values().get('buffered') == '0' and done(), 600, what)
        except AssertionError as err:
            last = {k: values().get(k) for k in ('buffered', 'estimates', 'stamp_s')}
            raise AssertionError(f'{err}; the last report has {last}') from None
        # Keep-last output: what the probe could not take in time is gone, the rest is in
        # order; the last published estimate ends it.
        end_s = last_s - (STAMP_MATCH_S if reliable else 1.0)  # lossy: the last may be lost
        probe.spin_until(lambda: odometry and _stamp_s(odometry[-1]) >= end_s, 120,
                         'the last published estimate')
        hogs.stop()
        hogs = None
        return odometry, values(), processes.log('ekf_node')
    finally:
        if hogs is not None:
            hogs.stop()
        processes.stop_all()
        probe.close()


def _offline_rows(offline: np.ndarray, odometry) -> tuple[np.ndarray, np.ndarray]:
    """Offline rows at the live estimates' stamps, and the live (x, y, yaw)."""
    from gyro_ekf.nodes.conversions import quaternion_yaw

    stamps = np.array([_stamp_s(m) for m in odometry])
    rows = np.clip(np.searchsorted(offline[:, 0], stamps - STAMP_MATCH_S), 0,
                   len(offline) - 1)
    assert np.abs(offline[rows, 0] - stamps).max() <= STAMP_MATCH_S
    live = np.array([(m.pose.pose.position.x, m.pose.pose.position.y,
                      quaternion_yaw(m.pose.pose.orientation)) for m in odometry])
    return offline[rows], live


@pytest.mark.parametrize('hogs_per_core', [1, 2])
def test_reliable_inputs_on_a_starved_machine_equal_the_offline_run(
        ros_harness, diagnostics_of, tmp_path, offline, hogs_per_core):
    expected = offline[PUBLISH_EVERY - 1::PUBLISH_EVERY]
    odometry, values, log = _demo_pipeline(ros_harness, diagnostics_of, tmp_path, True,
                                           hogs_per_core, expected[-1, 0], len(offline))
    assert values['resets'] == '0' and 'filter reset' not in log
    assert values['dropped_late'] == '0', log
    assert int(values['estimates']) == len(offline)  # every IMU sample, in stamp order
    rows, live = _offline_rows(offline, odometry)
    assert np.isin(rows[:, 0], expected[:, 0]).all()  # the published ones, no others
    assert abs(_stamp_s(odometry[-1]) - expected[-1, 0]) <= STAMP_MATCH_S
    assert np.abs(live[:, :2] - rows[:, 1:3]).max() < 1e-6
    yaw_error = np.angle(np.exp(1j * (live[:, 2] - rows[:, 3])))
    assert np.abs(yaw_error).max() < 1e-6
    variance_x = np.array([m.pose.covariance[0] for m in odometry])
    assert np.abs(variance_x - rows[:, 5]).max() < 1e-6


@pytest.mark.parametrize('hogs_per_core', [1, 2])
def test_default_qos_on_a_starved_machine_ends_within_1_cm_of_the_offline_run_or_says_so(
        ros_harness, diagnostics_of, tmp_path, offline, hogs_per_core):
    odometry, values, log = _demo_pipeline(ros_harness, diagnostics_of, tmp_path, False,
                                           hogs_per_core, offline[-1, 0])
    assert values['resets'] == '0' and 'filter reset' not in log
    # Lost messages are never late ones: what arrives is in order within its topic, and
    # no input that still sends goes stale.
    assert values['dropped_late'] == '0', log
    rows, live = _offline_rows(offline, odometry[-1:])
    error = math.hypot(*(live[0, :2] - rows[0, 1:3]))
    if error >= 0.01:
        # Starved beyond what its queues absorb (a slower machine, or another copy of the
        # suite beside this one), the node lost inputs and its pose went off: then it must
        # say so, never end off with the verdict ok (on 2026-12-02 such a run ended 5.4 m
        # off; what it said is checked here, not how starved the machine was).
        assert values['verdict'] != 'ok', (error, values)
        assert 'arrived' in values['verdict_reasons'], (error, values['verdict_reasons'])
