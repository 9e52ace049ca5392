"""The trip simulator: determinism, static start, gyro bias, LiDAR geometry, truth."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from gyro_ekf.core.angles import wrap_angle
from gyro_ekf.core.detection import detect_poles
from gyro_ekf.core.errors import CoreError
from gyro_ekf.core.models import observe, points_to_range_bearing, predict_state, sensor_to_map
from gyro_ekf.core.simulator import GRAVITY_M_S2, SimulationConfig, simulate_trip
from gyro_ekf.core.types import LidarMount, Trip


@pytest.fixture(scope='module')
def trip() -> Trip:
    return simulate_trip(seed=0)


def _truth_at(trip: Trip, stamps_s):
    index = np.searchsorted(trip.ground_truth.stamp_s, stamps_s)
    np.testing.assert_allclose(trip.ground_truth.stamp_s[index], stamps_s, atol=1e-9)
    return trip.ground_truth.pose[index]


def test_same_seed_same_trip_other_seed_other_trip():
    config = SimulationConfig(duration_s=20.0)
    first, again, other = (simulate_trip(config, seed) for seed in (3, 3, 4))
    for a, b in ((first, again),):
        np.testing.assert_array_equal(a.imu.angular_velocity_rad_s, b.imu.angular_velocity_rad_s)
        np.testing.assert_array_equal(a.speed.speed_m_s, b.speed.speed_m_s)
        np.testing.assert_array_equal(a.scans[0].ranges_m, b.scans[0].ranges_m)
        np.testing.assert_array_equal(a.ground_truth.pose, b.ground_truth.pose)
        np.testing.assert_array_equal(a.landmarks.xy_m, b.landmarks.xy_m)
    assert not np.allclose(first.landmarks.xy_m, other.landmarks.xy_m)
    assert not np.allclose(first.imu.angular_velocity_rad_s, other.imu.angular_velocity_rad_s)
    # The scene depends on the seed only, not on the duration.
    longer = simulate_trip(SimulationConfig(duration_s=30.0), seed=3)
    np.testing.assert_array_equal(longer.landmarks.xy_m, first.landmarks.xy_m)


def test_layout_stamps_and_defaults(trip):
    assert trip.name == 'sim_seed0'
    for stamps in (trip.imu.stamp_s, trip.speed.stamp_s, trip.scans[0].stamp_s,
                   trip.ground_truth.stamp_s):
        assert stamps[0] == 0.0 and np.all(np.diff(stamps) > 0)
        assert stamps[-1] == pytest.approx(120.0)
    assert np.median(np.diff(trip.imu.stamp_s)) == pytest.approx(1 / 200)
    assert np.median(np.diff(trip.speed.stamp_s)) == pytest.approx(1 / 100)
    assert np.median(np.diff(trip.scans[0].stamp_s)) == pytest.approx(1 / 10)
    assert np.median(np.diff(trip.ground_truth.stamp_s)) == pytest.approx(1 / 50)
    scans = trip.scans[0]
    assert scans.ranges_m.dtype == np.float32 and scans.ranges_m.shape[1] == 361
    assert scans.mount == LidarMount(0.46, 0.0, 0.0)
    assert scans.angles_rad[0] == pytest.approx(-math.pi / 2)
    assert scans.angles_rad[-1] == pytest.approx(math.pi / 2)
    assert np.isinf(scans.ranges_m).any()          # through the doorway
    assert not np.isnan(scans.ranges_m).any()
    assert set(np.unique(scans.intensities)) == {0.0, 1.0}
    assert trip.imu.angular_velocity_rad_s.shape == (trip.imu.stamp_s.size, 3)
    assert trip.imu.linear_acceleration_m_s2.shape == (trip.imu.stamp_s.size, 3)
    assert len(trip.landmarks) == 14
    assert trip.walls.shape[1] == 2
    np.testing.assert_allclose(trip.initial_pose, [0.0, 0.0, math.pi / 2], atol=1e-12)
    np.testing.assert_allclose(trip.ground_truth.pose[0], trip.initial_pose)
    assert trip.true_gyro_bias_rad_s[2] == pytest.approx(math.radians(-0.9))
    assert trip.noise.gyro_rad_s == pytest.approx(math.radians(0.25))


def test_static_start_then_driving(trip):
    static = trip.static_duration_s
    assert static == 8.0
    at_rest = trip.speed.stamp_s < static
    assert np.all(trip.speed.speed_m_s[at_rest] == 0.0)
    resting = trip.ground_truth.stamp_s <= static
    np.testing.assert_array_equal(trip.ground_truth.pose[resting],
                                  np.repeat(trip.initial_pose[None], resting.sum(), axis=0))
    cruising = trip.speed.stamp_s > static + 3.0
    speeds = trip.speed.speed_m_s[cruising]
    assert 0.25 < speeds.min() and speeds.max() < 1.05
    rates = trip.imu.yaw_rate_rad_s - trip.true_gyro_bias_rad_s[2]
    assert rates.max() > math.radians(10) and rates.min() < -math.radians(10)  # both ways
    # Accelerometer at rest: gravity on z only.
    accel = trip.imu.linear_acceleration_m_s2[trip.imu.stamp_s < static]
    np.testing.assert_allclose(accel.mean(axis=0), [0.0, 0.0, GRAVITY_M_S2], atol=0.01)


def test_static_gyro_mean_is_the_injected_bias(trip):
    window = trip.imu.stamp_s < trip.static_duration_s - 0.01
    rates = trip.imu.angular_velocity_rad_s[window]
    sigma = np.array([math.radians(v) for v in (0.20, 0.30, 0.25)])
    standard_error = sigma / math.sqrt(window.sum())
    error = rates.mean(axis=0) - trip.true_gyro_bias_rad_s
    assert np.all(np.abs(error) < 4.0 * standard_error)
    np.testing.assert_allclose(rates.std(axis=0), sigma, rtol=0.1)
    assert len(set(trip.true_gyro_bias_rad_s.tolist())) == 3


def test_detected_poles_sit_on_the_map_under_the_true_pose(trip):
    scans = trip.scans[0]
    poses = _truth_at(trip, scans.stamp_s)
    counts, range_errors, bearing_errors = [], [], []
    increment = scans.angle_increment_rad
    for ranges, intensities, pose in zip(scans.ranges_m, scans.intensities, poses):
        found = detect_poles(ranges, scans.angles_rad, intensities)
        counts.append(len(found))
        if not len(found):
            continue
        state = np.append(pose, 0.0)
        points = sensor_to_map(state, found.points_sensor_m, scans.mount)
        gaps = np.linalg.norm(points[:, None] - trip.landmarks.xy_m[None], axis=2)
        nearest = gaps.argmin(axis=1)
        # A single beam may graze the pole's edge: up to a radius deep and half a beam off.
        z = points_to_range_bearing(found.points_sensor_m)
        bound = 0.05 + 0.5 * increment * z[:, 0] + 4 * SimulationConfig().range_noise_m
        assert np.all(gaps[np.arange(len(found)), nearest] < bound)
        expected = observe(state, trip.landmarks.xy_m[nearest], scans.mount)
        range_errors.extend(z[:, 0] - expected[:, 0])
        bearing_errors.extend(wrap_angle(z[:, 1] - expected[:, 1]))
    counts = np.array(counts)
    assert np.mean(counts >= 3) > 0.9          # several poles in view most of the time
    # The per-beam figures bound the effective pole observation noise; the trip does not
    # state them, as they are not the noise of a detected pole.
    per_beam_range_m = SimulationConfig().range_noise_m
    assert np.std(range_errors) < 1.2 * per_beam_range_m
    assert abs(np.mean(range_errors)) < 0.5 * per_beam_range_m
    assert np.std(bearing_errors) < 1.2 * increment / math.sqrt(12.0)
    assert trip.noise.range_m is None and trip.noise.bearing_rad is None
    assert trip.noise.landmark_m == 0.0


def test_width_mode_finds_the_same_poles(trip):
    # Without intensities a pole partly hidden by a closer one is refused, and a wall end
    # at the doorway can pass for a pole: both are rare.
    scans = trip.scans[0]
    reflective = missed = extra = 0
    for ranges, intensities in zip(scans.ranges_m, scans.intensities):
        with_intensity = detect_poles(ranges, scans.angles_rad, intensities).points_sensor_m
        by_width = detect_poles(ranges, scans.angles_rad, None).points_sensor_m
        gaps = np.linalg.norm(with_intensity[:, None] - by_width[None], axis=2)
        reflective += len(with_intensity)
        missed += int(np.sum(gaps.min(axis=1, initial=np.inf) > 0.05))
        extra += int(np.sum(gaps.min(axis=0, initial=np.inf) > 0.05))
    assert missed < 0.02 * reflective
    assert extra < 0.02 * reflective


def test_path_keeps_clear_of_poles_and_walls(trip):
    xy = trip.ground_truth.pose[:, :2]
    to_poles = np.linalg.norm(xy[:, None] - trip.landmarks.xy_m[None], axis=2)
    assert to_poles.min() > 1.1
    spacing = np.linalg.norm(trip.landmarks.xy_m[:, None] - trip.landmarks.xy_m[None], axis=2)
    assert spacing[~np.eye(len(trip.landmarks), dtype=bool)].min() >= 2.0
    walls = trip.walls[np.all(np.isfinite(trip.walls), axis=1)]
    for start, end in zip(walls[:-1], walls[1:]):
        edge = end - start
        along = np.clip(((xy - start) @ edge) / (edge @ edge), 0.0, 1.0)
        assert np.linalg.norm(xy - (start + along[:, None] * edge), axis=1).min() > 2.5


def test_truth_is_the_integral_of_the_true_inputs():
    config = SimulationConfig(duration_s=40.0, speed_rate_hz=200.0, gyro_noise_x_rad_s=0.0,
                              gyro_noise_y_rad_s=0.0, gyro_noise_z_rad_s=0.0,
                              speed_noise_m_s=0.0, range_noise_m=0.0)
    trip = simulate_trip(config, seed=5)
    np.testing.assert_array_equal(trip.speed.stamp_s, trip.imu.stamp_s)
    rates = trip.imu.yaw_rate_rad_s - trip.true_gyro_bias_rad_s[2]
    speeds = trip.speed.speed_m_s
    dt = 1.0 / 200.0
    state = np.append(trip.initial_pose, 0.0)
    every = 4                                  # truth at 50 Hz, inputs at 200 Hz
    worst_xy, worst_yaw = 0.0, 0.0
    for k in range(trip.imu.stamp_s.size - 1):
        if k % every == 0:
            truth = trip.ground_truth.pose[k // every]
            worst_xy = max(worst_xy, float(np.hypot(*(state[:2] - truth[:2]))))
            worst_yaw = max(worst_yaw, abs(float(wrap_angle(state[2] - truth[2]))))
        # Samples are interval means, so a symmetric split (half turn, drive, half turn)
        # integrates them to second order.
        state = predict_state(state, 0.0, rates[k], 0.5 * dt)
        state = predict_state(state, speeds[k], 0.0, dt)
        state = predict_state(state, 0.0, rates[k], 0.5 * dt)
    assert worst_yaw < 1e-9
    assert worst_xy < 1e-3
    # Zero-order hold (the EventDriver's scheme) drifts only slowly on the same inputs.
    state = np.append(trip.initial_pose, 0.0)
    for k in range(trip.imu.stamp_s.size - 1):
        state = predict_state(state, speeds[k], rates[k], dt)
    assert np.hypot(*(state[:2] - trip.ground_truth.pose[-1][:2])) < 0.1


def test_options():
    trip = simulate_trip(SimulationConfig(duration_s=10.0, static_s=5.0,
                                          with_accelerometer=False, pole_count=6), seed=1)
    assert trip.imu.linear_acceleration_m_s2 is None
    assert len(trip.landmarks) == 6
    assert trip.static_duration_s == 5.0
    assert trip.end_s == pytest.approx(10.0)


@pytest.mark.parametrize('changes, match', [
    ({'duration_s': -1.0}, 'duration_s'),
    ({'min_speed_m_s': 0.9, 'max_speed_m_s': 0.5}, 'min_speed_m_s'),
    ({'pole_count': 200}, 'could place only'),
])
def test_bad_configs_are_refused(changes, match):
    config = dataclasses.replace(SimulationConfig(duration_s=5.0), **changes)
    with pytest.raises(CoreError, match=match):
        simulate_trip(config)
