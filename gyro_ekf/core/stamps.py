"""The one home of stamp arithmetic: integer ns since the epoch <-> (sec, nanosec), seconds.

Stamps stay integer nanoseconds wherever they are stored or compared; float seconds appear
only as time since a trip's time zero, the unit the filter works in.
"""

from __future__ import annotations

from typing import Any

import numpy as np

NS_PER_S = 1_000_000_000


def split_ns(stamp_ns: int) -> tuple[int, int]:
    """(sec, nanosec) of integer ns since the epoch (>= 0), as builtin_interfaces/Time holds."""
    sec, nanosec = divmod(int(stamp_ns), NS_PER_S)
    return sec, nanosec


def split_ns_array(stamps_ns: Any) -> tuple[np.ndarray, np.ndarray]:
    """(sec, nanosec) arrays of an array of integer ns stamps."""
    return np.divmod(np.asarray(stamps_ns, dtype=np.int64), NS_PER_S)


def join_ns(sec: int, nanosec: int) -> int:
    """Integer ns since the epoch of a (sec, nanosec) pair."""
    return int(sec) * NS_PER_S + int(nanosec)


def seconds_since(stamp_ns: Any, zero_ns: int) -> Any:
    """Seconds from zero_ns to stamp_ns (an int or an int64 array), negative before it."""
    if isinstance(stamp_ns, np.ndarray):
        return (stamp_ns - np.int64(zero_ns)) / float(NS_PER_S)
    return (stamp_ns - zero_ns) / float(NS_PER_S)


def ns_at(zero_ns: int, seconds: Any) -> np.ndarray:
    """Integer ns stamps, int64, of seconds since zero_ns, rounded to the nearest ns."""
    return np.int64(zero_ns) + np.rint(np.asarray(seconds) * NS_PER_S).astype(np.int64)
