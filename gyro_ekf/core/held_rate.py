"""What a held yaw rate may have done since its sample: the heading variance of an IMU gap.

Between samples the driver holds the last measured yaw rate (zero-order hold), and the
prediction gives the heading the noise of one sample per step: right while samples come
every few milliseconds, far too little over a gap of a second, when the platform may have
started or stopped a turn. Over a hold of age a the true rate has moved by about
alpha * a (alpha: the platform's yaw acceleration), so the heading is off by about
alpha a^2 / 2, one error for the whole gap, not noise that averages out: its variance is
alpha^2 a^4 / 4. The driver adds the growth of that variance over each prediction to the
heading's (``heading_variance``).

alpha is not a setting: the gyro measures it. Every ``CHECK_S`` seconds the change of the
measured rate since the last check, over the time between them, is one sample of the yaw
acceleration; its mean square over the last ``MEMORY_S`` (an exponential average) is
alpha^2. The gyro's white noise adds 2 sigma^2 / CHECK_S^2 to it: a little more heading
variance than needed over a gap, never less.
"""

from __future__ import annotations

import math

CHECK_S = 0.1
"""Spacing of the rate checks, s: long against the sample period (so the noise adds
little to the acceleration), short against a turn."""

MEMORY_S = 30.0
"""Time constant of the mean square of the yaw acceleration, s: a few turns."""

MIN_AGE_S = 0.02
"""A hold younger than this is an ordinary sample period (the real 2016 log's gyro samples
come every 0.5 ms, the simulator's every 5 ms); its variance is not worth a step's time."""


class HeldRate:
    """The platform's mean-square yaw acceleration, from the gyro; the variance of a hold.

    Attributes:
        acceleration2: alpha^2, (rad/s^2)^2 (0 until the first check).
    """

    __slots__ = ('_check_s', '_check_rate', 'acceleration2', '_weight')

    def __init__(self) -> None:
        """Start with no sample."""
        self._check_s: float | None = None
        self._check_rate = 0.0
        self.acceleration2 = 0.0
        # Weight gathered so far (the average starts unbiased, not from 0).
        self._weight = 0.0

    def save(self) -> tuple:
        """Return what ``restore`` needs."""
        return self._check_s, self._check_rate, self.acceleration2, self._weight

    def restore(self, saved: tuple) -> None:
        """Put back a state returned by ``save``."""
        self._check_s, self._check_rate, self.acceleration2, self._weight = saved

    def sample(self, stamp_s: float, rate_rad_s: float) -> None:
        """Take a gyro sample, rad/s, bias included (the bias cancels in a change)."""
        last = self._check_s
        if last is None:
            self._check_s, self._check_rate = stamp_s, rate_rad_s
            return
        dt = stamp_s - last
        if dt < CHECK_S:
            return
        acceleration = (rate_rad_s - self._check_rate) / dt
        # Exponential average over MEMORY_S; a gap between checks weighs as its length.
        keep = math.exp(-dt / MEMORY_S)
        weight = keep * self._weight + (1.0 - keep)
        self.acceleration2 += (1.0 - keep) / weight * (acceleration * acceleration
                                                       - self.acceleration2)
        self._weight = weight
        self._check_s, self._check_rate = stamp_s, rate_rad_s

    def heading_variance(self, age_from_s: float, age_to_s: float) -> float:
        """Variance (rad^2) the heading gains while a hold ages from one age to another (s)."""
        if age_to_s <= MIN_AGE_S:
            return 0.0
        a0 = max(age_from_s, 0.0)
        return 0.25 * self.acceleration2 * (age_to_s ** 4 - a0 ** 4)
