"""Base error of gyro_ekf: the CLI catches it once and prints one line."""


class GyroEkfError(Exception):
    """Any error gyro_ekf raises on purpose (bad input, refused calibration, ...)."""


def one_line(text: object) -> str:
    """Text of a message on one line (YAML errors point at the spot over several lines)."""
    return ' '.join(str(text).split())
