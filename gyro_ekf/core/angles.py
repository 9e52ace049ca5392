"""The one home of angle maths: wrapping, and quaternion <-> yaw (scalars and arrays).

Degrees appear only at human-facing edges.
"""

from __future__ import annotations

import math

import numpy as np


def wrap_angle(angle_rad):
    """Wrap an angle (scalar or array), rad, into [-pi, pi)."""
    return (np.asarray(angle_rad) + math.pi) % (2.0 * math.pi) - math.pi


_PI, _TWO_PI = math.pi, 2.0 * math.pi
"""pi and 2 pi as module globals: the filter wraps an angle at every step (143 000 times over
the 2016 log), and math.pi is an attribute look-up each time (the same numbers)."""


def wrap_scalar(angle_rad: float) -> float:
    """Wrap one angle, rad, into [-pi, pi) without numpy overhead."""
    return (angle_rad + _PI) % _TWO_PI - _PI


def quaternion_of_yaw(yaw_rad: float) -> tuple[float, float, float, float]:
    """(x, y, z, w) of a rotation about z by yaw_rad."""
    half = yaw_rad / 2.0
    return (0.0, 0.0, math.sin(half), math.cos(half))


def yaw_of_quaternion(x: float, y: float, z: float, w: float) -> float:
    """Yaw, rad, of a quaternion (the z rotation of its ZYX Euler angles).

    Written so that both arguments of atan2 scale with the norm squared: a quaternion
    within the accepted norm tolerance (0.01) but not unit gives the yaw of its unit one,
    where 1 - 2 (y^2 + z^2) moved it by up to 6 mrad.
    """
    return math.atan2(2.0 * (w * z + x * y), (w * w + x * x) - (y * y + z * z))


def quaternions_of_yaws(yaw_rad: np.ndarray) -> np.ndarray:
    """Return z and w of quaternion_of_yaw for each yaw, shape (n, 2), bit for bit.

    math's sin and cos element by element, not numpy's: numpy's SIMD sin may differ in the
    last bit, and rows written in batches must equal those written one by one.
    """
    half = (np.asarray(yaw_rad, dtype=np.float64).reshape(-1) / 2.0).tolist()
    return np.column_stack([
        np.fromiter(map(math.sin, half), dtype=np.float64, count=len(half)),
        np.fromiter(map(math.cos, half), dtype=np.float64, count=len(half))]).reshape(-1, 2)


def yaws_of_quaternions(x: np.ndarray, y: np.ndarray, z: np.ndarray,
                        w: np.ndarray) -> np.ndarray:
    """Return yaw_of_quaternion of each quaternion, shape (n,), bit for bit.

    numpy's + and * round as Python's do; math.atan2 element by element keeps the result
    identical to the one-by-one path.
    """
    numerator = (2.0 * (w * z + x * y)).tolist()
    denominator = ((w * w + x * x) - (y * y + z * z)).tolist()
    return np.fromiter(map(math.atan2, numerator, denominator), dtype=np.float64,
                       count=len(numerator))
