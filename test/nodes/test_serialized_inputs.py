"""The nodes on their serialized path fed bytes that are no message: dropped, counted, alive.

Each node reads its sensor inputs as CDR bytes (nodes/wire.py). A publisher of the right
type sends garbage bytes (``publish`` of ``bytes`` is rclpy's raw publication), then a good
message; the node counts the garbage as ``dropped_malformed`` and processes the good one.
Each test uses its own namespace and stamps, and checks only its own node's outputs.
"""

from __future__ import annotations

import pytest

from ekf_harness import EkfUnderTest

pytestmark = pytest.mark.ros

GARBAGE = (b'\x00\x01\x00\x00', b'\x00\x01\x00\x00' + b'\xff' * 40,
           b'\x00\x01\x00\x00\x05\x00\x00\x00')


def _imu(stamp_s: int, rate: float):
    from sensor_msgs.msg import Imu
    message = Imu()
    message.header.stamp.sec = stamp_s
    message.header.frame_id = 'imu'
    message.angular_velocity.z = rate
    return message


def test_garbage_bytes_on_imu_and_odom_are_dropped_as_malformed(ros_processes, diagnostics_of):
    from nav_msgs.msg import Odometry

    name = 'ekf_garbage'
    ekf = EkfUnderTest(ros_processes, diagnostics_of, name)
    # The good message's estimate is awaited on ekf/odometry: the node reports its readers
    # of it, so the harness can wait until the node's writer matched the probe's reader
    # (an estimate published before that never arrives).
    ekf.wait_for_node()
    for data in GARBAGE:
        ekf.imu.publish(data)
        ekf.odom.publish(data)
    speed = Odometry()
    speed.header.stamp.sec = 1_700_003_001
    ekf.odom.publish(speed)
    ekf.imu.publish(_imu(1_700_003_001, 0.25))
    ekf.probe.spin_until(lambda: any(m.header.stamp.sec == 1_700_003_001 for m in ekf.odometry),
                         20, 'the estimate of the good message')
    # The odometry's garbage is counted on arrival, in no order with the IMU's estimate once
    # the node's idle flush released the IMU sample: wait for every count.
    values = ekf.wait_for(lambda v: v.get('estimates') == '1'
                          and int(v.get('dropped_malformed') or 0) >= 2 * len(GARBAGE),
                          f'diagnostics after the messages: 1 estimate, {2 * len(GARBAGE)} '
                          'malformed')
    assert values['dropped_malformed'] == str(2 * len(GARBAGE))
    assert 'bytes are not a' in ekf.log()
    node = next(child for started, child in ekf.processes.started if started == name)
    assert node.poll() is None


def test_garbage_bytes_on_imu_are_dropped_by_the_calibration_node(ros_processes,
                                                                  diagnostics_of):
    from diagnostic_msgs.msg import DiagnosticArray
    from sensor_msgs.msg import Imu

    from gyro_ekf.nodes import qos

    processes, probe = ros_processes
    name = 'calibration_garbage'
    processes.node('calibration_node', '-r', f'__ns:=/{name}', '-p', 'reliable_inputs:=true',
                   '-p', 'use_odom:=false', '-p', 'diagnostics_period_s:=0.1', name=name)
    imu = probe.node.create_publisher(Imu, f'/{name}/imu', qos.LOSSLESS)
    diagnostics = probe.subscribe(DiagnosticArray, '/diagnostics', qos.LOSSLESS)
    probe.spin_until(lambda: imu.get_subscription_count() > 0, 20, 'calibration_node')
    for data in GARBAGE:
        imu.publish(data)
    imu.publish(_imu(1_700_004_001, 0.01))
    key = f'/{name}/calibration_node: gyro calibration'
    probe.spin_until(lambda: (diagnostics_of(diagnostics, key) or {}).get('imu_messages')
                     == '1', 20, 'diagnostics after the messages')
    assert diagnostics_of(diagnostics, key)['dropped_malformed'] == str(len(GARBAGE))


def test_garbage_bytes_on_scan_are_dropped_by_the_detector(ros_processes, diagnostics_of):
    from diagnostic_msgs.msg import DiagnosticArray
    from sensor_msgs.msg import LaserScan

    from gyro_ekf.nodes import qos

    processes, probe = ros_processes
    name = 'detector_garbage'
    node = processes.node('landmark_detector_node', '-r', f'__ns:=/{name}',
                          '-p', 'reliable_inputs:=true', '-p', 'diagnostics_period_s:=0.1',
                          name=name)
    scans = probe.node.create_publisher(LaserScan, f'/{name}/scan', qos.LOSSLESS)
    diagnostics = probe.subscribe(DiagnosticArray, '/diagnostics', qos.LOSSLESS)
    probe.spin_until(lambda: scans.get_subscription_count() > 0, 20, 'the detector')
    for data in GARBAGE:
        scans.publish(data)
    key = f'/{name}/landmark_detector_node: pole detector'
    probe.spin_until(lambda: (diagnostics_of(diagnostics, key) or {}).get('dropped_malformed')
                     == str(len(GARBAGE)), 20, 'the malformed scans counted')
    assert node.poll() is None
