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

A drift adds db^2 to the bias variance P_bb and changes nothing else: the filter, told it
does not know the bias as well as it thought, learns it again from the next updates as it
did at the start. Drifts that recur (a ramp) make the bias a random walk while they last:
the db^2 of the last ``WALK_WINDOW_S`` seconds, over that time, is the variance per second
the prediction adds to P_bb (``GyroBiasEkf.bias_walk_found``). A mount yaw error of one
LiDAR shifts its bearings by a constant, which the yaw absorbs once, not block after
block: its corrections add up to about nothing, and so does its db. Nothing of this is
silent: the run's verdict is degraded when the bias was re-opened (core/health.py).
"""

from __future__ import annotations

import math
from statistics import NormalDist

BLOCK_S = 2.0
"""Length of a block of updates, s: long enough for a dozen scans' corrections to add up,
short enough that a step in the bias is opened within a few seconds."""

WALK_WINDOW_S = 60.0
"""How far back the drifts found make the bias a random walk, s: a step opens it once and
is forgotten after this long; a ramp opens it again and again and keeps it walking."""

SIGNIFICANCE = 1e-5
"""Chance that a block of a consistent filter is taken for a drift (a 1-hour trip has 1800
blocks: 0.02 false openings, each adding only the tiny db^2 of its block)."""

_Z_LIMIT = NormalDist().inv_cdf(1.0 - SIGNIFICANCE / 2.0)


class BiasWatch:
    """Blocks of bearing innovations and yaw corrections; says when to re-open the bias.

    Attributes:
        openings: blocks taken for a drift so far.
        last_error_rad_s: the bias error the last drift implied, rad/s (0 before one).
    """

    __slots__ = ('_start_s', '_z_sum', '_variance', '_shared', '_correction_sum',
                 'openings', 'last_error_rad_s', '_drifts', 'walk')

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

    def copy(self) -> 'BiasWatch':
        """Return an independent duplicate, for the driver's save and restore."""
        clone = BiasWatch()
        clone._start_s, clone._z_sum = self._start_s, self._z_sum
        clone._variance = self._variance
        clone._shared = dict(self._shared)
        clone._correction_sum = self._correction_sum
        clone.openings, clone.last_error_rad_s = self.openings, self.last_error_rad_s
        clone._drifts, clone.walk = list(self._drifts), self.walk
        return clone

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
        self._z_sum += bearing_innovation_rad / math.sqrt(bearing_variance)
        share = map_variance / bearing_variance
        # Var(sum z) = n + sum over landmarks of ((sum sqrt share)^2 - sum share).
        root = math.sqrt(share)
        before = self._shared.get(landmark, 0.0)
        self._shared[landmark] = before + root
        self._variance += 1.0 + 2.0 * before * root

    def corrected(self, yaw_correction_rad: float) -> None:
        """Add the yaw change of one scan's updates (posterior minus prior yaw), rad."""
        if self._start_s is not None:
            self._correction_sum += yaw_correction_rad

    def close(self, stamp_s: float) -> float | None:
        """Before a scan's updates: close the block if it is BLOCK_S old; return db^2 on a drift.

        The closed block holds the scans before this one; their corrections took back the
        drift from its first scan to this one's stamp. A block that ran into a gap longer
        than BLOCK_S (a dropout, a stop) is dropped unjudged: its corrections do not span it.
        """
        start = self._start_s
        if start is None or stamp_s < start + BLOCK_S:
            return None
        length = stamp_s - start
        z = self._z_sum / math.sqrt(self._variance)
        error = -self._correction_sum / length
        self.pause()
        drifted = length <= 2.0 * BLOCK_S and abs(z) > _Z_LIMIT
        if drifted:
            self.openings += 1
            self.last_error_rad_s = error
            self._drifts.append((stamp_s, error * error))
        # The bias moved by about db at each drift: sum(db^2) over the window is the
        # variance a random walk gains in that time.
        self._drifts = [d for d in self._drifts if d[0] > stamp_s - WALK_WINDOW_S]
        self.walk = sum(d[1] for d in self._drifts) / WALK_WINDOW_S
        return error * error if drifted else None
