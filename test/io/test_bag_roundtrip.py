"""Trip -> bag -> Trip round trips, the bag's layout and metadata, and the params sidecar."""

from __future__ import annotations

from collections import Counter
import math
from pathlib import Path
import re
import tracemalloc

from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
import numpy as np
import pytest
from synthetic_logs import leftovers, make_trip
import yaml

from gyro_ekf.core.types import Trip
from gyro_ekf.io.bag_reader import iter_bag_messages, read_bag, read_trip_bag
from gyro_ekf.io.bag_writer import DEFAULT_EPOCH_NS, write_trip_bag
from gyro_ekf.io.errors import BagError
from gyro_ekf.io.messages import TYPESTORE
from gyro_ekf.io.sidecar import read_sidecar, sidecar_path

START_NS = 1_712_345_678_123_456_789


def _counts(trip: Trip) -> dict[str, int]:
    counts = {'/initialpose': 1, '/imu': len(trip.imu.stamp_s),
              '/odom': len(trip.speed.stamp_s)}
    counts.update({'/' + s.topic: len(s.stamp_s) for s in trip.scans})
    if trip.landmarks is not None:
        counts['/landmark_map'] = 1
    if trip.ground_truth is not None:
        counts['/ground_truth'] = len(trip.ground_truth.stamp_s)
    return counts


class Decoded:
    """One message decoded by the mcap packages (not rosbags)."""

    def __init__(self, channel, message, ros_msg) -> None:
        self.channel = channel
        self.log_time_ns = message.log_time
        self.ros_msg = ros_msg


def decoded_mcap(path: Path):
    """Yield every message of an mcap file, decoded by mcap + mcap-ros2-support."""
    with open(path, 'rb') as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        for _, channel, message, ros_msg in reader.iter_decoded_messages(log_time_order=True):
            yield Decoded(channel, message, ros_msg)


def assert_same_trip(back: Trip, trip: Trip, stamp_atol: float = 1e-9) -> None:
    """Require a read-back trip to equal the original (float32 fields to their precision)."""
    assert back.name == trip.name
    for got, want in ((back.imu.stamp_s, trip.imu.stamp_s),
                      (back.speed.stamp_s, trip.speed.stamp_s)):
        np.testing.assert_allclose(got, want, rtol=0, atol=stamp_atol)
    np.testing.assert_array_equal(back.imu.angular_velocity_rad_s,
                                  np.asarray(trip.imu.angular_velocity_rad_s) * np.array(
                                      trip.imu.axes_known))
    assert back.imu.axes_known == trip.imu.axes_known
    if trip.imu.linear_acceleration_m_s2 is None:
        assert back.imu.linear_acceleration_m_s2 is None
    else:
        np.testing.assert_array_equal(back.imu.linear_acceleration_m_s2,
                                      trip.imu.linear_acceleration_m_s2)
    np.testing.assert_array_equal(back.speed.speed_m_s, trip.speed.speed_m_s)
    assert len(back.scans) == len(trip.scans)
    for got, want in zip(back.scans, trip.scans):
        assert (got.topic, got.frame_id, got.mount) == (want.topic, want.frame_id, want.mount)
        np.testing.assert_allclose(got.stamp_s, want.stamp_s, rtol=0, atol=stamp_atol)
        np.testing.assert_array_equal(got.ranges_m, want.ranges_m)
        if want.intensities is None:
            assert got.intensities is None
        else:
            np.testing.assert_array_equal(got.intensities, want.intensities)
        for name in ('angle_min_rad', 'angle_increment_rad', 'range_min_m', 'range_max_m'):
            assert getattr(got, name) == pytest.approx(getattr(want, name), rel=1e-7, abs=1e-7)
    if trip.landmarks is None:
        assert back.landmarks is None
    else:
        np.testing.assert_array_equal(back.landmarks.xy_m, trip.landmarks.xy_m)
    np.testing.assert_allclose(back.initial_pose, trip.initial_pose, rtol=0, atol=1e-12)
    if trip.ground_truth is None:
        assert back.ground_truth is None
    else:
        np.testing.assert_allclose(back.ground_truth.stamp_s, trip.ground_truth.stamp_s,
                                   rtol=0, atol=stamp_atol)
        np.testing.assert_allclose(back.ground_truth.pose, trip.ground_truth.pose, rtol=0,
                                   atol=1e-12)
    if trip.true_gyro_bias_rad_s is None:
        assert back.true_gyro_bias_rad_s is None
    else:
        np.testing.assert_array_equal(back.true_gyro_bias_rad_s, trip.true_gyro_bias_rad_s)
    assert back.noise == trip.noise
    assert back.static_duration_s == trip.static_duration_s


@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
def test_round_trip_equals_the_trip(tmp_path, synthetic_trip, storage):
    bag = write_trip_bag(synthetic_trip, tmp_path / 'bag', storage=storage,
                         start_time_ns=START_NS)
    back = read_bag(bag)
    assert back.start_time_ns == START_NS
    assert back.params is not None and back.params.log_time_zero_ns == START_NS
    assert_same_trip(back.trip, synthetic_trip)
    assert_same_trip(read_trip_bag(bag), synthetic_trip)


def test_bag_folder_is_plain_rosbag2_and_sidecar_sits_beside(tmp_path, synthetic_trip):
    bag = write_trip_bag(synthetic_trip, tmp_path / 'out')
    assert sorted(p.name for p in bag.iterdir()) == ['metadata.yaml', 'out.mcap']
    assert leftovers(tmp_path) == ['out', 'out.params.yaml']
    assert sidecar_path(bag) == tmp_path / 'out.params.yaml'
    bag_sql = write_trip_bag(synthetic_trip, tmp_path / 'sql', storage='sqlite3')
    assert sorted(p.name for p in bag_sql.iterdir()) == ['metadata.yaml', 'sql.db3']


def test_metadata_version_hashes_and_qos(tmp_path, synthetic_trip):
    bag = write_trip_bag(synthetic_trip, tmp_path / 'bag')
    info = yaml.safe_load((bag / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    assert info['version'] == 9
    assert info['storage_identifier'] == 'mcap'
    assert info['starting_time']['nanoseconds_since_epoch'] == DEFAULT_EPOCH_NS
    topics = {t['topic_metadata']['name']: t for t in info['topics_with_message_count']}
    assert {name: t['message_count'] for name, t in topics.items()} == _counts(
        synthetic_trip)
    for name, entry in topics.items():
        meta = entry['topic_metadata']
        assert re.fullmatch(r'RIHS01_[0-9a-f]{64}', meta['type_description_hash']), name
        assert meta['type_description_hash'] == TYPESTORE.hash_rihs01(meta['type'])
        (qos,) = meta['offered_qos_profiles']
        latched = name in ('/landmark_map', '/initialpose')
        assert qos['durability'] == ('transient_local' if latched else 'volatile'), name
        assert qos['reliability'] == 'reliable'


def test_mcap_decodes_with_the_independent_reader(tmp_path, synthetic_trip):
    bag = write_trip_bag(synthetic_trip, tmp_path / 'bag', start_time_ns=START_NS)
    counts: Counter[str] = Counter()
    last = 0
    first_imu = None
    for item in decoded_mcap(bag / 'bag.mcap'):
        counts[item.channel.topic] += 1
        assert item.log_time_ns >= last
        last = item.log_time_ns
        stamp = item.ros_msg.header.stamp
        assert stamp.sec * 10**9 + stamp.nanosec == item.log_time_ns
        if item.channel.topic == '/imu' and first_imu is None:
            first_imu = item.ros_msg
        if item.channel.topic == '/scan2':
            assert item.ros_msg.header.frame_id == 'laser2'
            assert len(item.ros_msg.intensities) == 0
    assert dict(counts) == _counts(synthetic_trip)
    assert first_imu.header.frame_id == 'imu_link'
    assert first_imu.orientation_covariance[0] == -1.0
    assert first_imu.angular_velocity.z == synthetic_trip.imu.angular_velocity_rad_s[0, 2]
    assert first_imu.angular_velocity_covariance[8] == pytest.approx(0.02 ** 2)


def test_messages_interleave_in_time_order_with_latched_first(tmp_path, synthetic_trip):
    bag = write_trip_bag(synthetic_trip, tmp_path / 'bag', storage='sqlite3')
    stream = list(iter_bag_messages(bag))
    assert [m.topic for m in stream[:2]] == ['/landmark_map', '/initialpose']
    stamps = [m.stamp_ns for m in stream]
    assert stamps == sorted(stamps)
    assert stamps[0] == DEFAULT_EPOCH_NS
    # Interleaved, not topic after topic.
    assert len({m.topic for m in stream[2:40]}) >= 2
    only_scan2 = list(iter_bag_messages(bag, ['scan2']))
    assert {m.topic for m in only_scan2} == {'/scan2'}
    with pytest.raises(BagError, match="no topic '/nope'"):
        list(iter_bag_messages(bag, ['nope']))


def test_yaw_only_gyro_and_missing_accel_round_trip(tmp_path):
    trip = make_trip(seed=3)
    rates = np.asarray(trip.imu.angular_velocity_rad_s).copy()
    rates[:, :2] = 0.0
    from dataclasses import replace
    from gyro_ekf.core.types import ImuSeries, NoiseFigures
    trip = replace(trip, imu=ImuSeries(trip.imu.stamp_s, rates, (False, False, True), None),
                   noise=NoiseFigures(), true_gyro_bias_rad_s=None, ground_truth=None,
                   landmarks=None)
    bag = write_trip_bag(trip, tmp_path / 'bag')
    assert_same_trip(read_trip_bag(bag), trip)
    first = next(iter_bag_messages(bag, ['imu'])).message
    assert first.linear_acceleration_covariance[0] == -1.0
    assert first.angular_velocity_covariance[0] >= 1e6  # unknown axis, not REP-145's -1
    assert first.angular_velocity_covariance[8] == 0.0  # known axis, variance not stated


def test_sidecar_is_a_ros2_params_file(tmp_path, synthetic_trip):
    bag = write_trip_bag(synthetic_trip, tmp_path / 'bag', start_time_ns=START_NS)
    document = yaml.safe_load(sidecar_path(bag).read_text())
    params = document['/**']['ros__parameters']
    assert params['lidar']['topics'] == ['scan', 'scan2']
    assert params['lidar']['scan2'] == {'frame_id': 'laser2', 'x_m': -0.2, 'y_m': 0.0,
                                        'yaw_rad': math.pi}
    assert params['initial_pose'] == {'x_m': 1.5, 'y_m': -2.5, 'yaw_rad': 0.7}
    # An exact map (0) is a statement, not a missing figure.
    assert params['noise'] == {'gyro_rad_s': 0.02, 'speed_m_s': 0.05, 'bearing_rad': 0.01,
                               'landmark_m': 0.0}
    assert params['true_gyro_bias_rad_s'] == [0.001, -0.002, 0.003]
    assert params['trip']['log_time_zero_ns'] == START_NS
    sidecar = read_sidecar(bag)
    assert sidecar.lidars['scan'][1] == synthetic_trip.scans[0].mount
    rclpy_parameter = pytest.importorskip('rclpy.parameter')
    flat = rclpy_parameter.parameter_dict_from_yaml_file(str(sidecar_path(bag)),
                                                         use_wildcard=True)
    values = {k: rclpy_parameter.parameter_value_to_python(v.value) for k, v in flat.items()}
    assert values['lidar.scan.x_m'] == 0.3
    assert values['true_gyro_bias_rad_s'] == [0.001, -0.002, 0.003]
    assert values['trip.log_time_zero_ns'] == START_NS


def test_reader_without_sidecar_warns_and_defaults(tmp_path, synthetic_trip, caplog):
    bag = write_trip_bag(synthetic_trip, tmp_path / 'bag')
    sidecar_path(bag).unlink()
    back = read_bag(bag)
    assert back.params is None
    assert back.trip.scans[0].mount.x_m == 0.0
    assert 'no params sidecar' in caplog.text


def test_reader_errors(tmp_path, synthetic_trip):
    with pytest.raises(BagError, match='no such bag'):
        read_trip_bag(tmp_path / 'missing')
    (tmp_path / 'empty').mkdir()
    with pytest.raises(BagError, match='no metadata.yaml'):
        read_trip_bag(tmp_path / 'empty')
    bag = write_trip_bag(synthetic_trip, tmp_path / 'bag')
    (bag / 'bag.mcap').write_bytes(b'not an mcap file')
    with pytest.raises(BagError, match='bag'):
        read_trip_bag(bag)
    sidecar_path(bag).write_text('/**:\n  ros__parameters:\n    trip: {name: x}\n')
    with pytest.raises(BagError, match=r"bag.params.yaml: parameter '[a-z_.]+' is missing"):
        read_sidecar(bag)


def test_sidecar_noise_figures_must_be_non_negative(tmp_path, synthetic_trip):
    bag = write_trip_bag(synthetic_trip, tmp_path / 'bag')
    text = sidecar_path(bag).read_text()
    assert 'landmark_m: 0.0' in text
    sidecar_path(bag).write_text(text.replace('landmark_m: 0.0', 'landmark_m: -1.0'))
    with pytest.raises(BagError, match=r"bag.params.yaml: parameter 'noise.landmark_m' must "
                                       r'be a non-negative number'):
        read_sidecar(bag)


def test_stated_figures_are_checked_like_parameters():
    from gyro_ekf.core.config import EkfConfig, with_stated_noise
    from gyro_ekf.core.errors import CoreError
    from gyro_ekf.core.types import NoiseFigures
    assert with_stated_noise(EkfConfig(), NoiseFigures(landmark_m=0.0)).landmark_sigma_m == 0.0
    with pytest.raises(CoreError, match='stated noise figures.*landmark_sigma_m'):
        with_stated_noise(EkfConfig(), NoiseFigures(landmark_m=20.0))


def test_bag_without_imu_topic_is_refused(tmp_path):
    from rosbags.rosbag2 import Writer
    from gyro_ekf.io.messages import initial_pose_message, serialize
    with Writer(tmp_path / 'other', version=9) as writer:
        connection = writer.add_connection('/initialpose',
                                           'geometry_msgs/msg/PoseWithCovarianceStamped',
                                           typestore=TYPESTORE)
        writer.write(connection, 5, serialize(initial_pose_message(5, np.zeros(3))))
    with pytest.raises(BagError, match=r"other: no topic '/imu'"):
        read_trip_bag(tmp_path / 'other')


def test_progress_reaches_the_total(tmp_path, synthetic_trip):
    calls: list[tuple[int, int]] = []
    write_trip_bag(synthetic_trip, tmp_path / 'bag',
                   progress=lambda done, total: calls.append((done, total)))
    total = sum(_counts(synthetic_trip).values())
    assert calls[-1] == (total, total)
    assert all(t == total for _, t in calls)


def test_memory_stays_bounded_by_the_trip(tmp_path):
    """Writing never holds all messages: the peak stays well below the bag's size."""
    trip = make_trip(seed=1, n=20_000, m=600)
    tracemalloc.start()
    try:
        bag = write_trip_bag(trip, tmp_path / 'bag')
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    bag_bytes = sum(p.stat().st_size for p in Path(bag).iterdir())
    print(f'bag {bag_bytes / 1e6:.1f} MB, peak traced {peak / 1e6:.1f} MB')
    assert peak < bag_bytes / 2


def _report_that_dropped_samples():
    from gyro_ekf.core.validation import InputReport
    report = InputReport(source='IMU_dataC.mat, Speed_dataC.mat', skip_bad=True)
    report.count('imu.angular_velocity.z', 'not finite', 20000, 10)
    report.count('imu.stamp_s', 'time went back', 30000, 5)
    report.count('speed.speed_m_s', 'beyond limit', 7, 1)
    report.samples_dropped.update({'imu': 15, 'speed': 1})
    report.time_breaks['imu'] = 1
    return report


def test_what_a_conversion_dropped_is_kept_in_the_sidecar_as_ros_parameters(
        tmp_path, synthetic_trip):
    # convert --skip-bad used to leave no trace of the samples it dropped in the bag.
    dropped = _report_that_dropped_samples()
    bag = write_trip_bag(synthetic_trip, tmp_path / 'bag', converted=dropped)
    back = read_bag(bag)
    assert back.converted is not None and back.params.converted is back.converted
    assert back.converted.source == dropped.source
    assert back.converted.dropped == dropped.dropped
    assert back.converted.first_index == dropped.first_index
    assert back.converted.samples_dropped == {'imu': 15, 'speed': 1}
    assert back.converted.time_breaks == {'imu': 1}
    # A ROS 2 params file still: flat names with scalar or homogeneous list values.
    rclpy_parameter = pytest.importorskip('rclpy.parameter')
    flat = rclpy_parameter.parameter_dict_from_yaml_file(str(sidecar_path(bag)),
                                                         use_wildcard=True)
    values = {k: rclpy_parameter.parameter_value_to_python(v.value) for k, v in flat.items()}
    assert values['trip.dropped_when_converted.counts'] == [10, 5, 1]
    assert values['trip.dropped_when_converted.reasons'] == ['not finite', 'time went back',
                                                             'beyond limit']
    # Nothing dropped, nothing written.
    from gyro_ekf.core.validation import InputReport
    clean = write_trip_bag(synthetic_trip, tmp_path / 'clean',
                           converted=InputReport(source='x.mat', skip_bad=True))
    assert 'dropped_when_converted' not in sidecar_path(clean).read_text()
    assert read_bag(clean).converted is None


@pytest.mark.parametrize('old, new, match', [
    ('counts:\n        - 10', 'counts:\n        - -10', r"'trip.dropped_when_converted.counts' "
     'must be a list of non-negative whole numbers, got -10'),
    ('reasons:\n        - not finite\n', 'reasons:\n', r"'trip.dropped_when_converted': "
     'fields, reasons, counts, first_indexes must be lists of one non-zero length'),
    ('        source: IMU_dataC.mat, Speed_dataC.mat\n', '',
     r"'trip.dropped_when_converted.source' is missing"),
])
def test_a_damaged_conversion_record_in_the_sidecar_names_the_parameter(
        tmp_path, synthetic_trip, old, new, match):
    bag = write_trip_bag(synthetic_trip, tmp_path / 'bag',
                         converted=_report_that_dropped_samples())
    text = sidecar_path(bag).read_text()
    assert text.count(old) == 1, text
    sidecar_path(bag).write_text(text.replace(old, new))
    with pytest.raises(BagError, match='bag.params.yaml: parameter ' + match):
        read_sidecar(bag)
