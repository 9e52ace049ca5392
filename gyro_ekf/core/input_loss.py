"""Samples an input stream lost, counted from its own stamps.

A gyro or an odometry sampled at a fixed rate states, by its stamps, how many samples it
sent: an interval of k periods between two samples that arrived means k - 1 that did not.
The filter holds the last value across them (core/events.py), so a stream that arrives in
part still gives estimates, only worse ones; and nothing else would say it. A node too slow
for its inputs, or a best-effort link that overflows, loses samples that way (the EKF node
replayed at x10 on its former rclpy path took 38.6 % of the 2016 log's IMU messages, its
final bias 0.003 deg/s off, with nothing said); a bag recorded from such a link carries the
loss with it.

The period is taken from the first ``REFERENCE_INTERVALS`` intervals (a stream whose
rate changes later is judged against its start): from their 10th percentile, twice the
median of those within ``LOST_FACTOR`` times the period so far (``_period``). Not their
median: a stream that loses more than half its samples from the start (the replay above)
has a median interval of two periods or more; and not their smallest, which one stamp
glitch would set. An interval counts as lost samples only beyond ``LOST_FACTOR`` periods,
so stamp jitter of up to half a period costs nothing; each interval counts as
``round(interval / period)`` samples. The share received is the samples that arrived over
those the stamps imply; the verdict degrades a run below
``health.VERDICT_MIN_RECEIVED_SHARE``.

The state is a few scalars and, until the period is known, a short tuple, so ``save`` and
``restore`` (on every event, by ``core/lagged.py``) cost O(1).
"""

from __future__ import annotations

from typing import Any

REFERENCE_INTERVALS = 64
"""Intervals the stream's period is taken from."""

LOST_FACTOR = 1.5
"""An interval longer than this many periods holds lost samples."""


def _period(intervals: tuple[float, ...]) -> float:
    """Return the median of the intervals within LOST_FACTOR periods, from the 10th percentile.

    The 10th percentile is a period shortened by jitter; the median of the intervals within
    LOST_FACTOR of it, a period still leaning short; within LOST_FACTOR of that, the period.
    """
    ordered = sorted(intervals)
    period = ordered[len(ordered) // 10]
    for _ in range(2):
        near = [i for i in ordered if i <= LOST_FACTOR * period]
        period = near[len(near) // 2]
    return period


class InputLoss:
    """One stream's samples received and those its stamps imply (module docstring)."""

    __slots__ = ('received', 'lost', 'period_s', '_limit', '_last_s', '_intervals',
                 '_longest_s')

    def __init__(self) -> None:
        self.received = 0
        self.lost = 0
        self.period_s: float | None = None
        self._limit: float | None = None  # LOST_FACTOR periods, s
        self._last_s: float | None = None
        self._intervals: tuple[float, ...] = ()
        self._longest_s = 0.0

    def add(self, stamp_s: float) -> None:
        """Count a sample that arrived at stamp_s (stamps in the filter's order)."""
        # Once the period is known, one comparison per sample: this runs at every IMU and
        # odometry sample.
        self.received += 1
        last, self._last_s = self._last_s, stamp_s
        limit = self._limit
        if limit is not None:
            if last is not None and stamp_s - last > limit:
                interval = stamp_s - last
                self.lost += round(interval / self.period_s) - 1
                if interval > self._longest_s:
                    self._longest_s = interval
            return
        if last is None or stamp_s <= last:
            return
        intervals = self._intervals + (stamp_s - last,)
        if len(intervals) < REFERENCE_INTERVALS:
            self._intervals = intervals
            return
        self.period_s = period = _period(intervals)
        self._limit = LOST_FACTOR * period
        self._intervals = ()
        self._longest_s = max(intervals)
        # The reference intervals are judged too, against the period they gave.
        self.lost += sum(round(i / period) - 1 for i in intervals if i > self._limit)

    @property
    def longest_s(self) -> float:
        """Longest time between two samples that arrived, s (0 with fewer than two).

        Exact where it matters: once the period is known, only intervals beyond
        LOST_FACTOR periods can be the longest one that is more than that.
        """
        return max(self._longest_s, max(self._intervals, default=0.0))

    @property
    def share(self) -> float:
        """Samples received over those the stamps imply (1 before any was lost)."""
        total = self.received + self.lost
        return 1.0 if total == 0 else self.received / total

    def save(self) -> tuple:
        return (self.received, self.lost, self.period_s, self._limit, self._last_s,
                self._intervals, self._longest_s)

    def restore(self, saved: tuple) -> None:
        (self.received, self.lost, self.period_s, self._limit, self._last_s,
         self._intervals, self._longest_s) = saved

    def report(self) -> dict[str, Any]:
        """JSON-ready figures (summary.json ``input``, /diagnostics, the verdict)."""
        return {'received': self.received, 'lost': self.lost, 'share': self.share,
                'period_s': self.period_s, 'longest_interval_s': self.longest_s}
