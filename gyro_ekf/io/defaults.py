"""Light constants of the bag layer, importable without rosbags (the CLI help uses them)."""

from __future__ import annotations

from gyro_ekf.core.stamps import NS_PER_S

DEFAULT_EPOCH_NS = 1_700_000_000 * NS_PER_S
"""Default bag stamp of a log's time zero: 2023-11-14T22:13:20Z (1.7e9 s since 1970).

Fixed so conversions are reproducible, and far from 0, which ROS reads as "time unset".
"""

STORAGE_NAMES = ('mcap', 'sqlite3')
"""rosbag2 storage plugins the writer supports; mcap first, the Jazzy default."""
