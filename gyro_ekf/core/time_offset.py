"""A LiDAR's stamps against the gyro's: the time offset its headings show, measured and said.

A LaserScan stamped late by d (a driver that stamps the end of the sweep, a LiDAR and an IMU
on clocks that are not synchronised) shows the platform where it was d earlier. The filter
takes each scan at its stamp, so in every turn the LiDAR's heading runs omega d behind the
gyro's (and its position v d behind the odometry's), and the bias takes the difference in.
On simulated trips (docs/stress.md) scans 30 ms late left the final bias up to 0.2 deg/s
off and the NEES share in band at 0.08; 5 ms took it to 0.54-0.64. Every such run was
degraded, but for a bias that changed or a gyro that wanders: nothing named the stamps.

What measures it: each scan with ``MIN_UPDATES`` or more updates gives the LiDAR's own
heading, the filter's heading before the scan less the mean bearing innovation (this
LiDAR's innovations only: another LiDAR, or the filter's own heading error, does not
enter). Against the angle the gyro's raw readings integrate to (bias included), within
each window of ``WINDOW_S`` seconds of driving::

    heading(t) - turned(t) = r0 + beta * t + gamma * t^2 + kappa * turned(t)
                             - d * omega(t) + noise

with r0, beta (the bias), gamma (its ramp) and kappa (a gyro scale error,
``core/gyro_scale.py``) free in every window, so that a bias that moves or a scale that is
off is not taken for an offset; omega is the gyro's rate at the scan less the bias. Without
gamma, two bias_ramp trips of stress seed 85 (1 and 0.5 deg/s per minute) read 4.1 and -3.0
ms, found: their turns come at the same times of their windows, so the ramp's bend leaked
into omega's coefficient; with it, 0.0 and 0.4 ms. Only omega's variation about the
window's fit carries d (entering and leaving turns). Each window gives the residual
cross-products of the heading and omega after [1, t, t^2, turned]; together they give d, and
its standard error comes from the scatter of the windows' own d, weighted by their omega
variation (the heading's errors are correlated within a window, as for the gyro scale).

d is the LiDAR's stamps against the gyro's: which of the two is off, the headings cannot
tell (the 2022 course log reads -3.1 ms, and its scans moved by 3 ms end further from its
ground truth). The offset is reported once ``MIN_WINDOWS`` informative windows are in, and
*found* (the run is degraded, with the figure) when it lies beyond chance (``SIGNIFICANCE``,
``t_limit``) and its heading error matters (``MATERIAL_FACTOR``). Nothing is applied online: the
stamps are the drivers' or the clocks', and which of them is off is the user's to say. The
user corrects the stamps, or sets the figure the verdict gives as the LiDAR's
`lidar.<topic>.time_offset_s` (``MAX_TIME_OFFSET_S`` either way): `gyro-ekf run` (a params
file, ``io.params_file.with_lidar_mounts``) and the EKF node then take each scan at its
stamp less it, and the windows measure what is left (a simulated trip 30 ms late, set to
the 30.5 ms its run read: -0.5 ms left, within the bounds, verdict ok).

Measured (the 120-s simulated trips of the stress suite; the course logs): scans on time
read -1.6 to +0.6 ms (standard errors 0.4-1.0 ms), scans 30 ms late 27.3-31.4 ms, 10 ms
late 7.9-10.4 ms, 50 ms early -50.4 to -53.3 ms; a gyro 2 % off in scale -1.5 to -3.5 ms.
The 2016 real trip reads 7.9 +- 1.8 ms, but at its slow turns (4 deg/s RMS) that is 0.4
times its heading sigma: not found; 2023, -0.6 and +0.4 ms.

The state is the rows of the open window and of the one closed last (about a hundred each)
and an append-only list of window results, so ``save`` and ``restore`` (on every event, by
``core/lagged.py``) cost O(1); a restore reaches back over one window close at most, as the
EKF node's `late_observation_history_s` (5 s at most) is shorter than a window.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from gyro_ekf.core.angles import wrap_scalar

WINDOW_S = 10.0
"""Length of a window, s: long enough to enter or leave a turn, short enough that the bias
and the gyro's slow errors, free in each window, stay near a line within it."""

MIN_WINDOWS = 6
"""Fewest informative windows before the offset is reported (the scatter needs a few)."""

MIN_RATE_RAD_S = math.radians(1.0)
"""A window is informative when its yaw rate varied about the window's fit by at least this
RMS: a steady rate's lag cannot be told from a heading offset."""

SIGNIFICANCE = 1e-3
"""An offset is found when zero lies beyond Student's t at this two-sided chance (one dof
fewer than the windows: their scatter gives the standard error) ..."""

_T_LIMITS = (6.87, 5.96, 5.41, 5.04, 4.78, 4.59, 4.44, 4.32, 4.22, 4.14, 4.07, 4.01, 3.97,
             3.92, 3.88, 3.85, 3.82, 3.79, 3.77, 3.75, 3.73, 3.71, 3.69, 3.67, 3.66, 3.65,
             3.63, 3.62, 3.61, 3.60, 3.59, 3.58, 3.57, 3.57, 3.56, 3.55)
"""Student's t quantiles at 1 - SIGNIFICANCE / 2 for 5 to 40 dof (scipy.stats.t.ppf); more
dof take the last. With 6 windows a fixed 5 standard errors let one simulated trip with a
map 0.5 % too large through at 5.3 (its turns come at the same places of the path)."""

MATERIAL_FACTOR = 2.0
"""... when the heading error it makes, the offset times the RMS yaw rate, is at least this
many times the heading's own sigma (RMS over the same scans): a smaller one leaves the
filter consistent. The 2022 course log reads -3.6 +- 0.4 ms, 0.9 times, NEES share 0.947
(its scans moved 3 ms give 0.892: the gyro's stamps, not the LiDAR's, may be the ones
off); simulated scans 10 ms late read 8-11 ms, found on every trip (NEES share 0.2-0.25),
5 ms late 3.3-5.0 ms, found on one of four (0.54-0.64; two of four before the ramp's term)."""

MAX_TIME_OFFSET_S = 1.0
"""The largest time offset a LiDAR may be configured with either way
(`lidar.<topic>.time_offset_s`): a scan stamped a second off is a clock that is wrong, not
an offset to correct."""

MIN_UPDATES = 2
"""Fewest updates of one scan for its heading: with one pole the bearing innovation
carries the position's error as much as the heading's."""


def t_limit(windows: int) -> float:
    """Return how many standard errors from zero an offset over ``windows`` windows must be."""
    return _T_LIMITS[min(max(windows - 1, 5), 40) - 5]


class TimeOffsetWatch:
    """One LiDAR's windows of (heading - turned, omega) at scans; the offset they imply."""

    def __init__(self) -> None:
        # (r_ww, r_hw, scans, sum of omega^2, sum of the heading's variance) of the
        # informative windows.
        self.windows: list[tuple[float, float, int, float, float]] = []
        # (t, turned, heading - turned, omega, heading variance) rows, the open window's
        # from index _first (absolute: _base rows were trimmed off the front). A 10-s
        # window holds about a hundred, solved once when it closes; the window closed last
        # is kept, so that a restore to before its close (core/lagged.py) finds its rows.
        self._rows: list[tuple[float, float, float, float, float]] = []
        self._base = 0
        self._first = 0
        self._start: tuple[float, float, float] | None = None  # t0, turned0, r0

    def restart_window(self) -> None:
        """Drop the open window (the filter's heading was reset: not the LiDAR's view)."""
        self._start = None
        self._first = self._base + len(self._rows)

    def add(self, stamp_s: float, heading_rad: float, turned_rad: float, rate_rad_s: float,
            heading_variance: float) -> None:
        """Add a scan: the LiDAR's heading, the gyro's raw integral and its rate less the bias.

        heading_variance: the filter's heading variance before the scan, rad^2 (what the
        offset's heading error is weighed against).
        """
        if self._start is not None and stamp_s - self._start[0] >= WINDOW_S:
            self._close()
        relative = heading_rad - turned_rad
        if self._start is None:
            self._start = (stamp_s, turned_rad, relative)
            self._first = self._base + len(self._rows)
        t0, turned0, r0 = self._start
        self._rows.append((stamp_s - t0, turned_rad - turned0, wrap_scalar(relative - r0),
                           rate_rad_s, heading_variance))

    def _close(self) -> None:
        first = self._first - self._base
        rows = np.array(self._rows[first:])
        # Rows before the window just closed are no longer needed by any restore.
        del self._rows[:first]
        self._base += first
        self.restart_window()
        if len(rows) < 6:
            return  # too few scans for a line, a turn and a rate in one window
        t, turned, relative, rate, heading_variance = rows.T
        nuisance = np.column_stack([np.ones_like(t), t, t * t, turned])
        # Heading and rate with the window's line and turn taken out (Frisch-Waugh).
        both = np.column_stack([relative, rate])
        residual = both - nuisance @ np.linalg.lstsq(nuisance, both, rcond=None)[0]
        r_ww = float(residual[:, 1] @ residual[:, 1])
        if r_ww >= len(rows) * MIN_RATE_RAD_S ** 2:
            self.windows.append((r_ww, float(residual[:, 0] @ residual[:, 1]), len(rows),
                                 float(rate @ rate), float(heading_variance.sum())))

    def estimate(self) -> tuple[float, float] | None:
        """Return (d s, its standard error s) once MIN_WINDOWS windows are in, else None.

        d > 0: the scans are stamped late (taken d before their stamps).
        """
        m = len(self.windows)
        if m < MIN_WINDOWS:
            return None
        total = sum(window[0] for window in self.windows)
        slope = sum(window[1] for window in self.windows) / total
        spread = sum((r_ww * (r_hw / r_ww - slope)) ** 2
                     for r_ww, r_hw, *_ in self.windows)
        return -slope, math.sqrt(spread * m / (m - 1)) / total

    def _rms(self) -> tuple[float, float]:
        """RMS yaw rate, rad/s, and RMS heading sigma, rad, over the informative windows."""
        scans = sum(window[2] for window in self.windows)
        return (math.sqrt(sum(window[3] for window in self.windows) / scans),
                math.sqrt(sum(window[4] for window in self.windows) / scans))

    def found(self) -> bool:
        """Whether the LiDAR's stamps lie clearly off the gyro's, by enough to matter."""
        figures = self.estimate()
        if figures is None:
            return False
        offset, sigma = figures
        rate, heading_sigma = self._rms()
        return (abs(offset) > t_limit(len(self.windows)) * sigma
                and abs(offset) * rate > MATERIAL_FACTOR * heading_sigma)

    def save(self) -> tuple:
        return self._start, self._first, self._base + len(self._rows), len(self.windows)

    def restore(self, saved: tuple) -> None:
        self._start, self._first, rows, count = saved
        if rows < self._base:
            raise ValueError('TimeOffsetWatch.restore: the rows of that state were trimmed '
                             '(a restore across two closed windows)')
        del self._rows[rows - self._base:]
        del self.windows[count:]

    def report(self) -> dict[str, Any]:
        """JSON-ready figures (summary.json time_offsets, the verdict)."""
        figures = self.estimate()
        rate, heading_sigma = self._rms() if self.windows else (0.0, 0.0)
        return {'windows': len(self.windows),
                'offset_s': None if figures is None else figures[0],
                'offset_sigma_s': None if figures is None else figures[1],
                'rate_rms_deg_s': math.degrees(rate),
                'heading_sigma_deg': math.degrees(heading_sigma),
                'found': self.found()}
