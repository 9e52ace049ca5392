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


def test_the_static_window_takes_one_sample_per_stamp(ros_processes, diagnostics_of):
    """Two nodes fed one still platform, one with a second message at four stamps.

    Per input: an exact repeat is counted as a duplicate, other values as same_stamp, and
    the window takes the first message alone. Before, it took both: an IMU sample twice
    moved the mean, and a second odometry speed of 1 m/s at a stamp refused the window.
    """
    import re

    from diagnostic_msgs.msg import DiagnosticArray
    from geometry_msgs.msg import Vector3Stamped
    from nav_msgs.msg import Odometry
    from sensor_msgs.msg import Imu

    from gyro_ekf.nodes import qos

    processes, probe = ros_processes
    diagnostics = probe.subscribe(DiagnosticArray, '/diagnostics', qos.LOSSLESS)
    start = 1_700_003_100 * 10 ** 9
    nodes = {}
    for name in ('calibration_once', 'calibration_twice'):
        processes.node('calibration_node', '-r', f'__ns:=/{name}',
                       '-p', 'reliable_inputs:=true', '-p', 'diagnostics_period_s:=0.1',
                       name=name)
        imu = probe.node.create_publisher(Imu, f'/{name}/imu', qos.LOSSLESS)
        odom = probe.node.create_publisher(Odometry, f'/{name}/odom', qos.LOSSLESS)
        bias = probe.subscribe(Vector3Stamped, f'/{name}/gyro_bias', qos.LATCHED)
        probe.spin_until(lambda: imu.get_subscription_count() > 0
                         and odom.get_subscription_count() > 0, 20, f'the node {name}')
        nodes[name] = (imu, odom, bias)

    def speed(stamp_ns: int, speed_m_s: float):
        message = Odometry()
        message.header.stamp.sec, message.header.stamp.nanosec = divmod(stamp_ns, 10 ** 9)
        message.twist.twist.linear.x = speed_m_s
        return message

    def rates(k: int, more: float = 0.0) -> tuple[float, float, float]:
        return (0.01, -0.02, 0.03 + 0.002 * (k % 5 - 2) + more)  # a repeat moves the mean

    # The odometry first, and its repeats counted, before any IMU sample: the node reads
    # odometry only until the window is taken, and its two inputs' callbacks need not run
    # in publishing order (under load the IMU's ran seconds of stamps ahead, the window
    # closed, and the odometry's repeats were never read).
    for name, (_, odom, _) in nodes.items():
        twice = name == 'calibration_twice'
        for k in range(1200):  # 12 s at 100 Hz: a window refused at 5 s is taken again
            stamp = start + k * 10_000_000
            odom.publish(speed(stamp, 0.0))
            if twice and k in (200, 210):  # moving at 1 m/s; an exact repeat
                odom.publish(speed(stamp, 1.0 if k == 200 else 0.0))
    odom_key = '/calibration_twice/calibration_node: gyro calibration'
    probe.spin_until(lambda: (diagnostics_of(diagnostics, odom_key) or {}).get(
        'dropped_duplicate') == '1' and diagnostics_of(diagnostics, odom_key).get(
        'dropped_same_stamp') == '1', 20, 'the odometry repeats counted')
    for name, (imu, _, _) in nodes.items():
        twice = name == 'calibration_twice'
        for k in range(1200):
            stamp = start + k * 10_000_000
            imu.publish(_imu(stamp, rates(k)))
            if twice and k in (300, 303):  # another rate; an exact repeat (off the mean)
                imu.publish(_imu(stamp, rates(k, 0.01 if k == 300 else 0.0)))
    for name, (_, _, bias) in nodes.items():
        probe.spin_until(lambda: bias, 30, f'the bias of {name}')
    once, twice = ([b.vector.x, b.vector.y, b.vector.z] for _, _, (b, *_) in nodes.values())
    assert twice == once  # the same window, from the first message at each stamp
    assert once == pytest.approx([0.01, -0.02, 0.03], abs=1e-4)

    counted = {}
    for name, n in (('calibration_once', '0'), ('calibration_twice', '2')):
        key = f'/{name}/calibration_node: gyro calibration'

        def calibrated_and_counted() -> bool:
            # The bias is published at once, the diagnostics on their next period: a report
            # from before the window closed already has the counts but still says collecting.
            values = diagnostics_of(diagnostics, key) or {}
            return (values.get('state') == 'calibrated' and values.get('dropped_duplicate') == n
                    and values.get('dropped_same_stamp') == n)

        probe.spin_until(calibrated_and_counted, 20, f'the counts of {name}')
        counted[name] = diagnostics_of(diagnostics, key)

    def samples(name: str) -> str:
        # Logged after the bias is published, before the report that says calibrated.
        found = re.search(r'gyro bias from (\d+) samples over ([\d.]+) s',
                          processes.log(name))
        assert found, processes.log(name)
        return found.groups()

    assert samples('calibration_twice') == samples('calibration_once')
    values = counted['calibration_twice']
    assert values['refused_windows'] == '0'
    assert all(v == '0' for k, v in values.items() if k.startswith('dropped_')
               and k not in ('dropped_duplicate', 'dropped_same_stamp')), values
    log = processes.log('calibration_twice')
    assert any(f'/calibration_twice/{topic}: a second message at stamp 17000031{k // 100:02d}.'
               f'{k % 100:02d}0000000 ({k / 100:.6f} s) with another {field} than the one '
               'taken' in log for topic, k, field in (('odom', 200, 'twist.twist.linear.x'),
                                                      ('imu', 300, 'angular_velocity'))), log
