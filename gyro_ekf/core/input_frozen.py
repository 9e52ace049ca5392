"""A gyro that repeats one value sample after sample: frozen, its repeats left out.

A driver that hangs and republishes its last sample, a serial link that replays its buffer,
a bag recorded through a node that latched: the yaw rate keeps arriving on time, but it is
one value. The filter turns by it as by any sample, so a turn that started or ended while it
was frozen runs on in the heading; the LiDARs take that back as a bias that moved. On three
clean simulated trips, three freezes of 5 s each made bias estimates of 9-88 deg/s on two,
which lost the pose, and re-opened the bias 7 times on the third; each run was failed or
degraded, but none of the reasons named the gyro.

A live gyro is never frozen by chance: its white noise makes two samples in a row the same
float only where its output is quantised, and then a few times in a row (the course logs:
3 at most, on the 2021 log's quantised gyro, whose pairs repeat 2.4 % of the time; never on
the others). So once the stream has shown ``MIN_PAIRS`` pairs and repeats no more than
``NOISY_SHARE`` of them (a gyro without noise, a simulator's or a test's constant rate,
repeats by its nature, and is not judged), a run of repeats is frozen when it is at least
``MIN_REPEATS`` long and its chance, p^k for k repeats in a row where p is the stream's own
share of repeats outside frozen runs, is below ``CHANCE`` (at p = 0.2, 13 repeats: so
``MIN_REPEATS``). From then on, until the value changes, each sample is left out: the driver
holds the last rate taken (the frozen value at the freeze's start, a true sample then) and
treats the rest as an IMU gap (core/held_rate.py), so the heading's uncertainty grows as the
turn the gyro no longer shows may have moved it.

Only the gyro: an odometry speed is the same sample after sample at rest (0) and, where the
encoder is quantised, while cruising (the 2021 log: 131 samples in a row at 0.091 m/s). And
not a gyro repeating exactly 0: a simulator's gyro without noise reads that at rest, and
a stop of one is no freeze (a driver that publishes zeros when its device is lost is
left to the LiDARs).

The state is a few scalars: ``save`` and ``restore`` (on every event, core/lagged.py) are
O(1), and ``left_out`` costs one comparison per sample that differs from the last.
"""

from __future__ import annotations

import math
from typing import Any

MIN_REPEATS = 19
"""Fewest repeats of one value in a row (20 samples: 0.1 s at 200 Hz) that can be frozen."""

CHANCE = 1e-9
"""A run of repeats less likely than this by the stream's own repeat share is frozen."""

MIN_PAIRS = 1000
"""Pairs of samples in a row (5 s at 200 Hz) a stream shows before its repeats are judged."""

NOISY_SHARE = 0.2
"""A stream whose repeat share is above this is not judged: it repeats by its nature."""


class FrozenWatch:
    """One stream's runs of a repeated value; the repeats of a frozen one left out.

    Attributes:
        runs: frozen runs seen.
        samples: samples left out (the repeats of frozen runs from the freeze on).
        longest_s: the longest frozen run, from its first sample to its last, s.
        first_at_s: stamp of the first frozen run's first sample, s (None before one).
    """

    __slots__ = ('runs', 'samples', 'longest_s', 'first_at_s', '_last', '_repeats',
                 '_start_s', '_needed', '_frozen', '_pairs', '_repeat_pairs')

    def __init__(self) -> None:
        self.runs = 0
        self.samples = 0
        self.longest_s = 0.0
        self.first_at_s: float | None = None
        self._last = math.nan  # the last sample's value (NaN equals nothing: a new run)
        self._repeats = 0  # repeats of _last in a row so far
        self._start_s = 0.0  # stamp of the run's first sample
        self._needed = 0  # repeats that make this run frozen (set at its first repeat)
        self._frozen = False
        # Pairs of samples in a row outside frozen runs, and how many of them repeat.
        self._pairs = 0
        self._repeat_pairs = 0

    def left_out(self, stamp_s: float, value: float) -> bool:
        """Judge a sample; return whether it is a repeat of a frozen run (to be left out)."""
        if value != self._last:
            if self._repeats:
                self._end_run()
            self._pairs += 1
            self._last, self._start_s = value, stamp_s
            return False
        if value == 0.0:
            # Exactly 0 is what a noise-free simulated gyro reads at rest: not judged.
            return False
        self._repeats += 1
        if self._frozen:
            self.samples += 1
            self.longest_s = max(self.longest_s, stamp_s - self._start_s)
            return True
        if self._repeats == 1:
            self._needed = self._repeats_needed()
        if self._repeats < self._needed:
            return False
        self._frozen = True
        self.runs += 1
        if self.first_at_s is None:
            self.first_at_s = self._start_s
        self.samples += 1
        self.longest_s = max(self.longest_s, stamp_s - self._start_s)
        return True

    def _repeats_needed(self) -> int | float:
        """Return the repeats in a row whose chance by the stream's repeat share is CHANCE.

        Infinite (not judged) before MIN_PAIRS pairs, or for a stream that repeats more
        than NOISY_SHARE of them: quantised coarser than its noise, or without noise (a
        simulator's or a test's constant rate), it repeats by its nature.
        """
        if self._pairs < MIN_PAIRS:
            return math.inf
        # Laplace's rule: a share of the pairs seen, never 0.
        share = (self._repeat_pairs + 1) / (self._pairs + 2)
        if share > NOISY_SHARE:
            return math.inf
        return max(MIN_REPEATS, math.ceil(math.log(CHANCE) / math.log(share)))

    def _end_run(self) -> None:
        if self._frozen:
            self._frozen = False
        else:
            # An ordinary run: its repeats are the stream's own repeat share.
            self._pairs += self._repeats
            self._repeat_pairs += self._repeats
        self._repeats = 0

    def save(self) -> tuple:
        return (self.runs, self.samples, self.longest_s, self.first_at_s, self._last,
                self._repeats, self._start_s, self._needed, self._frozen, self._pairs,
                self._repeat_pairs)

    def restore(self, saved: tuple) -> None:
        (self.runs, self.samples, self.longest_s, self.first_at_s, self._last, self._repeats,
         self._start_s, self._needed, self._frozen, self._pairs, self._repeat_pairs) = saved

    def report(self) -> dict[str, Any]:
        """JSON-ready figures (summary.json ``gyro_frozen``, /diagnostics, the verdict)."""
        return {'runs': self.runs, 'samples': self.samples, 'longest_s': self.longest_s,
                'first_at_s': self.first_at_s}
