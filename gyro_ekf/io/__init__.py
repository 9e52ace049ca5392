"""File formats: course logs and trip files in, ROS 2 bags and their params sidecar out.

Imports core, scipy.io and rosbags, never rclpy. The names below are loaded on first use, so
`import gyro_ekf.io.defaults` (the CLI's help text) stays cheap.
"""

from __future__ import annotations

import importlib
from typing import Any

_EXPORTS = {
    'BagError': 'errors', 'LogFormatError': 'errors',
    'DEFAULT_EPOCH_NS': 'defaults',
    'load_course_log': 'matlab', 'load_log': 'sources',
    'load_trip': 'trip_file', 'save_trip': 'trip_file',
    'write_trip_bag': 'bag_writer',
    'BagTrip': 'bag_reader', 'iter_bag_messages': 'bag_reader', 'read_bag': 'bag_reader',
    'read_trip_bag': 'bag_reader', 'bag_summary': 'bag_info',
    'BagParams': 'sidecar', 'read_sidecar': 'sidecar', 'sidecar_path': 'sidecar',
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    if name not in _EXPORTS:
        raise AttributeError(f'module {__name__!r} has no attribute {name!r}')
    return getattr(importlib.import_module(f'{__name__}.{_EXPORTS[name]}'), name)
