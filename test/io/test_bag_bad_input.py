"""Bags whose messages are valid CDR but say something impossible: refused in one line.

Each test writes a bag of the synthetic trip with the project's writer, rewrites its
messages (in file order, through rosbags' Writer, chunk CRCs on) with one change, and reads
it back with the fast reader, with read_bag's rosbags path and with the test oracle
(rosbags_oracle), which must all refuse it naming bag, topic, field and message index.
"""

from __future__ import annotations

from collections.abc import Callable
import copy
import dataclasses
import functools
import math
from pathlib import Path
from typing import Any

from bag_edit import Item, of, rewrite
import numpy as np
import pytest
from rosbags_oracle import read_bag_rosbags
from synthetic_logs import make_trip

from gyro_ekf.cli.main import main
from gyro_ekf.core.errors import InvalidInputError
from gyro_ekf.core.validation import validate_trip
from gyro_ekf.io import bag_reader, messages as msgs
from gyro_ekf.io.bag_reader import read_bag
from gyro_ekf.io.bag_writer import write_trip_bag
from gyro_ekf.io.errors import BagError
from gyro_ekf.io.sidecar import sidecar_path


@functools.lru_cache(maxsize=1)
def _trip():
    return make_trip(n=400, m=30)


@pytest.fixture(scope='module')
def clean_bag(tmp_path_factory) -> Path:
    """The synthetic trip as the project's writer writes it."""
    return write_trip_bag(_trip(), tmp_path_factory.mktemp('clean') / 'clean')


def _read_rosbags_path(path: Path) -> Any:
    """read_bag through its rosbags path (what a bag mcap_chunks cannot read takes)."""
    original = bag_reader._single_mcap_file
    bag_reader._single_mcap_file = lambda path: None
    try:
        return read_bag(path)
    finally:
        bag_reader._single_mcap_file = original


READERS = pytest.mark.parametrize('read', [read_bag, _read_rosbags_path, read_bag_rosbags],
                                  ids=['fast', 'rosbags_path', 'oracle'])


def _set_rate_covariance(item: Item, index: int, value: float) -> None:
    covariance = np.array(item[3].angular_velocity_covariance, dtype=np.float64)
    covariance[index] = value
    item[3].angular_velocity_covariance = covariance


# -- (a) the IMU's measured axes are judged on every message ---------------------------


@pytest.mark.parametrize('message, entry, value, match', [
    (0, 0, -1.0, 'message index 0: angular_velocity_covariance[0] = -1 (REP-145'),
    (0, 8, 1e6, 'message index 0: angular_velocity_covariance[8] = 1e+06'),
    (37, 8, 1e6, 'message index 37: angular_velocity_covariance[8] = 1e+06')])
@READERS
def test_an_imu_message_marking_the_yaw_rate_not_measured_is_refused(
        tmp_path, clean_bag, read, message, entry, value, match):
    # Before, a first message so marked made the whole bag's yaw axis "unknown": its
    # values were never checked and the offline bias came out 0.
    def change(items):
        _set_rate_covariance(of(items, '/imu')[message], entry, value)
    bag = rewrite(clean_bag, tmp_path / 'bag', change)
    with pytest.raises(BagError, match=r"bag: topic '/imu': ") as error:
        read(bag)
    assert match in str(error.value) and 'yaw rate (z) is not measured' in str(error.value)


@READERS
def test_imu_messages_disagreeing_on_the_measured_axes_are_refused(tmp_path, clean_bag, read):
    def change(items):
        _set_rate_covariance(of(items, '/imu')[5], 0, 1e6)   # x "not measured" here only
    bag = rewrite(clean_bag, tmp_path / 'bag', change)
    with pytest.raises(BagError, match=(
            r"bag: topic '/imu': message index 5: angular_velocity_covariance marks the axes "
            r'y, z as measured, the messages before it x, y, z')):
        read(bag)


def test_a_log_marking_x_and_y_unknown_in_every_message_reads_as_before(tmp_path):
    # What `gyro-ekf convert` writes for a z-only gyro: 1e6 on x and y in every message.
    trip = _trip()
    z_only = dataclasses.replace(trip.imu, axes_known=(False, False, True))
    bag = write_trip_bag(dataclasses.replace(trip, imu=z_only), tmp_path / 'z')
    for read in (read_bag, _read_rosbags_path, read_bag_rosbags):
        imu = read(bag).trip.imu
        assert imu.axes_known == (False, False, True)
        np.testing.assert_array_equal(imu.angular_velocity_rad_s[:, 2],
                                      trip.imu.angular_velocity_rad_s[:, 2])


def test_run_refuses_a_first_imu_message_without_angular_velocity_in_one_line(
        tmp_path, clean_bag, capsys):
    def change(items):
        _set_rate_covariance(of(items, '/imu')[0], 0, -1.0)
    bag = rewrite(clean_bag, tmp_path / 'bag', change)
    assert main(['-q', 'run', str(bag), '-o', str(tmp_path / 'out')]) == 1
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and 'Traceback' not in err, err
    assert "topic '/imu': message index 0: angular_velocity_covariance[0] = -1" in err
    assert not (tmp_path / 'out').exists()


# -- (b) a scan's angle_max must be its last beam's bearing ----------------------------


def _angle_max_zero(scan: Any) -> None:
    scan.angle_max = 0.0


def _increment_negated(scan: Any) -> None:
    scan.angle_increment = -scan.angle_increment


@pytest.mark.parametrize('change_scan', [_angle_max_zero, _increment_negated],
                         ids=['angle_max_0', 'increment_negated'])
@READERS
def test_a_scan_whose_angles_disagree_with_its_ranges_is_refused(tmp_path, clean_bag, read,
                                                                 change_scan):
    def change(items):
        for item in of(items, '/scan'):
            change_scan(item[3])
    bag = rewrite(clean_bag, tmp_path / 'bag', change)
    with pytest.raises(BagError, match=(r"bag: topic '/scan': message index 0: angle_max "
                                        r'.* disagrees with its 181 ranges')):
        read(bag)


@READERS
def test_one_scan_mid_bag_with_a_wrong_angle_max_is_named(tmp_path, clean_bag, read):
    def change(items):
        of(items, '/scan2')[12][3].angle_max = math.pi
    bag = rewrite(clean_bag, tmp_path / 'bag', change)
    with pytest.raises(BagError, match=r"topic '/scan2': message index 12: angle_max 3.14159"):
        read(bag)


@READERS
def test_a_scan_listed_from_left_to_right_with_consistent_angles_is_read(tmp_path, clean_bag,
                                                                         read):
    def change(items):
        for item in of(items, '/scan'):
            scan = copy.deepcopy(item[3])
            scan.angle_min, scan.angle_max = item[3].angle_max, item[3].angle_min
            scan.angle_increment = -item[3].angle_increment
            scan.ranges = item[3].ranges[::-1].copy()
            scan.intensities = item[3].intensities[::-1].copy()
            item[3] = scan
    bag = rewrite(clean_bag, tmp_path / 'bag', change)
    scan = read(bag).trip.scans[0]
    assert scan.angle_increment_rad < 0
    np.testing.assert_array_equal(scan.ranges_m, _trip().scans[0].ranges_m[:, ::-1])


@READERS
def test_a_huge_rate_variance_on_the_first_imu_message_is_a_bad_covariance(
        tmp_path, clean_bag, read):
    # Not the not-measured marker: the yaw axis stays measured and its values checked;
    # core.validation ignores and counts the variance.
    def change(items):
        _set_rate_covariance(of(items, '/imu')[0], 8, 1e300)
    imu = read(rewrite(clean_bag, tmp_path / 'bag', change)).trip.imu
    assert imu.axes_known == (True, True, True)
    assert imu.yaw_rate_variance[0] == 1e300


# -- (c) the initial pose's quaternion -------------------------------------------------


def _scale_quaternion(factor: float, only_z: bool = False):
    def change(items):
        q = of(items, '/initialpose')[0][3].pose.pose.orientation
        q.z *= factor
        if not only_z:
            q.x, q.y, q.w = q.x * factor, q.y * factor, q.w * factor
    return change


@pytest.mark.parametrize('change, match', [
    (_scale_quaternion(0.0), 'quaternion norm 0 is not 1'),
    (_scale_quaternion(5.0, only_z=True), 'quaternion norm 1.95'),
    (_scale_quaternion(1.02), 'quaternion norm 1.02 is not 1')], ids=['zero', 'z_times_5', '1.02'])
@READERS
def test_an_initial_pose_whose_quaternion_is_none_is_refused(tmp_path, clean_bag, read, change,
                                                             match):
    bag = rewrite(clean_bag, tmp_path / 'bag', change)
    with pytest.raises(BagError, match=(r"bag: topic '/initialpose': pose.pose.orientation: "
                                        + match)):
        read(bag)


@READERS
def test_an_initial_pose_quaternion_within_the_norm_limit_is_read(tmp_path, clean_bag, read):
    bag = rewrite(clean_bag, tmp_path / 'bag', _scale_quaternion(1.005))
    # The yaw formula assumes a unit quaternion: 0.5 % off the norm moves it 6 mrad.
    np.testing.assert_allclose(read(bag).trip.initial_pose, _trip().initial_pose, atol=0.01)


# -- (d) one map, one initial pose, each landmark once ---------------------------------


def _second(topic: str, edit: Callable[[Any], None] | None):
    """Insert a copy of the topic's message 1 ns after it, edited by edit (None: identical)."""
    def change(items):
        at = next(k for k, item in enumerate(items) if item[0] == topic)
        copy_ = copy.deepcopy(items[at])
        copy_[2] += 1
        copy_[3].header.stamp = msgs.to_time(copy_[2])
        if edit is not None:
            edit(copy_[3])
        items.insert(at + 1, copy_)
    return change


def _move_pose(message: Any) -> None:
    message.pose.pose.position.x = 3.0


def _three_landmarks(message: Any) -> None:
    message.poses = message.poses[:3]


@pytest.mark.parametrize('topic, edit', [('/initialpose', _move_pose),
                                         ('/landmark_map', _three_landmarks)])
@READERS
def test_two_different_maps_or_initial_poses_are_refused_naming_both(tmp_path, clean_bag, read,
                                                                     topic, edit):
    bag = rewrite(clean_bag, tmp_path / 'bag', _second(topic, edit))
    with pytest.raises(BagError, match=(rf"bag: topic '{topic}': message index 0 and message "
                                        r'index 1 differ')):
        read(bag)


@READERS
def test_identical_copies_of_the_map_and_the_initial_pose_are_fine(tmp_path, clean_bag, read):
    def change(items):
        _second('/initialpose', None)(items)
        _second('/landmark_map', None)(items)
    trip = read(rewrite(clean_bag, tmp_path / 'bag', change)).trip
    np.testing.assert_array_equal(trip.landmarks.xy_m, _trip().landmarks.xy_m)
    np.testing.assert_allclose(trip.initial_pose, _trip().initial_pose, atol=1e-12)


def _landmark_twice(message: Any) -> None:
    twin = copy.deepcopy(message.poses[2])
    twin.position.x += 0.0005
    message.poses.append(twin)


@pytest.mark.parametrize('edit, match', [
    (_landmark_twice, 'landmarks 2 and 7 are 0.5 mm apart'),
    (lambda message: setattr(message, 'poses', []), 'the map lists no landmark')],
    ids=['duplicated', 'empty'])
@READERS
def test_a_map_with_a_landmark_twice_or_none_is_refused(tmp_path, clean_bag, read, edit, match):
    # Read as it is; the validation boundary refuses it, for bags and course logs alike.
    def change(items):
        edit(of(items, '/landmark_map')[0][3])
    bag = rewrite(clean_bag, tmp_path / 'bag', change)
    with pytest.raises(InvalidInputError, match=rf'bag: landmarks.xy_m: {match}'):
        validate_trip(read(bag).trip, 'bag')


def test_calibrate_mounts_on_an_empty_map_is_one_line(tmp_path, clean_bag, capsys):
    # It used to end in a ValueError traceback from mount_calibration._nearest.
    def change(items):
        of(items, '/landmark_map')[0][3].poses = []
    bag = rewrite(clean_bag, tmp_path / 'bag', change)
    assert main(['-q', 'calibrate-mounts', str(bag), '-o', str(tmp_path / 'm.yaml')]) == 1
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and 'Traceback' not in err, err
    assert 'landmarks.xy_m: the map lists no landmark' in err


def test_a_file_given_for_the_bag_names_the_folder_to_give(clean_bag, tmp_path, capsys):
    # The .mcap itself gave "[Errno 20] Not a directory: '.../x.mcap/metadata.yaml'" (info)
    # and a params file "Unrecognized storage format '.yaml'" (run).
    (mcap,) = clean_bag.glob('*.mcap')
    with pytest.raises(BagError, match=f'^{mcap}: is a file; give the bag folder that holds '
                                       f'it, {clean_bag}$'):
        read_bag(mcap)
    assert main(['info', str(mcap)]) == 1
    assert capsys.readouterr().err.strip() == (
        f'gyro-ekf info: error: {mcap}: is a file; give the bag folder that holds it, '
        f'{clean_bag}')
    params = sidecar_path(clean_bag)
    assert main(['run', str(params), '-o', str(tmp_path / 'out')]) == 1
    assert capsys.readouterr().err.strip() == (
        f'gyro-ekf run: error: {params}: is a file; give the bag folder (the one holding '
        'metadata.yaml)')
    assert not (tmp_path / 'out').exists()
