"""ekf_node takes a calibrate-mounts params file's mounts and shows them (diagnostics, topic)."""

from __future__ import annotations

import math

import pytest
import yaml

pytestmark = pytest.mark.ros


def test_the_calibrated_mounts_override_the_bags_and_appear_in_diagnostics(
        ros_processes, diagnostics_of, tmp_path):
    from diagnostic_msgs.msg import DiagnosticArray
    from geometry_msgs.msg import PoseArray

    from gyro_ekf.cli.main import main
    from gyro_ekf.nodes import qos
    from gyro_ekf.nodes.conversions import quaternion_yaw

    bag = tmp_path / 'sim'
    assert main(['-q', 'simulate', '-o', str(bag), '--seed', '51', '--duration-s', '20',
                 '--second-lidar', '--lidar2-yaw-error-deg', '-6']) == 0
    mounts = tmp_path / 'mounts.yaml'
    assert main(['-q', 'calibrate-mounts', str(bag), '-o', str(mounts)]) == 0
    written = yaml.safe_load(mounts.read_text())['/**']['ros__parameters']['lidar']['scan2']
    assert math.degrees(written['yaw_rad']) == pytest.approx(174.0, abs=0.2)

    processes, probe = ros_processes
    diagnostics = probe.subscribe(DiagnosticArray, '/diagnostics', qos.LOSSLESS)
    latched = probe.subscribe(PoseArray, 'ekf/mounts', qos.LATCHED)
    # The later params file wins: the bag's sidecar states 180 deg for scan2.
    processes.node('ekf_node', '--params-file', f'{bag}.params.yaml', '--params-file',
                   str(mounts), '-p', 'diagnostics_period_s:=0.2', '-r',
                   '__node:=ekf_node_mounts')
    key = 'ekf_node_mounts: gyro bias EKF'
    probe.spin_until(lambda: diagnostics_of(diagnostics, key) is not None, 120,
                     'diagnostics of the EKF node')
    values = diagnostics_of(diagnostics, key)
    assert values['mount_scan2_frame_id'] == 'laser2'
    assert float(values['mount_scan2_yaw_deg']) == pytest.approx(
        math.degrees(written['yaw_rad']), abs=0.001)
    assert float(values['mount_scan2_x_m']) == pytest.approx(written['x_m'], abs=1e-4)
    assert float(values['mount_scan2_y_m']) == pytest.approx(written['y_m'], abs=1e-4)
    assert (values['mount_scan_x_m'], values['mount_scan_yaw_deg']) == ('0.4600', '0.000')
    # Every LiDAR but the first has its mount estimated online; no data yet: no estimate.
    assert values['mount_scan2_online'] == 'acquiring'
    assert values['mount_scan2_online_yaw_sigma_deg'] == ''
    assert values['mount_scan2_online_noise_scale'] == '1'
    assert values['mount_scan2_online_pulls'] == 'false'
    assert values['mount_scan2_online_first_pulls'] == 'false'
    assert values['mount_scan2_online_noise_scale_reason'] == ''
    assert 'mount_scan_online' not in values

    probe.spin_until(lambda: len(latched) >= 1, 60, 'the latched ekf/mounts')
    (message,) = latched
    assert message.header.frame_id == 'base_link'
    (front, rear) = message.poses
    assert (front.position.x, front.position.y, quaternion_yaw(front.orientation)) == (
        0.46, 0.0, 0.0)
    assert (rear.position.x, rear.position.y) == (written['x_m'], written['y_m'])
    assert math.remainder(quaternion_yaw(rear.orientation) - written['yaw_rad'],
                          2 * math.pi) == pytest.approx(0.0, abs=1e-9)
