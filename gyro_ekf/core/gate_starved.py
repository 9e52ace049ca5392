"""Notice a filter whose own gate keeps out the evidence that it is wrong.

The chi-square gate takes a detection only where the filter expects a pole, within its
covariance. A heading that runs off faster than the covariance grows (a gyro bias that
steps by 0.5 deg/s just as the platform sets off, with the bias known to 0.01 deg/s from
the static start) soon leaves most detections outside the gate. They lie beside the poles
they came from, unmatched; the few still taken (the nearest pole, whose bearing error
moves it least) keep the filter from counting a gap, so the distance-based recovery after
``recovery_after_s`` without an update never starts. In the stress suite's seed 37
bias_step #4 that went on for 6 s: the heading 1.3 deg off at a sigma of 0.2, NEES 20-300,
until the last match was lost.

Here the driver counts, per scan and LiDAR, the detections it matched and those it left
unmatched within ``recovery_max_distance_m`` of a mapped pole. When over the last
``recovery_after_s`` the unmatched ones near poles outnumber the matched ones for every
LiDAR seen (and are at least ``MIN_MISSED`` in all), the filter is starved by its own
gate, and the next scan is associated by map distance as after a gap
(core/association.py, ``associate_by_distance``); the count then starts again. A
reflector beside a pole or a pole moved in the world leaves one such detection per scan
beside the others' matches, which is not enough; a LiDAR off its mount while another
matches is the health monitor's (core/health.py), not this.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Hashable

MIN_MISSED = 8
"""Fewest unmatched detections near poles in the window to call the filter starved: a
handful of scans' worth, so that a stray look or two is not enough."""


class GateStarvation:
    """Matched and near-missed detections per LiDAR over a sliding window of scans."""

    __slots__ = ('window_s', '_scans', '_sums', '_missed')

    def __init__(self, window_s: float) -> None:
        self.window_s = window_s
        self._scans: deque[tuple[float, Hashable, int, int]] = deque()
        # Per LiDAR: [matched, missed] over the window; and the misses of all of them.
        self._sums: dict[Hashable, list[int]] = {}
        self._missed = 0

    def copy(self) -> 'GateStarvation':
        """Return an independent copy, for the driver's save and restore."""
        clone = GateStarvation(self.window_s)
        clone._scans = deque(self._scans)
        clone._sums = {key: list(sums) for key, sums in self._sums.items()}
        clone._missed = self._missed
        return clone

    def add(self, stamp_s: float, key: Hashable, matched: int, missed: int) -> None:
        """Count one scan of a LiDAR: detections matched, and unmatched near a pole."""
        if matched or missed:
            self._scans.append((stamp_s, key, matched, missed))
            sums = self._sums.setdefault(key, [0, 0])
            sums[0] += matched
            sums[1] += missed
            self._missed += missed
        self._drop(stamp_s)

    def starved(self, stamp_s: float) -> bool:
        """Whether near misses outnumber matches for every LiDAR seen in the window.

        Pooled, a LiDAR off its mount (near misses) would outvote one that matches, and the
        distance association would let it drag the pose: that one is the health monitor's.
        """
        self._drop(stamp_s)
        return self._missed >= MIN_MISSED and all(
            missed > matched for matched, missed in self._sums.values())

    def clear(self) -> None:
        """Start counting again (after a scan associated by distance)."""
        self._scans.clear()
        self._sums.clear()
        self._missed = 0

    def _drop(self, stamp_s: float) -> None:
        scans = self._scans
        while scans and stamp_s - scans[0][0] > self.window_s:
            _, key, matched, missed = scans.popleft()
            sums = self._sums[key]
            sums[0] -= matched
            sums[1] -= missed
            self._missed -= missed
            if not any(sums):
                del self._sums[key]
