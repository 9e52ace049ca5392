"""calibration_node fed implausible rates and a first message far ahead: dropped, counted,
and the window still completes. The test checks only its own node's bias and diagnostics."""

from __future__ import annotations

import math

import pytest

pytestmark = pytest.mark.ros


def _imu(stamp_ns: int, rates: tuple[float, float, float]):
    from sensor_msgs.msg import Imu

    message = Imu()
    message.header.stamp.sec, message.header.stamp.nanosec = divmod(stamp_ns, 10 ** 9)
    w = message.angular_velocity
    w.x, w.y, w.z = rates
    return message


def test_bad_rates_and_a_first_stamp_far_ahead_leave_the_window_intact(
        ros_processes, diagnostics_of):
    from diagnostic_msgs.msg import DiagnosticArray
    from geometry_msgs.msg import Vector3Stamped
    from sensor_msgs.msg import Imu

    from gyro_ekf.nodes import qos

    processes, probe = ros_processes
    name = 'calibration_bad'
    processes.node('calibration_node', '-r', f'__ns:=/{name}', '-p', 'reliable_inputs:=true',
                   '-p', 'use_odom:=false', '-p', 'diagnostics_period_s:=0.1', name=name)
    imu = probe.node.create_publisher(Imu, f'/{name}/imu', qos.LOSSLESS)
    bias = probe.subscribe(Vector3Stamped, f'/{name}/gyro_bias', qos.LATCHED)
    diagnostics = probe.subscribe(DiagnosticArray, '/diagnostics', qos.LOSSLESS)
    probe.spin_until(lambda: imu.get_subscription_count() > 0, 20, 'the calibration node')
    start = 1_700_003_000 * 10 ** 9
    true_bias = (0.01, -0.02, 0.03)
    # Before: a first message 100 s ahead set where the window starts, and every later
    # sample was "before the window" for 100 s.
    imu.publish(_imu(start + 100 * 10 ** 9, true_bias))
    for k in range(700):  # 7 s at 100 Hz
        stamp = start + k * 10_000_000
        if k == 100:
            imu.publish(_imu(stamp + 1, (1e300, 0.0, 0.0)))
            imu.publish(_imu(stamp + 2, (0.0, math.nan, 0.0)))
        imu.publish(_imu(stamp, true_bias))
    probe.spin_until(lambda: bias, 30, 'the bias')
    assert [bias[0].vector.x, bias[0].vector.y, bias[0].vector.z] == pytest.approx(true_bias)
    key = f'/{name}/calibration_node: gyro calibration'
    probe.spin_until(lambda: (diagnostics_of(diagnostics, key) or {}).get('state')
                     == 'calibrated', 20, 'the calibrated state')
    values = diagnostics_of(diagnostics, key)
    assert values['dropped_out_of_range'] == '1'
    assert values['dropped_non_finite'] == '1'
    assert values['dropped_stamp_jump'] == '1'
    assert values['refused_windows'] == '0'
