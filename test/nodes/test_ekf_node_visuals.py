"""ekf_node's outputs for viewers and IMU users: ekf/path, ekf/markers, landmark_markers, ekf/imu.

One node in a namespace of its own, fed by the test process: a gyro bias seeded with a tiny
sigma (so the online bias stays where it was put), IMU messages in a frame of the test's
own, odometry, and one observation of a pole of the map. Only messages the test sent are
checked.
"""

from __future__ import annotations

import math
import time

import pytest

pytestmark = pytest.mark.ros

NS = 'visuals'
T0_NS = 1_700_000_000 * 10 ** 9
STEP_NS = 10_000_000
BIAS = 0.02  # rad/s
RATE = 0.05  # rad/s, every IMU message
RATE_VARIANCE = 1e-4


def _stamp(message, ns):
    message.header.stamp.sec, message.header.stamp.nanosec = divmod(ns, 10 ** 9)
    return message


def _ns(message):
    return message.header.stamp.sec * 10 ** 9 + message.header.stamp.nanosec


@pytest.fixture(scope='module')
def visual_run(ros_processes, diagnostics_of, tmp_path_factory):
    from diagnostic_msgs.msg import DiagnosticArray
    from geometry_msgs.msg import Pose, PoseArray, Vector3Stamped
    from nav_msgs.msg import Odometry, Path
    from sensor_msgs.msg import Imu
    from visualization_msgs.msg import MarkerArray

    from gyro_ekf.nodes import qos

    processes, probe = ros_processes
    landmarks = tmp_path_factory.mktemp('map') / 'map.yaml'
    landmarks.write_text('landmarks: [[2.0, 0.0], [0.0, 3.0], [-4.0, 1.0]]\n')
    processes.node('ekf_node', '-r', f'__ns:=/{NS}', '-p', 'reliable_inputs:=true',
                   '-p', f'landmarks_file:={landmarks}', '-p', 'use_calibration:=true',
                   '-p', 'calibration_bias_sigma_rad_s:=1e-9', '-p', 'path_length:=5',
                   '-p', 'diagnostics_period_s:=0.1', name=NS)
    node = probe.node
    imu = node.create_publisher(Imu, f'/{NS}/imu', qos.LOSSLESS)
    odom = node.create_publisher(Odometry, f'/{NS}/odom', qos.LOSSLESS)
    poles = node.create_publisher(PoseArray, f'/{NS}/landmarks', qos.LOSSLESS)
    bias = node.create_publisher(Vector3Stamped, f'/{NS}/gyro_bias', qos.LATCHED)
    got = {
        'imu': probe.subscribe(Imu, f'/{NS}/ekf/imu', qos.LOSSLESS),
        'bias': probe.subscribe(Vector3Stamped, f'/{NS}/ekf/bias', qos.LOSSLESS),
        'path': probe.subscribe(Path, f'/{NS}/ekf/path', qos.OUTPUT),
        'markers': probe.subscribe(MarkerArray, f'/{NS}/ekf/markers', qos.OUTPUT),
        'landmarks': probe.subscribe(MarkerArray, f'/{NS}/landmark_markers', qos.LATCHED),
    }
    diagnostics = probe.subscribe(DiagnosticArray, '/diagnostics', qos.LOSSLESS)
    key = f'/{NS}/ekf_node: gyro bias EKF'
    probe.spin_until(lambda: all(p.get_subscription_count() for p in (imu, odom, poles, bias))
                     and all(node.count_publishers(f'/{NS}/{t}') for t in (
                         'ekf/imu', 'ekf/bias', 'ekf/path', 'ekf/markers', 'landmark_markers')),
                     20, 'the EKF node and its outputs')
    seeded = Vector3Stamped()
    seeded.vector.z = BIAS
    bias.publish(_stamp(seeded, T0_NS))
    # The node skips ekf/bias while it has no reader, and its writer matches the probe's
    # reader on the node's own discovery, which can come after the probe sees the writer:
    # the last bias would be lost. The node reports its side of that match.
    probe.spin_until(lambda: abs(float((diagnostics_of(diagnostics, key) or {}).get(
        'bias_deg_s', 'nan')) - math.degrees(BIAS)) < 1e-4 and int(
        diagnostics_of(diagnostics, key).get('bias_readers') or 0) > 0, 30,
        'the seeded bias, the bias writer matched')

    sent = []

    def send() -> None:
        i = len(sent)
        ns = T0_NS + i * STEP_NS
        message = Odometry()
        odom.publish(_stamp(message, ns))
        message = Imu()
        message.header.frame_id = 'imu_of_the_test'
        message.angular_velocity.z = RATE
        message.angular_velocity_covariance[8] = RATE_VARIANCE
        imu.publish(_stamp(message, ns))
        sent.append(ns)
        if i == 150:  # the pole at (2, 0) seen from the origin, turned as the gyro says
            yaw = (RATE - BIAS) * (i + 0.5) * STEP_NS / 1e9
            seen = PoseArray()
            seen.poses = [Pose()]
            seen.poses[0].position.x = 2.0 * math.cos(yaw)
            seen.poses[0].position.y = -2.0 * math.sin(yaw)
            poles.publish(_stamp(seen, ns + STEP_NS // 2))

    # ekf/imu goes out only while its writer has a reader, and the node does not report
    # that match: the first pairs go one a second (the same stream, only slower) until a
    # copy comes back. Every IMU message sent after that must have its copy.
    paced: list[float] = []

    def imu_copy_back() -> bool:
        if any(_ns(m) in sent for m in got['imu']):
            return True
        if len(sent) < 100 and (not paced or time.monotonic() - paced[-1] > 1.0):
            send()
            paced.append(time.monotonic())
        return False

    probe.spin_until(imu_copy_back, 120, 'a first ekf/imu message of the node')
    got['imu_checked'] = set(T0_NS + i * STEP_NS for i in range(len(sent), 300))
    while len(sent) < 300:
        send()
    last = sent[-1]
    waiting = {
        'the last bias': lambda: any(_ns(m) == last for m in got['bias']),
        'markers with the pole': lambda: any(
            _ns(m.markers[0]) >= T0_NS + 150 * STEP_NS and m.markers[2].points
            for m in got['markers']),
        'the newest path': lambda: any(m.poses and _ns(m) >= last - 2 * 10 ** 8
                                       for m in got['path']),
        'the map': lambda: bool(got['landmarks'])}
    for what, condition in waiting.items():
        probe.spin_until(condition, 60, f'{what} (diagnostics: '
                         f'{diagnostics_of(diagnostics, key)}, log: {processes.log(NS)})')
    got['sent'] = set(sent)
    got['log'] = processes.log(NS)
    return got


def test_ekf_imu_is_the_input_less_the_online_bias_in_the_input_frame(visual_run):
    mine = [m for m in visual_run['imu'] if _ns(m) in visual_run['sent']]
    # The first messages come before any estimate, or before the writer matched the probe.
    assert len(visual_run['imu_checked']) >= 200
    assert {_ns(m) for m in mine} >= visual_run['imu_checked']
    for message in mine:
        assert message.header.frame_id == 'imu_of_the_test'
        assert message.angular_velocity.z == pytest.approx(RATE - BIAS, abs=1e-6)
        # The bias estimate's variance is added to the sensor's.
        assert message.angular_velocity_covariance[8] > RATE_VARIANCE


def test_ekf_bias_is_in_the_imu_frame(visual_run):
    mine = [m for m in visual_run['bias'] if _ns(m) in visual_run['sent']]
    assert mine and {m.header.frame_id for m in mine} == {'imu_of_the_test'}


def test_path_is_bounded_and_in_the_map_frame(visual_run):
    paths = [m for m in visual_run['path'] if m.poses]
    assert paths and all(len(m.poses) <= 5 for m in paths)
    newest = paths[-1]
    assert newest.header.frame_id == 'map'
    assert all(_ns(p) in visual_run['sent'] for p in newest.poses)
    # Turning at RATE - BIAS from yaw 0 at rest: the path's poses turn that way.
    last = newest.poses[-1]
    yaw = 2.0 * math.atan2(last.pose.orientation.z, last.pose.orientation.w)
    assert yaw == pytest.approx((RATE - BIAS) * (_ns(last) - T0_NS) / 1e9, abs=0.02)


def test_markers_show_the_ellipse_and_the_associated_pole(visual_run):
    with_scan = [m for m in visual_run['markers'] if m.markers[2].points]
    assert with_scan
    by_ns = {m.ns: m for m in with_scan[-1].markers}
    assert {m.header.frame_id for m in with_scan[-1].markers} == {'map'}
    assert by_ns['ellipse'].scale.x > 0.0
    (point,) = by_ns['associated'].points
    assert (point.x, point.y) == pytest.approx((2.0, 0.0), abs=0.05)
    line = by_ns['association'].points
    assert (line[1].x, line[1].y) == (2.0, 0.0)  # to the landmark itself


def test_landmark_markers_hold_the_map(visual_run):
    markers = visual_run['landmarks'][-1].markers
    assert [(m.pose.position.x, m.pose.position.y) for m in markers] == [
        (2.0, 0.0), (0.0, 3.0), (-4.0, 1.0)]


def test_tf_is_broadcast_or_its_absence_said_once(visual_run):
    try:
        import tf2_msgs.msg  # noqa: F401
    except ImportError:
        assert visual_run['log'].count('tf2_msgs is not installed') == 1
    else:
        assert 'tf2_msgs is not installed' not in visual_run['log']
