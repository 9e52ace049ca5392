"""Errors of the io layer: course logs that cannot be read and bags that cannot be used.

Every message names the file (and, for logs, the field) and says what was expected.
"""

from __future__ import annotations

from gyro_ekf.errors import GyroEkfError


class LogFormatError(GyroEkfError):
    """A course log or trip file is unreadable, of an unknown format or inconsistent."""


class BagError(GyroEkfError):
    """A bag cannot be written, or is missing, unreadable or lacks a needed topic."""
