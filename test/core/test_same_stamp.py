"""SameStampCheck: a live message at the stamp of the last one taken on its stream."""

from __future__ import annotations

import math

import numpy as np

from gyro_ekf.core.same_stamp import describe_repeat, DUPLICATE, Repeat, SAME_STAMP, \
    SameStampCheck, same_values


def test_an_exact_repeat_is_a_duplicate_and_other_values_are_same_stamp():
    check = SameStampCheck()
    assert check.judge('imu', 1_000, (0.2, None)) is None
    assert check.judge('imu', 1_000, (0.2, None)) == Repeat(DUPLICATE)
    # The second value differs: named by its index; the first stays the one taken.
    assert check.judge('imu', 1_000, (0.2, 0.25)) == Repeat(SAME_STAMP, 1)
    assert check.judge('imu', 1_000, (5.0, None)) == Repeat(SAME_STAMP, 0)
    assert check.judge('imu', 1_000, (0.2, None)) == Repeat(DUPLICATE)
    assert check.judge('imu', 1_001, (5.0, None)) is None  # one nanosecond on: taken


def test_streams_are_judged_apart():
    # Gyro and odometry share stamps in every course log, and so do two LiDARs in 2023.
    check = SameStampCheck()
    assert check.judge('imu', 10, (0.0, None)) is None
    assert check.judge('odom', 10, (0.0, None)) is None
    assert check.judge('scan', 10, (np.zeros((2, 2)),)) is None
    assert check.judge('scan2', 10, (np.ones((2, 2)),)) is None
    assert check.judge('scan2', 10, (np.ones((2, 2)),)) == Repeat(DUPLICATE)


def test_a_late_message_is_not_judged_and_does_not_hide_a_repeat():
    check = SameStampCheck()
    assert check.judge('odom', 20, (1.0, None)) is None
    assert check.judge('odom', 10, (1.0, None)) is None  # late: the merger's business
    assert check.judge('odom', 10, (3.0, None)) is None  # judged by nobody here either
    # The newest taken is still 20: a copy of it after the late ones is a repeat.
    assert check.judge('odom', 20, (1.0, None)) == Repeat(DUPLICATE)
    assert check.judge('odom', 20, (3.0, None)) == Repeat(SAME_STAMP, 0)


def test_clear_forgets_every_stream():
    check = SameStampCheck()
    check.judge('imu', 10, (0.0,))
    check.clear()
    assert check.judge('imu', 10, (1.0,)) is None  # after a reset: the first at its stamp
    assert check.judge('imu', 10, (1.0,)) == Repeat(DUPLICATE)


def test_values_compare_as_read_nan_equal_to_nan():
    assert same_values(math.nan, math.nan)
    assert same_values((0.1, math.nan), (0.1, math.nan))
    assert not same_values(0.1, float(np.nextafter(0.1, 1.0)))  # one ulp apart
    assert same_values(None, None) and not same_values(None, 0.0)
    points = np.array([[1.0, 2.0], [3.0, math.nan]])
    assert same_values(points, points.copy())
    assert not same_values(points, points[:1])  # another shape
    moved = points.copy()
    moved[0, 0] += 1e-9
    assert not same_values(points, moved)
    assert same_values(np.array(['a']), np.array(['a']))  # no NaN to think of
    check = SameStampCheck()
    check.judge('scan', 5, (points, 'mount'))
    assert check.judge('scan', 5, (points.copy(), 'mount')) == Repeat(DUPLICATE)
    assert check.judge('scan', 5, (moved, 'mount')) == Repeat(SAME_STAMP, 0)
    assert check.judge('scan', 5, (points, 'other mount')) == Repeat(SAME_STAMP, 1)
    assert check.judge('scan', 5, (points,)) == Repeat(SAME_STAMP, 0)  # fewer values


def test_the_description_names_topic_stamp_and_field():
    fields = ('angular_velocity.z', 'angular_velocity_covariance[8]')
    ns = 1_700_000_000 * 10 ** 9 + 70_000_000
    assert describe_repeat(Repeat(SAME_STAMP, 1), '/robot/imu', ns, 0.7, fields) == (
        '/robot/imu: a second message at stamp 1700000000.070000000 (0.700000 s) with another '
        'angular_velocity_covariance[8] than the one taken: two values for one instant, the '
        'later dropped')
    assert describe_repeat(Repeat(DUPLICATE), '/robot/imu', ns, 0.7, fields) == (
        '/robot/imu: an exact repeat of the message taken at stamp 1700000000.070000000 '
        '(0.700000 s) dropped')
