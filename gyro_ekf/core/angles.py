"""The one place angles are wrapped; degrees appear only at human-facing edges."""

from __future__ import annotations

import math

import numpy as np


def wrap_angle(angle_rad):
    """Wrap an angle (scalar or array), rad, into [-pi, pi)."""
    return (np.asarray(angle_rad) + math.pi) % (2.0 * math.pi) - math.pi


def wrap_scalar(angle_rad: float) -> float:
    """Wrap one angle, rad, into [-pi, pi) without numpy overhead."""
    return (angle_rad + math.pi) % (2.0 * math.pi) - math.pi
