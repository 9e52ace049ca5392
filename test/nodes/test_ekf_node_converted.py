"""ekf_node given the params sidecar of a bag `gyro-ekf convert --skip-bad` wrote.

The sidecar records what the conversion dropped from the log (trip.dropped_when_converted);
`gyro-ekf run` on the bag counts it and is degraded, and so must the live node's verdict in
/diagnostics be. Bags are written by the real `convert` in its own process, and each node,
in a namespace of its own, is fed IMU and odometry messages by the test itself.
"""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from ekf_harness import EkfUnderTest, STEP_NS

pytestmark = pytest.mark.ros

N_PAIRS = 50


@pytest.fixture(scope='module')
def converted(ros_processes, tmp_path_factory):
    """Bags of one simulated log converted with and without two NaN gyro samples.

    Returns the bag convert --skip-bad wrote, the clean log's bag and the reasons of the
    verdict `gyro-ekf run` gives on the first.
    """
    from gyro_ekf.core.simulator import SimulationConfig, simulate_trip
    from gyro_ekf.io.trip_file import save_trip

    processes, _ = ros_processes
    folder = tmp_path_factory.mktemp('converted')
    trip = simulate_trip(SimulationConfig(duration_s=10.0, static_s=5.0), seed=4)
    rates = trip.imu.angular_velocity_rad_s.copy()
    rates[[300, 301], 2] = np.nan
    bad_log = save_trip(dataclasses.replace(trip, imu=dataclasses.replace(
        trip.imu, angular_velocity_rad_s=rates)), folder / 'trip.npz')
    clean_log = save_trip(trip, folder / 'clean.npz')
    bags = {}
    for name, log, options in (('dropped', bad_log, ['--skip-bad']),
                               ('clean', clean_log, [])):
        bags[name] = folder / name
        processes.run(f'convert_{name}', 'gyro_ekf.cli.main', '-q', 'convert', str(log),
                      '-o', str(bags[name]), *options, timeout_s=120)
    processes.run('run_dropped', 'gyro_ekf.cli.main', '-q', 'run', str(bags['dropped']),
                  '-o', str(folder / 'run'), '--no-plots', '--no-bag', '--no-progress',
                  timeout_s=300)
    health = json.loads((folder / 'run' / 'summary.json').read_text())['health']
    return bags['dropped'], bags['clean'], health


def _node_on(ros_processes, diagnostics_of, name: str, bag) -> EkfUnderTest:
    """Start an ekf_node with the bag's sidecar, feed it IMU and odometry, return it."""
    ekf = EkfUnderTest(ros_processes, diagnostics_of, name,
                       node_args=('--params-file', f'{bag}.params.yaml'))
    ekf.wait_for_node()
    start = 1_700_000_001 * 10 ** 9  # 1 s after the sidecar's time zero
    for i in range(N_PAIRS):
        ekf.send_odom(start + i * STEP_NS)
        ekf.send_imu(start + i * STEP_NS)
    ekf.wait_for(lambda v: int(v.get('estimates') or 0) >= N_PAIRS, 'every sample processed')
    return ekf


def test_the_verdict_counts_what_convert_skip_bad_dropped_from_the_bag_log(
        ros_processes, diagnostics_of, converted):
    # The node used to take the record without a warning and ignore it: a live replay of
    # the bag said ok where `gyro-ekf run` said degraded.
    dropped_bag, _, offline = converted
    reason = ('input dropped when the log was converted (gyro-ekf convert --skip-bad on '
              'trip.npz): 2 (imu samples 2), more than 0')
    assert offline['verdict'] == 'degraded' and reason in offline['reasons'], offline
    values = _node_on(ros_processes, diagnostics_of, 'converted_dropped', dropped_bag).values()
    assert values['verdict'] == 'degraded', values
    assert reason in values['verdict_reasons'].split(' | '), values['verdict_reasons']
    assert values['dropped_when_converted'] == '2'
    assert values['dropped_when_converted_imu'] == '2'
    assert values['converted_from'] == 'trip.npz'
    assert values['dropped_non_finite'] == '0'  # nothing dropped by the node itself


def test_without_a_conversion_record_the_verdict_names_no_conversion_drop(
        ros_processes, diagnostics_of, converted):
    _, clean_bag, _ = converted
    values = _node_on(ros_processes, diagnostics_of, 'converted_clean', clean_bag).values()
    assert 'converted' not in values['verdict_reasons'], values['verdict_reasons']
    # A few seconds of samples and no stop: the bias is not pinned down, the one thing said.
    assert values['verdict'] == 'degraded', values
    assert values['verdict_reasons'].startswith('the gyro bias is known only to +-2.0000 '
                                                'deg/s'), values['verdict_reasons']
    assert ' | ' not in values['verdict_reasons'], values['verdict_reasons']
    assert values['dropped_when_converted'] == '0'
    assert values['converted_from'] == ''
    assert not any(key.startswith('dropped_when_converted_') for key in values), values


@pytest.mark.parametrize('case, old, new, words', [
    pytest.param('negative', 'counts:\n        - 2\n', 'counts:\n        - -2\n',
                 "parameter 'trip.dropped_when_converted.counts' must be a list of "
                 'non-negative whole numbers, got -2 in it', id='negative'),
    pytest.param('missing', '        source: trip.npz\n', '',
                 "parameter 'trip.dropped_when_converted.source' is missing", id='missing'),
])
def test_a_damaged_conversion_record_stops_the_node_naming_the_parameter(
        ros_processes, converted, tmp_path, case, old, new, words):
    # As `gyro-ekf run` refuses the bag: a record the node cannot read is no "nothing
    # dropped" (the node used to ignore it, whatever it said).
    import time

    from gyro_ekf.io.sidecar import sidecar_path

    processes, _ = ros_processes
    text = sidecar_path(converted[0]).read_text()
    assert text.count(old) == 1, text
    damaged = tmp_path / 'damaged.params.yaml'
    damaged.write_text(text.replace(old, new))
    name = f'damaged_{case}'
    node = processes.node('ekf_node', '-r', f'__ns:=/{name}', '--params-file', str(damaged),
                          name=name)
    deadline = time.monotonic() + 120.0
    # Polling its log file (exit or ready), not waiting for discovery.
    while node.poll() is None and 'EKF ready' not in processes.log(name):
        assert time.monotonic() < deadline, f'the node neither stopped nor started:\n' \
            f'{processes.log(name)}'
        time.sleep(0.05)
    assert 'EKF ready' not in processes.log(name), processes.log(name)
    assert node.wait(timeout=30) == 1, processes.log(name)
    lines = processes.log(name).strip().splitlines()
    assert lines == [f'[FATAL] node /{name}/ekf_node: {words}'], lines
