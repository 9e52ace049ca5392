"""ekf_node estimates a mis-mounted LiDAR's mount online: ekf/mounts, /diagnostics.

A replayed two-LiDAR bag whose rear LiDAR is stated 6 deg off its true yaw, through two
detector nodes and the EKF node, against `gyro-ekf run` on the same bag. In its own
module, so its processes run in their own ROS domain next to nobody else's.
"""

from __future__ import annotations

import json
import math

import pytest
from health_trips import two_lidar_trip

pytestmark = pytest.mark.ros

STATUS = 'ekf_node: gyro bias EKF'


def test_the_node_finds_the_mount_publishes_it_and_readmits_the_lidar(
        ros_processes, diagnostics_of, tmp_path):
    from diagnostic_msgs.msg import DiagnosticArray
    from geometry_msgs.msg import PoseArray

    from gyro_ekf.cli.main import main
    from gyro_ekf.io import read_bag
    from gyro_ekf.io.bag_writer import write_trip_bag
    from gyro_ekf.nodes import qos
    from gyro_ekf.nodes.conversions import quaternion_yaw

    # True rear mount: 0.3 m behind base_link, facing back; stated 6 deg off.
    bag = write_trip_bag(two_lidar_trip(seed=3, rear_yaw_error_deg=6.0), tmp_path / 'bag')
    assert main(['-q', 'run', str(bag), '-o', str(tmp_path / 'out'), '--no-progress',
                 '--no-plots', '--no-bag']) == 0
    offline = json.loads((tmp_path / 'out' / 'summary.json').read_text())
    offline_yaw = offline['online_mounts']['scan2']['used']['yaw_deg']
    assert offline_yaw == pytest.approx(180.0, abs=0.2)

    processes, probe = ros_processes
    diagnostics = probe.subscribe(DiagnosticArray, '/diagnostics', qos.LOSSLESS)
    mounts = probe.subscribe(PoseArray, 'ekf/mounts', qos.LATCHED)
    detectors = processes.two_lidar_nodes(bag)
    probe.spin_until(lambda: probe.node.count_publishers('/landmarks') == 2
                     and probe.node.count_subscribers('/landmarks') == 1
                     and len(mounts) >= 1, 20, 'two detectors, the EKF node and ekf/mounts')
    probe.wait_for_landmarks_readers(diagnostics, detectors)
    # First the stated mounts.
    stated = mounts[0].poses[1]
    assert quaternion_yaw(stated.orientation) == pytest.approx(
        math.remainder(math.pi + math.radians(6.0), 2 * math.pi), abs=1e-9)
    replay = processes.replay_two_lidar_bag(bag)
    assert 'all acknowledged: True' in replay
    n_imu = str(len(read_bag(bag).trip.imu.stamp_s))
    probe.spin_until(lambda: (diagnostics_of(diagnostics, STATUS) or {}).get('estimates')
                     == n_imu, 60, f'{n_imu} estimates in /diagnostics')
    seen = len(diagnostics)
    probe.spin_until(lambda: len(diagnostics) >= seen + 2, 10, 'two more diagnostics')
    values = diagnostics_of(diagnostics, STATUS)
    assert values['mount_scan2_online'] == 'confirmed'
    assert values['body_frame_lidar'] == 'scan'
    assert float(values['mount_scan2_online_yaw_sigma_deg']) < 0.01
    assert (float(values['mount_scan2_online_yaw_sigma_with_heading_deg'])
            >= float(values['mount_scan2_online_yaw_sigma_deg']))
    # A mount estimated online weighs a ninth, live as offline.
    assert offline['online_mounts']['scan2']['noise_scale'] == 9.0
    assert values['mount_scan2_online_noise_scale'] == '9'
    assert values['mount_scan2_online_noise_scale_reason'] == 'estimated online'
    yaw_deg = float(values['mount_scan2_yaw_deg'])
    assert math.remainder(yaw_deg - 180.0, 360.0) == pytest.approx(0.0, abs=0.2)
    # The same estimate as the offline run (scans sharing a stamp may come in either order).
    assert math.remainder(yaw_deg - offline_yaw, 360.0) == pytest.approx(0.0, abs=0.05)
    assert float(values['mount_scan2_x_m']) == pytest.approx(-0.3, abs=0.01)
    assert values['lidar_scan2_excluded'] == 'false'
    assert values['mount_scan_yaw_deg'] == '0.000'
    # A yaw is not a shift of the body frame: the pose is not published between the two.
    assert values['mount_scan2_online_right_share'] == ''
    assert values['mount_scan2_online_widened_m'] == ''
    # ekf/mounts was published again with the estimated mount; the first LiDAR's stays.
    front, rear = mounts[-1].poses
    assert len(mounts) >= 2
    assert (front.position.x, quaternion_yaw(front.orientation)) == (0.46, 0.0)
    assert math.remainder(quaternion_yaw(rear.orientation) - math.pi, 2 * math.pi) == (
        pytest.approx(0.0, abs=math.radians(0.2)))
    assert rear.position.x == pytest.approx(-0.3, abs=0.01)
