"""The gyro's scale factor, measured against the heading the LiDARs hold, said and applied.

A MEMS gyro reads (1 + e) times the true yaw rate plus its bias, e up to a few per cent.
The filter turns by (w - b) / (1 + e0), e0 the scale in use: the configured
``gyro_scale_error`` (0 unless the user knows better) until one measured here is applied.
It has no state for e: over a turn of angle A its prediction runs (e - e0) A ahead of the
heading, the LiDARs take it back, and the bias watch takes that for a bias that moved. On
50 simulated trips 0.7-3 % off, the final bias ended a median 0.21 deg/s off (up to 1.1),
every run degraded for a bias that changed, none of it naming the scale (docs/stress.md).

What measures it: within each window of ``WINDOW_S`` seconds of driving, the filter's
heading after each scan's updates (held by the LiDARs to a few hundredths of a degree)
against the angle the gyro's raw readings integrate to (bias included)::

    psi(t) = psi_0 + alpha * turned(t) + gamma * t + noise,   alpha = 1 / (1 + e)

with psi_0 and gamma (the bias over 1 + e) free in every window, so a bias that moves
between windows (a step, a ramp, a wander) is not taken for a scale. Only the turn's
variation about a steady rate within a window carries alpha: a steady circle's turn cannot
be told from a bias. Each window gives the residual cross-products of psi and turned after
[1, t], r_pt and r_tt; together they give alpha = sum r_pt / sum r_tt. Its standard error
comes from the scatter of the windows' own alphas (r_pt / r_tt, weighted by r_tt): the
heading's errors are correlated within a window, so a least-squares sigma over its scans
would be far too small.

e = 1 / alpha - 1 is reported once ``MIN_WINDOWS`` informative windows are in, and found
(the run is degraded, with the figure to set ``gyro_scale_error`` to) when it lies farther
than ``MIN_SCALE_DIFFERENCE`` and a threshold of standard errors from the configured one:
``SIGMAS`` from 6 windows on, Student's t for fewer (the scatter of 3 windows has 2
degrees of freedom: 9.9 standard errors at 3 windows, 5.8 at 4, 4.6 at 5, each crossed by
chance 1 % of the time, as 4 is at 6).

**Applied** (``learn``, ``EkfConfig.learn_gyro_scale``): when a window closes and e lies
that far from the scale in use, it becomes the scale in use (``add`` returns True; later
changes need only ``MIN_REFINEMENT``). The windows compare the heading with the gyro's raw
integral, so applying a scale does not change what they measure. The driver then starts
again what the old scale's error drew on (``events.EventDriver._gyro_scale_applied``). A
scale applied by mistake would turn every later turn wrong, and the heading the windows rest
on is held by LiDARs whose mounts and map are taken as right; so it is applied only as
found (the thresholds above, 0.2 %, 3 windows of 20 s at least), and said in the verdict
either way. On 12 simulated 120-s trips 0.5-3 % off it is applied at 60 s on every one
(with 6 windows first, at 120 s, the end of the trip: a 3 % gyro's bias ended 0.26-0.64
deg/s off, now 0.026-0.029). Over exact gyros (30-minute trips, stress suites) the windows
read at most 0.01 %.

The state is a handful of sums and an append-only list of window results, so ``save`` and
``restore`` (on every event, by ``core/lagged.py``) cost O(1).
"""

from __future__ import annotations

import math
from typing import Any

from gyro_ekf.core.angles import wrap_scalar

WINDOW_S = 20.0
"""Length of a window, s: long enough to hold a turn and a straight, short enough that the
bias, free in each window, stays nearly constant within it."""

MIN_WINDOWS = 3
"""Fewest informative windows before the scale is reported: the scatter's 2 degrees of
freedom, made up for by a wider threshold (``_THRESHOLDS``)."""

MIN_TURN_RAD = math.radians(5.0)
"""A window is informative when its turn varied about a steady rate by at least this RMS."""

SIGMAS = 4.0
"""A scale is found beyond this many standard errors from the one configured (with 6 or
more windows; fewer take ``_THRESHOLDS``)."""

# The standard error comes from the windows' own scatter, with m - 1 degrees of freedom,
# so its ratio to the error is Student's t, not normal: a fixed 4 would be crossed by
# chance 6 % of the time at 3 windows. Each m below gets t's two-sided 1 % point, the chance
# of 4 at 6 windows (t 4.03 on 5 degrees of freedom); from 6 on, 4 holds (chance below it).
_THRESHOLDS = {3: 9.925, 4: 5.841, 5: 4.604}

MIN_SCALE_DIFFERENCE = 0.002
"""... and beyond this (0.2 %): what a LiDAR-held heading resolves over a trip's turns."""

MIN_REFINEMENT = 0.0005
"""Once one was applied, a scale beyond SIGMAS standard errors and this (0.05 %) off the one
in use replaces it."""


class GyroScaleWatch:
    """Windows of (heading, turned angle) at scans; the scale they imply (module docstring)."""

    def __init__(self, configured: float = 0.0, learn: bool = False) -> None:
        self.configured = configured
        self.learn = learn
        # The scale the filter turns by: the configured one until a measured one is applied.
        self.in_use = configured
        self.applied = 0
        self.applied_at_s: float | None = None
        self.windows: list[tuple[float, float]] = []  # (r_tt, r_pt) of informative ones
        # The gyro's mean square turn rate over the last window closed, (rad/s)^2.
        self.mean_square_rate = 0.0
        self._reset_window()

    def _reset_window(self) -> None:
        self._start: tuple[float, float] | None = None  # t0, turned0
        self._psi = 0.0  # unwrapped heading since psi0
        self._last_yaw = 0.0
        self._sums = (0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
        self._last = (0.0, 0.0)  # stamp s, turned rad of the last scan
        self._rate_sums = (0.0, 0.0)  # sum of (turn between scans)^2 / dt, sum of dt

    def restart_window(self) -> None:
        """Drop the open window (the filter's heading was reset: not a turn of the gyro's)."""
        self._reset_window()

    def add(self, stamp_s: float, yaw_rad: float, turned_rad: float) -> bool:
        """Add a scan: the heading after its updates and the gyro's integral up to it.

        Returns whether the scale in use changed (``learn``: a window closed and the
        windows place the scale clearly off the one in use).
        """
        changed = False
        if self._start is not None and stamp_s - self._start[0] >= WINDOW_S:
            count = len(self.windows)
            self._close()
            if self.learn and len(self.windows) > count:
                changed = self._apply(stamp_s)
        if self._start is None:
            self._start = (stamp_s, turned_rad)
            self._psi, self._last_yaw = 0.0, yaw_rad
        t0, turned0 = self._start
        self._psi += wrap_scalar(yaw_rad - self._last_yaw)
        self._last_yaw = yaw_rad
        t, p, a = stamp_s - t0, self._psi, turned_rad - turned0
        last_t, last_a = self._last
        if t > last_t:
            squares, span = self._rate_sums
            self._rate_sums = (squares + (a - last_a) ** 2 / (t - last_t), span + t - last_t)
        self._last = (t, a)
        n, st, stt, sp, spt, sa, sat, saa, spa = self._sums
        self._sums = (n + 1, st + t, stt + t * t, sp + p, spt + p * t, sa + a, sat + a * t,
                      saa + a * a, spa + p * a)
        return changed

    def _apply(self, stamp_s: float) -> bool:
        figures = self.estimate()
        if figures is None:
            return False
        scale, sigma = figures
        off = abs(scale - self.in_use)
        least = MIN_REFINEMENT if self.applied else MIN_SCALE_DIFFERENCE
        if not (off > self._sigmas() * sigma and off > least):
            return False
        self.in_use = scale
        self.applied += 1
        if self.applied_at_s is None:
            self.applied_at_s = stamp_s
        return True

    def _close(self) -> None:
        n, st, stt, sp, spt, sa, sat, saa, spa = self._sums
        squares, span = self._rate_sums
        if span > 0.0:
            self.mean_square_rate = squares / span
        self._reset_window()
        if n < 3:
            return
        # Cross-products about the means, then with t's share taken out.
        c_tt = stt - st * st / n
        if c_tt <= 0.0:
            return
        c_at, c_pt = sat - sa * st / n, spt - sp * st / n
        r_tt = (saa - sa * sa / n) - c_at * c_at / c_tt
        r_pt = (spa - sp * sa / n) - c_pt * c_at / c_tt
        if r_tt >= n * MIN_TURN_RAD ** 2:
            self.windows.append((r_tt, r_pt))

    def estimate(self) -> tuple[float, float] | None:
        """Return (e, its standard error) once MIN_WINDOWS windows are in, else None."""
        m = len(self.windows)
        if m < MIN_WINDOWS:
            return None
        total = sum(r_tt for r_tt, _ in self.windows)
        alpha = sum(r_pt for _, r_pt in self.windows) / total
        if not alpha > 0.0:
            return None
        spread = sum((r_tt * (r_pt / r_tt - alpha)) ** 2 for r_tt, r_pt in self.windows)
        sigma_alpha = math.sqrt(spread * m / (m - 1)) / total
        return 1.0 / alpha - 1.0, sigma_alpha / (alpha * alpha)

    def found(self) -> bool:
        """Whether the gyro's scale lies clearly off the one configured."""
        return self._off(self.estimate())

    def _off(self, figures: tuple[float, float] | None) -> bool:
        if figures is None:
            return False
        scale, sigma = figures
        off = abs(scale - self.configured)
        return off > self._sigmas() * sigma and off > MIN_SCALE_DIFFERENCE

    def _sigmas(self) -> float:
        """Return the standard errors a scale must lie off by, for the windows in so far."""
        return _THRESHOLDS.get(len(self.windows), SIGMAS)

    def save(self) -> tuple:
        return (self._start, self._psi, self._last_yaw, self._sums, len(self.windows),
                self.in_use, self.applied, self.applied_at_s, self._last, self._rate_sums,
                self.mean_square_rate)

    def restore(self, saved: tuple) -> None:
        (self._start, self._psi, self._last_yaw, self._sums, count, self.in_use,
         self.applied, self.applied_at_s, self._last, self._rate_sums,
         self.mean_square_rate) = saved
        del self.windows[count:]

    def report(self) -> dict[str, Any]:
        """JSON-ready figures (summary.json gyro_scale, the verdict)."""
        figures = self.estimate()
        return {'configured': self.configured, 'windows': len(self.windows),
                'scale_error': None if figures is None else figures[0],
                'scale_error_sigma': None if figures is None else figures[1],
                'found': self._off(figures), 'in_use': self.in_use,
                'applied': self.applied, 'applied_at_s': self.applied_at_s}
