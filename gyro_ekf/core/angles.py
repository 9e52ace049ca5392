"""The one place angles are wrapped and converted."""

from __future__ import annotations

import math

import numpy as np


def wrap_angle(angle_rad):
    """Wrap an angle (scalar or array), rad, into [-pi, pi)."""
    return (np.asarray(angle_rad) + math.pi) % (2.0 * math.pi) - math.pi


def wrap_scalar(angle_rad: float) -> float:
    """Wrap one angle, rad, into [-pi, pi) without numpy overhead."""
    return (angle_rad + math.pi) % (2.0 * math.pi) - math.pi


def deg_to_rad(value_deg):
    """Degrees to radians; only the human-facing edges use degrees."""
    return np.deg2rad(value_deg)


def rad_to_deg(value_rad):
    """Radians to degrees, for printing and plots."""
    return np.rad2deg(value_rad)
