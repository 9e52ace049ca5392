"""The offline validation boundary (core.validation.validate_trip) on hand-made trips."""

from __future__ import annotations

import dataclasses
import math
import re

import numpy as np
import pytest

from gyro_ekf.core.calibration import estimate_gyro_bias
from gyro_ekf.core.config import CalibrationConfig, InputLimits
from gyro_ekf.core.ekf import GyroBiasEkf
from gyro_ekf.core.errors import CalibrationError, CoreError, InvalidInputError
from gyro_ekf.core.types import (GroundTruth, ImuSeries, LandmarkMap, LidarMount, NoiseFigures,
                                 ScanSeries, SpeedSeries, Trip)
from gyro_ekf.core.validation import (JUMPED_AHEAD, NOT_FINITE, SAME_STAMP, TIME_WENT_BACK,
                                      validate_trip)


def _trip(n: int = 2000, m: int = 40) -> Trip:
    """A plain 10 s trip at 200 Hz / 4 Hz with a map, a LiDAR and ground truth."""
    rng = np.random.default_rng(5)
    imu_s = np.arange(n) * 0.005
    scan_s = 0.002 + np.arange(m) * 0.25
    ranges = rng.uniform(0.5, 30.0, (m, 181)).astype(np.float32)
    ranges[:, ::7] = np.inf     # no return (REP-117)
    ranges[:, 3] = np.nan       # also no return
    return Trip(
        name='hand', imu=ImuSeries(imu_s, rng.normal(0.0, 0.2, (n, 3))),
        speed=SpeedSeries(imu_s.copy(), rng.uniform(0.0, 2.0, n)),
        scans=(ScanSeries(scan_s, ranges, rng.integers(0, 8, (m, 181)).astype(np.float32),
                          -math.pi / 2, math.pi / 180, 0.0, 80.0, LidarMount(0.4, 0.0, 0.0)),),
        landmarks=LandmarkMap(rng.uniform(-20.0, 20.0, (5, 2))),
        initial_pose=np.array([1.0, 2.0, 0.3]),
        ground_truth=GroundTruth(scan_s.copy(), rng.normal(0.0, 3.0, (m, 3))),
        noise=NoiseFigures(gyro_rad_s=0.02, landmark_m=0.0))


def _with_imu(trip: Trip, rates=None, stamps=None) -> Trip:
    imu = dataclasses.replace(
        trip.imu, angular_velocity_rad_s=trip.imu.angular_velocity_rad_s if rates is None
        else rates, stamp_s=trip.imu.stamp_s if stamps is None else stamps)
    return dataclasses.replace(trip, imu=imu)


def test_a_good_trip_passes_unchanged():
    trip = _trip()
    checked, report = validate_trip(trip, 'hand.npz')
    assert checked is trip
    assert report.total_dropped == 0 and report.warning() is None
    assert report.to_dict()['dropped'] == []


def test_ten_nan_gyro_samples_refused_naming_field_and_index_or_dropped_and_counted():
    trip = _trip()
    rates = trip.imu.angular_velocity_rad_s.copy()
    rates[1234:1244, 2] = np.nan
    bad = _with_imu(trip, rates)
    with pytest.raises(InvalidInputError) as caught:
        validate_trip(bad, 'trip2016.mat')
    assert str(caught.value) == 'trip2016.mat: imu.angular_velocity.z[1234]: nan is not finite'
    assert (caught.value.field, caught.value.index) == ('imu.angular_velocity.z', 1234)

    checked, report = validate_trip(bad, 'trip2016.mat', skip_bad=True)
    assert len(checked.imu.stamp_s) == len(trip.imu.stamp_s) - 10
    assert np.isfinite(checked.imu.angular_velocity_rad_s).all()
    assert report.dropped == {('imu.angular_velocity.z', NOT_FINITE): 10}
    assert report.first_index[('imu.angular_velocity.z', NOT_FINITE)] == 1234
    assert report.samples_dropped == {'imu': 10}
    assert '10 imu.angular_velocity.z (not finite)' in report.warning()
    assert checked.speed is trip.speed      # the other streams are left alone


def test_inf_gyro_and_implausible_yaw_rate_are_refused():
    trip = _trip()
    rates = trip.imu.angular_velocity_rad_s.copy()
    rates[7, 2] = np.inf
    with pytest.raises(InvalidInputError, match=r'imu.angular_velocity.z\[7\]: inf is not fin'):
        validate_trip(_with_imu(trip, rates), 'x')
    rates[7, 2] = 1e300
    with pytest.raises(InvalidInputError, match=r'z\[7\]: \|1e\+300\| rad/s exceeds the limit '
                                                r'35 rad/s'):
        validate_trip(_with_imu(trip, rates), 'x')
    assert validate_trip(_with_imu(trip, rates), 'x', InputLimits(max_yaw_rate_rad_s=1e3),
                         skip_bad=True)[1].total_dropped == 1


def test_unknown_gyro_axes_are_not_checked():
    trip = _trip()
    rates = trip.imu.angular_velocity_rad_s.copy()
    rates[:, 0] = np.nan
    imu = dataclasses.replace(trip.imu, angular_velocity_rad_s=rates,
                              axes_known=(False, True, True))
    checked, report = validate_trip(dataclasses.replace(trip, imu=imu), 'x')
    assert report.total_dropped == 0


@pytest.mark.parametrize('value, reason', [(np.nan, 'nan is not finite'),
                                           (-80.0, '|-80| m/s exceeds the limit 50 m/s')])
def test_bad_speed(value, reason):
    trip = _trip()
    speeds = trip.speed.speed_m_s.copy()
    speeds[99] = value
    bad = dataclasses.replace(trip, speed=SpeedSeries(trip.speed.stamp_s, speeds))
    with pytest.raises(InvalidInputError, match=rf'x: speed.speed_m_s\[99\]: {re.escape(reason)}'):
        validate_trip(bad, 'x')
    checked, report = validate_trip(bad, 'x', skip_bad=True)
    assert len(checked.speed.speed_m_s) == len(speeds) - 1 and report.samples_dropped == {
        'speed': 1}


@pytest.mark.parametrize('factor', [100.0, 1000.0])
def test_a_speed_in_cm_or_mm_per_second_is_named_and_not_skipped(factor):
    # Every moving sample beyond the limit: no corrupt samples to drop, the series' units.
    trip = _trip()
    moving = np.abs(trip.speed.speed_m_s) * factor > 50.0
    assert moving.mean() > 0.1
    speeds = np.where(moving, trip.speed.speed_m_s * factor, trip.speed.speed_m_s)
    bad = dataclasses.replace(trip, speed=SpeedSeries(trip.speed.stamp_s, speeds))
    first = int(np.argmax(moving))
    pattern = (rf'x: speed.speed_m_s\[{first}\]: \|[0-9.]+\| m/s exceeds the limit 50 m/s '
               rf'\(limits.max_speed_m_s\), and so do {int(moving.sum())} of its '
               rf'{speeds.size} samples, up to [0-9.]+ m/s: not a few corrupt samples but the '
               r'series in other units than m/s')
    with pytest.raises(InvalidInputError, match=pattern):
        validate_trip(bad, 'x')
    with pytest.raises(InvalidInputError, match=pattern + r'.*\(too many to skip\)'):
        validate_trip(bad, 'x', skip_bad=True)
    # A handful beyond it are corrupt samples: dropped with skip_bad, the message plain.
    few = trip.speed.speed_m_s.copy()
    few[np.flatnonzero(moving)[:9]] = 80.0
    bad = dataclasses.replace(trip, speed=SpeedSeries(trip.speed.stamp_s, few))
    with pytest.raises(InvalidInputError, match=r'exceeds the limit 50 m/s$'):
        validate_trip(bad, 'x')
    assert validate_trip(bad, 'x', skip_bad=True)[1].samples_dropped == {'speed': 9}


def test_scans_negative_range_and_nan_intensity_drop_the_scan():
    trip = _trip()
    scan = trip.scans[0]
    ranges = scan.ranges_m.copy()
    ranges[5, 17] = -3.0
    intensities = scan.intensities.copy()
    intensities[9, 2] = np.nan
    bad = dataclasses.replace(trip, scans=(dataclasses.replace(
        scan, ranges_m=ranges, intensities=intensities),))
    with pytest.raises(InvalidInputError, match=r'lidar.scan.ranges_m\[5\]: range -3.0 m at '
                                                r'beam 17 is negative'):
        validate_trip(bad, 'x')
    checked, report = validate_trip(bad, 'x', skip_bad=True)
    assert len(checked.scans[0].stamp_s) == len(scan.stamp_s) - 2
    assert report.samples_dropped == {'lidar.scan': 2}


@pytest.mark.parametrize('change, match', [
    (dict(angle_increment_rad=0.0), 'lidar.scan.geometry: angle_increment is 0'),
    (dict(range_max_m=float('nan')), 'lidar.scan.geometry: beam geometry'),
    (dict(mount=LidarMount(float('nan'), 0.0, 0.0)), 'lidar.scan.mount: mount is not finite'),
    (dict(mount=LidarMount(0.0, 50.0, 0.0)), 'lidar.scan.mount: mount offset 50 m exceeds'),
])
def test_scan_geometry_and_mount_are_always_refused(change, match):
    trip = _trip()
    bad = dataclasses.replace(trip, scans=(dataclasses.replace(trip.scans[0], **change),))
    with pytest.raises(InvalidInputError, match=re.escape(match)):
        validate_trip(bad, 'x', skip_bad=True)


@pytest.mark.parametrize('change, match', [
    (lambda t: dict(landmarks=LandmarkMap(np.array([[1.0, 2.0], [np.nan, 3.0]]))),
     'x: landmarks.xy_m[1]: nan is not finite'),
    (lambda t: dict(landmarks=LandmarkMap(np.array([[1.0, 2e9]]))),
     'x: landmarks.xy_m[0]: |2e+09| m exceeds the limit'),
    (lambda t: dict(initial_pose=np.array([np.nan, 0.0, 0.0])),
     'x: initial_pose: nan is not finite'),
    (lambda t: dict(initial_pose=np.array([0.0, 0.0, np.inf])),
     'x: initial_pose: yaw inf is not finite'),
    (lambda t: dict(initial_pose=np.array([0.0, 0.0, 1e308])),
     'x: initial_pose: yaw |1e+308| rad exceeds the limit 1000 rad'),
    (lambda t: dict(static_duration_s=1e308),
     'x: static_duration_s: 1e+308 s exceeds the limit 1e+06 s'),
    (lambda t: dict(static_duration_s=-1.0),
     'x: static_duration_s: -1.0 is not a finite non-negative duration'),
    (lambda t: dict(scans=(dataclasses.replace(t.scans[0], mount=LidarMount(0.4, 0.0, 1e30)),)),
     'x: lidar.scan.mount: |1e+30| rad exceeds the limit 1000 rad'),
    (lambda t: dict(noise=NoiseFigures(gyro_rad_s=np.inf)), 'x: noise.gyro_rad_s: inf is not'),
    (lambda t: dict(noise=NoiseFigures(range_m=-0.1)), 'x: noise.range_m: -0.1 is not'),
    (lambda t: dict(true_gyro_bias_rad_s=np.array([0.0, np.nan, 0.0])),
     'x: true_gyro_bias_rad_s[1]: nan is not finite'),
])
def test_map_pose_and_noise_have_nothing_to_skip(change, match):
    trip = _trip()
    with pytest.raises(InvalidInputError, match=re.escape(match)):
        validate_trip(dataclasses.replace(trip, **change(trip)), 'x', skip_bad=True)


def test_time_going_back_ten_seconds():
    trip = _trip(n=6000)
    stamps = trip.imu.stamp_s.copy()
    stamps[2000:] -= 10.0   # 10 s in, the clock steps back 10 s
    bad = _with_imu(trip, stamps=stamps)
    with pytest.raises(InvalidInputError, match=r'x: imu.stamp_s\[2000\]: time went back 9.995 s '
                                                r'\(from 9.995000 s to 0.000000 s\)'):
        validate_trip(bad, 'x')
    checked, report = validate_trip(bad, 'x', skip_bad=True)
    # The older samples are dropped until time passes the last kept stamp again; sample
    # 3999 comes back to that very stamp (9.995 s) with other values and goes too.
    assert np.all(np.diff(checked.imu.stamp_s) > 0)
    assert report.dropped == {('imu.stamp_s', TIME_WENT_BACK): 2000}
    assert report.first_index[('imu.stamp_s', TIME_WENT_BACK)] == 2000
    assert report.time_breaks == {'imu': 1}
    assert checked.imu.stamp_s[-1] == stamps[-1]


def test_a_lone_stamp_300000_s_ahead_is_refused_or_dropped():
    trip = _trip()
    stamps = trip.imu.stamp_s.copy()
    stamps[500] += 300_000.0   # one flipped bit
    bad = _with_imu(trip, stamps=stamps)
    with pytest.raises(InvalidInputError, match=r'imu.stamp_s\[500\]: stamp jumped ahead 300000'):
        validate_trip(bad, 'x')
    checked, report = validate_trip(bad, 'x', skip_bad=True)
    assert report.dropped == {('imu.stamp_s', JUMPED_AHEAD): 1}
    assert checked.imu.stamp_s.max() < 11.0


def test_a_silent_sensor_is_flagged_and_kept_while_other_streams_cover_the_gap():
    trip = _trip(n=20_000)     # 100 s of IMU and speed
    scan = trip.scans[0]
    stamps = scan.stamp_s.copy()
    stamps[20:] += 60.0        # the LiDAR says nothing for 60 s, then carries on
    checked, report = validate_trip(dataclasses.replace(
        trip, scans=(dataclasses.replace(scan, stamp_s=stamps),)), 'x')
    assert checked.scans[0].stamp_s is stamps and report.total_dropped == 0
    assert report.gaps == ['lidar.scan.stamp_s[20]: stamp jumped ahead 60.25 s (from 4.752000 s '
                           'to 65.002000 s; the limit is 30 s)']
    assert '1 long gap(s) in a stream' in report.warning()


def test_a_gap_no_stream_covers_is_refused_even_with_skip_bad():
    trip = _trip()

    def shift(stamps):
        return np.where(stamps > 5.0, stamps + 300_000.0, stamps)
    # The IMU alone jumps 300 000 s and stays: the other streams end at 10 s.
    with pytest.raises(InvalidInputError, match=r'x: stamps: no stream has a sample between '
                                                r'9.99\d+ s and 300005.00\d+ s'):
        validate_trip(_with_imu(trip, stamps=shift(trip.imu.stamp_s)), 'x', skip_bad=True)
    # Every stream jumps together.
    every = dataclasses.replace(
        _with_imu(trip, stamps=shift(trip.imu.stamp_s)),
        speed=SpeedSeries(shift(trip.speed.stamp_s), trip.speed.speed_m_s),
        scans=(dataclasses.replace(trip.scans[0], stamp_s=shift(trip.scans[0].stamp_s)),))
    with pytest.raises(InvalidInputError, match='a gap of 300000 s'):
        validate_trip(every, 'x', skip_bad=True)
    # A stream that starts long after the others leaves a gap no stream covers.
    late_speed = dataclasses.replace(trip, speed=SpeedSeries(
        trip.speed.stamp_s[:10] + 200.0, trip.speed.speed_m_s[:10]))
    with pytest.raises(InvalidInputError, match=r'x: stamps: no stream has a sample between'):
        validate_trip(late_speed, 'x', skip_bad=True)


def test_nan_stamp_and_nan_ground_truth():
    trip = _trip()
    stamps = trip.imu.stamp_s.copy()
    stamps[3] = np.nan
    with pytest.raises(InvalidInputError, match=r'imu.stamp_s\[3\]: stamp nan is not finite'):
        validate_trip(_with_imu(trip, stamps=stamps), 'x')
    pose = trip.ground_truth.pose.copy()
    pose[4, 2] = np.nan
    bad = dataclasses.replace(trip, ground_truth=GroundTruth(trip.ground_truth.stamp_s, pose))
    with pytest.raises(InvalidInputError, match=r'ground_truth.pose.yaw\[4\]'):
        validate_trip(bad, 'x')
    checked, report = validate_trip(bad, 'x', skip_bad=True)
    assert len(checked.ground_truth.stamp_s) == len(pose) - 1


def test_ekf_refuses_a_non_finite_start():
    with pytest.raises(CoreError, match='initial state .* is not finite'):
        GyroBiasEkf(pose=np.array([np.nan, 0.0, 0.0]))
    with pytest.raises(CoreError, match='initial covariance is not finite'):
        GyroBiasEkf(covariance=np.full((5, 5), np.nan))


def test_one_imu_sample_ahead_of_its_neighbours_is_the_one_refused_or_dropped():
    # A message logged 10 s out of place (below the 30 s jump limit) made every later
    # sample look older than it: --skip-bad dropped the 10 s behind it, and the error
    # named the first of those instead of the sample out of place.
    trip = _trip()
    stamps = trip.imu.stamp_s.copy()
    stamps[1000] += 8.0
    bad = _with_imu(trip, stamps=stamps)
    with pytest.raises(InvalidInputError) as caught:
        validate_trip(bad, 'x')
    assert str(caught.value) == ('x: imu.stamp_s[1000]: stamp 13.000000 s lies 7.995 s ahead of '
                                 'the samples around it (4.995000 s and 5.005000 s)')
    checked, report = validate_trip(bad, 'x', skip_bad=True)
    assert report.samples_dropped == {'imu': 1}
    assert len(checked.imu.stamp_s) == len(stamps) - 1
    # Time that really goes back (a segment break) is still that.
    stamps = trip.imu.stamp_s.copy()
    stamps[1000:] -= 8.0
    with pytest.raises(InvalidInputError, match=re.escape('imu.stamp_s[1000]: time went back')):
        validate_trip(_with_imu(trip, stamps=stamps), 'x')


def test_with_skip_bad_a_sample_back_at_the_last_kept_stamp_is_dropped_not_kept_twice():
    # After the stamps stepped back, a sample at exactly the last kept stamp was kept: two
    # values for one instant, which a bag refuses (two messages with one stamp).
    trip = _trip()
    rates = trip.imu.angular_velocity_rad_s
    stamps = trip.imu.stamp_s.copy()                 # 0.005 s steps
    stamps[1000:] -= 0.05                            # back 0.05 s after 4.995 s (index 999)
    assert stamps[1009] == stamps[999] and rates[1009, 2] != rates[999, 2]
    checked, report = validate_trip(_with_imu(trip, stamps=stamps), 'x', skip_bad=True)
    assert np.all(np.diff(checked.imu.stamp_s) > 0)
    assert report.dropped == {('imu.stamp_s', TIME_WENT_BACK): 10}      # 1000 to 1009
    assert report.time_breaks == {'imu': 1}
    np.testing.assert_array_equal(checked.imu.stamp_s[999:1001], [stamps[999], stamps[1010]])
    assert checked.imu.angular_velocity_rad_s[999, 2] == rates[999, 2]
    # A lone sample ahead, then one at the stamp kept before it: both dropped.
    stamps = trip.imu.stamp_s.copy()
    stamps[1000] += 8.0
    stamps[1001] = stamps[999]
    checked, report = validate_trip(_with_imu(trip, stamps=stamps), 'x', skip_bad=True)
    assert np.all(np.diff(checked.imu.stamp_s) > 0)
    assert report.dropped == {('imu.stamp_s', JUMPED_AHEAD): 1,
                              ('imu.stamp_s', TIME_WENT_BACK): 1}
    assert report.first_index[('imu.stamp_s', TIME_WENT_BACK)] == 1001
    assert len(checked.imu.stamp_s) == len(stamps) - 2
    # Equal stamps side by side: test_two_values_at_one_stamp_are_refused_or_dropped_...


_VALUES = {'imu': ('angular_velocity_rad_s', 'yaw_rate_variance'),
           'speed': ('speed_m_s', 'speed_variance'), 'ground_truth': ('pose',),
           'scan': ('ranges_m', 'intensities')}


def _series(trip: Trip, stream: str):
    """A trip's series by stream: 'imu', 'speed', 'ground_truth' or a scan index ('0')."""
    return getattr(trip, stream) if stream in _VALUES else trip.scans[int(stream)]


def _repeat_sample(trip: Trip, stream: str, i: int, change=None) -> Trip:
    """Give sample i of a stream the stamp of sample i - 1 and, unless `change` alters
    them (change(arrays, i) on copies), the values of sample i - 1 too."""
    series = _series(trip, stream)
    names = _VALUES.get(stream, _VALUES['scan'])
    arrays = {n: getattr(series, n).copy() for n in names if getattr(series, n) is not None}
    stamps = series.stamp_s.copy()
    stamps[i] = stamps[i - 1]
    for values in arrays.values():
        values[i] = values[i - 1]
    if change is not None:
        change(arrays, i)
    series = dataclasses.replace(series, stamp_s=stamps, **arrays)
    if stream in ('imu', 'speed', 'ground_truth'):
        return dataclasses.replace(trip, **{stream: series})
    scans = list(trip.scans)
    scans[int(stream)] = series
    return dataclasses.replace(trip, scans=tuple(scans))


def _bump(name, column=None):
    def change(arrays, i):
        if column is None:
            arrays[name][i] += 0.125
        else:
            arrays[name][i, column] += 0.125
    return change


def _with_variances(trip: Trip) -> Trip:
    n = len(trip.imu.stamp_s)
    return dataclasses.replace(trip, imu=dataclasses.replace(
        trip.imu, yaw_rate_variance=np.full(n, 1e-4)))


@pytest.mark.parametrize('stream, i, change, field, value_field', [
    ('imu', 1001, _bump('angular_velocity_rad_s', 2), 'imu.stamp_s',
     'imu.angular_velocity'),
    ('imu', 1001, _bump('yaw_rate_variance'), 'imu.stamp_s',
     'imu.angular_velocity_covariance[8]'),
    ('speed', 700, _bump('speed_m_s'), 'speed.stamp_s', 'speed.speed_m_s'),
    ('0', 21, _bump('ranges_m', 40), 'lidar.scan.stamp_s', 'lidar.scan.ranges_m'),
    ('ground_truth', 21, _bump('pose', 2), 'ground_truth.stamp_s', 'ground_truth.pose'),
])
def test_two_values_at_one_stamp_are_refused_or_dropped_and_counted(
        stream, i, change, field, value_field):
    # A course log or trip file with two samples of one stream at one stamp and other
    # values was accepted (equal stamps side by side stayed): the filter took one value,
    # then the other after a prediction of length 0. A bag with such messages is refused.
    trip = _repeat_sample(_with_variances(_trip()), stream, i, change)
    stamp = _series(trip, stream).stamp_s[i]
    with pytest.raises(InvalidInputError) as caught:
        validate_trip(trip, 'trip.npz')
    assert caught.value.field == field and caught.value.index == i
    assert str(caught.value) == (
        f'trip.npz: {field}[{i}]: stamp {stamp:.6f} s is that of sample {i - 1}, but '
        f'{value_field} differs: two values for one instant (an exact repeat would be '
        'dropped)')

    checked, report = validate_trip(trip, 'trip.npz', skip_bad=True)
    name = field.rsplit('.', 1)[0]
    assert report.dropped == {(field, SAME_STAMP): 1}
    assert report.first_index == {(field, SAME_STAMP): i}
    assert report.samples_dropped == {name: 1} and report.duplicates == {}
    assert f'1 {field} (same stamp as the previous sample, other values)' in report.warning()
    assert report.to_dict()['dropped'] == [
        {'field': field, 'reason': 'same stamp as the previous sample, other values',
         'count': 1, 'first_index': i}]
    series, given = _series(checked, stream), _series(trip, stream)
    assert np.all(np.diff(series.stamp_s) > 0)
    assert len(series.stamp_s) == len(given.stamp_s) - 1
    values = _VALUES.get(stream, _VALUES['scan'])[0]    # the first value is the one kept
    np.testing.assert_array_equal(getattr(series, values)[i - 1:i + 1],
                                  getattr(given, values)[[i - 1, i + 1]])


def test_a_third_sample_at_one_stamp_is_judged_against_the_one_kept():
    # a, b, a at one stamp: b is the conflict; with --skip-bad it goes and the second a is
    # an exact repeat of the kept one.
    trip = _trip()
    rates = trip.imu.angular_velocity_rad_s.copy()
    stamps = trip.imu.stamp_s.copy()
    stamps[1001:1003] = stamps[1000]
    rates[1002] = rates[1000]
    rates[1001, 2] = rates[1000, 2] + 0.5
    bad = _with_imu(trip, rates, stamps)
    with pytest.raises(InvalidInputError, match=re.escape(
            'x: imu.stamp_s[1001]: stamp 5.000000 s is that of sample 1000, but '
            'imu.angular_velocity differs')):
        validate_trip(bad, 'x')
    checked, report = validate_trip(bad, 'x', skip_bad=True)
    assert report.dropped == {('imu.stamp_s', SAME_STAMP): 1}
    assert report.duplicates == {'imu': 1} and report.duplicate_first_index == {'imu': 1002}
    assert report.samples_dropped == {'imu': 1}
    assert np.all(np.diff(checked.imu.stamp_s) > 0)
    np.testing.assert_array_equal(checked.imu.angular_velocity_rad_s[1000], rates[1000])


def test_an_exact_repeat_is_dropped_and_counted_as_a_duplicate_with_or_without_skip_bad():
    # A sample recorded twice (same stamp, same values) was kept twice; a bag's copy of a
    # message is dropped and counted (summary.json input.duplicates_dropped), not refused.
    # The two LiDARs scan at the same instants (separate streams), as gyro and odometry
    # sample at the same instants: no repeat there.
    trip = _trip()
    second = dataclasses.replace(trip.scans[0], topic='scan2', frame_id='laser2')
    trip = dataclasses.replace(trip, scans=(trip.scans[0], second))
    assert np.array_equal(trip.imu.stamp_s, trip.speed.stamp_s)
    repeated = _repeat_sample(_repeat_sample(trip, 'imu', 1001), '0', 21)
    assert np.isnan(repeated.scans[0].ranges_m[21]).any()     # no return equals no return
    for skip_bad in (False, True):
        checked, report = validate_trip(repeated, 'trip.npz', skip_bad=skip_bad)
        assert report.duplicates == {'imu': 1, 'lidar.scan': 1}
        assert report.duplicate_first_index == {'imu': 1001, 'lidar.scan': 21}
        assert report.dropped == {} and report.samples_dropped == {}
        assert report.total_dropped == 0
        assert report.to_dict()['duplicates_dropped'] == {'imu': 1, 'lidar.scan': 1}
        assert report.warning() == (
            'trip.npz: dropped 2 exact repeat(s) of the sample before (same stamp and values, '
            'kept once): 1 imu (first at index 1001), 1 lidar.scan (first at index 21)')
        assert len(checked.imu.stamp_s) == len(trip.imu.stamp_s) - 1
        assert np.all(np.diff(checked.imu.stamp_s) > 0)
        assert len(checked.speed.stamp_s) == len(trip.speed.stamp_s)
        assert [len(s.stamp_s) for s in checked.scans] == [39, 40]
        np.testing.assert_array_equal(np.delete(repeated.scans[0].ranges_m, 21, axis=0),
                                      checked.scans[0].ranges_m)
    assert 'duplicates_dropped' not in validate_trip(trip, 'x')[1].to_dict()
    # After the stamps went back, a copy of the last kept sample is a repeat too.
    rates = trip.imu.angular_velocity_rad_s.copy()
    stamps = trip.imu.stamp_s.copy()
    stamps[1000:] -= 0.05                            # back 0.05 s after 4.995 s (index 999)
    rates[1009] = rates[999]
    checked, report = validate_trip(_with_imu(trip, rates, stamps), 'x', skip_bad=True)
    assert report.dropped == {('imu.stamp_s', TIME_WENT_BACK): 9}       # 1000 to 1008
    assert report.duplicates == {'imu': 1} and report.samples_dropped == {'imu': 9}
    assert np.all(np.diff(checked.imu.stamp_s) > 0)


def test_a_trip_without_speed_samples_is_refused_and_its_span_still_known():
    # A bag with /odom declared but empty once crashed in the summary (start_s indexed the
    # empty speed stamps) and, in calibrate-mounts, fitted a mount to a platform held still.
    trip = _trip()
    empty = dataclasses.replace(trip, speed=SpeedSeries(np.zeros(0), np.zeros(0)))
    assert empty.start_s == 0.0 and empty.end_s == pytest.approx(trip.imu.stamp_s[-1])
    with pytest.raises(InvalidInputError, match=re.escape('x: speed: no samples')):
        validate_trip(empty, 'x')
    speeds = trip.speed.speed_m_s.copy()
    speeds[:] = np.nan
    bad = dataclasses.replace(trip, speed=SpeedSeries(trip.speed.stamp_s, speeds))
    with pytest.raises(InvalidInputError,
                       match=re.escape('x: speed: no samples left (2000 dropped as bad)')):
        validate_trip(bad, 'x', skip_bad=True)


def test_an_empty_map_or_a_pole_listed_twice_is_refused_naming_the_landmarks():
    trip = _trip()
    empty = dataclasses.replace(trip, landmarks=LandmarkMap(np.zeros((0, 2))))
    with pytest.raises(InvalidInputError,
                       match=re.escape('m.bag: landmarks.xy_m: the map lists no landmark')):
        validate_trip(empty, 'm.bag')
    xy = np.asarray(trip.landmarks.xy_m).copy()
    twice = dataclasses.replace(trip, landmarks=LandmarkMap(np.vstack([xy, xy[2] + [5e-4, 0.0]])))
    with pytest.raises(InvalidInputError) as caught:
        validate_trip(twice, 'm.bag')
    assert str(caught.value).startswith('m.bag: landmarks.xy_m: landmarks 2 and 5 are 0.5 mm '
                                        'apart')
    # Two poles 2 mm apart are two poles.
    near = dataclasses.replace(trip, landmarks=LandmarkMap(np.vstack([xy, xy[2] + [2e-3, 0.0]])))
    validate_trip(near, 'm.bag')


def test_calibration_refuses_non_finite_samples_instead_of_a_nan_bias():
    stamps = np.arange(2000) * 0.005
    rates = np.zeros((2000, 3)) + 0.01
    rates[300, 2] = np.nan
    with pytest.raises(CalibrationError, match='non-finite gyro sample at 1.500 s'):
        estimate_gyro_bias(stamps, rates, CalibrationConfig())
    rates[300, 2] = 0.01
    speeds = np.zeros(2000)
    speeds[400] = np.nan
    with pytest.raises(CalibrationError, match='platform moved: speed nan'):
        estimate_gyro_bias(stamps, rates, CalibrationConfig(), stamps, speeds)


def test_a_trip_without_imu_samples_is_refused():
    # The gyro drives the filter; `run` once crashed in its summary on an empty bag.
    trip = _trip()
    empty = _with_imu(trip, rates=np.zeros((0, 3)), stamps=np.zeros(0))
    with pytest.raises(InvalidInputError, match=re.escape('x: imu: no samples')):
        validate_trip(empty, 'x')
    rates = trip.imu.angular_velocity_rad_s.copy()
    rates[:, 2] = np.nan
    with pytest.raises(InvalidInputError,
                       match=re.escape('x: imu: no samples left (2000 dropped as bad)')):
        validate_trip(_with_imu(trip, rates), 'x', skip_bad=True)
