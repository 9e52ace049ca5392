"""One value per instant on each live input: a second message at a stamp already taken.

Offline, two samples of one stream at one stamp are judged by their values
(core.validation): an exact repeat is dropped and counted as a duplicate, other values are
refused (with --skip-bad the later one is dropped and counted, and the run is degraded); a
bag's reader does the same per topic. A live node cannot refuse its input, so
``SameStampCheck`` keeps, per stream (imu, odom, each LiDAR's detections as the node tells
them apart), the newest stamp taken and the values the node used from that message, and
judges a message at that very stamp:

- the same values (a message delivered or published twice, a relay doubling a topic):
  ``DUPLICATE``, dropped and counted apart; nothing was lost, so it is no bad input (no
  degraded verdict, as offline);
- other values: ``SAME_STAMP``, two values for one instant; the first is kept, the later one
  dropped (as --skip-bad does offline) and counted as bad input.

Before, the filter took both: a second event after a prediction of length 0, the later
value held until the next stamp (a yaw rate of 0.2 then 5.0 rad/s at one 100 Hz stamp
turned the heading 2.75 deg further), and at rest both gyro samples were zero-rate updates.

A message older than the newest taken is not judged here (it is late: the merger's
business) and does not replace it, so a late message between two copies hides nothing.
The node offers only what its stamp gate passed on (core.stamp_gate), so an outlier far
ahead, held and dropped there, cannot become the newest stamp. Stamps are integer
nanoseconds, compared exactly; values compare as the node read them, NaN equal to NaN.
"""

from __future__ import annotations

import math
from collections.abc import Hashable
from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = ['DUPLICATE', 'SAME_STAMP', 'Repeat', 'SameStampCheck', 'describe_repeat',
           'same_values']

DUPLICATE = 'duplicate'
"""Drop reason of an exact repeat: the stamp and the values of the message taken."""

SAME_STAMP = 'same_stamp'
"""Drop reason of a message at the stamp of the one taken with other values."""


@dataclass(frozen=True, slots=True)
class Repeat:
    """A message at the stamp of the newest one taken on its stream.

    Attributes:
        reason: DUPLICATE (the same values) or SAME_STAMP (other values).
        field: index in the values of the first one that differs; None for DUPLICATE.
    """

    reason: str
    field: int | None = None


_DUPLICATE = Repeat(DUPLICATE)


def same_values(a: Any, b: Any) -> bool:
    """Tell whether two values a node read are the same, NaN equal to NaN.

    Numbers, None, tuples or lists of them and numpy arrays (equal shape and elements).
    """
    if a is b:
        return True
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        a, b = np.asarray(a), np.asarray(b)
        if a.shape != b.shape:
            return False
        try:
            return bool(np.array_equal(a, b, equal_nan=True))
        except TypeError:  # not numbers: no NaN to think of
            return bool(np.array_equal(a, b))
    if isinstance(a, (tuple, list)) and isinstance(b, (tuple, list)):
        return len(a) == len(b) and all(same_values(x, y) for x, y in zip(a, b))
    if isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b):
        return True
    return bool(a == b)


def describe_repeat(repeat: Repeat, topic: str, stamp_ns: int, stamp_s: float,
                    fields: tuple[str, ...]) -> str:
    """Say what was dropped: the topic, the stamp (ns since the epoch and s) and the field.

    fields: the names of the values judged, in their order.
    """
    sec, nanosec = divmod(stamp_ns, 1_000_000_000)
    at = f'stamp {sec}.{nanosec:09d} ({stamp_s:.6f} s)'
    if repeat.reason == DUPLICATE:
        return f'{topic}: an exact repeat of the message taken at {at} dropped'
    return (f'{topic}: a second message at {at} with another {fields[repeat.field]} than the '
            'one taken: two values for one instant, the later dropped')


class SameStampCheck:
    """Per stream, the newest stamp taken and its values; judges a message at that stamp."""

    def __init__(self) -> None:
        """Start with nothing taken."""
        self._newest: dict[Hashable, tuple[int, tuple]] = {}

    def judge(self, stream: Hashable, stamp_ns: int, values: tuple) -> Repeat | None:
        """Judge a message of `stream` stamped `stamp_ns`, the node's values from it.

        Returns None when the message is to be taken (a newer stamp, remembered with its
        values; or an older one, not judged here), else the Repeat saying why it is to be
        dropped: its stamp is that of the newest message taken on the stream.
        """
        newest = self._newest.get(stream)
        if newest is None or stamp_ns > newest[0]:
            self._newest[stream] = (stamp_ns, values)
            return None
        if stamp_ns < newest[0]:
            return None
        taken = newest[1]
        if len(taken) != len(values):
            return Repeat(SAME_STAMP, 0)
        for i, (a, b) in enumerate(zip(taken, values)):
            if not same_values(a, b):
                return Repeat(SAME_STAMP, i)
        return _DUPLICATE

    def clear(self) -> None:
        """Forget every stream (after a filter reset or a new calibration window)."""
        self._newest.clear()
