"""Errors raised by the estimation core."""

from __future__ import annotations

from gyro_ekf.errors import GyroEkfError


class CoreError(GyroEkfError):
    """Invalid input to a core computation."""


class CalibrationError(CoreError):
    """A static window was refused: too few samples, a gap, or motion.

    Attributes:
        stream: the input the refusal is about, 'imu' (the gyro), 'speed' or
            'lidar:<scan topic>' (a LiDAR that saw a turn): the core knows no file or topic,
            so the caller names the one that stream came from.
    """

    def __init__(self, message: str, stream: str = 'imu'):
        super().__init__(message)
        self.stream = stream


class TimeWentBackwardsError(CoreError):
    """An event is older than the last one the filter processed."""


class InvalidInputError(CoreError):
    """A value entering the core failed its check; names where it came from.

    Attributes:
        source: the file, bag or topic the value came from.
        field: what the value is ('imu.angular_velocity.z', 'lidar.scan2.yaw_rad').
        index: the sample index within that field, or None for a single value.
        reason: what is wrong with it.
    """

    def __init__(self, source: str, field: str, index: int | None, reason: str):
        self.source = source
        self.field = field
        self.index = index
        self.reason = reason
        where = field if index is None else f'{field}[{index}]'
        super().__init__(f'{source}: {where}: {reason}')
