"""ekf_node's health verdict in /diagnostics, on a replayed two-LiDAR bag with one LiDAR
mis-mounted, against the verdict `gyro-ekf run` writes in summary.json for the same bag.

In its own module, so its processes run in their own ROS domain next to nobody else's.
"""

from __future__ import annotations

import json

import pytest
from health_trips import two_lidar_trip

pytestmark = pytest.mark.ros


@pytest.fixture(scope='module')
def mis_mounted_run(ros_processes, tmp_path_factory):
    """The bag through two detector nodes and the EKF node, and through `gyro-ekf run`."""
    from diagnostic_msgs.msg import DiagnosticArray

    from gyro_ekf.cli.main import main
    from gyro_ekf.io import read_bag
    from gyro_ekf.io.bag_writer import write_trip_bag
    from gyro_ekf.nodes import qos

    tmp = tmp_path_factory.mktemp('health')
    # The rear LiDAR's stated yaw is 6 deg off its true mount. The monitor alone: online
    # mount calibration would readmit it (test/core/test_mount_online.py).
    bag = write_trip_bag(two_lidar_trip(seed=3, rear_yaw_error_deg=6.0), tmp / 'bag')
    off = tmp / 'off.yaml'
    off.write_text('/**:\n  ros__parameters:\n    mount_online_yaw_sigma_rad: 0.0\n')
    assert main(['-q', 'run', str(bag), '-o', str(tmp / 'out'), '--no-progress',
                 '--no-plots', '--no-bag', '--params-file', str(off)]) == 0
    offline = json.loads((tmp / 'out' / 'summary.json').read_text())['health']

    processes, probe = ros_processes
    diagnostics = probe.subscribe(DiagnosticArray, '/diagnostics', qos.LOSSLESS)
    detectors = processes.two_lidar_nodes(bag, '--params-file', str(off))
    probe.wait_for_lidar_nodes(diagnostics, detectors)
    replay = processes.replay_two_lidar_bag(bag)
    status = probe.wait_for_every_estimate(diagnostics, len(read_bag(bag).trip.imu.stamp_s))
    return offline, status, replay, processes.log('ekf_node')


def test_node_reports_the_verdict_summary_json_gives(mis_mounted_run):
    from diagnostic_msgs.msg import DiagnosticStatus

    offline, (level, message, values), replay, _ = mis_mounted_run
    assert 'all acknowledged: True' in replay
    assert offline['verdict'] == 'degraded'
    assert values['verdict'] == 'degraded'
    assert level == DiagnosticStatus.WARN
    reasons = values['verdict_reasons'].split(' | ')
    print('node:', reasons, '\noffline:', offline['reasons'])
    assert len(reasons) == len(offline['reasons'])
    # Scans of the two LiDARs that share a stamp reach the node in either order, so the
    # exclusion may come one scan apart from the offline run's: the time excluded is
    # compared to 0.1 s, every other reason word for word.
    prefix = 'LiDAR scan2 excluded 1 time(s), '
    assert reasons[0].startswith(prefix) and offline['reasons'][0].startswith(prefix)
    node_s, offline_s = (float(r[len(prefix):].split(' s in all')[0])
                         for r in (reasons[0], offline['reasons'][0]))
    assert abs(node_s - offline_s) <= 0.11
    assert reasons[0].split(' s in all')[1] == offline['reasons'][0].split(' s in all')[1]
    assert reasons[1:] == offline['reasons'][1:]
    assert message.startswith('degraded: LiDAR scan2 excluded')
    # The online odometry estimate is reported as the mounts are: exact odometry, kept.
    assert values['odometry_scale'] == '1.00000' and values['odometry_scale_applied'] == '0'
    assert values['odometry_first_lidar_offset_applied'] == '0'
    # How far the scale may be off (the walk it adds): at most the prior, once fitted.
    assert 0.0 < float(values['odometry_scale_uncertainty']) <= 0.01


def test_node_reports_the_excluded_lidar_and_logs_it(mis_mounted_run):
    offline, (_, _, values), _, log = mis_mounted_run
    assert values['lidar_scan2_excluded'] == 'true'
    assert values['lidar_scan_excluded'] == 'false'
    assert values['lidar_scan2_exclusions'] == '1'
    assert values['lidar_scan2_disagreement'].startswith('associates 0% of its detections')
    assert int(values['excluded_detections']) > 0
    assert 'LiDAR scan2 excluded at' in log
    assert [lidar['name'] for lidar in offline['lidars']] == ['scan', 'scan2']
    # Both LiDARs turn as the gyro does (a stated yaw 6 deg off does not turn the other
    # way: core/turn_sign.py), and no mapped pole stands elsewhere (core/map_poles.py).
    for name in ('scan', 'scan2'):
        assert int(values[f'turn_sign_{name}_votes']) >= 10
        assert values[f'turn_sign_{name}_opposite'] == '0'
    assert values['map_poles_elsewhere'] == '0'
