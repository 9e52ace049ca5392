"""Samples an input stream lost, counted from its own stamps, and stamps that scatter.

A gyro or an odometry sampled at a fixed rate states, by its stamps, how many samples it
sent: the samples sit on a grid of its period, and a slot of the grid with no sample is a
sample that did not arrive. The filter holds the last value across it (core/events.py),
so a stream that arrives in part still gives estimates, only worse ones; and nothing else
would say it. A node too slow for its inputs, or a best-effort link that overflows, loses
samples that way (the EKF node replayed at x10 on its former rclpy path took 38.6 % of the
2016 log's IMU messages, its final bias 0.003 deg/s off, with nothing said); a bag recorded
from such a link carries the loss with it.

**Slots, not intervals.** A driver that stamps samples on arrival at the host scatters
them about the grid by its latency's spread (a USB IMU: a few ms at 200 Hz). Counted
interval by interval, one late stamp makes a long interval and the next a short one: with
stamps scattered by 0.4 of a period, 37-61 % of the samples of a stream that lost none
read as arrived. So each sample is put in the slot of the grid nearest its stamp, the grid
following the stamps' mean (``_PHASE_GAIN`` of each offset), and the samples lost are the
slots the stamps spanned less the samples received (never below zero: two samples in one
slot are two stamps taken together, not a lost one given back). A stamp pushed over the
edge of its slot is counted as lost and given back by the next, so the count stays right
whatever the scatter, as long as the grid is right.

**The grid** is fitted to the first ``REFERENCE_INTERVALS`` intervals (a stream whose rate
changes later is judged against its start, so one that halves its rate from then on reads
as half lost: said, as it should be looked at). Three guesses of the period start a running
least-squares line, each stamp taking the slot nearest the line so far (``_fit_grid``):
``_period`` (intervals under a quarter of their mean left out, stamps taken in pairs or a
glitch; from the 10th percentile of the rest, the mean of those within half to
``LOST_FACTOR`` times the period so far, four times over: right for a stream that loses
most samples from its start, whose median interval is two periods), the mean interval
(right for one that lost none) and the median one. The line whose stamps lie nearest it
wins. A wrong grid leaves them about uniform over a slot (an RMS of 0.25-0.29 of it).

**Stamps too scattered to count by.** Beyond ``SCATTER_LIMIT`` of a period (RMS) in the
reference, no grid can be told from a wrong one; the mean interval is taken (none lost in
the reference) and the stream is ``scattered``: its losses are counted from that grid, but
one lost sample cannot be told from a late one, and every sample is integrated over an
interval off by as much. So it is said (health.verdict), as is a stream whose samples later
land in another slot than the next, more than 0.35 of a period off it (``misplaced``: a
stamp pushed over a slot's edge; a lost sample's successor lies near its slot), in more
than ``MISPLACED_SHARE`` of them. Measured on stamps scattered by a normal law (8 trials
each): an RMS of 0.05-0.15 of a period is fitted right on every trial, with none lost or
10-30 % (60 % at 0.05); 0.2 on most (the rest said); 0.25 and more is said. The simulator's
streams and the 2016, 2021 and 2023 logs' read 0; 2022's, stamped in whole milliseconds,
0.1 of its 10-ms period.

The state is a few scalars and, until the grid is known, a short tuple, so ``save`` and
``restore`` (on every event, by ``core/lagged.py``) cost O(1).
"""

from __future__ import annotations

import statistics
from typing import Any

REFERENCE_INTERVALS = 64
"""Intervals the stream's grid is fitted to."""

LOST_FACTOR = 1.5
"""Within ``_period``: intervals up to this many periods are taken as one period."""

SCATTER_LIMIT = 0.2
"""RMS distance of the reference stamps from their slots, in periods, beyond which the grid
is not trusted (module docstring)."""

MISPLACED_SHARE = 0.01
"""Share of the samples put in a slot other than the next that lie more than 0.35 of a
period off it (pushed over a slot's edge, not lost) that says the stamps scatter."""

_PHASE_GAIN = 1.0 / 16.0
"""Share of each sample's offset from its slot that moves the grid: the grid follows a
clock that drifts, and averages the scatter of 16 samples."""

_PERIOD_SLOTS = 256
"""Slots over which the period is corrected by the grid's mean move per slot, at the first
sample out of its slot after them: 64 scattered intervals give the period to about 1 %,
enough for the grid to hold, not to keep it centred (16 moves of 1 % put it a sixth of a
period off)."""

_FIXED_SLOPE_STAMPS = 16
"""Stamps over which ``_fit_grid`` holds the guessed period (two stamps' slope is noise)."""


def _period(intervals: tuple[float, ...]) -> float:
    """Return a guess of the stream's period from its intervals (module docstring)."""
    floor = 0.25 * sum(intervals) / len(intervals)
    ordered = sorted(i for i in intervals if i >= floor)
    period = ordered[len(ordered) // 10]
    for _ in range(4):
        near = [i for i in ordered if 0.5 * period <= i <= LOST_FACTOR * period]
        period = sum(near) / len(near)
    return period


def _fit_grid(stamps: tuple[float, ...], guess: float) -> tuple[float, float, int, float]:
    """Fit a grid to stamps from a guessed period.

    Returns (period, RMS offset / period, the last stamp's slot, that slot's time). Each
    stamp takes the slot nearest the line fitted to the stamps before it (their slots
    from the first, least squares), so a period guessed a little off is corrected before
    the slots it sets drift by one.
    """
    first = stamps[0]
    offset, period = 0.0, guess
    count = sum_n = sum_nn = sum_t = sum_nt = 0.0
    slots = []
    for stamp in stamps:
        t = stamp - first
        n = round((t - offset) / period) if count else 0
        slots.append(n)
        count += 1.0
        sum_n += n
        sum_nn += n * n
        sum_t += t
        sum_nt += n * t
        spread = count * sum_nn - sum_n * sum_n
        if count >= _FIXED_SLOPE_STAMPS and spread > 0.0:
            period = (count * sum_nt - sum_n * sum_t) / spread
        offset = (sum_t - period * sum_n) / count
    if period <= 0.0:
        return guess, float('inf'), slots[-1], stamps[-1]
    squares = sum((s - first - offset - period * n) ** 2 for s, n in zip(stamps, slots))
    rms = (squares / len(stamps)) ** 0.5
    return period, rms / period, slots[-1], first + offset + period * slots[-1]


class InputLoss:
    """One stream's samples received, those its stamps imply, their scatter (module doc)."""

    __slots__ = ('received', 'lost', 'period_s', 'scatter_s', 'scattered', 'misplaced',
                 '_half', '_next_s', '_last_s', '_stamps', '_longest_s', '_anchor')

    def __init__(self) -> None:
        self.received = 0
        self.lost = 0
        self.period_s: float | None = None
        self.scatter_s: float | None = None  # RMS offset of the reference stamps, s
        self.scattered = False
        self.misplaced = 0
        # Half a period once the grid is known: -1 sends every sample to _settle until then.
        self._half = -1.0
        self._next_s = 0.0  # where the grid puts the next slot, s
        self._last_s: float | None = None
        self._stamps: tuple[float, ...] = ()
        self._longest_s = 0.0
        # (the grid's next slot, slots so far) when the period was last set.
        self._anchor: tuple[float, int] = (0.0, 0)

    def add(self, stamp_s: float) -> None:
        """Count a sample that arrived at stamp_s (stamps in the filter's order)."""
        # One subtraction and comparison per sample in its slot: this runs at every IMU
        # and odometry sample.
        self.received += 1
        offset = stamp_s - self._next_s
        half = self._half
        if -half < offset < half:
            self._next_s += 2.0 * half + _PHASE_GAIN * offset
            self._last_s = stamp_s
            return
        self._settle(stamp_s, offset)

    def _settle(self, stamp_s: float, offset: float) -> None:
        """Count a sample outside the next slot, or any before the grid is known."""
        last, self._last_s = self._last_s, stamp_s
        if last is not None and stamp_s <= last:
            return  # a repeat, or a stamp out of order: received, spanning nothing
        if last is not None and stamp_s - last > self._longest_s:
            self._longest_s = stamp_s - last
        period = self.period_s
        if period is None:
            self._stamps += (stamp_s,)
            if len(self._stamps) > REFERENCE_INTERVALS:
                self._fit()
            return
        slots = round(offset / period)  # slots from the next one: 1 or more skipped, or back
        residual = offset - slots * period
        if slots and abs(residual) > 0.7 * self._half:
            self.misplaced += 1
        self.lost = max(0, self.lost + slots)
        self._next_s += (slots + 1) * period + _PHASE_GAIN * residual
        # The grid's moves toward the stamps, per slot since the period was last set, are
        # what the period is off by (here, off the path taken by samples in their slot).
        anchor_s, anchor_slots = self._anchor
        slots_since = self.received + self.lost - anchor_slots
        if slots_since >= _PERIOD_SLOTS:
            self.period_s = period = period + (
                self._next_s - anchor_s - slots_since * period) / slots_since
            self._half = 0.5 * period
            self._anchor = (self._next_s, self.received + self.lost)

    def _fit(self) -> None:
        stamps, self._stamps = self._stamps, ()
        intervals = tuple(b - a for a, b in zip(stamps, stamps[1:]))
        guesses = (_period(intervals), (stamps[-1] - stamps[0]) / len(intervals),
                   statistics.median(intervals))
        period, scatter, last_slot, last_grid_s = min(
            (_fit_grid(stamps, guess) for guess in guesses), key=lambda fit: fit[1])
        if scatter > SCATTER_LIMIT:
            # No grid stands out of the scatter: take the one that lost nothing here.
            self.scattered = True
            period = (stamps[-1] - stamps[0]) / len(intervals)
            mean_slot = len(intervals) / 2.0
            last_slot = len(intervals)
            last_grid_s = (sum(stamps) / len(stamps)) + period * (last_slot - mean_slot)
        self.period_s = period
        self.scatter_s = scatter * period
        self._half = 0.5 * period
        self._next_s = last_grid_s + period
        # The samples received so far (repeats included) against the slots they spanned.
        self.lost = max(0, last_slot + 1 - self.received)
        self._anchor = (self._next_s, self.received + self.lost)

    @property
    def last_s(self) -> float | None:
        """Stamp of the last sample that arrived, s (None before one)."""
        return self._last_s

    @property
    def longest_s(self) -> float:
        """Longest time between two samples that arrived, s (0 with fewer than two).

        Exact for an interval longer than two periods: the only ones that matter (an
        input silent for longer than a prediction step, health.verdict), and only those
        can leave the next slot empty.
        """
        return self._longest_s

    @property
    def share(self) -> float:
        """Samples received over those the stamps imply (1 before any was lost)."""
        total = self.received + self.lost
        return 1.0 if total == 0 else self.received / total

    @property
    def scatters(self) -> bool:
        """The stamps scatter too much to count losses one by one (module docstring)."""
        return self.scattered or self.misplaced > MISPLACED_SHARE * self.received

    def save(self) -> tuple:
        return (self.received, self.lost, self.period_s, self.scatter_s, self.scattered,
                self.misplaced, self._half, self._next_s, self._last_s, self._stamps,
                self._longest_s, self._anchor)

    def restore(self, saved: tuple) -> None:
        (self.received, self.lost, self.period_s, self.scatter_s, self.scattered,
         self.misplaced, self._half, self._next_s, self._last_s, self._stamps,
         self._longest_s, self._anchor) = saved

    def report(self) -> dict[str, Any]:
        """JSON-ready figures (summary.json ``input_loss``, /diagnostics, the verdict)."""
        return {'received': self.received, 'lost': self.lost, 'share': self.share,
                'period_s': self.period_s, 'longest_interval_s': self.longest_s,
                'last_s': self._last_s, 'stamp_scatter_s': self.scatter_s,
                'misplaced': self.misplaced, 'scatters': self.scatters}


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
