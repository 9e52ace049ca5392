"""An upside-down gyro or LiDAR, found from scan to scan (core/turn_sign.py), and named."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from gyro_ekf.analysis.offline import run_trip
from gyro_ekf.analysis.summary import summarize
from gyro_ekf.core.simulator import SimulationConfig, simulate_trip
from gyro_ekf.core.turn_sign import MAX_VOTES, MIN_VOTES, TurnSignCheck
from gyro_ekf.core.types import LidarMount

POLES = np.array([[4.0, 1.0], [6.0, -2.0], [3.0, -3.5], [8.0, 2.5], [5.0, 4.0]])
MOUNT = LidarMount(0.3, 0.1, math.pi)  # rear-facing, off the centre


def _seen(pose: tuple[float, float, float], mirrored: bool = False) -> np.ndarray:
    """Poles in the sensor frame of a platform at pose (x, y, yaw), mirrored if asked."""
    x, y, yaw = pose
    c, s = math.cos(yaw), math.sin(yaw)
    sx, sy = x + c * MOUNT.x_m - s * MOUNT.y_m, y + s * MOUNT.x_m + c * MOUNT.y_m
    h = yaw + MOUNT.yaw_rad
    d = POLES - (sx, sy)
    points = np.column_stack([math.cos(h) * d[:, 0] + math.sin(h) * d[:, 1],
                              -math.sin(h) * d[:, 0] + math.cos(h) * d[:, 1]])
    return points * (1.0, -1.0) if mirrored else points


def _drive(check: TurnSignCheck, gyro_sign: float, mirrored: bool, scans: int = 40) -> None:
    # An arc at 1 m/s and 30 deg/s, one scan every 0.1 s; the gyro's integral as it
    # reads (its sign) plus a bias of 0.5 deg/s the first stop learnt.
    rate, speed, bias = math.radians(30.0), 1.0, math.radians(0.5)
    x = y = yaw = 0.0
    for k in range(scans):
        t = 0.1 * k
        check.scan('front', 'front', t, _seen((x, y, yaw), mirrored), MOUNT,
                   gyro_sign * rate * t + bias * t, bias, speed)
        x += speed * 0.1 * math.cos(yaw + rate * 0.05)
        y += speed * 0.1 * math.sin(yaw + rate * 0.05)
        yaw += rate * 0.1


@pytest.mark.parametrize('gyro_sign, mirrored, opposite', [
    (1.0, False, False), (-1.0, False, True), (1.0, True, True), (-1.0, True, False)])
def test_scans_vote_on_the_sign_of_the_gyros_turn(gyro_sign, mirrored, opposite):
    check = TurnSignCheck()
    _drive(check, gyro_sign, mirrored)
    [lidar] = check.report()
    assert lidar['votes'] >= MIN_VOTES
    assert lidar['opposite'] == (lidar['votes'] if opposite else 0)
    assert lidar['opposite_found'] is opposite
    assert lidar['scale'] == (-1.0 if opposite else 1.0) and not lidar['scale_found']
    if not mirrored:
        # The path the scans show, against the odometry's 1 m/s (a mirrored LiDAR's lever
        # arm is mirrored too: off by 12 % here).
        assert lidar['speed_ratio'] == pytest.approx(1.0, abs=0.05)


@pytest.mark.parametrize('gyro_scale', [180.0 / math.pi, -180.0 / math.pi, math.pi / 180.0])
def test_a_gyro_in_degrees_per_second_is_found(gyro_scale):
    # The last reads a fraction of each turn: its pairs are tried on time alone, one in
    # 0.4 s of the 12-s arc.
    check = TurnSignCheck()
    _drive(check, gyro_scale, False, scans=120)
    [lidar] = check.report()
    assert lidar['scale'] == pytest.approx(gyro_scale) and lidar['scale_found']


def test_a_gyro_that_reads_none_of_the_turns_is_found_and_a_good_one_is_not():
    # Its turns below MIN_TURN_RAD: only pairs on time alone are tried, where the scans
    # still show the arc's 12-15 deg every 0.4-0.5 s.
    check = TurnSignCheck()
    _drive(check, 0.0, False, scans=120)
    [lidar] = check.report()
    assert lidar['votes'] == 0 and lidar['unseen_found']
    assert lidar['unseen_turns'] >= MIN_VOTES
    # 30 deg/s over the 0.4-0.5 s between the pair's scans.
    assert 12.0 <= lidar['unseen_largest_deg'] <= 15.5
    # A gyro that reads them votes, and never finds a turn it did not read.
    check = TurnSignCheck()
    _drive(check, 1.0, False, scans=120)
    [lidar] = check.report()
    assert lidar['votes'] >= MIN_VOTES and lidar['unseen_turns'] == 0


def test_straight_driving_and_few_poles_do_not_vote_and_votes_stop():
    check = TurnSignCheck()
    for k in range(20):  # straight ahead: the two signs are the same turn
        check.scan('front', 'front', 0.1 * k, _seen((0.05 * k, 0.0, 0.0)), MOUNT, 0.0, 0.0, 0.5)
    for k in range(20):  # one pole in view
        check.scan('side', 'side', 0.1 * k, _seen((0.0, 0.0, 0.05 * k))[:1], MOUNT,
                   0.05 * k, 0.0, 0.0)
    assert check.report() == []
    _drive(check, 1.0, False, scans=3 * MAX_VOTES)
    assert check.report()[0]['votes'] == MAX_VOTES


def test_restore_takes_votes_back():
    check = TurnSignCheck()
    _drive(check, -1.0, False, scans=5)
    saved, before = check.save(), check.report()
    _drive(check, -1.0, False)
    assert check.report() != before
    check.restore(saved)
    assert check.report() == before


def _gyro_negated(trip):
    w = trip.imu.angular_velocity_rad_s.copy()
    w[:, 2] *= -1.0
    return dataclasses.replace(trip, imu=dataclasses.replace(trip.imu, angular_velocity_rad_s=w))


def _mirrored(scans):
    return dataclasses.replace(
        scans, ranges_m=np.ascontiguousarray(scans.ranges_m[:, ::-1]),
        intensities=None if scans.intensities is None
        else np.ascontiguousarray(scans.intensities[:, ::-1]))


def test_an_upside_down_gyro_is_named_as_the_cause():
    # A gyro upside down ends metres off and used to be failed for its effects only (a
    # bias beyond 10 deg/s, the pose lost); now the first reason names it, and the
    # LiDAR's first looks at the start pose say which of the two it is.
    trip = simulate_trip(SimulationConfig(duration_s=40.0), 2)
    flipped = summarize(run_trip(_gyro_negated(trip)))
    assert flipped['health']['verdict'] == 'failed'
    first = flipped['health']['reasons'][0]
    assert first.startswith('the gyro and LiDAR scan turn opposite ways') and (
        'the IMU is mounted upside down' in first), first
    assert flipped['turn_signs']['scan']['opposite_found']
    upright = summarize(run_trip(trip))
    assert not upright['turn_signs']['scan']['opposite_found']
    assert upright['turn_signs']['scan']['votes'] >= MIN_VOTES
    assert upright['turn_signs']['scan']['speed_ratio'] == pytest.approx(1.0, abs=0.1)
    assert not [r for r in upright['health']['reasons'] if 'turn' in r and 'opposite' in r]


@pytest.mark.parametrize('stream, factor, said', [
    ('gyro', 180.0 / math.pi, 'its yaw rate is in deg/s where REP-103 has rad/s'),
    ('gyro', math.pi / 180.0, 'a yaw rate in rad/s was converted as if it were in deg/s'),
    ('odometry', -1.0, "its speed's sign is reversed"),
    ('odometry', 0.01, "its speed's units or scale are wrong")])
def test_inputs_in_the_wrong_units_or_sign_are_named(stream, factor, said):
    # Each ends metres off, failed for the pose lost or under 50 % associated; the first
    # reason now says which input and what is wrong with it.
    trip = simulate_trip(SimulationConfig(duration_s=40.0), 2)
    if stream == 'gyro':
        w = trip.imu.angular_velocity_rad_s.copy()
        w[:, 2] *= factor
        trip = dataclasses.replace(trip, imu=dataclasses.replace(
            trip.imu, angular_velocity_rad_s=w))
    else:
        trip = dataclasses.replace(trip, speed=dataclasses.replace(
            trip.speed, speed_m_s=trip.speed.speed_m_s * factor))
    summary = summarize(run_trip(trip))
    first = summary['health']['reasons'][0]
    assert summary['health']['verdict'] == 'failed'
    assert first.startswith(f'the {stream} reads ') and said in first, first


def test_a_second_lidar_turned_half_a_turn_is_named_not_the_odometry():
    """A helper's find: a rear LiDAR stated forward (180 deg off) made the odometry's sign
    the first reason of a failed run, while the other LiDAR agreed with the odometry and
    the pose held to 2.4 mm. Reversed odometry, both LiDARs disagreeing, is still that."""
    config = SimulationConfig(duration_s=40.0, second_lidar=True,
                              lidar2_yaw_error_rad=math.pi)
    summary = summarize(run_trip(simulate_trip(config, 2)))
    said = [r for r in summary['health']['reasons'] if 'm per metre' in r]
    assert len(said) == 1 and said[0].startswith(
        "LiDAR scan2's scans show the platform going -0.9"), said
    assert "where LiDAR scan's show 0.99:" in said[0] and 'about 180 deg off' in said[0]
    assert not [r for r in summary['health']['reasons'] if r.startswith('the odometry')]
    assert summary['ground_truth']['position_rmse_m'] < 0.02
    trip = simulate_trip(SimulationConfig(duration_s=40.0, second_lidar=True), 2)
    reversed_odometry = dataclasses.replace(trip, speed=dataclasses.replace(
        trip.speed, speed_m_s=-trip.speed.speed_m_s))
    summary = summarize(run_trip(reversed_odometry))
    first = summary['health']['reasons'][0]
    assert summary['health']['verdict'] == 'failed'
    assert first.startswith('the odometry reads -') and "speed's sign is reversed" in first
    # Two LiDARs agree with each other: no hint that one of them faces the other way.
    assert 'faces the other way' not in first


def test_an_upside_down_second_lidar_is_named_and_the_run_holds():
    trip = simulate_trip(SimulationConfig(duration_s=40.0, second_lidar=True), 2)
    mirrored = dataclasses.replace(trip, scans=trip.scans[:-1] + (_mirrored(trip.scans[-1]),))
    summary = summarize(run_trip(mirrored))
    said = [r for r in summary['health']['reasons'] if 'turns the other way' in r]
    assert len(said) == 1 and said[0].startswith('LiDAR scan2 ') and 'upside down' in said[0]
    assert summary['ground_truth']['position_rmse_m'] < 0.02


def test_an_upside_down_lidar_published_inverted_as_the_verdict_says_runs_as_upright():
    trip = simulate_trip(SimulationConfig(duration_s=40.0), 2)
    scans = trip.scans[0]
    mirrored = _mirrored(scans)
    summary = summarize(run_trip(dataclasses.replace(trip, scans=(mirrored,))))
    first = summary['health']['reasons'][0]
    assert 'the LiDAR is mounted upside down' in first and 'angle_increment negated' in first
    assert 'set lidar.scan.upside_down: true' in first
    # The same beams with the angles its driver would publish inverted: as the upright run.
    last = scans.angle_min_rad + scans.angle_increment_rad * (scans.ranges_m.shape[1] - 1)
    inverted = dataclasses.replace(mirrored, angle_min_rad=last,
                                   angle_increment_rad=-scans.angle_increment_rad)
    fixed = summarize(run_trip(dataclasses.replace(trip, scans=(inverted,))))
    upright = summarize(run_trip(trip))
    assert (fixed['health']['verdict'], fixed['health']['reasons']) == (
        upright['health']['verdict'], upright['health']['reasons'])
    assert fixed['ground_truth']['position_rmse_m'] == pytest.approx(
        upright['ground_truth']['position_rmse_m'], rel=1e-3)
    # Or the scans as they are, with the params file's upside_down: the same.
    from gyro_ekf.io.params_file import read_params_text, with_lidar_mounts
    params = read_params_text('/**:\n  ros__parameters:\n    lidar:\n      topics: [scan]\n'
                              '      scan: {upside_down: true}\n')
    assert params.lidars_upside_down == {'scan'} and not params.lidars
    given = with_lidar_mounts(dataclasses.replace(trip, scans=(mirrored,)), params)
    assert given.scans[0].upside_down and given.scans[0].mount == scans.mount
    flipped = summarize(run_trip(given))
    assert (flipped['health']['verdict'], flipped['health']['reasons']) == (
        upright['health']['verdict'], upright['health']['reasons'])
    assert flipped['ground_truth']['position_rmse_m'] == pytest.approx(
        upright['ground_truth']['position_rmse_m'], rel=1e-3)


@pytest.mark.parametrize('how', ['dead', 'on its side'])
def test_a_gyro_whose_z_axis_misses_the_turns_is_named(how):
    # A dead z axis reads 0; an IMU on its side reads the turns on x and its x axis's
    # bias and noise on z. Either loses the pose (its effects were the reasons: a bias
    # beyond 10 deg/s, the pose lost); the first reason now says the z axis is blind.
    trip = simulate_trip(SimulationConfig(duration_s=40.0), 2)
    w = trip.imu.angular_velocity_rad_s.copy()
    if how == 'dead':
        w[:, 2] = 0.0
    else:
        w[:, [0, 2]] = w[:, [2, 0]]
    summary = summarize(run_trip(dataclasses.replace(trip, imu=dataclasses.replace(
        trip.imu, angular_velocity_rad_s=w))))
    first = summary['health']['reasons'][0]
    assert summary['health']['verdict'] == 'failed'
    assert first.startswith('the gyro reads almost none of the turns LiDAR scan') and (
        'an IMU mounted on its side' in first), first
    upright = summarize(run_trip(trip))['turn_signs']['scan']
    assert upright['unseen_turns'] == 0


@pytest.fixture(scope='module')
def real_2016_trip(shared_data):
    from gyro_ekf.io.matlab import load_course_log
    return load_course_log([shared_data('2016_project1'),
                            shared_data('2021_aas01/MapMTRN4010.mat')])


@pytest.mark.parametrize('upside_down', ['gyro', 'lidar'])
def test_the_real_2016_log_with_a_sensor_upside_down_names_which(real_2016_trip, upside_down):
    # The real log's one LiDAR scans at 37 Hz, each scan under 1 deg after the last. Upright
    # it votes as the gyro turns; with either sensor upside down it votes the other way,
    # and its detections before the first turn (matched as usual, or hardly at all) say
    # which sensor it is.
    trip = real_2016_trip
    upright = summarize(run_trip(trip))['turn_signs']['scan']
    assert upright['votes'] >= MIN_VOTES and upright['opposite'] == 0
    assert upright['unseen_turns'] == 0
    if upside_down == 'gyro':
        trip, named = _gyro_negated(trip), 'the IMU is mounted upside down'
    else:
        trip = dataclasses.replace(trip, scans=(_mirrored(trip.scans[0]),))
        named = 'the LiDAR is mounted upside down'
    summary = summarize(run_trip(trip))
    first = summary['health']['reasons'][0]
    assert summary['health']['verdict'] == 'failed'
    assert first.startswith('the gyro and LiDAR scan turn opposite ways') and named in first
