"""The four shared course logs: convert, read back, compare with the raw .mat contents.

Raw values are decoded here directly from scipy.io.loadmat, independently of the readers.
Each log is converted once per module (the `converted` fixture) and the bags are re-read with
rosbags (`read_bag`) and, for mcap, with the mcap packages.
"""

from __future__ import annotations

from collections import Counter
import dataclasses
import math

import numpy as np
import pytest
import scipy.io
from test_bag_roundtrip import decoded_mcap
import yaml

from gyro_ekf.cli.main import main
from gyro_ekf.io.bag_reader import read_bag
from gyro_ekf.io.bag_writer import DEFAULT_EPOCH_NS

pytestmark = pytest.mark.shared_data

NS_PER_COUNT = 100_000  # one stamp count is 0.1 ms


def _load(path, name):
    return scipy.io.loadmat(path, squeeze_me=True, struct_as_record=False)[name]


def _bag_counts(bag):
    info = yaml.safe_load((bag / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    return {t['topic_metadata']['name']: t['message_count']
            for t in info['topics_with_message_count']}


def _stamps_ns(stamp_s, start_ns=DEFAULT_EPOCH_NS):
    return start_ns + np.rint(np.asarray(stamp_s) * 1e9).astype(np.int64)


def _matched_poles(trip, scan, k, pose, max_range_m=15.0, tolerance_m=0.15):
    """Count landmarks whose predicted beam in scan k sees a return at the predicted range.

    Uses the README's observation model in the ROS convention (0 = forward, CCW) with the
    LiDAR mount; a pole's surface is ~5 cm nearer than its centre.
    """
    x, y, phi = pose
    mount = scan.mount
    x_l = x + mount.x_m * math.cos(phi) - mount.y_m * math.sin(phi)
    y_l = y + mount.x_m * math.sin(phi) + mount.y_m * math.cos(phi)
    matched = []
    for xa, ya in trip.landmarks.xy_m:
        distance = math.hypot(xa - x_l, ya - y_l)
        bearing = math.atan2(ya - y_l, xa - x_l) - phi - mount.yaw_rad
        bearing = (bearing + math.pi) % (2 * math.pi) - math.pi
        if distance > max_range_m or not scan.angles_rad[1] < bearing < scan.angles_rad[-2]:
            continue
        beam = int(np.argmin(np.abs(scan.angles_rad - bearing)))
        near = scan.ranges_m[k, beam - 1:beam + 2]
        if np.min(np.abs(near - distance)) < tolerance_m:
            matched.append((xa, ya))
    return matched


def test_2021_counts_values_stamps(shared_data, converted):
    folder = shared_data('2021_aas01')
    trip, bag = converted('aas2021', [folder])
    raw = _load(folder / 'Measurements_AAS01.mat', 'A')
    samples = raw.Z[2] <= 0
    counts = _bag_counts(bag)
    assert counts == {'/landmark_map': 1, '/initialpose': 1, '/imu': int(samples.sum()),
                      '/odom': int(samples.sum()), '/scan': int((~samples).sum())}
    assert (counts['/imu'], counts['/odom'], counts['/scan']) == (44578, 44578, 8292)
    back = read_bag(bag)
    assert back.start_time_ns == DEFAULT_EPOCH_NS
    got = back.trip
    # Stamps: exactly (t - t0) counts of 0.1 ms after the start time, to the nanosecond.
    counts_rel = raw.t.astype(np.int64) - int(raw.t[0])
    np.testing.assert_array_equal(_stamps_ns(got.imu.stamp_s),
                                  DEFAULT_EPOCH_NS + counts_rel[samples] * NS_PER_COUNT)
    np.testing.assert_array_equal(_stamps_ns(got.scans[0].stamp_s),
                                  DEFAULT_EPOCH_NS + counts_rel[~samples] * NS_PER_COUNT)
    np.testing.assert_allclose(got.speed.speed_m_s, raw.Z[0][samples] * 1e-3, rtol=1e-15)
    np.testing.assert_allclose(got.imu.yaw_rate_rad_s,
                               raw.Z[1][samples] * 0.01 * math.pi / 180, rtol=1e-15)
    assert got.imu.axes_known == (False, False, True)
    assert not got.imu.angular_velocity_rad_s[:, :2].any()
    columns = raw.Z[2][~samples] - 1
    words = raw.scans[:, columns].T
    want = (words & 0x1FFF).astype(np.float32) / np.float32(100)
    want[(words & 0x1FFF) >= 8000] = np.inf
    np.testing.assert_array_equal(got.scans[0].ranges_m, want)
    np.testing.assert_array_equal(got.scans[0].intensities, (words >> 13).astype(np.float32))
    map_raw = _load(folder / 'MapMTRN4010.mat', 'Map')
    np.testing.assert_array_equal(got.landmarks.xy_m, np.column_stack([map_raw.x, map_raw.y]))
    np.testing.assert_allclose(got.initial_pose, [0, 0, math.pi / 2], atol=1e-15)
    assert got.scans[0].mount.x_m == 0.46


def test_2021_poles_at_the_right_bearing(shared_data, converted):
    trip, bag = converted('aas2021', [shared_data('2021_aas01')])
    got = read_bag(bag).trip
    scan = got.scans[0]
    # Static at the initial pose for the first scans: the poles show up where the map says,
    # as reflective returns (intensity > 0), 0 rad = forward.
    matched = _matched_poles(got, scan, 0, got.initial_pose)
    assert len(matched) >= 4, matched
    for xa, ya in matched:
        x_l, y_l = 0.0, 0.46
        bearing = math.atan2(ya - y_l, xa - x_l) - math.pi / 2
        beam = int(np.argmin(np.abs(scan.angles_rad - bearing)))
        assert scan.intensities[0, beam - 2:beam + 3].max() > 0
    # The old 0 = right convention would put them 90 deg off.
    shifted = dataclasses.replace(scan, angle_min_rad=0.0)
    assert len(_matched_poles(got, shifted, 0, got.initial_pose)) < len(matched)


def test_2021_mcap_decodes_every_message(shared_data, converted):
    trip, bag = converted('aas2021', [shared_data('2021_aas01')])
    counts: Counter[str] = Counter()
    yaw = []
    for item in decoded_mcap(bag / 'aas2021.mcap'):
        counts[item.channel.topic] += 1
        if item.channel.topic == '/imu':
            yaw.append(item.ros_msg.angular_velocity.z)
        elif item.channel.topic == '/scan' and counts['/scan'] == 1:
            assert item.ros_msg.angle_min == pytest.approx(-math.pi / 2)
            assert item.ros_msg.header.frame_id == 'laser'
    assert dict(counts) == _bag_counts(bag)
    np.testing.assert_array_equal(yaw, trip.imu.yaw_rate_rad_s)


def test_2016_trio_with_map_matches_2021(shared_data, converted, tmp_path):
    folder = shared_data('2016_project1')
    map_path = shared_data('2021_aas01/MapMTRN4010.mat')
    out = tmp_path / 'p2016'
    assert main(['convert', str(folder), '--map', str(map_path), '-o', str(out)]) == 0
    counts = _bag_counts(out)
    assert counts == {'/landmark_map': 1, '/initialpose': 1, '/imu': 44578, '/odom': 44578,
                      '/scan': 8292}
    got = read_bag(out).trip
    imu = _load(folder / 'IMU_dataC.mat', 'IMU')
    np.testing.assert_array_equal(got.imu.angular_velocity_rad_s, imu.DATAf[3:6].T)
    np.testing.assert_allclose(got.imu.linear_acceleration_m_s2,
                               imu.DATAf[0:3].T.astype(np.float64) * 9.80665, rtol=1e-15)
    vel = _load(folder / 'Speed_dataC.mat', 'Vel')
    np.testing.assert_array_equal(got.speed.speed_m_s, vel.speeds)
    # Same trip as 2021: same relative stamps, same scans, yaw rates equal to the 2021
    # quantisation (0.01 deg/s), which also confirms the +DATAf(6,:) sign.
    trip21, bag21 = converted('aas2021', [shared_data('2021_aas01')])
    np.testing.assert_array_equal(got.imu.stamp_s, trip21.imu.stamp_s)
    np.testing.assert_array_equal(got.scans[0].stamp_s, trip21.scans[0].stamp_s)
    np.testing.assert_array_equal(got.scans[0].ranges_m, trip21.scans[0].ranges_m)
    np.testing.assert_allclose(got.imu.yaw_rate_rad_s, trip21.imu.yaw_rate_rad_s, rtol=0,
                               atol=math.radians(0.005) + 1e-9)


def test_2016_without_map_has_no_landmark_topic(shared_data, tmp_path):
    out = tmp_path / 'nomap'
    assert main(['convert', str(shared_data('2016_project1')), '-o', str(out)]) == 0
    assert '/landmark_map' not in _bag_counts(out)


def test_2022_sqlite3_counts_values_truth_sidecar(shared_data, converted):
    path = shared_data('2022_sim/data019b.mat')
    trip, bag = converted('sim2022', [path], 'sqlite3')
    assert (bag / 'sim2022.db3').exists()
    raw = _load(path, 'data')
    kinds = raw.table[2]
    counts = _bag_counts(bag)
    assert counts == {'/landmark_map': 1, '/initialpose': 1, '/imu': int((kinds == 2).sum()),
                      '/odom': int((kinds == 2).sum()), '/scan': int((kinds == 1).sum()),
                      '/ground_truth': int((kinds == 1).sum())}
    back = read_bag(bag)  # rosbags reads the sqlite3 bag
    got = back.trip
    columns = raw.table[1][kinds == 2] - 1
    np.testing.assert_array_equal(got.speed.speed_m_s, raw.vw[0, columns])
    np.testing.assert_array_equal(got.imu.yaw_rate_rad_s, raw.vw[1, columns])
    np.testing.assert_array_equal(_stamps_ns(got.imu.stamp_s),
                                  DEFAULT_EPOCH_NS + raw.table[0][kinds == 2].astype(np.int64)
                                  * NS_PER_COUNT)
    scan_columns = raw.table[1][kinds == 1] - 1
    truth = raw.verify.poseL[:, scan_columns].T
    np.testing.assert_allclose(got.ground_truth.pose[:, :2], truth[:, :2], rtol=0, atol=1e-6)
    # A quaternion carries the heading modulo 2 pi (the log's runs past +pi).
    yaw_error = np.angle(np.exp(1j * (got.ground_truth.pose[:, 2] - truth[:, 2])))
    np.testing.assert_allclose(yaw_error, 0.0, rtol=0, atol=1e-6)
    np.testing.assert_array_equal(got.scans[0].ranges_m,
                                  raw.scans[:, scan_columns].T.astype(np.float32) / 100)
    np.testing.assert_array_equal(got.landmarks.xy_m, raw.Landmarks.T)
    np.testing.assert_allclose(got.initial_pose, raw.pose0, rtol=0, atol=1e-6)
    assert got.scans[0].mount.x_m == 0.4 and got.scans[0].mount.yaw_rad == 0.0
    assert got.noise.speed_m_s == pytest.approx(raw.etc.ns[0], rel=1e-7)
    assert got.noise.gyro_rad_s == pytest.approx(raw.etc.ns[1], rel=1e-7)
    np.testing.assert_allclose(got.true_gyro_bias_rad_s, [0, 0, 0.005236], atol=1e-6)
    assert back.params.true_gyro_bias_rad_s is not None


def test_2022_poles_at_the_right_bearing(shared_data, converted):
    trip, bag = converted('sim2022', [shared_data('2022_sim/data019b.mat')], 'sqlite3')
    got = read_bag(bag).trip
    for k in (0, len(got.scans[0].stamp_s) // 2):
        matched = _matched_poles(got, got.scans[0], k, got.ground_truth.pose[k])
        assert len(matched) >= 3, (k, matched)


def test_2023_two_lidars(shared_data, converted):
    path = shared_data('2023_sim/DataUsr_006k.mat')
    trip, bag = converted('sim2023', [path])
    raw = _load(path, 'data')
    scans = int((raw.table[2] == 1).sum())
    counts = _bag_counts(bag)
    assert counts['/scan'] == counts['/scan2'] == counts['/ground_truth'] == scans
    assert counts['/imu'] == counts['/odom'] == int((raw.table[2] == 2).sum())
    decoded = Counter(item.channel.topic for item in decoded_mcap(bag / 'sim2023.mcap'))
    assert dict(decoded) == counts
    got = read_bag(bag).trip
    first, second = got.scans
    assert (second.topic, second.frame_id) == ('scan2', 'laser2')
    assert second.mount.yaw_rad == pytest.approx(math.pi)
    columns = raw.table[1][raw.table[2] == 1] - 1
    words = raw.scans2[:, columns].T
    want = (words & 16383).astype(np.float32) / np.float32(100)
    want[(words & 16383) == 0] = np.inf
    np.testing.assert_array_equal(second.ranges_m, want)
    np.testing.assert_array_equal(second.intensities, (words >> 14).astype(np.float32))
    k = len(first.stamp_s) // 2
    assert len(_matched_poles(got, first, k, got.ground_truth.pose[k])) >= 3
    assert len(_matched_poles(got, second, k, got.ground_truth.pose[k])) >= 2
