"""Errors raised by the estimation core."""

from gyro_ekf.errors import GyroEkfError


class CoreError(GyroEkfError):
    """Invalid input to a core computation."""


class CalibrationError(CoreError):
    """A static window was refused: too few samples, a gap, or motion."""


class TimeWentBackwardsError(CoreError):
    """An event is older than the last one the filter processed."""
