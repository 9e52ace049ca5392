"""ekf_node hands the body frame over when the first LiDAR disagrees with the map.

A replayed two-LiDAR bag whose FIRST LiDAR is mounted 5 deg off its stated yaw, through two
detector nodes and the EKF node, against `gyro-ekf run` on the same bag: the rear LiDAR
takes over defining the body frame, the first one's mount is estimated online, and
/diagnostics says so as summary.json does. In its own module, so its processes run in their
own ROS domain next to nobody else's.
"""

from __future__ import annotations

import json
import math

import pytest

pytestmark = pytest.mark.ros

STATUS = 'ekf_node: gyro bias EKF'


def test_the_node_hands_the_body_frame_over_and_says_so(
        ros_processes, diagnostics_of, tmp_path):
    from diagnostic_msgs.msg import DiagnosticArray

    from gyro_ekf.cli.main import main
    from gyro_ekf.core.simulator import SimulationConfig, simulate_trip
    from gyro_ekf.io import read_bag
    from gyro_ekf.io.bag_writer import write_trip_bag
    from gyro_ekf.nodes import qos

    trip = simulate_trip(SimulationConfig(duration_s=30.0, second_lidar=True,
                                          lidar_yaw_error_rad=math.radians(5.0)), 51)
    bag = write_trip_bag(trip, tmp_path / 'bag')
    assert main(['-q', 'run', str(bag), '-o', str(tmp_path / 'out'), '--no-progress',
                 '--no-plots', '--no-bag']) == 0
    offline = json.loads((tmp_path / 'out' / 'summary.json').read_text())
    assert set(offline['online_mounts']) == {'scan'}
    assert offline['online_mounts']['scan']['handed_over_s'] is not None

    processes, probe = ros_processes
    diagnostics = probe.subscribe(DiagnosticArray, '/diagnostics', qos.LOSSLESS)
    detectors = processes.two_lidar_nodes(bag)
    probe.spin_until(lambda: probe.node.count_publishers('/landmarks') == 2
                     and probe.node.count_subscribers('/landmarks') == 1
                     and (diagnostics_of(diagnostics, STATUS) or {}).get('body_frame_lidar')
                     == 'scan', 20, 'two detectors and the EKF node, scan defining the frame')
    probe.wait_for_landmarks_readers(diagnostics, detectors)
    replay = processes.replay_two_lidar_bag(bag)
    assert 'all acknowledged: True' in replay
    n_imu = str(len(read_bag(bag).trip.imu.stamp_s))
    probe.spin_until(lambda: (diagnostics_of(diagnostics, STATUS) or {}).get('estimates')
                     == n_imu, 60, f'{n_imu} estimates in /diagnostics')
    seen = len(diagnostics)
    probe.spin_until(lambda: len(diagnostics) >= seen + 2, 10, 'two more diagnostics')
    values = diagnostics_of(diagnostics, STATUS)
    assert values['body_frame_lidar'] == 'scan2'
    assert values['mount_scan_online'] == offline['online_mounts']['scan']['state']
    # The same verdict and reasons as the offline run.
    assert values['verdict'] == offline['health']['verdict'] == 'degraded'
    assert 'scan2 defines the body frame' in values['verdict_reasons']
    yaw_deg = float(values['mount_scan_yaw_deg'])
    assert yaw_deg == pytest.approx(5.0, abs=0.2)
    assert yaw_deg == pytest.approx(offline['online_mounts']['scan']['used']['yaw_deg'],
                                    abs=0.05)
