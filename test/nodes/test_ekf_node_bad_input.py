"""ekf_node fed hostile input by the test process: values, stamps and clocks that are wrong.

Each test starts its own node in its own namespace and checks only the estimates and the
diagnostics of that node, for messages it sent itself (stamps unique to the test).
"""

from __future__ import annotations

import math

import pytest

from ekf_harness import EkfUnderTest as _Harness, stamped, STEP_NS

pytestmark = pytest.mark.ros


class EkfUnderTest(_Harness):
    """The harness's node, with an initialpose publisher."""

    def __init__(self, ros_processes, diagnostics_of, name: str, *params: str):
        from geometry_msgs.msg import PoseWithCovarianceStamped

        from gyro_ekf.nodes import qos

        super().__init__(ros_processes, diagnostics_of, name, *params)
        self.pose = self.probe.node.create_publisher(
            PoseWithCovarianceStamped, f'/{name}/initialpose', qos.OUTPUT)
        self.wait_for_node(self.pose)

    def send_pairs(self, start_ns: int, first: int, last: int, speed: float = 0.0) -> None:
        for i in range(first, last):
            self.send_odom(start_ns + i * STEP_NS, speed)
            self.send_imu(start_ns + i * STEP_NS)

    def estimates_at(self, stamps_ns) -> list:
        wanted = set(stamps_ns)
        return [m for m in self.odometry
                if m.header.stamp.sec * 10 ** 9 + m.header.stamp.nanosec in wanted]


@pytest.fixture
def start_ekf(ros_processes, diagnostics_of):
    """Start an ekf_node in a namespace of its own: start_ekf(name, 'param:=value', ...)."""
    return lambda name, *params: EkfUnderTest(ros_processes, diagnostics_of, name, *params)


def _count(key: str, at_least: int):
    return lambda values: int(values.get(key, '0') or 0) >= at_least


def test_implausible_and_non_finite_values_are_dropped_per_reason(start_ekf):
    from gyro_ekf.nodes.conversions import quaternion_yaw

    ekf = start_ekf('values')
    start = 1_700_000_000 * 10 ** 9
    ekf.send_pairs(start, 0, 50, speed=1.0)
    ekf.send_imu(start + 50 * STEP_NS + 1, 1e300)  # heading would jump 105 deg
    ekf.send_imu(start + 50 * STEP_NS + 2, math.nan)
    ekf.send_odom(start + 50 * STEP_NS + 3, math.inf)
    ekf.send_odom(start + 50 * STEP_NS + 4, 1e4)  # 10 km/s
    ekf.send_pairs(start, 51, 100, speed=1.0)
    values = ekf.wait_for(_count('estimates', 99), 'the good samples processed')
    assert values['dropped_out_of_range'] == '2'
    assert values['dropped_non_finite'] == '2'
    assert values['resets'] == '0'
    ekf.probe.spin_until(lambda: len(ekf.odometry) >= 99, 10, 'the estimates')
    own = ekf.estimates_at(start + i * STEP_NS for i in range(100))
    assert len(own) == 99
    yaws = [abs(quaternion_yaw(m.pose.pose.orientation)) for m in own]
    assert max(yaws) < 1e-9  # every yaw rate taken was 0
    speeds = {m.twist.twist.linear.x for m in own}
    assert speeds <= {0.0, 1.0}


def test_bad_message_covariances_are_ignored_and_counted_and_good_ones_used(start_ekf):
    from nav_msgs.msg import Odometry
    from sensor_msgs.msg import Imu

    ekf = start_ekf('covariances')
    start = 1_700_000_100 * 10 ** 9
    # Moving: standing at its exactly given start pose the filter would hold the pose and
    # its covariance (core/held_start.py), and no variance would grow.
    ekf.send_pairs(start, 0, 20, speed=1.0)
    for i, (rate_variance, speed_variance) in enumerate(
            [(math.nan, -3.0), (1e9, math.inf), (-1.0, 0.0), (0.25, 0.04)]):
        ns = start + (20 + i) * STEP_NS
        odom = Odometry()
        odom.twist.covariance[0] = speed_variance
        ekf.odom.publish(stamped(odom, ns))
        imu = Imu()
        imu.angular_velocity_covariance[8] = rate_variance
        ekf.imu.publish(stamped(imu, ns))
    ekf.send_pairs(start, 24, 60)
    ekf.probe.spin_until(lambda: len(ekf.estimates_at([start + 59 * STEP_NS])) == 1, 30,
                         'the last estimate')
    values = ekf.wait_for(_count('estimates', 60), 'every sample processed')
    # NaN, -3, 1e9, inf: four bad values; -1 and 0 mean "not given".
    assert values['ignored_covariances'] == '4'
    assert values['dropped_non_finite'] == '0' and values['resets'] == '0'
    own = {m.header.stamp.sec * 10 ** 9 + m.header.stamp.nanosec: m.pose.covariance[35]
           for m in ekf.estimates_at(start + i * STEP_NS for i in range(60))}
    # The 0.25 (rad/s)^2 message: the next step's yaw variance grows by T^2 * 0.25 at
    # least, far beyond the configured gyro noise's share.
    step = own[start + 24 * STEP_NS] - own[start + 23 * STEP_NS]
    assert step >= 0.01 ** 2 * 0.25 * 0.999


def test_an_initial_pose_with_a_negative_variance_or_a_zero_quaternion_is_refused(
        start_ekf):
    from geometry_msgs.msg import PoseWithCovarianceStamped

    ekf = start_ekf('pose')
    negative = PoseWithCovarianceStamped()
    negative.pose.pose.position.x = 3.0
    negative.pose.pose.orientation.w = 1.0
    negative.pose.covariance[0] = -0.25
    zero_quaternion = PoseWithCovarianceStamped()
    zero_quaternion.pose.pose.position.x = 4.0
    zero_quaternion.pose.pose.orientation.w = 0.0
    nan_pose = PoseWithCovarianceStamped()
    nan_pose.pose.pose.position.y = math.nan
    nan_pose.pose.pose.orientation.w = 1.0
    good = PoseWithCovarianceStamped()
    good.pose.pose.position.x = 5.0
    good.pose.pose.orientation.w = 1.0
    good.pose.covariance[0] = good.pose.covariance[7] = 0.25
    for message in (negative, zero_quaternion, nan_pose, good):
        ekf.pose.publish(message)
    ekf.probe.spin_until(lambda: 'pose set to [5.0' in ekf.processes.log('pose'), 20,
                         'the good pose')
    # A status published between two of the bad poses may arrive after the log line: wait
    # for one that counts all three.
    values = ekf.wait_for(lambda v: _count('dropped_bad_pose', 2)(v)
                          and _count('dropped_non_finite', 1)(v), 'the bad poses counted')
    assert values['dropped_bad_pose'] == '2'
    assert values['dropped_non_finite'] == '1'
    assert 'pose set to [3.0' not in ekf.processes.log('pose')
    assert 'pose set to [4.0' not in ekf.processes.log('pose')
    start = 1_700_000_100 * 10 ** 9
    ekf.send_pairs(start, 0, 10)
    ekf.probe.spin_until(lambda: len(ekf.estimates_at([start + 9 * STEP_NS])) == 1, 20,
                         'an estimate after the pose')
    estimate = ekf.estimates_at([start + 9 * STEP_NS])[0]
    assert estimate.pose.pose.position.x == pytest.approx(5.0)
    assert estimate.pose.covariance[0] >= 0.25


def test_a_stamp_far_ahead_is_dropped_not_predicted_through(start_ekf):
    ekf = start_ekf('ahead')
    start = 1_700_000_200 * 10 ** 9
    ekf.send_pairs(start, 0, 50)
    ekf.send_imu(start + 50 * STEP_NS + 10 ** 15)  # 1e6 s ahead: 52 s of CPU before
    ekf.send_odom(start + 50 * STEP_NS + 4 * 10 ** 17)  # 4e8 s ahead: hours before
    ekf.send_pairs(start, 51, 100)
    values = ekf.wait_for(lambda v: _count('estimates', 99)(v)
                          and _count('dropped_stamp_jump', 2)(v), 'the far stamps dropped')
    assert values['dropped_stamp_jump'] == '2'
    assert values['dropped_late'] == '0' and values['resets'] == '0'
    assert values['long_gaps'] == '0'
    assert float(values['stamp_s']) == pytest.approx(0.99)


def test_a_first_message_far_ahead_does_not_wedge_the_node(start_ekf):
    ekf = start_ekf('first')
    start = 1_700_000_300 * 10 ** 9
    ekf.send_imu(start + 100 * 10 ** 9)  # the first message, 100 s ahead of the rest
    ekf.send_pairs(start, 0, 100)
    values = ekf.wait_for(_count('estimates', 100), 'every later sample processed')
    assert values['dropped_stamp_jump'] == '1'
    assert values['dropped_late'] == '0' and values['resets'] == '0'
    ekf.probe.spin_until(lambda: len(ekf.estimates_at([start + 99 * STEP_NS])) == 1, 10,
                         'the last estimate')


def test_a_gap_every_input_agrees_on_is_taken(start_ekf):
    # Both publishers stop for 10 s of stamp time and resume: a real gap, even beyond
    # max_stamp_jump_s.
    ekf = start_ekf('gap', 'limits.max_stamp_jump_s:=5.0')
    start = 1_700_000_400 * 10 ** 9
    ekf.send_pairs(start, 0, 50, speed=1.0)
    # The publishers really stop: the node goes idle and flushes what it held.
    ekf.wait_for(_count('estimates', 50), 'the samples before the pause')
    ekf.send_pairs(start + 10 * 10 ** 9, 50, 100, speed=1.0)
    values = ekf.wait_for(_count('estimates', 100), 'both sides of the gap processed')
    assert values['dropped_stamp_jump'] == '0' and values['dropped_late'] == '0'
    assert values['resets'] == '0'
    ekf.probe.spin_until(
        lambda: len(ekf.estimates_at([start + 10 * 10 ** 9 + 99 * STEP_NS])) == 1, 10,
        'the last estimate')
    last = ekf.estimates_at([start + 10 * 10 ** 9 + 99 * STEP_NS])[0]
    assert last.pose.pose.position.x == pytest.approx(10.99)  # 1 m/s through the gap


def test_one_input_far_behind_the_others_is_dropped_as_late_without_a_reset(start_ekf):
    # What ended `make demo` 16 m off: odometry 35.9 s behind the filter, 20 in a row.
    ekf = start_ekf('behind')
    start = 1_700_000_600 * 10 ** 9
    ekf.send_pairs(start, 0, 100)
    ekf.wait_for(_count('estimates', 99), 'the first samples')
    back = int(35.9e9)
    for i in range(100, 150):  # 50 in a row, while the IMU is still active
        ekf.send_odom(start + i * STEP_NS - back)
    ekf.wait_for(_count('dropped_late', 50), 'the late odometry dropped')
    ekf.send_pairs(start, 100, 160)
    values = ekf.wait_for(_count('estimates', 160), 'the IMU samples processed')
    assert values['resets'] == '0'
    assert values['dropped_late'] == '50'
    assert 'filter reset' not in ekf.processes.log('behind')


def test_an_input_running_5_s_ahead_is_held_without_a_reset(start_ekf):
    ekf = start_ekf('skewed')
    start = 1_700_000_800 * 10 ** 9
    for i in range(300):
        ekf.send_odom(start + 5 * 10 ** 9 + i * STEP_NS)
        ekf.send_imu(start + i * STEP_NS)
    values = ekf.wait_for(_count('estimates', 300), 'every IMU sample processed')
    assert values['resets'] == '0'
    assert values['dropped_late'] == '0' and values['dropped_stamp_jump'] == '0'


def test_a_burst_of_10000_imu_messages_in_one_second_is_processed(start_ekf):
    ekf = start_ekf('burst')
    start = 1_700_001_000 * 10 ** 9
    for i in range(10_000):
        ekf.send_imu(start + i * 100_000)  # 10 kHz of stamps
    values = ekf.wait_for(_count('estimates', 10_000), 'the burst processed', 120.0)
    assert values['estimates'] == '10000' and values['resets'] == '0'
    assert all(v == '0' for k, v in values.items() if k.startswith('dropped_')), values


def test_clock_going_backwards_resets_once_with_the_reason_logged(start_ekf):
    from rclpy.qos import QoSProfile
    from rosgraph_msgs.msg import Clock

    from gyro_ekf.nodes.conversions import to_stamp

    ekf = start_ekf('clock', 'use_sim_time:=true')
    clock = ekf.probe.node.create_publisher(Clock, '/clock', QoSProfile(depth=10))
    ekf.probe.spin_until(lambda: clock.get_subscription_count() > 0, 20, '/clock readers')
    start = 1_700_001_200 * 10 ** 9
    now = [start]

    def tick() -> None:  # /clock runs on while the probe spins (the node's timers use it)
        now[0] += 20_000_000
        clock.publish(Clock(clock=to_stamp(now[0])))
    timer = ekf.probe.node.create_timer(0.02, tick)
    try:
        ekf.send_pairs(start, 0, 50)
        ekf.wait_for(_count('estimates', 50), 'the first samples')
        assert ekf.values()['resets'] == '0'
        now[0] -= 100 * 10 ** 9  # /clock goes back 100 s
        values = ekf.wait_for(_count('resets', 1), 'the reset')
        assert 'ROS time jumped back 99.' in ekf.processes.log('clock')
        # The data starts over with the clock; the node goes on.
        ekf.send_pairs(start - 100 * 10 ** 9, 0, 50)
        values = ekf.wait_for(lambda v: int(v.get('estimates', '0')) >= 100,
                              'samples after the reset')
    finally:
        ekf.probe.node.destroy_timer(timer)
    assert values['resets'] == '1'
    assert ekf.processes.log('clock').count('filter reset') == 1
