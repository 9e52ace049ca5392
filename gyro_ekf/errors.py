"""Base error of gyro_ekf: the CLI catches it once and prints one line."""


class GyroEkfError(Exception):
    """Any error gyro_ekf raises on purpose (bad input, refused calibration, ...)."""
