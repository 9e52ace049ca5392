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

Here the driver counts, per scan, the detections it matched and those it left unmatched
within ``recovery_max_distance_m`` of a mapped pole. When over the last
``recovery_after_s`` the unmatched ones near poles outnumber the matched ones (and are at
least ``MIN_MISSED``), the filter is starved by its own gate, and the next scan is
associated by map distance as after a gap (core/association.py,
``associate_by_distance``); the count then starts again. A reflector beside a pole or a
pole moved in the world leaves one such detection per scan beside the others' matches,
which is not enough.
"""

from __future__ import annotations

from collections import deque

MIN_MISSED = 8
"""Fewest unmatched detections near poles in the window to call the filter starved: a
handful of scans' worth, so that a stray look or two is not enough."""


class GateStarvation:
    """Matched and near-missed detections over a sliding window of scans."""

    __slots__ = ('window_s', '_scans', '_matched', '_missed')

    def __init__(self, window_s: float) -> None:
        self.window_s = window_s
        self._scans: deque[tuple[float, int, int]] = deque()
        self._matched = 0
        self._missed = 0

    def copy(self) -> 'GateStarvation':
        """Return an independent copy, for the driver's save and restore."""
        clone = GateStarvation(self.window_s)
        clone._scans = deque(self._scans)
        clone._matched, clone._missed = self._matched, self._missed
        return clone

    def add(self, stamp_s: float, matched: int, missed: int) -> None:
        """Count one scan: detections matched, and unmatched within reach of a pole."""
        if matched or missed:
            self._scans.append((stamp_s, matched, missed))
            self._matched += matched
            self._missed += missed
        self._drop(stamp_s)

    def starved(self, stamp_s: float) -> bool:
        """Whether the window's near misses outnumber its matches (and reach MIN_MISSED)."""
        self._drop(stamp_s)
        return self._missed >= MIN_MISSED and self._missed > self._matched

    def clear(self) -> None:
        """Start counting again (after a scan associated by distance)."""
        self._scans.clear()
        self._matched = self._missed = 0

    def _drop(self, stamp_s: float) -> None:
        scans = self._scans
        while scans and stamp_s - scans[0][0] > self.window_s:
            _, matched, missed = scans.popleft()
            self._matched -= matched
            self._missed -= missed
