"""What a returned value is compared with: per-field digests of a Trip, and its problems.

A digest per field (not one for the whole trip) lets a report say *which* field of the fast
reader differs from rosbags'. `problems` lists values the project should never hand to the
filter: non-finite numbers, values beyond `core.config.InputLimits`, stamps going back or
jumping ahead, broken beam geometry.
"""

from __future__ import annotations

import dataclasses
import hashlib
import math
from typing import Any

import numpy as np

from gyro_ekf.core import validation
from gyro_ekf.core.config import InputLimits

LIMITS = InputLimits()


def _digest(value: Any) -> str:
    if value is None:
        return 'None'
    if isinstance(value, np.ndarray):
        array = np.ascontiguousarray(value)
        head = f'{array.dtype.str}{array.shape}'.encode()
        return hashlib.sha1(head + array.tobytes()).hexdigest()[:16]
    return repr(value)


def trip_fields(trip: Any) -> dict[str, str]:
    """Digest of every field of a Trip (arrays bit for bit)."""
    fields: dict[str, str] = {'name': trip.name}
    fields['imu.stamp_s'] = _digest(trip.imu.stamp_s)
    fields['imu.angular_velocity'] = _digest(trip.imu.angular_velocity_rad_s)
    fields['imu.axes_known'] = repr(tuple(bool(a) for a in trip.imu.axes_known))
    fields['imu.linear_acceleration'] = _digest(trip.imu.linear_acceleration_m_s2)
    fields['speed.stamp_s'] = _digest(trip.speed.stamp_s)
    fields['speed.speed_m_s'] = _digest(trip.speed.speed_m_s)
    for i, scan in enumerate(trip.scans):
        for name in ('stamp_s', 'ranges_m', 'intensities'):
            fields[f'scans[{i}].{name}'] = _digest(getattr(scan, name))
        fields[f'scans[{i}].geometry'] = repr((scan.angle_min_rad, scan.angle_increment_rad,
                                               scan.range_min_m, scan.range_max_m))
        fields[f'scans[{i}].mount'] = repr(scan.mount)
        fields[f'scans[{i}].names'] = repr((scan.topic, scan.frame_id))
    fields['landmarks'] = _digest(None if trip.landmarks is None else trip.landmarks.xy_m)
    fields['initial_pose'] = _digest(np.asarray(trip.initial_pose, dtype=np.float64))
    truth = trip.ground_truth
    fields['ground_truth'] = 'None' if truth is None else (
        _digest(truth.stamp_s) + _digest(truth.pose))
    fields['true_gyro_bias'] = _digest(trip.true_gyro_bias_rad_s)
    fields['noise'] = repr(trip.noise)
    fields['static_duration_s'] = repr(trip.static_duration_s)
    return fields


def _bad(values: Any, limit: float) -> int:
    array = np.asarray(values, dtype=np.float64)
    if array.size == 0:
        return 0
    return int(validation.bad_values(array.reshape(array.shape[0], -1) if array.ndim else
                                     array.reshape(1), limit).sum())


def _stamps(name: str, stamps: Any) -> list[str]:
    s = np.asarray(stamps, dtype=np.float64)
    if s.size == 0:
        return []
    if not np.isfinite(s).all():
        return [f'{name}: non-finite stamp']
    steps = np.diff(s)
    out = []
    if (steps < 0).any():
        out.append(f'{name}: stamps go back ({float(steps.min()):.3g} s)')
    if steps.size and steps.max() > LIMITS.max_stamp_jump_s:
        out.append(f'{name}: stamps jump {float(steps.max()):.3g} s ahead')
    if abs(float(s[0])) > 1e7:
        out.append(f'{name}: first stamp {float(s[0]):.3g} s from time zero')
    return out


def trip_problems(trip: Any) -> list[str]:
    """Values of a Trip the filter should never see; empty when the trip is plausible."""
    out: list[str] = []
    out += _stamps('imu', trip.imu.stamp_s)
    out += _stamps('speed', trip.speed.stamp_s)
    if _bad(trip.imu.angular_velocity_rad_s, LIMITS.max_yaw_rate_rad_s):
        out.append('imu: angular velocity not finite or beyond '
                   f'{LIMITS.max_yaw_rate_rad_s:g} rad/s')
    if _bad(trip.speed.speed_m_s, LIMITS.max_speed_m_s):
        out.append(f'speed: not finite or beyond {LIMITS.max_speed_m_s:g} m/s')
    for scan in trip.scans:
        out += _stamps(f'{scan.topic}', scan.stamp_s)
        beams = int(np.shape(scan.ranges_m)[1]) if np.ndim(scan.ranges_m) == 2 else 0
        if beams:
            angle_max = scan.angle_min_rad + scan.angle_increment_rad * (beams - 1)
            problem = validation.scan_geometry_problem(
                scan.angle_min_rad, angle_max, scan.angle_increment_rad, beams,
                scan.range_min_m, scan.range_max_m)
            if problem:
                out.append(f'{scan.topic}: {problem}')
        # NaN is REP-117's "erroneous measurement" and +inf its "no return"; a negative
        # range is neither.
        with np.errstate(invalid='ignore'):
            if (np.asarray(scan.ranges_m) < 0).any():
                out.append(f'{scan.topic}: negative range')
        problem = validation.mount_problem(scan.mount.x_m, scan.mount.y_m, scan.mount.yaw_rad)
        if problem:
            out.append(f'{scan.topic}: {problem}')
    if trip.landmarks is not None and _bad(trip.landmarks.xy_m, LIMITS.max_coordinate_m):
        out.append('landmarks: not finite or beyond the coordinate limit')
    pose = np.asarray(trip.initial_pose, dtype=np.float64)
    if pose.shape != (3,) or not np.isfinite(pose).all() or (
            np.abs(pose[:2]) > LIMITS.max_coordinate_m).any():
        out.append(f'initial pose {pose.tolist()} not finite or beyond the limit')
    truth = trip.ground_truth
    if truth is not None:
        out += _stamps('ground_truth', truth.stamp_s)
        if _bad(truth.pose, LIMITS.max_coordinate_m):
            out.append('ground truth: not finite or beyond the coordinate limit')
    if trip.true_gyro_bias_rad_s is not None and _bad(
            np.asarray(trip.true_gyro_bias_rad_s).reshape(1, -1), LIMITS.max_yaw_rate_rad_s):
        out.append('true gyro bias not finite')
    for key, value in dataclasses.asdict(trip.noise).items():
        if value is not None and (not math.isfinite(value) or value < 0):
            out.append(f'noise.{key} = {value}')
    if not math.isfinite(trip.static_duration_s) or trip.static_duration_s < 0:
        out.append(f'static_duration_s = {trip.static_duration_s}')
    return out


def summarise_trip(trip: Any) -> dict[str, Any]:
    return {'fields': trip_fields(trip), 'problems': trip_problems(trip)}
