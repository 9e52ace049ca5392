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
rate changes later is judged against its start, so one that halves its rate from then on
reads as half lost: said, as it should be looked at). ``_period``: intervals under a
quarter of their mean are left out (stamps taken in pairs, a glitch); from the 10th
percentile of the rest, the mean of those within half to ``LOST_FACTOR`` times the period
so far, four times over. Not their median: a stream that loses more than half its samples
from the start (the replay above) has a median interval of two periods or more; not their
smallest, which one stamp glitch would set; and not the 10th percentile alone, which jitter
shortens. An interval counts as lost samples only beyond ``LOST_FACTOR`` periods, so an
interval jitter of up to half a period (stamps +-0.25 of one) costs nothing; each interval
counts as ``round(interval / period)`` samples. The share received is the samples that
arrived over those the stamps imply; the verdict degrades a run below
``health.VERDICT_MIN_RECEIVED_SHARE``. ``longest_s`` and ``last_s`` give the verdict its
input silences, between samples and since the last one.

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
    """Return the stream's period from its reference intervals (module docstring)."""
    floor = 0.25 * sum(intervals) / len(intervals)
    ordered = sorted(i for i in intervals if i >= floor)
    period = ordered[len(ordered) // 10]
    for _ in range(4):
        near = [i for i in ordered if 0.5 * period <= i <= LOST_FACTOR * period]
        period = sum(near) / len(near)
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
    def last_s(self) -> float | None:
        """Stamp of the last sample that arrived, s (None before one)."""
        return self._last_s

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
        """JSON-ready figures (summary.json ``input_loss``, /diagnostics, the verdict)."""
        return {'received': self.received, 'lost': self.lost, 'share': self.share,
                'period_s': self.period_s, 'longest_interval_s': self.longest_s,
                'last_s': self._last_s}


def silences(reports: dict[str, dict[str, Any]], now_s: float | None) -> dict[str, float]:
    """Return each stream's longest silence, s: between two samples, or since its last.

    ``reports``: InputLoss.report() per stream; ``now_s``: the newest stamp of any input (a
    stream that stopped while the others went on is silent since its last sample). A
    stream with no sample yet is not judged.
    """
    out = {}
    for name, report in reports.items():
        last = report['last_s']
        if last is None:
            continue
        since = 0.0 if now_s is None else max(now_s - last, 0.0)
        out[name] = max(report['longest_interval_s'], since)
    return out
