"""Errors of the analysis layer (offline runs, outputs, parameter files)."""

from gyro_ekf.errors import GyroEkfError
# Their home is io (the result writers and the params parser live there); named here too, as
# the error vocabulary of the offline run.
from gyro_ekf.io.errors import OutputError, ParamsFileError

__all__ = ['AnalysisError', 'OutputError', 'ParamsFileError']


class AnalysisError(GyroEkfError):
    """An offline run or its analysis cannot go on."""
