"""A gyro's wander, seen in the samples of a stop (pure Python).

Standing still, the gyro reads its bias b, a wander c (``core/gyro_wander.py``) and white
noise. The white noise averages out: the means of a still stop's 2-s blocks scatter about
the stop's mean by sigma_w / sqrt(n) (0.0125 deg/s for the simulator's 0.25 deg/s at
200 Hz), whatever the bias. A wander does not: over seconds it moves every block's mean
alike, and the blocks scatter more. The zero-rate updates take the stop's mean, b plus the
wander's mean over the stop, for b, with a sigma that counts the white noise alone; and the
blocks of driving can find a wander only after 20 s of them (``gyro_wander.MIN_BLOCKS``:
28-116 s on the simulator's wanders). Until then the heading grows less certain than the
filter says (stress seed 0 coloured_gyro 20, a wander of 0.035 deg/s over 3.9 s: above the
NEES band on 53 % of 12-18 s, NEES share 0.889).

So at the end of a stop the block means' scatter is judged against the white noise's:
their weighted sum of squares about the weighted mean, ``sum n_k (m_k - m)^2 /
sigma_w^2``, is chi-square with K - 1 dof for a gyro with no wander (sigma_w^2 the stop's
sample spread, whose share of a wander is a few per cent). Beyond chance
(``SIGNIFICANCE``), the excess, ``(sum - (K - 1)) sigma_w^2 / (N - sum n_k^2 / N)`` (N the
stop's samples; the variance-component estimate of the block means), is a wander's share
the stop shows. It reads low: a wander of correlation time tau shows within a stop of
length T only its variance less that of its mean over T (about 0.7 of the sigma for tau
4 s, T 8 s). The driver models it as a prior wander from the stop's end, ruled out by the
blocks of driving as the configured prior is (``GyroWander.seen_at_stop``).

A ramping bias scatters the blocks too (over 8 s, a ramp and a wander of tau 4 s look
alike). A stop while a bias rate is in use (``core/bias_rate.py``, found at rest or while
driving) is not judged. A ramp too slow to be found at rest that still scatters the blocks
gets a wander prior it did not need, which costs it little: with the prior modelled the
heading is less certain while the ramp is learnt (stress bias_ramp, seeds 0-9 and 27-29:
94 of 325 trips changed, the NEES share up on 87, three more within the bounds, none lost;
docs/health.md).
"""

from __future__ import annotations

import math

from gyro_ekf.core.health import chi_square_upper

__all__ = ['StopBlocks']

BLOCK_S = 2.0
"""Length of the blocks whose means are judged, s: the bias watch's blocks of driving
(0.5-s blocks would see the real 2016 gyro's excess at short times, which no wander of
seconds explains)."""

MIN_SHARE = 0.5
"""A stop's last, unfinished block counts when it spans at least this share of a block."""

SIGNIFICANCE = 1e-3
"""Chance that a still stop of a gyro with no wander is taken for one. A false one costs a
prior wander of about 0.02 deg/s until the blocks of driving rule it out."""


class StopBlocks:
    """The 2-s block means of one stop's gyro samples, and the wander they show."""

    __slots__ = ('_closed', '_open')

    def __init__(self) -> None:
        """Start a stop with no samples."""
        # (samples, mean rad/s) of each closed block, and the open one as
        # [first stamp s, last stamp s, sum of rates, samples] (None: none open).
        self._closed: list[tuple[int, float]] = []
        self._open: list[float] | None = None

    def copy(self) -> 'StopBlocks':
        """Return an independent duplicate, for the driver's save and restore."""
        clone = StopBlocks()
        clone._closed = list(self._closed)
        clone._open = None if self._open is None else list(self._open)
        return clone

    def add(self, stamp_s: float, rate_rad_s: float) -> None:
        """Take one gyro sample of the stop (stamp s, measured yaw rate rad/s)."""
        block = self._open
        if block is not None and stamp_s - block[0] < BLOCK_S:
            block[1] = stamp_s
            block[2] += rate_rad_s
            block[3] += 1
            return
        if block is not None:
            self._closed.append((int(block[3]), block[2] / block[3]))
        self._open = [stamp_s, stamp_s, rate_rad_s, 1]

    def wander(self, white_variance: float) -> float | None:
        """Return the wander's sigma the blocks show beyond chance, rad/s (None: none).

        Args:
            white_variance: sigma_w^2, the variance of one sample, (rad/s)^2.
        """
        blocks = list(self._closed)
        block = self._open
        if block is not None and block[1] - block[0] >= MIN_SHARE * BLOCK_S:
            blocks.append((int(block[3]), block[2] / block[3]))
        dof = len(blocks) - 1
        if dof < 2 or not 0.0 < white_variance < math.inf:
            return None
        total = sum(n for n, _ in blocks)
        mean = sum(n * m for n, m in blocks) / total
        scatter = sum(n * (m - mean) ** 2 for n, m in blocks) / white_variance
        if not scatter > chi_square_upper(SIGNIFICANCE, dof):
            return None
        effective = total - sum(n * n for n, _ in blocks) / total
        return math.sqrt((scatter - dof) * white_variance / effective)
