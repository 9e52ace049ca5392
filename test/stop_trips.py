"""Simulated trips with stops along the way, for the zero-rate update tests.

Not a test module: test files import it (pytest puts this folder on sys.path through the
conftest beside it). The simulator's trips stop only at the start; here a trip is cut at
chosen scan stamps and a stop of a given length inserted: the platform stands at the pose
it had there (speed exactly 0, the gyro reads its bias plus white noise, the LiDAR sees
the scene it saw from there), and everything after moves on by the stop's length.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from gyro_ekf.core.simulator import GRAVITY_M_S2, SimulationConfig, simulate_trip
from gyro_ekf.core.types import Trip


def _cut(stamps: np.ndarray, at_s: float) -> int:
    # Index of the first sample at or after at_s (sample times are k / rate, so allow
    # for their rounding).
    return int(np.searchsorted(stamps, at_s - 1e-9))


def _stop_stamps(stamps: np.ndarray, at_s: float, length_s: float) -> np.ndarray:
    period = float(np.median(np.diff(stamps)))
    return at_s + period * np.arange(int(round(length_s / period)))


def _insert(stamps: np.ndarray, values: np.ndarray, at_s: float, length_s: float,
            fill: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Samples before at_s, the stop's samples (fill, one row per stamp), the rest shifted."""
    cut = _cut(stamps, at_s)
    new = _stop_stamps(stamps, at_s, length_s)
    fill = np.broadcast_to(fill, (new.size,) + values.shape[1:]).astype(values.dtype)
    return (np.concatenate([stamps[:cut], new, stamps[cut:] + length_s]),
            np.concatenate([values[:cut], fill, values[cut:]]))


def add_stop(trip: Trip, at_s: float, length_s: float, gyro_sigma_rad_s: np.ndarray,
             rng: np.random.Generator) -> Trip:
    """Insert a stop of length_s at the scan stamp at_s (see the module docstring)."""
    imu = trip.imu
    n_imu = _stop_stamps(imu.stamp_s, at_s, length_s).size
    gyro = trip.true_gyro_bias_rad_s + gyro_sigma_rad_s * rng.standard_normal((n_imu, 3))
    cut = _cut(imu.stamp_s, at_s)
    imu_stamps = np.concatenate([imu.stamp_s[:cut], _stop_stamps(imu.stamp_s, at_s, length_s),
                                 imu.stamp_s[cut:] + length_s])
    rates = np.concatenate([imu.angular_velocity_rad_s[:cut], gyro,
                            imu.angular_velocity_rad_s[cut:]])
    accel = imu.linear_acceleration_m_s2
    if accel is not None:
        _, accel = _insert(imu.stamp_s, accel, at_s, length_s,
                           np.array([0.0, 0.0, GRAVITY_M_S2]))
    speed_stamps, speeds = _insert(trip.speed.stamp_s, trip.speed.speed_m_s, at_s, length_s,
                                   np.zeros(1))
    scans = []
    for scan in trip.scans:
        at = _cut(scan.stamp_s, at_s)
        stamps, ranges = _insert(scan.stamp_s, scan.ranges_m, at_s, length_s,
                                 scan.ranges_m[at])
        intensities = None if scan.intensities is None else _insert(
            scan.stamp_s, scan.intensities, at_s, length_s, scan.intensities[at])[1]
        scans.append(dataclasses.replace(scan, stamp_s=stamps, ranges_m=ranges,
                                         intensities=intensities))
    truth = trip.ground_truth
    pose = np.array([np.interp(at_s, truth.stamp_s, truth.pose[:, k]) for k in range(2)]
                    + [np.interp(at_s, truth.stamp_s, np.unwrap(truth.pose[:, 2]))])
    truth_stamps, truth_pose = _insert(truth.stamp_s, truth.pose, at_s, length_s, pose)
    return dataclasses.replace(
        trip, imu=dataclasses.replace(imu, stamp_s=imu_stamps, angular_velocity_rad_s=rates,
                                      linear_acceleration_m_s2=accel),
        speed=dataclasses.replace(trip.speed, stamp_s=speed_stamps, speed_m_s=speeds),
        scans=tuple(scans),
        ground_truth=dataclasses.replace(truth, stamp_s=truth_stamps, pose=truth_pose))


def trip_with_stops(seed: int, stops_at_s: tuple[float, ...], stop_s: float,
                    duration_s: float = 60.0, static_s: float = 0.0
                    ) -> tuple[Trip, list[tuple[float, float]]]:
    """A simulated trip with a stop of stop_s at each of stops_at_s (trip time, moving).

    Returns:
        The trip and each stop's (start, end) in its stamps, s.
    """
    config = SimulationConfig(duration_s=duration_s, static_s=static_s)
    trip = simulate_trip(config, seed)
    sigma = np.array([config.gyro_noise_x_rad_s, config.gyro_noise_y_rad_s,
                      config.gyro_noise_z_rad_s])
    rng = np.random.default_rng(seed + 1000)
    # The latest first, so each cut is at its stamp in the simulated trip.
    for at_s in sorted(stops_at_s, reverse=True):
        trip = add_stop(trip, at_s, stop_s, sigma, rng)
    spans = [(at_s + k * stop_s, at_s + (k + 1) * stop_s)
             for k, at_s in enumerate(sorted(stops_at_s))]
    return dataclasses.replace(trip, name=f'{trip.name}_stops'), spans
