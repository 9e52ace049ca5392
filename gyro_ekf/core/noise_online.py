"""Each LiDAR's range and bearing noise, measured from its own innovations (pure Python).

A detected pole's noise is not a figure of the sensor alone: it depends on the beam
spacing, the pole's size and range and the detector that averages the pole's beams (the
simulator's 1.5 cm per-beam noise gives poles placed to 0.7 cm at 2 m and 1.8 cm at
15 m). A configured figure that is too large makes the filter conservative (its pose NEES
falls below the band), one too small makes it overconfident. So the filter measures it.

Covariance matching (Mehra 1972): an update's innovation y has covariance
S = H P H^T + R_map + R, so ``y y^T - (S - R)`` is a sample of R whose mean is R when P
is right. Each LiDAR keeps the mean of those samples' diagonal (range, bearing) over its
last ``window`` updates (an exponential mean) and reports it. With ``limit`` above 1, once
it has ``min_updates`` of them, the LiDAR's updates and association use that mean instead of
the configured figure, within ``[1/limit, limit]`` times the configured variance (a filter
gone wrong must not talk itself into a near-zero R). The default limit is 1 (reported
only): the simulator's detection errors change slowly from scan to scan, and with the
measured figure in use clean trips failed the whiteness test (config.py says more). Only
updates at the LiDAR's plain R count (not a repeated look at rest, whose error repeats, nor
a mount on probation, whose R is inflated).
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ['NoiseMatch']

REFRESH_UPDATES = 20
"""Updates between two refreshes of the figures in use."""


class NoiseMatch:
    """The range and bearing noise variances of one LiDAR, from its innovations.

    Attributes:
        variances: range (m^2) and bearing (rad^2) noise variances to use now.
        R: the same as a diagonal 2x2 matrix (association takes R).
        updates: updates taken so far (those left out while settling not counted).
    """

    def __init__(self, range_var: float, bearing_var: float, window: int,
                 min_updates: int, limit: float) -> None:
        """Start from the configured variances (m^2, rad^2).

        Args:
            range_var: configured range noise variance, m^2.
            bearing_var: configured bearing noise variance, rad^2.
            window: updates the exponential mean spans (> 0).
            min_updates: updates before the measured figures are used.
            limit: the measured variances stay within [1/limit, limit] times the
                configured ones (>= 1).
        """
        self.configured = (range_var, bearing_var)
        self.window, self.min_updates, self.limit = window, min_updates, limit
        self.updates = 0
        self._mean = [range_var, bearing_var]
        self._refresh()

    def add(self, y: tuple[float, float], s: tuple[float, float, float],
            used: tuple[float, float]) -> None:
        """Take one update: innovation y, its S as (s_rr, s_rb, s_bb), the sensor R it used.

        An update whose S is mostly the pose's uncertainty (S more than twice R: the filter
        is still settling) says little about R and much about whether P is right, so
        it is left out.
        """
        range_used, bearing_used = used
        if s[0] > 2.0 * range_used or s[2] > 2.0 * bearing_used:
            return
        # Unrolled: this runs at every landmark update.
        n = self.updates = self.updates + 1
        weight = 1.0 / (n if n < self.window else self.window)
        mean = self._mean
        mean[0] += weight * (y[0] * y[0] - s[0] + range_used - mean[0])
        mean[1] += weight * (y[1] * y[1] - s[2] + bearing_used - mean[1])
        if self.limit > 1.0 and (n % REFRESH_UPDATES == 0 or n == self.min_updates):
            self._refresh()

    def _refresh(self) -> None:
        # The mean over ~window updates moves slowly: the figures in use are taken from it
        # every REFRESH_UPDATES updates, not at every scan (the run's hot path).
        if self.in_use:
            self.variances = tuple(min(max(mean, c / self.limit), c * self.limit)
                                   for mean, c in zip(self._mean, self.configured))
        else:
            self.variances = self.configured
        self.R = np.diag(self.variances)

    @property
    def in_use(self) -> bool:
        """Whether the measured figures are used (with limit 1 they are only reported)."""
        return self.updates >= self.min_updates and self.limit > 1.0

    def report(self) -> dict:
        """Return the sigmas measured, in use and configured, and the updates they rest on.

        A measured sigma is None while the mean of its samples is not positive (P too large
        for the innovations: nothing to say about R).
        """
        (range_var, bearing_var), (range_cfg, bearing_cfg) = self.variances, self.configured
        measured_range, measured_bearing = (math.sqrt(mean) if mean > 0.0 else None
                                            for mean in self._mean)
        return {'measured_range_sigma_m': measured_range,
                'measured_bearing_sigma_deg': (None if measured_bearing is None
                                               else math.degrees(measured_bearing)),
                'range_sigma_m': math.sqrt(range_var),
                'bearing_sigma_deg': math.degrees(math.sqrt(bearing_var)),
                'configured_range_sigma_m': math.sqrt(range_cfg),
                'configured_bearing_sigma_deg': math.degrees(math.sqrt(bearing_cfg)),
                'updates': self.updates, 'in_use': self.in_use}

    def save(self) -> tuple:
        """Return everything ``restore`` needs."""
        return self.updates, tuple(self._mean)

    def restore(self, saved: tuple) -> None:
        """Put the estimate back as ``save`` found it."""
        self.updates, mean = saved
        self._mean = list(mean)
        self._refresh()
