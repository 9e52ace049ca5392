"""calibration_node in its own process, fed the replayed 2016 real log and synthetic data."""

from __future__ import annotations

import math

import pytest

pytestmark = pytest.mark.ros

STATIC_BIAS_DEG_S = -0.9748  # mean yaw rate over the first 5 s (shared data README)


@pytest.fixture(scope='module')
def calibrated(ros_processes, real_bag, diagnostics_of):
    """Replay the first 7 s of the real log into a calibration node; wait until it is done."""
    from diagnostic_msgs.msg import DiagnosticArray

    from gyro_ekf.nodes import qos

    processes, probe = ros_processes
    diagnostics = probe.subscribe(DiagnosticArray, '/diagnostics', qos.OUTPUT)
    processes.node('calibration_node', '-p', 'reliable_inputs:=true',
                   '-p', 'diagnostics_period_s:=0.2')
    output = processes.run(
        'replay', 'gyro_ekf.cli.main', 'replay', str(real_bag), '--rate', '10',
        '--duration-s', '7', '--topics', 'imu', 'odom', '--wait-for', '1', timeout_s=300)

    def done():
        values = diagnostics_of(diagnostics, '/calibration_node: gyro calibration')
        return values is not None and values['state'] == 'calibrated'
    probe.spin_until(done, 120, 'the calibration node to report a calibrated bias')
    return processes, probe, output, real_bag


def test_bias_of_the_real_log_reaches_a_late_subscriber(calibrated):
    from geometry_msgs.msg import Vector3Stamped

    from gyro_ekf.nodes import qos

    processes, probe, replay_output, _ = calibrated
    # Subscribed only now, after the bias was published: transient local still delivers it.
    bias = probe.subscribe(Vector3Stamped, 'gyro_bias', qos.LATCHED)
    probe.spin_until(lambda: bias, 60, 'gyro_bias on a late subscription')
    assert math.degrees(bias[0].vector.z) == pytest.approx(STATIC_BIAS_DEG_S, abs=0.002)
    log = processes.log('calibration_node')
    assert 'deg/s' in log and 'sigma' in log
    assert 'all acknowledged: True' in replay_output


def test_corrected_imu_has_the_bias_removed(calibrated):
    from rclpy.qos import qos_profile_sensor_data
    from sensor_msgs.msg import Imu

    from gyro_ekf.nodes import qos

    from gyro_ekf.io import bag_summary

    processes, probe, _, calibrated_bag = calibrated
    corrected = probe.subscribe(Imu, 'imu/corrected', qos_profile_sensor_data)
    publisher = probe.node.create_publisher(Imu, 'imu', qos.LOSSLESS)
    probe.spin_until(lambda: publisher.get_subscription_count() > 0, 60, 'the node on imu')
    # A stamp no replayed message has (the replay stops after 7 s of the log): on a busy
    # machine the node may still be working through the replay's queue, and only this
    # test's own message is checked.
    stamp_ns = bag_summary(calibrated_bag).start_time_ns + 8 * 10 ** 9 + 123_457
    message = _imu(stamp_ns, 0.5)

    def own(received):
        return [m for m in received if _stamp_ns(m) == stamp_ns]

    def published_and_received():
        publisher.publish(message)
        return bool(own(corrected))
    probe.spin_until(published_and_received, 60, 'imu/corrected of the test\'s own message')
    expected = 0.5 - math.radians(STATIC_BIAS_DEG_S)
    assert own(corrected)[0].angular_velocity.z == pytest.approx(expected,
                                                                 abs=math.radians(0.002))


def _stamp_ns(message) -> int:
    return message.header.stamp.sec * 1_000_000_000 + message.header.stamp.nanosec


def _imu(stamp_ns: int, rate_rad_s: float):
    from sensor_msgs.msg import Imu

    message = Imu()
    message.header.stamp.sec, message.header.stamp.nanosec = divmod(stamp_ns, 1_000_000_000)
    message.angular_velocity.z = rate_rad_s
    return message


class _Calibrating:
    """A calibration_node in namespace `name` with a 1-s window, the probe's ends of its topics."""

    def __init__(self, ros_processes, diagnostics_of, name: str):
        from diagnostic_msgs.msg import DiagnosticArray
        from geometry_msgs.msg import PoseArray, Vector3Stamped
        from nav_msgs.msg import Odometry
        from sensor_msgs.msg import Imu

        from gyro_ekf.nodes import qos

        self.processes, probe = ros_processes
        self.name, self._diagnostics_of = name, diagnostics_of
        self.processes.node('calibration_node', '-r', f'__ns:=/{name}',
                            '-p', 'reliable_inputs:=true', '-p', 'window_length_s:=1.0',
                            '-p', 'diagnostics_period_s:=0.1', name=name)
        self.imu = probe.node.create_publisher(Imu, f'/{name}/imu', qos.LOSSLESS)
        self.odom = probe.node.create_publisher(Odometry, f'/{name}/odom', qos.LOSSLESS)
        self.poles = probe.node.create_publisher(PoseArray, f'/{name}/landmarks', qos.LOSSLESS)
        self.bias = probe.subscribe(Vector3Stamped, f'/{name}/gyro_bias', qos.LATCHED)
        self._diagnostics = probe.subscribe(DiagnosticArray, '/diagnostics', qos.OUTPUT)
        probe.spin_until(lambda: all(p.get_subscription_count() for p in (
            self.imu, self.odom, self.poles)), 60, 'the node on imu, odom and landmarks')

    def diagnosed(self, key: str, at_least: int) -> bool:
        """Whether the node's last /diagnostics counts at least at_least under key."""
        values = self._diagnostics_of(self._diagnostics, f'/{self.name}/calibration_node: gyro')
        return values is not None and int(values[key]) >= at_least


def test_a_window_with_motion_is_refused_then_a_still_one_accepted(ros_processes,
                                                                   diagnostics_of):
    from nav_msgs.msg import Odometry

    node = _Calibrating(ros_processes, diagnostics_of, 'calibration_motion')
    imu, odom, bias, probe = node.imu, node.odom, node.bias, ros_processes[1]
    start = 1_800_000_000 * 10 ** 9
    step = 5_000_000  # 200 Hz
    for i in range(260):  # 1.3 s, driving at 0.5 m/s and turning
        stamp = start + i * step
        moving = Odometry()
        moving.header.stamp = _imu(stamp, 0.0).header.stamp
        moving.twist.twist.linear.x = 0.5
        odom.publish(moving)
        imu.publish(_imu(stamp, 0.3 * math.sin(i / 20.0)))

    probe.spin_until(lambda: node.diagnosed('refused_windows', 1), 120, 'a refused window')
    assert not bias
    log = node.processes.log(node.name)
    assert 'static window refused' in log
    assert 'moved' in log or 'not static' in log
    for i in range(260, 900):  # still: a later window (once the moving samples are out) passes
        imu.publish(_imu(start + i * step, 0.01))
    probe.spin_until(lambda: bias, 120, 'gyro_bias after a still window')
    assert bias[0].vector.z == pytest.approx(0.01, abs=1e-9)


def _poles(stamp_ns: int, turned_rad: float):
    """Three poles in the LiDAR's frame, seen from a platform turned by turned_rad."""
    from geometry_msgs.msg import Pose, PoseArray

    message = PoseArray()
    message.header.stamp = _imu(stamp_ns, 0.0).header.stamp
    message.header.frame_id = 'laser'
    for bearing, range_m in ((0.4, 5.0), (-0.9, 7.0), (2.0, 9.0)):
        pose = Pose()
        pose.position.x = range_m * math.cos(bearing - turned_rad)
        pose.position.y = range_m * math.sin(bearing - turned_rad)
        message.poses.append(pose)
    return message


def test_a_turn_in_place_the_poles_show_is_refused_then_a_still_window_accepted(
        ros_processes, diagnostics_of):
    # Turning on the spot: no speed and a steady gyro rate, which the window's mean took
    # for bias. The detector's poles turn about the platform.
    from nav_msgs.msg import Odometry

    node = _Calibrating(ros_processes, diagnostics_of, 'calibration_turn')
    imu, odom, poles, bias, probe = node.imu, node.odom, node.poles, node.bias, ros_processes[1]
    start = 1_800_000_000 * 10 ** 9
    step = 5_000_000  # IMU at 200 Hz, scans every 20th sample (10 Hz)
    turn = math.radians(0.5)

    def counted(n):
        return node.diagnosed('pole_messages', n)
    # The first window's scans first, 0-1 s: two topics' messages may be served in any
    # order. Its IMU samples end with it (the sample at 1 s completes it), so the next
    # window starts still: a turn that ends part way into a 1-s window is within what the
    # poles' half-beam steps can tell (core/calibration.py).
    for i in range(0, 201, 20):
        poles.publish(_poles(start + i * step, turn * i * step * 1e-9))
    probe.spin_until(lambda: counted(11), 120, 'the node to take the scans')
    for i in range(201):
        still = Odometry()
        still.header.stamp = _imu(start + i * step, 0.0).header.stamp
        odom.publish(still)
        imu.publish(_imu(start + i * step, 0.01 + turn))

    probe.spin_until(lambda: node.diagnosed('refused_windows', 1), 120, 'a refused window')
    assert not bias
    log = node.processes.log(node.name)
    assert "static window refused: platform not static: its LiDAR 'laser' saw it turn +0.5" \
        in log, log
    # Still from here, where the turn ended: the next window passes.
    for i in range(220, 900, 20):
        poles.publish(_poles(start + i * step, turn * 200 * step * 1e-9))
    probe.spin_until(lambda: counted(11 + 34), 120, 'the node to take the scans')
    for i in range(201, 900):
        imu.publish(_imu(start + i * step, 0.01))
    probe.spin_until(lambda: bias, 120, 'gyro_bias after a still window')
    assert bias[0].vector.z == pytest.approx(0.01, abs=1e-9)
    # Calibrated, the node no longer takes the poles (nor pays for their messages).
    probe.spin_until(lambda: poles.get_subscription_count() == 0, 120,
                     'the pole subscription to go once calibrated')
