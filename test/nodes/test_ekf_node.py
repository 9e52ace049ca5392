"""ekf_node (with landmark_detector_node) in their own processes, fed replayed bags.

The offline reference is the core's drive_trip on the trip read back from the same bag, with
the configuration the node builds from the bag's params sidecar: the same inputs in the same
order must give the same numbers.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

pytestmark = pytest.mark.ros

PUBLISH_EVERY = 20


def _offline(bag):
    from gyro_ekf.core.config import EkfConfig, with_stated_noise
    from gyro_ekf.core.events import EventDriver
    from gyro_ekf.core.trip_run import drive_trip
    from gyro_ekf.io import read_bag

    bag_trip = read_bag(bag)
    config = with_stated_noise(EkfConfig(), bag_trip.params.noise)
    run = drive_trip(bag_trip.trip, EventDriver(config, pose=bag_trip.trip.initial_pose))
    return bag_trip, run


def _pipeline(ros_processes, diagnostics_of, bag, rate: float, publish_every: int,
              ekf_args: tuple[str, ...] = ()):
    """Run detector + EKF on a replayed bag; return the probe's odometry, bias, diagnostics."""
    from diagnostic_msgs.msg import DiagnosticArray
    from geometry_msgs.msg import Vector3Stamped
    from nav_msgs.msg import Odometry

    from gyro_ekf.io import read_bag
    from gyro_ekf.nodes import qos

    processes, probe = ros_processes
    odometry = probe.subscribe(Odometry, 'ekf/odometry', qos.LOSSLESS)
    bias = probe.subscribe(Vector3Stamped, 'ekf/bias', qos.LOSSLESS)
    diagnostics = probe.subscribe(DiagnosticArray, '/diagnostics', qos.LOSSLESS)
    lossless = ('-p', 'reliable_inputs:=true')
    processes.node('landmark_detector_node', *lossless)
    processes.node('ekf_node', '--params-file', f'{bag}.params.yaml', *lossless, *ekf_args,
                   '-p', f'publish_every_n:={publish_every}')
    # The node skips ekf/odometry and ekf/bias while they have no reader, and its writers
    # match the probe's readers on its own discovery, which can come after the probe sees
    # them: an estimate published before then never arrives (the count below would never
    # be reached). Wait for the node's side of both matches, as its diagnostics report it.
    probe.spin_until(lambda: all(
        int((diagnostics_of(diagnostics, '/ekf_node: gyro bias EKF') or {}).get(readers)
            or 0) > 0 for readers in ('odometry_readers', 'bias_readers')), 60,
        'the EKF node, its odometry and bias writers matched')
    # So with the detector's landmarks writer and the EKF node's reader: the first scans'
    # landmarks would be lost, and the estimates would not be the offline run's.
    probe.wait_for_landmarks_readers(diagnostics)
    replay = processes.run(
        'replay', 'gyro_ekf.cli.main', 'replay', str(bag), '--rate', str(rate),
        '--topics', 'imu', 'odom', 'scan', 'landmark_map', 'initialpose',
        '--wait-for', 'imu:1', '--wait-for', 'odom:1', '--wait-for', 'scan:1',
        # Reliable inputs: the replay goes as fast as the nodes take it, slowly on a busy
        # machine. Timeouts here say "stuck", not "slow".
        timeout_s=900)
    trip = read_bag(bag)
    n_imu = len(trip.trip.imu.stamp_s)
    expected = n_imu // publish_every
    probe.spin_until(lambda: len(odometry) >= expected and len(bias) >= expected, 300,
                     f'{expected} estimates')
    return odometry, bias, diagnostics, replay, trip


@pytest.fixture(scope='module')
def sim_run(ros_processes, sim_bag, diagnostics_of):
    """The simulated bag through the live pipeline and through drive_trip."""
    odometry, bias, diagnostics, replay, bag_trip = _pipeline(
        ros_processes, diagnostics_of, sim_bag, 5.0, PUBLISH_EVERY)
    _, run = _offline(sim_bag)
    return odometry, bias, diagnostics, replay, bag_trip, run


def _rows(messages, start_ns):
    return np.array([((m.header.stamp.sec * 10 ** 9 + m.header.stamp.nanosec) - start_ns) / 1e9
                     for m in messages])


def test_node_estimates_equal_the_offline_core(sim_run):
    from gyro_ekf.nodes.conversions import quaternion_yaw

    odometry, bias, _, replay, bag_trip, run = sim_run
    assert 'all acknowledged: True' in replay
    offline = run.estimates
    stamps = _rows(odometry, bag_trip.start_time_ns)
    rows = np.searchsorted(offline.stamp_s, stamps)
    assert len(odometry) == len(offline.stamp_s) // PUBLISH_EVERY
    assert np.array_equal(offline.stamp_s[rows], stamps)
    live = np.array([(m.pose.pose.position.x, m.pose.pose.position.y,
                      quaternion_yaw(m.pose.pose.orientation)) for m in odometry])
    yaw_error = np.angle(np.exp(1j * (live[:, 2] - offline.state[rows, 2])))
    assert np.abs(live[:, :2] - offline.state[rows, :2]).max() < 1e-9
    assert np.abs(yaw_error).max() < 1e-9
    covariance = np.array([m.pose.covariance[0] for m in odometry])
    assert np.abs(covariance - offline.covariance[rows, 0, 0]).max() < 1e-9
    live_bias = np.array([m.vector.z for m in bias])
    bias_rows = np.searchsorted(offline.stamp_s, _rows(bias, bag_trip.start_time_ns))
    assert np.abs(live_bias - offline.state[bias_rows, 3]).max() < 1e-9


def test_bias_on_a_simulated_bag_is_within_002_deg_s_of_the_truth(sim_run, diagnostics_of):
    odometry, bias, diagnostics, _, bag_trip, _ = sim_run
    true_bias = bag_trip.params.true_gyro_bias_rad_s[2]
    assert math.degrees(abs(bias[-1].vector.z - true_bias)) < 0.02
    values = diagnostics_of(diagnostics, '/ekf_node: gyro bias EKF')
    assert values is not None
    assert int(values['dropped_late']) == 0
    # A replayed bag has one message per topic and stamp: no repeat is dropped either.
    assert all(v == '0' for k, v in values.items() if k.startswith('dropped_')), values
    assert int(values['associated']) > 0
    # A clean trip: the health verdict (summary.json's, live) is ok with no reason.
    assert values['verdict'] == 'ok' and values['verdict_reasons'] == '', values
    assert values['lidar_scan_excluded'] == 'false'


@pytest.mark.shared_data
def test_bias_on_the_real_log_is_within_005_deg_s_of_the_calibration(
        tmp_path_factory, real_bag, ros_harness, diagnostics_of):
    from gyro_ekf.core.calibration import estimate_gyro_bias
    from gyro_ekf.io import read_trip_bag

    trip = read_trip_bag(real_bag)
    calibration = estimate_gyro_bias(trip.imu.stamp_s, trip.imu.angular_velocity_rad_s,
                                     speed_stamp_s=trip.speed.stamp_s,
                                     speed_m_s=trip.speed.speed_m_s)
    tmp = tmp_path_factory.mktemp('real')
    env = ros_harness.node_env(tmp)
    processes = ros_harness.Processes(env, tmp)
    probe = ros_harness.Probe(int(env['ROS_DOMAIN_ID']))
    try:
        _, bias, _, _, _ = _pipeline((processes, probe), diagnostics_of, real_bag, 5.0, 200)
        final = bias[-1].vector.z
    finally:
        processes.stop_all()
        probe.close()
    assert math.degrees(abs(final - calibration.bias_rad_s[2])) < 0.05


def _stamped(message, stamp_ns):
    message.header.stamp.sec, message.header.stamp.nanosec = divmod(stamp_ns, 10 ** 9)
    return message


def test_bad_messages_are_dropped_and_a_looped_stream_resets(ros_processes, diagnostics_of):
    from diagnostic_msgs.msg import DiagnosticArray
    from geometry_msgs.msg import Pose, PoseArray, Vector3Stamped
    from nav_msgs.msg import Odometry
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import Imu

    from gyro_ekf.nodes import qos

    processes, probe = ros_processes
    name = 'robust'
    processes.node('ekf_node', '-r', f'__ns:=/{name}', '-p', 'reliable_inputs:=true',
                   '-p', 'diagnostics_period_s:=0.1', name=name)
    imu = probe.node.create_publisher(Imu, f'/{name}/imu', qos.LOSSLESS)
    odom = probe.node.create_publisher(Odometry, f'/{name}/odom', qos.LOSSLESS)
    latched_10 = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE,
                            durability=DurabilityPolicy.TRANSIENT_LOCAL)
    landmark_map = probe.node.create_publisher(PoseArray, f'/{name}/landmark_map', latched_10)
    bias: list = []
    bias_sub = probe.node.create_subscription(Vector3Stamped, f'/{name}/ekf/bias', bias.append,
                                              qos.LOSSLESS)
    diagnostics = probe.subscribe(DiagnosticArray, '/diagnostics', qos.LOSSLESS)
    key = f'/{name}/ekf_node: gyro bias EKF'
    # The node skips ekf/bias while it has no reader, and an estimate published before its
    # writer matched the probe's reader never arrives: wait for the match both ways, the
    # node's side as it reports it (as EkfUnderTest.wait_for_node does for ekf/odometry).
    probe.spin_until(lambda: imu.get_subscription_count() and odom.get_subscription_count()
                     and landmark_map.get_subscription_count()
                     and bias_sub.get_publisher_count() > 0
                     and int((diagnostics_of(diagnostics, key) or {}).get('bias_readers')
                             or 0) > 0, 60, 'the EKF node, its bias writer matched')
    pose = Pose()
    pose.position.x = 3.0
    landmark_map.publish(PoseArray())  # empty: dropped
    probe.spin_until(lambda: (diagnostics_of(diagnostics, key) or {}).get(
        'dropped_empty_map') == '1', 60, 'the empty map to be dropped')
    landmark_map.publish(PoseArray(poses=[pose, pose]))  # one pole listed twice: dropped
    probe.spin_until(lambda: (diagnostics_of(diagnostics, key) or {}).get(
        'dropped_bad_map') == '1', 60, 'the map listing a pole twice to be dropped')
    landmark_map.publish(PoseArray(poses=[pose]))
    start = 1_800_000_000 * 10 ** 9
    step = 10_000_000

    def send(first: int, last: int) -> None:
        for i in range(first, last):
            odom.publish(_stamped(Odometry(), start + i * step))
            imu.publish(_stamped(Imu(), start + i * step))

    send(0, 100)
    bad = Imu()
    bad.angular_velocity.z = math.nan
    imu.publish(_stamped(bad, start + 100 * step))
    odom.publish(Odometry())  # zero stamp
    send(100, 200)
    imu.publish(_stamped(Imu(), start + 10 * step))  # far out of order
    send(200, 300)

    def counted():
        # The drops too: the zero stamp is odometry's, counted on arrival, in no order with
        # the IMU's estimates once the node's idle flush released IMU samples.
        values = diagnostics_of(diagnostics, key)
        return (values is not None and int(values['estimates']) >= 299 and len(bias) >= 299
                and all(int(values[f'dropped_{reason}']) >= 1
                        for reason in ('non_finite', 'zero_stamp', 'late')))
    probe.spin_until(counted, 120, 'all good samples processed and published, and one '
                     'non_finite, zero_stamp and late drop each')
    values = diagnostics_of(diagnostics, key)
    assert int(values['dropped_non_finite']) == 1
    assert int(values['dropped_zero_stamp']) == 1
    assert int(values['dropped_late']) == 1
    assert int(values['dropped_empty_map']) == 1
    # The map has no order with the other inputs: wait for it.
    probe.spin_until(lambda: 'landmark map: 1 landmarks' in processes.log(name), 60,
                     'the one-landmark map taken')
    # The stream starts over (a looped bag without /clock): the filter resets and goes on.
    received = len(bias)
    send(0, 100)
    probe.spin_until(lambda: (diagnostics_of(diagnostics, key) or {}).get('resets') == '1'
                     and len(bias) > received + 50, 120, 'a reset and new estimates')
    assert 'filter reset' in processes.log(name)
