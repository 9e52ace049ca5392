"""Re-open the bias when the LiDARs see the heading drift the same way, block after block.

The filter's bias model is all but a constant (``bias_random_walk_rad_s2``: a few
thousandths of a deg/s over a trip), which is what a gyro at a steady temperature does and
what keeps a coloured wander out of the estimate. A bias that steps or ramps then leaves a
wrong b in a confident filter: the yaw it predicts drifts, and every landmark update pulls
it back the same way while the bias, whose variance is all but zero, does not move. Making
the model agile for every trip would put every wander into the bias; watching for the
drift and opening the bias only when it is seen does not.

Two figures per block of ``BLOCK_S`` seconds of applied landmark updates (not at rest):

- Z, the normalised bearing innovations y_b / sqrt(S_bb) summed and divided by the square
  root of their count: standard normal for a consistent filter (the innovations are
  independent), large when they are alike. With a stated map error, every look at one
  pole shares that pole's error, so the sum's variance adds their correlations. A block
  is a drift when |Z| exceeds the two-sided normal quantile of ``SIGNIFICANCE``.
- The bias error that drift implies: the updates' yaw corrections over the block, taken
  back from the filter's yaw, add up to the drift of a bias error db, so
  db = -sum(corrections) / block length (yaw += T (w - b): a b too small by db makes the
  prediction run ahead by db per second).

A block whose Z is already beyond a stricter limit (``SIGNIFICANCE`` spread over
``EARLY_LOOKS`` looks) once ``EARLY_MIN_S`` old closes then, as a drift: a step makes the
heading run off at once, and waiting out the block let it run a degree.

A run of the last k blocks (2 <= k <= ``NOISE_BLOCKS``) that are no drift of their own is
judged as one longer block: its normalised innovations summed, over the root of their
variance (a pole's map error is shared by its looks in every block of the run), are
standard normal for a consistent filter, and beyond the limit of ``SIGNIFICANCE`` spread
over the ``NOISE_BLOCKS - 1`` runs looked at when a block closes they are a drift, of the
run's db (its corrections over its length). A bias error too small for one block to show
adds up in a run: a ramp of 0.3 deg/s per minute gave blocks of Z -2 to -3.8, each below
the single-block limit of 4.4, for 15 s (the heading 0.07 deg off, NEES above its band)
until one block passed it; the first four together are a drift, 9 s sooner.

A drift adds db^2 to the bias variance P_bb and changes nothing else: the filter, told it
does not know the bias as well as it thought, learns it again from the next updates as it
did at the start. Drifts that recur (a ramp) make the bias a random walk while they last:
the db^2 of the last ``WALK_WINDOW_S`` seconds, over that time, is the variance per second
the prediction adds to P_bb (``GyroBiasEkf.bias_walk_found``), until ``QUIET_S`` pass
without a drift (a step, once learnt, is a constant again: a walk kept for the whole
window let the learnt bias wander 0.02-0.035 deg/s off to the end of the trip). A mount
yaw error of one LiDAR shifts its bearings by a constant, which the yaw absorbs once, not
block after block: its corrections add up to about nothing, and so does its db. Nothing of
this is silent: the run's verdict is degraded when the bias was re-opened
(core/health.py).
"""

from __future__ import annotations

import math
from statistics import NormalDist
from typing import NamedTuple

from gyro_ekf.core.health import chi_square_upper

BLOCK_S = 2.0
"""Length of a block of updates, s: long enough for a dozen scans' corrections to add up,
short enough that a step in the bias is opened within a few seconds."""

WALK_WINDOW_S = 60.0
"""How far back the drifts found make the bias a random walk, s: a step opens it once and
is forgotten after this long; a ramp opens it again and again and keeps it walking."""

NOISE_BLOCKS = 10
"""Blocks (20 s of driving) judged together: a slow drift, or a gyro noisier than stated."""

QUIET_S = NOISE_BLOCKS * BLOCK_S
"""After this long without a drift the drifts have stopped recurring and the walk ends, s:
a window of blocks the slow-drift judge would have seen a ramp in."""

NOISE_SIGNIFICANCE = 1e-3
"""Chance that a window of a consistent filter's blocks is taken for a noisier gyro."""

MAX_NOISE_SCALE = 100.0
"""Largest factor on the gyro's stated noise variance (10 times its sigma)."""

SIGNIFICANCE = 1e-5
"""Chance that a block of a consistent filter is taken for a drift (a 1-hour trip has 1800
blocks: 0.02 false openings, each adding only the tiny db^2 of its block)."""

EARLY_MIN_S = 0.5
"""A block may close before BLOCK_S, once this old, when its drift is already plain."""

EARLY_LOOKS = 40
"""Looks at an open block's Z before it is BLOCK_S old (a scan each, two LiDARs at 10 Hz):
the early limit spends SIGNIFICANCE over that many looks, so a consistent filter's block
is no more often taken for a drift than before."""

_Z_LIMIT = NormalDist().inv_cdf(1.0 - SIGNIFICANCE / 2.0)
_RUN_Z_LIMIT = NormalDist().inv_cdf(1.0 - SIGNIFICANCE / (2.0 * (NOISE_BLOCKS - 1)))
_EARLY_Z_LIMIT = NormalDist().inv_cdf(1.0 - SIGNIFICANCE / (2.0 * EARLY_LOOKS))
_NOISE_HIGH = chi_square_upper(NOISE_SIGNIFICANCE, NOISE_BLOCKS) / NOISE_BLOCKS
_NOISE_LOW = chi_square_upper(1.0 - NOISE_SIGNIFICANCE, NOISE_BLOCKS) / NOISE_BLOCKS
T_LIMIT = 4.781
"""Student's t, 9 dof (NOISE_BLOCKS - 1), two-sided NOISE_SIGNIFICANCE."""


class _Block(NamedTuple):
    """A judged block that was no drift of its own, as the runs and the windows take it."""

    looks_sum: float
    """Its normalised bearing innovations y_b / sqrt(S_bb), summed."""
    variance: float
    """That sum's variance: the looks' count plus the correlation of looks at one pole."""
    shared: dict[int, float]
    """Per landmark, the sum of sqrt(map share) of its looks (see ``BiasWatch.add``)."""
    error: float
    """db, the bias error its yaw corrections imply, rad/s."""
    length: float
    """s."""
    start_yaw_variance: float
    """The heading's variance where it started, rad^2."""
    heading_noise: float
    """The heading noise its predictions added, rad^2."""

    @property
    def z_squared(self) -> float:
        """Z^2: standard normal Z for a consistent filter, squared."""
        return self.looks_sum * self.looks_sum / self.variance


class BiasWatch:
    """Blocks of bearing innovations and yaw corrections; says when to re-open the bias.

    Attributes:
        openings: blocks taken for a drift so far.
        last_error_rad_s: the bias error the last drift implied, rad/s (0 before one).
    """

    __slots__ = ('_start_s', '_z_sum', '_variance', '_shared', '_correction_sum',
                 'openings', 'last_error_rad_s', '_drifts', 'walk', '_blocks', 'noise_scale',
                 'noise_floor',
                 '_start_yaw_variance', 'block')

    def __init__(self) -> None:
        """Start with no block open."""
        self._start_s: float | None = None
        self._z_sum = 0.0
        self._variance = 0.0
        # Per landmark: the sum of sqrt(map share) of its looks in the block.
        self._shared: dict[int, float] = {}
        self._correction_sum = 0.0
        self.openings = 0
        self.last_error_rad_s = 0.0
        # (stamp s, db^2) of the drifts of the last WALK_WINDOW_S.
        self._drifts: list[tuple[float, float]] = []
        self.walk = 0.0
        # The last blocks that were no drift of their own; noise_scale is the factor their
        # Z^2 set on the gyro's noise variance.
        self._blocks: list[_Block] = []
        self._start_yaw_variance = 0.0
        self.noise_scale = 1.0
        # The least noise_scale may fall to: what the gyro's spread at a stop measured
        # (set_noise_floor); 1 (the stated noise) until one did.
        self.noise_floor = 1.0
        # (start s, length s, implied bias error db rad/s) of the last block closed and
        # judged, None when the last one was dropped (core/bias_rate.py fits its db).
        self.block: tuple[float, float, float] | None = None

    def copy(self) -> 'BiasWatch':
        """Return an independent duplicate, for the driver's save and restore."""
        clone = BiasWatch()
        clone._start_s, clone._z_sum = self._start_s, self._z_sum
        clone._variance = self._variance
        clone._shared = dict(self._shared)
        clone._correction_sum = self._correction_sum
        clone.openings, clone.last_error_rad_s = self.openings, self.last_error_rad_s
        clone._drifts, clone.walk = list(self._drifts), self.walk
        clone._blocks, clone.noise_scale = list(self._blocks), self.noise_scale
        clone.noise_floor = self.noise_floor
        clone._start_yaw_variance = self._start_yaw_variance
        clone.block = self.block
        return clone

    def set_noise_floor(self, scale: float) -> None:
        """Never let the noise factor fall below ``scale`` (a stop's gyro spread measured it).

        A factor the floor set follows it; one the blocks raised above it stays unless the
        floor is higher.
        """
        floor = min(max(float(scale), 1.0), MAX_NOISE_SCALE)
        if self.noise_scale == self.noise_floor:
            self.noise_scale = floor
        self.noise_scale = max(self.noise_scale, floor)
        self.noise_floor = floor

    def pause(self) -> None:
        """Drop the open block (at rest, a gap: its corrections would not span a drift)."""
        self._start_s = None
        self._z_sum, self._variance, self._correction_sum = 0.0, 0.0, 0.0
        self._shared = {}

    def add(self, stamp_s: float, bearing_innovation_rad: float, bearing_variance: float,
            landmark: int = 0, map_variance: float = 0.0) -> None:
        """Add one applied landmark update.

        Args:
            stamp_s: scan stamp, s.
            bearing_innovation_rad: y_b, rad.
            bearing_variance: its S_bb, rad^2.
            landmark: index of the landmark in the map.
            map_variance: the share of S_bb that the map's error adds (sigma^2 / r^2), rad^2:
                every look at one pole shares it, so their normalised innovations are
                correlated by sqrt(share_i share_j) and the block's sum varies more than
                its count.
        """
        if self._start_s is None:
            self._start_s = stamp_s
        scale = 1.0 / math.sqrt(bearing_variance)
        self._z_sum += bearing_innovation_rad * scale
        if map_variance <= 0.0:
            self._variance += 1.0
            return
        # Var(sum z) = n + sum over landmarks of ((sum sqrt share)^2 - sum share).
        root = math.sqrt(map_variance) * scale
        before = self._shared.get(landmark, 0.0)
        self._shared[landmark] = before + root
        self._variance += 1.0 + 2.0 * before * root

    def corrected(self, yaw_correction_rad: float) -> None:
        """Add the yaw change of one scan's updates (posterior minus prior yaw), rad."""
        if self._start_s is not None:
            self._correction_sum += yaw_correction_rad

    @property
    def start_yaw_variance(self) -> float:
        """The heading's variance where the open block started (the last block's close), rad^2."""
        return self._start_yaw_variance

    @property
    def idle(self) -> bool:
        """Whether no block is open (the next landmark update starts one)."""
        return self._start_s is None

    def drift_sign(self) -> float:
        """Sign of the last drift's bias error if one lies within WALK_WINDOW_S, else 0."""
        if not self._drifts or self.last_error_rad_s == 0.0:
            return 0.0
        return math.copysign(1.0, self.last_error_rad_s)

    def due(self, stamp_s: float) -> bool:
        """Whether a scan at stamp_s closes the open block (``close`` would judge it)."""
        return self._start_s is not None and (stamp_s >= self._start_s + BLOCK_S
                                              or self._early(stamp_s))

    def _early(self, stamp_s: float) -> bool:
        """Whether the open block already shows a drift at the early limit.

        A bias step makes the heading run off at once; waiting for the end of the block
        lets it run 2-4 s with a confident filter (NEES far above its band), while the
        updates' bearing innovations show it within a few tenths of a second.
        """
        start = self._start_s
        return (start is not None and stamp_s >= start + EARLY_MIN_S and self._variance > 0.0
                and abs(self._z_sum) > _EARLY_Z_LIMIT * math.sqrt(self._variance))

    def close(self, stamp_s: float, bias_variance: float = 0.0, yaw_variance: float = 0.0,
              heading_noise: float = 0.0) -> float | None:
        """Before a scan's updates: close the block if it is BLOCK_S old; return db^2 on a drift.

        A block whose drift is already plain (``_early``) closes sooner, as a drift.

        The closed block holds the scans before this one; their corrections took back the
        drift from its first scan to this one's stamp. A block that ran into a gap longer
        than BLOCK_S (a dropout, a stop) is dropped unjudged: its corrections do not span it.
        """
        start = self._start_s
        if start is None or (stamp_s < start + BLOCK_S and not self._early(stamp_s)):
            return None
        length = stamp_s - start
        z = self._z_sum / math.sqrt(self._variance)
        error = -self._correction_sum / length
        # pause() starts a new dict of shares: this one stays the block's.
        block = _Block(self._z_sum, self._variance, self._shared, error, length,
                       self._start_yaw_variance, heading_noise)
        self.pause()
        judged = length <= 2.0 * BLOCK_S
        self.block = (start, length, error) if judged else None
        drifted = judged and abs(z) > _Z_LIMIT
        if judged and not drifted:
            # Not a drift of its own: maybe one of a run's or a slow drift's blocks, or a
            # noisier gyro.
            drifted = self._window(block, bias_variance, yaw_variance)
            if drifted:
                error = self.last_error_rad_s
        elif drifted:
            self.last_error_rad_s = error
            self._blocks.clear()
        # The heading's variance where the next block starts (a window's first block).
        self._start_yaw_variance = yaw_variance
        if drifted:
            self.openings += 1
            self._drifts.append((stamp_s, error * error))
        # The bias moved by about db at each drift: sum(db^2) over the window is the
        # variance a random walk gains in that time.
        drifts = self._drifts = [d for d in self._drifts if d[0] > stamp_s - WALK_WINDOW_S]
        recurring = drifts and drifts[-1][0] > stamp_s - QUIET_S
        self.walk = sum(d[1] for d in drifts) / WALK_WINDOW_S if recurring else 0.0
        return error * error if drifted else None

    def found(self, stamp_s: float, error_rad_s: float) -> float:
        """Take a drift another test found at this block (``GyroWander.held``); return db^2.

        It counts as one of the watch's own: the window starts again, and the walk and the
        drift's sign (which a ramp's line asks for, core/bias_rate.py) include it.
        """
        self.last_error_rad_s = error_rad_s
        self._blocks.clear()
        self.openings += 1
        self._drifts.append((stamp_s, error_rad_s * error_rad_s))
        self.walk = sum(d[1] for d in self._drifts) / WALK_WINDOW_S
        return error_rad_s * error_rad_s

    def _window(self, block: _Block, bias_variance: float, yaw_variance: float) -> bool:
        """Judge the last blocks together; return True on a drift of a run or a slow drift.

        First the runs of the last 2 to NOISE_BLOCKS blocks, each as one longer block (see
        the module docstring). Then, once there are NOISE_BLOCKS of them: a bias that
        ramps, or steps by too little for one block to show, leaves blocks whose implied
        errors db share a sign: their mean, against their own scatter (Student's t with
        NOISE_BLOCKS - 1 dof), is a drift, of that mean, when it also lies beyond three
        sigmas of what the filter already allows for: its bias error, its heading error at
        the window's ends (the corrections take back the heading error's change too) and
        the heading noise its predictions added over the window (the gyro's white noise).
        Otherwise a window whose mean Z^2 lies far from 1 scales the gyro's noise
        (covariance matching, Mehra): a consistent filter's Z^2 has mean 1, and a gyro
        noisier at low frequencies than its stated white noise (a bias that wanders over
        seconds) leaves blocks alike inside, so their Z^2 is larger by about the factor by
        which the filter's heading noise is too small. The stated rate variance is
        multiplied by it; a window below the lower bound takes a factor back (never under
        1). The window starts afresh at each change.
        """
        blocks = self._blocks
        blocks.append(block)
        # A run's Z is its looks' sum over the root of its variance: the blocks' own, plus
        # what looks at one pole in different blocks share (a stated map's error is the
        # pole's, from block to block), as add() sums it within a block.
        run_sum = run_variance = run_error = run_length = 0.0
        run_shared: dict[int, float] = {}
        for k, block in enumerate(reversed(blocks), start=1):
            run_sum += block.looks_sum
            run_variance += block.variance
            for landmark, root in block.shared.items():
                before = run_shared.get(landmark, 0.0)
                run_shared[landmark] = before + root
                run_variance += 2.0 * before * root
            # db = -corrections / length: the run's db is its blocks' db weighted by length.
            run_error += block.error * block.length
            run_length += block.length
            if k > 1 and abs(run_sum) > _RUN_Z_LIMIT * math.sqrt(run_variance):
                self.last_error_rad_s = run_error / run_length
                blocks.clear()
                return True
        if len(blocks) < NOISE_BLOCKS:
            return False
        n = len(blocks)
        mean_error = sum(b.error for b in blocks) / n
        spread = math.sqrt(sum((b.error - mean_error) ** 2 for b in blocks) / (n - 1))
        span = sum(b.length for b in blocks)
        allowed = bias_variance + (blocks[0].start_yaw_variance + yaw_variance
                                   + sum(b.heading_noise for b in blocks)) / (span * span)
        if (abs(mean_error) > T_LIMIT * spread / math.sqrt(n)
                and mean_error * mean_error > 9.0 * allowed):
            self.last_error_rad_s = mean_error
            blocks.clear()
            return True
        mean = sum(b.z_squared for b in blocks) / n
        blocks.pop(0)
        if mean > _NOISE_HIGH:
            scale = min(self.noise_scale * mean, MAX_NOISE_SCALE)
        elif mean < _NOISE_LOW and self.noise_scale > self.noise_floor:
            scale = max(self.noise_scale * mean, self.noise_floor)
        else:
            return False
        self.noise_scale = scale
        blocks.clear()
        return False
