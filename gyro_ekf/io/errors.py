"""Errors of the io layer: logs and bags that cannot be read, outputs and params files.

Every message names the file (and, for logs, the field) and says what was expected.
"""

from __future__ import annotations

from gyro_ekf.errors import GyroEkfError


class LogFormatError(GyroEkfError):
    """A course log or trip file is unreadable, of an unknown format or inconsistent."""


class BagError(GyroEkfError):
    """A bag cannot be written, or is missing, unreadable or lacks a needed topic."""


class OutputError(GyroEkfError):
    """An output cannot be written (exists already, or the file system refused)."""


class ParamsFileError(GyroEkfError):
    """A ROS 2 params YAML is unreadable or holds a bad value."""


class LandmarksFileError(GyroEkfError):
    """A landmark map file is missing, unreadable, binary or not a list of (x, y) in m."""
