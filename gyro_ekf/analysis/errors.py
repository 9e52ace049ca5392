"""Errors of the analysis layer (offline runs, outputs, parameter files)."""

from gyro_ekf.errors import GyroEkfError


class AnalysisError(GyroEkfError):
    """An offline run or its analysis cannot go on."""


class OutputError(AnalysisError):
    """An output cannot be written (exists already, or the file system refused)."""


class ParamsFileError(AnalysisError):
    """A ROS 2 params YAML is unreadable or holds a bad value."""
