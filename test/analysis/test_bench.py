"""The offline part of `make bench`, briefly: the run benchmark reports what the runs measured."""

from __future__ import annotations

from pathlib import Path

from benchmarks.bench import core_benchmark, run_benchmark

BUNDLED = Path(__file__).resolve().parents[2] / 'bags' / 'sim_moving_start'


def test_run_benchmark_reports_the_median_of_its_runs(tmp_path):
    result = run_benchmark(BUNDLED, tmp_path, repeats=3)
    assert result['exit_code'] == 0, result.get('stderr_tail')
    factors = sorted(run['real_time_factor'] for run in result['runs'])
    assert len(factors) == 3 and result['real_time_factor'] == factors[1]
    assert result['real_time_factor_min'] == factors[0]
    assert result['real_time_factor_max'] == factors[2]
    for run in result['runs']:
        assert run['trip_duration_s'] > 40.0
        assert 0.0 < run['read_s'] < run['processing_s']
        assert run['real_time_factor_wall'] < run['real_time_factor']


def test_core_benchmark_gives_filterpy_the_same_estimates():
    result = core_benchmark(steps=500)
    assert result['max_abs_state_difference'] < 1e-9
    assert result['max_abs_covariance_difference'] < 1e-9
    assert result['core_predict_us'] > 0.0 and result['filterpy_predict_us'] > 0.0


def test_the_table_shows_both_message_paths_and_the_replay():
    from benchmarks.bench import live_rows
    from benchmarks.replay_bench import replay_rows

    node_run = {'name': 'calibration_node 1000 Hz, rclpy messages', 'messages_sent': 10,
                'outputs_received': 9, 'node_cpu_us_per_message': 259.0,
                'node_cpu_share': 0.26, 'window_cpu_us_per_message': 199.6}
    rows = dict(live_rows({'runs': [], 'node_runs': [node_run]}))
    assert rows['live calibration_node 1000 Hz, rclpy messages: node CPU (us/msg)'] == (
        '259 (26% of a core, 1 outputs missing)')
    assert rows['live calibration_node 1000 Hz, rclpy messages: static window CPU (us/msg)'] \
        == '200'
    replay = {'rate': 10.0, 'node_io': 'serialized', 'measured': True,
              'calibration_bias_deg_s': -0.9707, 'offline_final_bias_deg_s': -0.9774,
              'ekf_final_bias_deg_s': -0.9762, 'ekf_minus_offline_deg_s': 0.0012,
              'calibration_processed_share': 0.975, 'ekf_processed_share': 0.995,
              'imu_messages_in_bag': 44578, 'ekf_gyro_lost': 223, 'ekf_verdict': 'ok',
              'goals': {'calibration_bias': False, 'ekf_bias': True,
                        'calibration_processed': False, 'ekf_processed': True}}
    rows = dict(replay_rows({'runs': [replay]}))
    name = 'replay x10, serialized nodes'
    assert rows[f'{name}: calibration bias (deg/s)'].endswith('MISSED)')
    assert rows[f'{name}: EKF final bias - run (deg/s)'] == '+0.0012 (-0.9762 vs -0.9774)'
    assert rows[f'{name}: IMU processed (calibration, EKF)'] == (
        '97.5 %, 99.5 % of 44578, MISSED')
    assert rows[f'{name}: EKF node says (IMU lost, verdict)'] == '223, ok'


def test_replay_bench_sends_the_map():
    """The replay into the nodes sends the landmark map: `gyro-ekf run` reads it from the
    bag, and an EKF without it associates nothing (its bias came from the stops alone)."""
    from benchmarks.replay_bench import replay_command
    from gyro_ekf import topics

    args = replay_command(Path('log2016'), 10.0)
    sent = args[args.index('--topics') + 1:args.index('--wait-for')]
    assert topics.LANDMARK_MAP in sent
    assert {topics.IMU, topics.ODOM, topics.INITIAL_POSE, 'scan'} <= set(sent)
