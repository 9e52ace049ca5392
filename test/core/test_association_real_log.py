"""Detection and association on the REAL 2016 log, by dead reckoning alone (no updates).

The bias is the mean yaw rate over the first 5 s (static). The state [x, y, yaw, bias] is
predicted with ``models.predict_state`` (zero-order hold on the 200 Hz speed and raw yaw
rate) and its covariance with ``process_jacobian``/``process_noise`` under the course's
2019 Project 3 figures for this log (uncorrected dead reckoning needs their breadth), from
the known initial
pose and the standard error of the calibrated bias. Every scan of the first 60 s is run
through ``detect_poles`` and ``associate`` at the dead-reckoned state.
"""

from __future__ import annotations

import math

import numpy as np

from gyro_ekf.core.association import AssociationOutcome, associate
from gyro_ekf.core.config import EkfConfig
from gyro_ekf.core.detection import detect_poles
from gyro_ekf.core.models import (points_to_range_bearing, predict_state, process_jacobian,
                                  process_noise, sensor_to_map)

WINDOW_S = 5.0
HORIZON_S = 60.0


def _dead_reckon(trip, config: EkfConfig):
    """States (n, 4) and covariances (n, 4, 4) at every IMU stamp up to the horizon."""
    stamps = trip.imu.stamp_s
    rates = trip.imu.yaw_rate_rad_s
    static = stamps < stamps[0] + WINDOW_S
    bias = float(rates[static].mean())
    bias_se = float(rates[static].std() / math.sqrt(static.sum()))
    # The 2016 speed shares the IMU stamps; hold the latest speed anyway, to be safe.
    speed_index = np.searchsorted(trip.speed.stamp_s, stamps, side='right') - 1
    speeds = np.where(speed_index >= 0, trip.speed.speed_m_s[np.maximum(speed_index, 0)], 0.0)
    last = int(np.searchsorted(stamps, stamps[0] + HORIZON_S, side='right'))
    x = np.array([*trip.initial_pose, bias])
    P = np.diag([config.initial_position_sigma_m ** 2, config.initial_position_sigma_m ** 2,
                 config.initial_yaw_sigma_rad ** 2, bias_se ** 2])
    states, covariances = [x], [P]
    for k in range(last):
        dt = float(stamps[k + 1] - stamps[k])
        J = process_jacobian(x, speeds[k], dt)
        Q = process_noise(x, dt, config.speed_noise_m_s, config.gyro_noise_rad_s,
                          config.position_random_walk_m_sqrt_s, config.bias_random_walk_rad_s2)
        P = J @ P @ J.T + Q
        x = predict_state(x, speeds[k], rates[k], dt)
        states.append(x)
        covariances.append(P)
    return stamps[:last + 1], np.array(states), np.array(covariances), bias


def test_detected_poles_associate_with_the_map_by_dead_reckoning(shared_data):
    from gyro_ekf.io.matlab import load_course_log

    trip = load_course_log([shared_data('2016_project1'),
                            shared_data('2021_aas01/MapMTRN4010.mat')])
    assert trip.landmarks is not None and len(trip.landmarks) == 5
    config = EkfConfig(gyro_noise_rad_s=math.radians(1.4), speed_noise_m_s=0.4,
                       range_noise_m=0.16, bearing_noise_rad=math.radians(1.1),
                       position_random_walk_m_sqrt_s=0.0021)
    stamps, states, covariances, bias = _dead_reckon(trip, config)
    assert abs(math.degrees(bias) - (-0.9748)) < 0.001

    scans = trip.scans[0]
    R = np.diag([config.range_noise_m ** 2, config.bearing_noise_rad ** 2])
    counts = dict.fromkeys(AssociationOutcome, 0)
    detected = near = 0
    for j in np.flatnonzero(scans.stamp_s <= stamps[-1]):
        found = detect_poles(scans.ranges_m[j], scans.angles_rad, scans.intensities[j])
        if not len(found):
            continue
        k = int(np.searchsorted(stamps, scans.stamp_s[j], side='right')) - 1
        result = associate(points_to_range_bearing(found.points_sensor_m), states[k],
                           covariances[k], R, trip.landmarks.xy_m, scans.mount,
                           config.gate_probability)
        for outcome in AssociationOutcome:
            counts[outcome] += result.count(outcome)
        points = sensor_to_map(states[k], found.points_sensor_m, scans.mount)
        gaps = np.linalg.norm(points[:, None] - trip.landmarks.xy_m[None], axis=2)
        near += int(np.sum(gaps.min(axis=1) < 0.4))
        detected += len(found)

    rate = counts[AssociationOutcome.MATCHED] / detected
    print(f'2016 log, first {HORIZON_S:.0f} s by dead reckoning: {detected} poles detected, '
          f'{100 * rate:.2f} % matched, {100 * near / detected:.2f} % within 0.4 m of a '
          f'landmark; ' + ', '.join(f'{o.name} {c}' for o, c in counts.items()))
    assert detected > 5000
    assert rate > 0.95
    assert near / detected > 0.99
