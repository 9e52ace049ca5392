"""The one validation boundary: checks of every value that enters the core.

Each check returns None for a good value or a short reason ("not finite", "|w| = 1e300 rad/s
exceeds 35 rad/s") for a bad one, so that the two edges can act on it their own way: offline
readers raise `InvalidInputError` naming file, field and index (or drop and count the sample
with --skip-bad); live nodes drop the message and count the reason in /diagnostics. The
limits are `core.config.InputLimits` (parameters with defaults, SI units).

Array versions return a boolean mask of the bad rows, so a million samples are checked in
one numpy pass.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from gyro_ekf.core.config import InputLimits

BoolArray = NDArray[np.bool_]

LIMITS = InputLimits()
"""The default limits."""

_SYMMETRY_TOLERANCE = 1e-9
"""Relative asymmetry of a covariance matrix still taken as rounding."""


def value_problem(value: float, limit: float, unit: str) -> str | None:
    """Why a scalar is not a finite value within +-limit, or None."""
    if not math.isfinite(value):
        return f'{value} is not finite'
    if abs(value) > limit:
        return f'|{value:.6g}| {unit} exceeds the limit {limit:g} {unit}'
    return None


def rate_problem(rate_rad_s: float, limits: InputLimits = LIMITS) -> str | None:
    """Why an angular velocity (one axis, rad/s) is refused, or None."""
    return value_problem(rate_rad_s, limits.max_yaw_rate_rad_s, 'rad/s')


def speed_problem(speed_m_s: float, limits: InputLimits = LIMITS) -> str | None:
    """Why an odometry speed (m/s) is refused, or None."""
    return value_problem(speed_m_s, limits.max_speed_m_s, 'm/s')


def coordinate_problem(values: Sequence[float], limits: InputLimits = LIMITS) -> str | None:
    """Why map-frame coordinates (m) are refused, or None."""
    for value in values:
        problem = value_problem(float(value), limits.max_coordinate_m, 'm')
        if problem:
            return problem
    return None


def bad_values(values: NDArray, limit: float) -> BoolArray:
    """Mask of the rows of `values` (shape (n,) or (n, k)) that are bad.

    A row is bad when it holds a non-finite value or one beyond +-limit.
    """
    array = np.asarray(values, dtype=np.float64)
    with np.errstate(invalid='ignore'):
        bad = ~np.isfinite(array) | (np.abs(array) > limit)
    return bad if bad.ndim == 1 else bad.any(axis=tuple(range(1, bad.ndim)))


def quaternion_problem(x: float, y: float, z: float, w: float,
                       limits: InputLimits = LIMITS) -> str | None:
    """Why a quaternion is refused (not finite, or not of unit norm), or None."""
    if not all(math.isfinite(v) for v in (x, y, z, w)):
        return 'quaternion is not finite'
    norm = math.sqrt(x * x + y * y + z * z + w * w)
    if abs(norm - 1.0) > limits.quaternion_norm_tolerance:
        return f'quaternion norm {norm:.6g} is not 1 (within {limits.quaternion_norm_tolerance:g})'
    return None


def covariance_problem(matrix: NDArray) -> str | None:
    """Why a covariance matrix is refused (not finite, asymmetric, negative), or None."""
    m = np.asarray(matrix, dtype=np.float64)
    if m.ndim != 2 or m.shape[0] != m.shape[1]:
        return f'covariance of shape {m.shape} is not square'
    if not np.isfinite(m).all():
        return 'covariance is not finite'
    scale = max(float(np.abs(m).max()), 1e-300)
    if float(np.abs(m - m.T).max()) > _SYMMETRY_TOLERANCE * scale:
        return 'covariance is not symmetric'
    if float(np.linalg.eigvalsh(m).min()) < -_SYMMETRY_TOLERANCE * scale:
        return 'covariance has a negative variance (not positive semi-definite)'
    return None


def scan_geometry_problem(angle_min_rad: float, angle_max_rad: float,
                          angle_increment_rad: float, beam_count: int, range_min_m: float,
                          range_max_m: float) -> str | None:
    """Why a LaserScan's beam geometry is refused, or None.

    The bearings are angle_min + k * angle_increment; they must be finite, advance by a
    non-zero step, span at most one turn, and agree with the number of ranges (REP-117's
    angle_max is the last beam's bearing, so count = (max - min) / increment + 1, within one
    beam for rounding).
    """
    values = (angle_min_rad, angle_max_rad, angle_increment_rad, range_min_m, range_max_m)
    if not all(math.isfinite(v) for v in values):
        return 'beam geometry (angles, range limits) is not finite'
    if angle_increment_rad == 0.0:
        return 'angle_increment is 0'
    if beam_count < 1:
        return 'the scan has no ranges'
    span = angle_increment_rad * (beam_count - 1)
    if abs(span) > 2.0 * math.pi + abs(angle_increment_rad):
        return f'{beam_count} beams of {angle_increment_rad:.6g} rad span more than one turn'
    expected = (angle_max_rad - angle_min_rad) / angle_increment_rad + 1.0
    if abs(expected - beam_count) > 1.0 + 1e-6:
        return (f'{beam_count} ranges, but angle_min/max/increment give {expected:.1f} beams')
    if range_min_m < 0.0 or range_max_m <= range_min_m:
        return f'range limits [{range_min_m}, {range_max_m}] m are not a valid interval'
    return None


def mount_problem(x_m: float, y_m: float, yaw_rad: float,
                  limits: InputLimits = LIMITS) -> str | None:
    """Why a LiDAR mount (m, m, rad) is refused, or None."""
    if not all(math.isfinite(v) for v in (x_m, y_m, yaw_rad)):
        return 'mount is not finite'
    if math.hypot(x_m, y_m) > limits.max_mount_offset_m:
        return (f'mount offset {math.hypot(x_m, y_m):.6g} m exceeds the limit '
                f'{limits.max_mount_offset_m:g} m')
    return None
