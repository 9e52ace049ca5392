"""Two LiDARs that disagree: the pose reported between them (core/body_frame.py)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from gyro_ekf.analysis.offline import effective_config, run_trip
from gyro_ekf.analysis.stress import stress_trip
from gyro_ekf.analysis.summary import summarize
from gyro_ekf.core.body_frame import (disagreement_spread, heading_spread, mixture_shift,
                                      other_right_share, shift_estimates, with_heading)
from gyro_ekf.core.events import EventDriver
from gyro_ekf.core.trip_run import drive_trip
from gyro_ekf.core.types import LidarMount

D = (0.006, -0.008)


def _rotation(yaw):
    return np.array([[math.cos(yaw), -math.sin(yaw)], [math.sin(yaw), math.cos(yaw)]])


@pytest.mark.parametrize('share', [0.0, 0.2, 0.5, 0.97, 1.0])
def test_the_shift_is_the_two_hypotheses_mean_and_covariance(share):
    # A: the pose as the filter has it; B: R(yaw) d further. Weighted w_A, w_B, their
    # mean and covariance about it, written out here the long way.
    rng = np.random.default_rng(4)
    states = rng.normal(size=(6, 4))
    A = rng.normal(size=(6, 4, 4))
    covariances = A @ np.transpose(A, (0, 2, 1))
    expected_states, expected_cov = states.copy(), covariances.copy()
    for k in range(6):
        moved = _rotation(states[k, 2]) @ np.array(D)
        hypotheses = [states[k, :2], states[k, :2] + moved]
        weights = [1.0 - share, share]
        mean = sum(w * h for w, h in zip(weights, hypotheses))
        spread = sum(w * np.outer(h - mean, h - mean) for w, h in zip(weights, hypotheses))
        expected_states[k, :2] = mean
        expected_cov[k, :2, :2] += spread
    shift_estimates(states, covariances, mixture_shift(D, share))
    np.testing.assert_allclose(states, expected_states, atol=1e-15)
    np.testing.assert_allclose(covariances, expected_cov, atol=1e-15)


@pytest.mark.parametrize('share', [0.1, 0.5])
def test_a_disagreement_under_the_limits_widens_the_covariance_by_what_either_side_puts_off(
        share):
    # Both LiDARs weigh with their stated mounts; the other one holds a share s of the
    # pose. Its fit reads d: under A (it is off by a) the pose is off by s a and d = (1 - s)
    # a; under B (the first one off by b) by (1 - s) b and d = -(1 - s) b. The pose stays,
    # and the covariance gains R d d^T R^T, at least either side's error squared.
    rng = np.random.default_rng(5)
    states = rng.normal(size=(4, 4))
    A = 0.01 * rng.normal(size=(4, 4, 4))  # a pose's covariance, cm^2: as d's scale
    covariances = A @ np.transpose(A, (0, 2, 1))
    before_states, before_cov = states.copy(), covariances.copy()
    shift_estimates(states, covariances, disagreement_spread(D))
    np.testing.assert_array_equal(states, before_states)
    a = np.array(D) / (1.0 - share)
    b = -np.array(D) / (1.0 - share)
    for k in range(4):
        rotation = _rotation(states[k, 2])
        added = covariances[k] - before_cov[k]
        np.testing.assert_allclose(added[:2, :2], np.outer(rotation @ D, rotation @ D),
                                   rtol=1e-9, atol=1e-18)
        np.testing.assert_array_equal(added[2:], 0.0)
        np.testing.assert_array_equal(added[:, 2:], 0.0)
        for error in (share * a, (1.0 - share) * b):  # the pose's error under A, under B
            e = rotation @ error
            assert e @ e <= (e @ added[:2, :2] @ e / (e @ e)) * (1.0 + 1e-9)


def _offset(x, y, sigma=0.004, dof=7.0):
    return (x, y, sigma * sigma, 0.0, sigma * sigma, dof)


def test_the_weights_follow_the_evidence():
    # No evidence: even.
    assert other_right_share(D, None, None, None) == pytest.approx(0.5)
    # At the start pose the first LiDAR reads -d off its mount and the other its own: B.
    assert other_right_share(D, _offset(-D[0], -D[1]), _offset(0.0, 0.0), None) > 0.99
    # ... the first its own and the other d off: A.
    assert other_right_share(D, _offset(0.0, 0.0), _offset(*D), None) < 0.01
    # A start that cannot tell (both read halfway) stays even.
    half = _offset(-D[0] / 2, -D[1] / 2), _offset(D[0] / 2, D[1] / 2)
    assert other_right_share(D, *half, None) == pytest.approx(0.5)
    # The odometry's path fit places the first LiDAR -d off (B), or at its mount (A).
    assert other_right_share(D, *half, (-D[0], -D[1], 0.002, 0.002)) > 0.99
    assert other_right_share(D, *half, (0.0, 0.0, 0.002, 0.002)) < 0.01


@pytest.mark.parametrize('bad', [
    (0.01, 0.0, 0.0, 0.0, 0.0, 7.0),                       # singular covariance
    (0.01, 0.0, 1e-6, 2e-6, 1e-6, 7.0),                    # not positive definite
    (math.nan, 0.0, 1e-6, 0.0, 1e-6, 7.0),                 # not finite
    (0.01, 0.0, math.inf, 0.0, 1e-6, 7.0)])
def test_a_stop_fit_with_no_usable_covariance_says_nothing(bad):
    # Counted, it made B certain (weight 1.0) from evidence that says nothing.
    assert other_right_share(D, bad, bad, None) == pytest.approx(0.5)
    assert other_right_share(D, bad, None, (math.nan, 0.0, 0.002, 0.002)) == (
        pytest.approx(0.5))
    good = other_right_share(D, _offset(-D[0], -D[1]), _offset(0.0, 0.0), None)
    assert other_right_share(D, _offset(-D[0], -D[1]), bad, None) != 1.0
    assert other_right_share(D, bad, _offset(0.0, 0.0), None) < good
    assert other_right_share((math.nan, 0.0), None, None, None) == 0.5


def test_a_first_lidar_a_centimetre_off_is_reported_where_the_other_puts_it():
    # Stress seed 0, mount_offset 1: the first LiDAR 1.07 cm off beside an exact rear one.
    # Taken as right, the first held the pose 1 cm off, its sigma 2 mm, until the
    # odometry's path fit moved it at 110 s (NEES share in band 0.19). Both LiDARs' scans
    # at the trusted start pose point at it: the pose is reported where the rear one puts
    # it.
    summary = summarize(run_trip(stress_trip('mount_offset', 0, 1)))
    assert summary['ground_truth']['position_rmse_m'] <= 0.005
    assert summary['ground_truth']['nees_share_in_band'] >= 0.9


def test_a_first_lidar_half_a_centimetre_off_is_said_and_reported_where_the_other_puts_it():
    # Stress seed 0, mount_offset 23: the first LiDAR 0.43 cm off, never moved by the
    # odometry (NEES share in band 0.84 when taken as right).
    summary = summarize(run_trip(stress_trip('mount_offset', 0, 23)))
    assert summary['ground_truth']['nees_share_in_band'] >= 0.9
    assert summary['online_mounts']['scan2']['right_share'] > 0.9
    assert any('% for scan2 being the one right' in reason
               for reason in summary['health']['reasons'])


def test_a_second_lidar_off_its_mount_leaves_the_pose_where_the_first_puts_it():
    # Stress seed 0, mount_offset 2: the rear LiDAR 7.9 cm off. Its own scans at the start
    # pose say so: nothing moves, and the run stays within the bounds.
    run = run_trip(stress_trip('mount_offset', 0, 2))
    [mount] = run.result.mounts.report()
    assert mount['right_share'] is not None and mount['right_share'] < 1e-6
    summary = summarize(run)
    assert summary['ground_truth']['position_rmse_m'] <= 0.005
    assert summary['ground_truth']['nees_share_in_band'] >= 0.9


def test_after_a_hand_over_at_the_start_the_two_swap_roles():
    # Stress seed 40, mount_offset 24: the second LiDAR 1.8 cm off. At the stop the exact
    # first LiDAR read 3.2 sigmas off, the second 2.8, and the body frame went to the
    # second; taken as right it held the pose 1 cm off (NEES share 0.67) until the path fit
    # moved its mount. Weighed against the first one, now tracked, the pose lies between
    # them until then.
    summary = summarize(run_trip(stress_trip('mount_offset', 40, 24)))
    reasons = summary['health']['reasons']
    assert any('scan2 defines the body frame' in r for r in reasons)
    assert any('scan2 sits off its stated mount against the odometry' in r for r in reasons)
    assert summary['ground_truth']['nees_share_in_band'] >= 0.9


def test_a_second_lidar_millimetres_off_under_the_limits_widens_the_pose_s_covariance():
    # Stress seed 15, mount_offset 8: the second LiDAR 4.7 mm off, read 2.7 mm at 12 of
    # the fit's sigmas, under the 5 mm a mount is corrected by: both keep their stated
    # mounts, the pose leans towards the second, and the run said "the pose may be off by
    # as much" with a covariance that did not (NEES share 0.882). The covariance reported
    # now spans the disagreement: the pose stays where the filter has it.
    trip = stress_trip('mount_offset', 15, 8)
    driver = _driver(trip)
    result = drive_trip(trip, driver)
    [tracker] = driver.mounts.trackers.values()
    assert tracker.used == tracker.stated
    dx, dy = tracker.watched_read_off_m
    assert 0.0018 < math.hypot(dx, dy) < 0.005
    assert tracker.widened_m == pytest.approx(math.hypot(dx, dy))
    estimate = driver.estimate()
    np.testing.assert_array_equal(estimate.state, driver.ekf.x[:4])
    rotated = _rotation(estimate.state[2]) @ np.array([dx, dy])
    np.testing.assert_allclose(estimate.covariance[:2, :2] - driver.ekf.P[:2, :2],
                               np.outer(rotated, rotated), atol=1e-15)
    np.testing.assert_allclose(estimate.covariance, result.estimates.covariance[-1],
                               atol=1e-15)
    summary = summarize(run_trip(trip))
    [said] = [reason for reason in summary['health']['reasons']
              if reason.startswith('LiDAR scan2 and scan disagree by')]
    assert f'(its covariance is widened by {1000.0 * math.hypot(dx, dy):.1f} mm' in said
    assert summary['online_mounts']['scan2']['widened_m'] == pytest.approx(
        math.hypot(dx, dy))
    assert summary['ground_truth']['nees_share_in_band'] >= 0.9


def test_a_lidar_handed_over_and_read_off_leaves_the_covariance_as_it_is():
    # Stress seed 8, mount_offset 6: the first LiDAR 6.4 mm off, named by its first looks
    # and handed over; its watch reads 4.9 mm, and it weighs a ninth. The pose leans on
    # the other LiDAR: widened by the whole disagreement the NEES share fell 0.896 -> 0.861.
    trip = stress_trip('mount_offset', 8, 6)
    driver = _driver(trip)
    drive_trip(trip, driver)
    [tracker] = driver.mounts.trackers.values()
    assert tracker.handed_over_s is not None and tracker.used == tracker.stated
    assert tracker.watched_read_off_m is not None
    assert tracker.noise_scale == 9.0
    # The position as it is (the heading may be widened by the body frame's yaw: below).
    assert tracker.widened_m is None
    assert driver.frame_shift is None or driver.frame_shift[:5] == (0.0,) * 5


@pytest.mark.parametrize('yaw, sigma, expected', [
    (0.0, 0.001, 0.0), (0.0005, 0.001, 0.0), (0.0015, 0.001, 0.0), (-0.002, 0.001, 0.0),
    (-0.003, 0.001, 8e-6), (0.002, 0.0, 4e-6)])
def test_a_body_frame_yaw_read_off_adds_what_it_reads_beyond_its_noise(yaw, sigma, expected):
    # E[e^2] = delta^2 + sigma^2; a fit within 2 sigmas adds nothing.
    assert heading_spread(yaw, sigma) == pytest.approx(expected, abs=1e-18)


def test_the_heading_widening_adds_to_the_heading_alone_and_to_any_mixture():
    rng = np.random.default_rng(6)
    states = rng.normal(size=(3, 4))
    A = 0.01 * rng.normal(size=(3, 4, 4))
    covariances = A @ np.transpose(A, (0, 2, 1))
    before_states, before_cov = states.copy(), covariances.copy()
    assert with_heading(None, 0.0) is None
    shift_estimates(states, covariances, with_heading(None, 4e-6))
    np.testing.assert_array_equal(states, before_states)
    added = covariances - before_cov
    np.testing.assert_allclose(added[:, 2, 2], 4e-6, rtol=1e-12)
    added[:, 2, 2] = 0.0
    np.testing.assert_array_equal(added, 0.0)
    mixed = with_heading(mixture_shift(D, 0.5), 4e-6)
    assert mixed[:5] == mixture_shift(D, 0.5)[:5] and mixed[5] == 4e-6


def _driver(trip):
    # As run_trip makes it: the trip's stated noise and its trusted start pose.
    config, _ = effective_config(trip.noise)
    return EventDriver(config, trip.landmarks, trip.initial_pose)


def test_the_node_s_estimate_is_the_row_the_offline_run_reports():
    # EventDriver.estimate (the node's) and drive_trip's rows move the pose alike.
    trip = stress_trip('mount_offset', 0, 23)
    driver = _driver(trip)
    result = drive_trip(trip, driver)
    assert driver.frame_shift is not None
    estimate = driver.estimate()
    assert trip.imu.stamp_s[-1] >= max(scan.stamp_s[-1] for scan in trip.scans)
    np.testing.assert_allclose(estimate.state, result.estimates.state[-1], atol=1e-12)
    np.testing.assert_allclose(estimate.covariance, result.estimates.covariance[-1],
                               atol=1e-15)


def test_save_and_restore_keep_the_mixture():
    trip = stress_trip('mount_offset', 0, 23)
    driver = _driver(trip)
    drive_trip(trip, driver)
    saved = driver.save()
    shift, share = driver.frame_shift, driver.mounts.trackers[trip.scans[1].mount].right_share
    assert shift is not None and share is not None
    driver.frame_shift = None
    driver.mounts.trackers[trip.scans[1].mount].right_share = None
    driver.restore(saved)
    assert driver.frame_shift == shift
    assert driver.mounts.trackers[trip.scans[1].mount].right_share == share
    assert isinstance(trip.scans[1].mount, LidarMount)
