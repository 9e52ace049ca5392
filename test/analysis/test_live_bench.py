"""The live benchmark's plumbing: ekf_node in a child process, poses matched to the steps sent.

Only what holds on a machine of any speed is asserted here: how sends complete steps, that
poses come back and are matched to the steps by stamp, and that the accounting adds up.
Latency, loss and CPU figures are for `make bench` (results/bench.json), not for tests.
"""

from __future__ import annotations

import os

import numpy as np
import pytest

pytestmark = pytest.mark.ros

MIN_WAIT_S = 90.0
"""Shortest wait for the node before a run is cut short: test/nodes/conftest.py's MIN_WAIT_S
(with a second copy of the suite on the same two cores a message can take tens of seconds).
The bench's own bounds are shorter; passed to live_suite, these let every count settle."""
WAITS = {'startup_timeout_s': MIN_WAIT_S, 'settle_timeout_s': MIN_WAIT_S}


def test_completion_follows_the_release_rule():
    from benchmarks.live_bench import completion_indices

    period = 10_000_000
    streams = ['odom', 'imu'] * 6
    stamps = np.repeat(np.arange(6) * period, 2)
    targets = np.arange(6) * period
    # No window: each imu message (odd index) completes its own step; the very first odom
    # message releases step 0 itself, as the node has seen no imu stream yet.
    assert completion_indices(streams, stamps, 0.0, 0, targets).tolist() == [0, 3, 5, 7, 9, 11]
    # A 25 ms window: step k waits for the odom message of step k + 3; the last three never.
    windowed = completion_indices(streams, stamps, 0.025, 0, targets)
    assert windowed.tolist() == [6, 8, 10, -1, -1, -1]


def test_observations_in_stamp_order_hold_each_step_until_the_next_scan():
    from benchmarks.live_bench import completion_indices

    period = 10_000_000
    # Observations at steps 0 and 3, sent before that step's odom and imu (as the bench does).
    streams, stamps = [], []
    for step in range(6):
        if step % 3 == 0:
            streams.append('landmarks')
            stamps.append(step * period)
        streams += ['odom', 'imu']
        stamps += [step * period] * 2
    stamps = np.array(stamps)
    targets = np.arange(6) * period
    # Held in stamp order: the first message releases step 0 (no other stream seen yet);
    # steps 1 and 2 wait for the scan of step 3 (index 7), step 3 for its imu (index 9),
    # steps 4 and 5 for a scan never sent (the node's idle flush lets them out).
    held = completion_indices(streams, stamps, 0.0, 0, targets)
    assert held.tolist() == [0, 7, 7, 9, -1, -1]
    # Replayed when late, observations are left out of the release: each imu completes its
    # own step, as in the case without observations.
    kept = [i for i, stream in enumerate(streams) if stream != 'landmarks']
    replayed = completion_indices([streams[i] for i in kept], stamps[kept], 0.0, 0, targets)
    assert [kept[i] for i in replayed.tolist()] == [1, 4, 6, 9, 11, 13]


def _check_measured(run):
    """What must hold of a measured run however loaded the machine is."""
    assert run['measured'], run.get('error', '') + run.get('node_log_tail', '')
    # The warm-up only ends once poses come back, so the measured phase matches some of its
    # own steps by stamp.
    assert run['poses_received'] > 0
    # Causality, not speed: a pose cannot leave the node before its IMU message was sent, so
    # a latency at or below zero means poses were matched to the wrong steps.
    if run['poses_received'] > run['poses_released_by_idle_flush']:
        assert run['latency_ms']['p50'] > 0.0
    # CPU is read from /proc in clock ticks.
    ticks = run['node_cpu_s'] / run['cpu_clock_tick_s']
    assert ticks >= 0 and ticks == pytest.approx(round(ticks), abs=1e-6)
    # The node's own counters came back through /diagnostics.
    assert run['node']['estimates'] > 0


def test_a_short_live_run_matches_poses_to_the_steps_sent(ros_env):
    from benchmarks.live_bench import LiveCase, live_suite

    results = live_suite((LiveCase(200.0, 1.0, warmup_s=0.5),),
                         domain_id=int(ros_env['ROS_DOMAIN_ID']), **WAITS)
    assert results['domain_id'] == int(ros_env['ROS_DOMAIN_ID'])
    run = results['runs'][0]
    assert results['measured'], run.get('error', '') + run.get('node_log_tail', '')
    assert run['steps'] == 200 and run['messages_sent'] == 400
    _check_measured(run)
    # The node publishes one pose per step; a second pose of a stamp would come from another
    # run sending the same stamps in the same domain.
    assert run['duplicate_poses'] == 0


def test_observations_reach_the_filter_in_both_release_modes(ros_env):
    from benchmarks.live_bench import LiveCase, live_suite

    # How long poses wait in either mode is a `make bench` figure (the two landmark cases).
    cases = (LiveCase(200.0, 1.0, landmarks_hz=10.0, warmup_s=0.5),
             LiveCase(200.0, 1.0, landmarks_hz=10.0, warmup_s=0.5,
                      late_observation_history_s=0.5))
    results = live_suite(cases, domain_id=int(ros_env['ROS_DOMAIN_ID']), **WAITS)
    assert results['measured'], [r.get('error', '') + r.get('node_log_tail', '')
                                 for r in results['runs']]
    strict, lagged = results['runs']
    for run in (strict, lagged):
        assert run['messages_sent'] == 2 * 200 + 10
        _check_measured(run)
        # The poles lie where the map has them, seen from the known initial pose.
        assert run['node']['associated'] > 0
    assert 'replayed_observations' not in strict['node']
    assert 'replayed_observations' in lagged['node']


def test_the_bench_claims_a_domain_of_its_own_and_gives_it_back(monkeypatch):
    from benchmarks.live_bench import ros_environment
    from gyro_ekf.ros_env import try_claim

    monkeypatch.setenv('ROS_DOMAIN_ID', '42')
    with ros_environment() as env:
        domain = int(env['ROS_DOMAIN_ID'])
        assert domain != 42 and env['ROS_AUTOMATIC_DISCOVERY_RANGE'] == 'LOCALHOST'
        assert try_claim(domain) is None  # nobody else gets it meanwhile
    again = try_claim(domain)
    assert again is not None
    again.release()
    assert os.environ['ROS_DOMAIN_ID'] == '42'  # the caller's environment is restored


def test_both_message_paths_publish_pose_odometry_and_bias_for_every_step(ros_env):
    from benchmarks.live_bench import LiveCase, live_suite

    cases = tuple(LiveCase(200.0, 1.0, warmup_s=0.5, node_io=io)
                  for io in ('serialized', 'rclpy'))
    results = live_suite(cases, domain_id=int(ros_env['ROS_DOMAIN_ID']), **WAITS)
    assert results['measured'], [r.get('error', '') + r.get('node_log_tail', '')
                                 for r in results['runs']]
    for run in results['runs']:
        _check_measured(run)
        # The bench subscribes to odometry and bias, so the node publishes them too (it
        # skips outputs nobody reads); each is one message per estimate, like the pose.
        outputs = run['outputs_received']
        assert set(outputs) == {'ekf/odometry', 'ekf/bias'}
        assert all(0 < count <= run['node']['estimates'] for count in outputs.values())
    assert [run['name'] for run in results['runs']] == ['200 Hz', '200 Hz, rclpy messages']


@pytest.mark.parametrize('node', ['calibration_node', 'landmark_detector_node'])
@pytest.mark.parametrize('node_io', ['serialized', 'rclpy'])
def test_calibration_and_detector_cases_count_every_output(ros_env, node, node_io):
    from benchmarks.live_bench import CALIBRATION_WINDOW_S, live_suite, NodeCase

    case = NodeCase(node, 200.0 if node == 'calibration_node' else 20.0, 1.0, node_io,
                    reliable_inputs=True)
    results = live_suite((), domain_id=int(ros_env['ROS_DOMAIN_ID']), node_cases=(case,),
                         **WAITS)
    run = results['node_runs'][0]
    assert results['measured'], run.get('error', '') + run.get('node_log_tail', '')
    # Counts, not rates: the case sends exactly rate x duration messages of its own, and with
    # reliable keep-all inputs every one is processed, one output each.
    assert run['messages_sent'] == round(case.rate_hz * case.duration_s)
    assert run['outputs_received'] == run['messages_sent']
    ticks = run['node_cpu_s'] / run['cpu_clock_tick_s']
    assert ticks >= 0 and ticks == pytest.approx(round(ticks), abs=1e-6)
    if node == 'calibration_node':
        # The bias needs CALIBRATION_WINDOW_S of stamps (spaced 1/rate apart, however slow the
        # machine), so at least that many of the case's messages went out before it.
        assert run['window_messages'] >= CALIBRATION_WINDOW_S * case.rate_hz
