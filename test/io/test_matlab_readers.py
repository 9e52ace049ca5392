"""Course-log readers on small synthetic logs of each vintage: detection, units, conventions."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest
import scipy.io
from synthetic_logs import (
    POLE_LOG_DEG, POLE_RANGE_CM, SIM_POLE_DEG, T0_COUNTS, write_2016, write_2021, write_2022,
    write_2023, write_map, _sim_poses)

from gyro_ekf.core.errors import InvalidInputError
from gyro_ekf.io.errors import LogFormatError
from gyro_ekf.io.matlab import detect_course_log, load_course_log
from gyro_ekf.io.sources import load_log

G = 9.80665


def _nearest_beam(scan, bearing_rad):
    return int(np.argmin(np.abs(scan.angles_rad - bearing_rad)))


def test_2016_trio_units_axes_and_stamps(tmp_path):
    paths = write_2016(tmp_path / 'log')
    trip = load_course_log([tmp_path / 'log'])
    imu = scipy.io.loadmat(paths[0], squeeze_me=True, struct_as_record=False)['IMU']
    laser = scipy.io.loadmat(paths[2], squeeze_me=True, struct_as_record=False)['dataL']
    np.testing.assert_array_equal(trip.imu.angular_velocity_rad_s, imu.DATAf[3:6].T)
    np.testing.assert_allclose(trip.imu.linear_acceleration_m_s2,
                               imu.DATAf[0:3].T.astype(np.float64) * G, rtol=1e-12)
    assert trip.imu.axes_known == (True, True, True)
    # Stamps: s since the earliest stamp of the three files, from counts of 0.1 ms.
    np.testing.assert_array_equal(trip.imu.stamp_s, (imu.times - T0_COUNTS) / 1e4)
    np.testing.assert_array_equal(trip.scans[0].stamp_s, (laser.times - T0_COUNTS) / 1e4)
    assert trip.landmarks is None
    np.testing.assert_allclose(trip.initial_pose, [0.0, 0.0, math.pi / 2])
    assert trip.scans[0].mount.x_m == pytest.approx(0.46)


def test_2016_pole_lands_at_the_ros_bearing(tmp_path):
    write_2016(tmp_path / 'log')
    scan = load_course_log([tmp_path / 'log']).scans[0]
    assert scan.angle_min_rad == pytest.approx(-math.pi / 2)
    assert scan.angles_rad[-1] == pytest.approx(math.pi / 2)
    # 135 deg with 0 = right is 45 deg left of forward: +45 deg in ROS.
    beam = _nearest_beam(scan, math.radians(POLE_LOG_DEG - 90.0))
    assert scan.ranges_m[0, beam] == pytest.approx(POLE_RANGE_CM / 100.0)
    assert scan.intensities[0, beam] == 5.0
    assert scan.ranges_m[0, _nearest_beam(scan, math.radians(-45.0))] == np.inf
    assert scan.ranges_m[0, 10] == pytest.approx(2.5) and scan.intensities[0, 10] == 0.0


def test_2016_map_given_or_found_beside(tmp_path):
    write_2016(tmp_path / 'log')
    map_path = write_map(tmp_path / 'elsewhere' / 'MapMTRN4010.mat')
    given = load_log([tmp_path / 'log'], map_path)
    np.testing.assert_allclose(given.landmarks.xy_m, [[1, 4], [2, 5], [3, 6.5]])
    write_map(tmp_path / 'log' / 'the_map.mat')
    found = load_course_log([tmp_path / 'log'])
    assert found.landmarks is not None and len(found.landmarks) == 3


def test_2021_event_table_units_and_split(tmp_path):
    path = write_2021(tmp_path / 'log')
    trip = load_course_log([path])  # the map beside it is found
    a = scipy.io.loadmat(path, squeeze_me=True, struct_as_record=False)['A']
    samples = a.Z[2] <= 0
    assert len(trip.imu.stamp_s) == samples.sum() == len(trip.speed.stamp_s)
    assert len(trip.scans[0].stamp_s) == (~samples).sum()
    np.testing.assert_allclose(trip.speed.speed_m_s, a.Z[0][samples] / 1000.0, rtol=1e-15)
    np.testing.assert_allclose(trip.imu.yaw_rate_rad_s,
                               np.deg2rad(a.Z[1][samples] / 100.0), rtol=1e-15)
    assert trip.imu.axes_known == (False, False, True)
    assert trip.imu.linear_acceleration_m_s2 is None
    np.testing.assert_array_equal(trip.scans[0].stamp_s, (a.t[~samples] - a.t[0]) / 1e4)
    beam = _nearest_beam(trip.scans[0], math.radians(POLE_LOG_DEG - 90.0))
    assert trip.scans[0].ranges_m[:, beam] == pytest.approx(POLE_RANGE_CM / 100.0)
    assert len(trip.landmarks) == 3


def test_2022_sim_mount_in_degrees_noise_bias_truth(tmp_path):
    path = write_2022(tmp_path / 'data019b.mat')
    detected = detect_course_log([path])
    assert detected.vintage == 'sim2022'
    trip = load_course_log([path])
    scan = trip.scans[0]
    assert scan.mount.x_m == pytest.approx(0.4)
    assert scan.mount.yaw_rad == pytest.approx(math.pi / 2)  # Alpha = 90 is in degrees
    assert trip.noise.speed_m_s == 0.08 and trip.noise.gyro_rad_s == 0.017453292
    np.testing.assert_array_equal(trip.true_gyro_bias_rad_s, [0.0, 0.0, 0.005235988])
    assert scan.intensities is None and scan.beam_count == 321
    beam = _nearest_beam(scan, math.radians(SIM_POLE_DEG))
    assert scan.angles_rad[beam] == pytest.approx(math.radians(SIM_POLE_DEG))
    assert scan.ranges_m[0, beam] == pytest.approx(7.33)
    assert np.isinf(scan.ranges_m[0, beam + 1])
    assert trip.ground_truth.pose.shape == (8, 3)
    np.testing.assert_array_equal(trip.ground_truth.stamp_s, scan.stamp_s)
    assert trip.walls.shape == (4, 2)


def test_2023_sim_two_lidars(tmp_path):
    write_2023(tmp_path / 'DataUsr_006k.mat')
    trip = load_course_log([tmp_path])
    first, second = trip.scans
    assert (first.topic, first.frame_id, second.topic, second.frame_id) == (
        'scan', 'laser', 'scan2', 'laser2')
    assert second.mount.yaw_rad == pytest.approx(math.pi)
    assert first.angle_min_rad == pytest.approx(math.radians(-75.0))
    assert np.isinf(first.ranges_m[0, 0]) and first.ranges_m[0, 1] == pytest.approx(10.0)
    beam = _nearest_beam(second, math.radians(SIM_POLE_DEG))
    assert second.ranges_m[0, beam] == pytest.approx(4.21)
    assert second.intensities[0, beam] == 3.0
    assert trip.noise.gyro_rad_s is None and trip.true_gyro_bias_rad_s is None
    assert len(trip.landmarks) == 3


@pytest.mark.parametrize('fov', [[math.nan, 75.0, 0.5], [-75.0, math.inf, 0.5],
                                 [-75.0, 75.0, -math.inf]])
def test_2023_a_field_of_view_that_is_not_finite_is_a_format_error(tmp_path, fov):
    # Found by `make fuzz`: the beam count was int(nan) (ValueError) or int(inf).
    def change(data):
        data['LidarsCfg']['Lidar2'] = dict(data['LidarsCfg']['Lidar2'], FoV=np.array(fov))
    write_2023(tmp_path / 'DataUsr_006k.mat', change=change)
    with pytest.raises(LogFormatError, match=r"DataUsr_006k.mat: field "
                                             r"'data.LidarsCfg.Lidar2.FoV' = .* is not finite"):
        load_course_log([tmp_path])


@pytest.mark.parametrize('value, shown', [(math.inf, 'inf'), (math.nan, 'nan'), (2.5, '2.5')])
def test_2021_an_event_index_that_is_not_a_whole_number_is_a_format_error(tmp_path, value,
                                                                          shown):
    # Found by `make fuzz` (inf: OverflowError); 2.5 was truncated to scan 2 silently.
    def change(variables):
        z = variables['A']['Z'].astype(np.float64)
        z[2, 3] = value  # event 4 is the first scan
        variables['A']['Z'] = z
    path = write_2021(tmp_path / 'log', change=change)
    with pytest.raises(LogFormatError, match=re.escape(
            f"Measurements_AAS01.mat: field 'A.Z(3,:)' holds {shown} at event 4, not an index")):
        load_course_log([path])


def test_a_ground_truth_yaw_of_1e300_is_refused(tmp_path):
    def change(data):
        poses = _sim_poses(8).astype(np.float64)
        poses[2, 5] = 1e300
        data['verify'] = {'poseL': poses}
    write_2023(tmp_path / 'DataUsr_006k.mat', change=change)
    with pytest.raises(InvalidInputError, match=re.escape(
            'ground_truth.pose.yaw[5]: |1e+300| rad exceeds the limit 1000 rad')):
        load_log([tmp_path])


@pytest.mark.parametrize('dtype', [np.uint8, np.uint32])
def test_2023_scan_words_of_another_width_are_a_format_error(tmp_path, dtype):
    # Found by `make fuzz`: uint8 words made `words & 0x3FFF` an OverflowError.
    def change(data):
        data['scans'] = data['scans'].astype(dtype)
    write_2023(tmp_path / 'DataUsr_006k.mat', change=change)
    with pytest.raises(LogFormatError, match=re.escape(
            f"DataUsr_006k.mat: field 'data.scans' has type {np.dtype(dtype)}, expected uint16 "
            'words')):
        load_course_log([tmp_path])


def test_a_map_whose_count_is_not_its_poles_is_a_format_error(tmp_path):
    """A helper's find: Map.n 7 beside 5 poles converted without a word."""
    from gyro_ekf.io.matlab.aas2021 import read_map

    path = write_map(tmp_path / 'MapMTRN4010.mat')
    assert len(read_map(path).xy_m) == 3
    scipy.io.savemat(path, {'Map': {'x': np.array([1.0, 2.0, 3.0], dtype=np.float32),
                                    'y': np.array([4.0, 5.0, 6.5], dtype=np.float32),
                                    'n': 7}})
    with pytest.raises(LogFormatError, match=r"MapMTRN4010\.mat: field 'Map\.n' says 7 poles "
                       r"but 'Map\.x' and 'Map\.y' hold 3"):
        read_map(path)
