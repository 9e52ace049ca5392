"""A LiDAR's stamps that scatter about the time its scans were taken: measured and said.

A driver that stamps each scan when it arrives on the host, not when it was taken, gives
stamps off by a few milliseconds that change from scan to scan. The filter predicts to the
stamp, so every pole of a scan is seen from where the platform was a little earlier or
later: in a turn at 0.5 rad/s, 10 ms is 5 mrad of bearing, three times the bearing noise,
the same for every pole of the scan. Nothing in R covers it, and the filter is
overconfident in turns. On clean simulated trips with the scans' stamps scattered by 10 ms
(standard deviation) the NEES share in band fell 0.94 -> 0.76-0.79, and the verdict blamed
the gyro ("the gyro wanders"); by 5 ms, 0.88-0.905, some of them with the verdict ok.

What measures it: a scan taken delta before its stamp shows each pole where it was delta
earlier, so its offset from where the filter predicts it, e = p_measured - p_predicted
(sensor frame, against the filter's pose before the scan), is -j delta plus noise, with
j the pole's velocity in the sensor frame as the platform moves (speed v, yaw rate omega
less the bias): -u - omega x p, u the sensor's own velocity. Weighing e's radial and
tangential parts by the range and bearing noise (W: the LiDAR's measured noise, and the
map's), each scan gives

    delta_k = -sum(j^T W e) / g_k,   g_k = sum(j^T W j),
    var(delta_k) = (g_k + b_k^T P b_k) / g_k^2,   b_k = sum((dq/dpose)^T W j)

where the second term is the pose's error before the scan (P, its covariance), which
every pole of the scan shares: left out, it read 2.6 ms of scatter on the 2023 course log,
whose stamps, against its ground truth, scatter by 0.6 ms. Over the scans the stamps'
scatter is the weighted variance of delta_k about their mean less var(delta_k): a method of
moments, weighted by 1 / var(delta_k)^2 (the inverse of each term's variance when there is
no scatter), whose standard error is then sqrt(2 / sum of the weights).
The mean is a constant offset (``core/time_offset.py`` measures that one, from the
headings); only the scatter about it is this. Scans whose delta_k would carry more than
``MAX_SCAN_SIGMA_S`` (a slow platform: the real 2016 trip drives at 0.3 m/s and 4 deg/s)
are left out, as there a stamp error of that size hides in the scan's noise. So are scans
at rest, repeated looks and LiDARs held out, as for the filter's other watches.

It is *found* (the run degraded, with the figure) when it lies beyond ``T_LIMIT`` standard
errors and matters: its variance times the scans' mean g_k, the share it adds to a scan's
error against the noise the filter allows, is at least ``MATERIAL_SHARE``. Measured on
120-s simulated trips: stamps on time read 0-0.4 ms (-1.8 to +0.5 standard errors),
scattered by 3 ms read 2.5-2.7 ms (share 1.06-1.21; NEES share 0.92-0.93), 5 ms 3.5-4.0 ms
(NEES share 0.88-0.905), 10 ms 5.0-5.7 ms: a scan stamped 20 ms off in a turn puts its
poles outside the association gate, so the largest errors are never seen and the figure is
a floor. The 2022 and 2023 course logs read 0.9 and 0 ms, not found. Nothing is applied:
the fix is the driver's (stamp each scan when it is taken, by the LiDAR's own clock where it
has one).

The state is a few sums, so ``save`` and ``restore`` (on every event, by
``core/lagged.py``) cost O(1).
"""

from __future__ import annotations

import math
from typing import Any

MAX_SCAN_SIGMA_S = 0.01
"""A scan whose own stamp estimate is less sure than this is left out, s."""

MIN_SCANS = 100
"""Fewest scans before the scatter is reported."""

T_LIMIT = 6.0
"""Standard errors the scatter's variance must lie above zero to be found (the weights are
those of no scatter, and a filter's P is only as right as its model)."""

MATERIAL_SHARE = 1.0
"""The scatter is found when its variance adds at least this share to a scan's noise
variance (g_k times it, on average): from there the filter's NEES falls visibly."""


class StampJitterWatch:
    """One LiDAR's per-scan stamp estimates and the scatter they show (module docstring)."""

    __slots__ = ('scans', '_a', '_g', '_b', '_w', '_wd', '_wd2', '_sum_noise', '_sum_g')

    def __init__(self) -> None:
        self.scans = 0
        # The open scan's sums: j^T W e, j^T W j and (dq/dpose)^T W j over (x, y, yaw).
        self._a = self._g = 0.0
        self._b = [0.0, 0.0, 0.0]
        # Over the scans taken, with w = 1 / var(delta)^2: sum w, sum w delta,
        # sum w delta^2, sum w var(delta), and sum g.
        self._w = self._wd = self._wd2 = self._sum_noise = self._sum_g = 0.0

    @staticmethod
    def scan_is_informative(updates: int, rate_rad_s: float, speed_m_s: float,
                            range_variance: float, bearing_variance: float) -> bool:
        """Whether a scan of this many updates can tell its stamp within MAX_SCAN_SIGMA_S.

        About: a pole's bearing moves at the yaw rate, its range at up to the speed.
        """
        g = updates * (rate_rad_s * rate_rad_s / bearing_variance
                       + speed_m_s * speed_m_s / range_variance)
        return g * MAX_SCAN_SIGMA_S * MAX_SCAN_SIGMA_S >= 1.0

    def add(self, a: float, g: float, bx: float = 0.0, by: float = 0.0, bt: float = 0.0
            ) -> None:
        """Add one update's j^T W e, j^T W j and (dq/dpose)^T W j to the open scan."""
        self._a += a
        self._g += g
        b = self._b
        b[0] += bx
        b[1] += by
        b[2] += bt

    def close_scan(self, pose_covariance: tuple[float, ...] | None = None,
                   common: float = 0.0) -> None:
        """End the open scan: take its stamp estimate if it is sure enough.

        pose_covariance: P of the pose before the scan (xx, xy, x yaw, yy, y yaw, yaw yaw).
        b^T P b, with b the scan's sum of (dq/dpose)^T W j, is the variance the pose's error
        adds to sum(j^T W e): shared by all the scan's poles, it is not in g (their noise,
        independent). common: a variance to add to it (tests give it directly).
        """
        a, g = self._a, self._g
        bx, by, bt = self._b
        self._a = self._g = 0.0
        self._b = [0.0, 0.0, 0.0]
        if pose_covariance is not None:
            pxx, pxy, pxt, pyy, pyt, ptt = pose_covariance
            common += (bx * (pxx * bx + pxy * by + pxt * bt)
                       + by * (pxy * bx + pyy * by + pyt * bt)
                       + bt * (pxt * bx + pyt * by + ptt * bt))
        if g * MAX_SCAN_SIGMA_S * MAX_SCAN_SIGMA_S < 1.0:
            return
        delta = -a / g
        noise = (g + common) / (g * g)  # delta's variance with no scatter
        w = 1.0 / (noise * noise)
        self.scans += 1
        self._w += w
        self._wd += w * delta
        self._wd2 += w * delta * delta
        self._sum_noise += w * noise
        self._sum_g += g

    def estimate(self) -> tuple[float, float, float] | None:
        """Return (variance s^2, its standard error s^2, share) from MIN_SCANS scans on.

        The variance may come out below zero (no scatter, and chance).
        """
        if self.scans < MIN_SCANS:
            return None
        w = self._w
        variance = (self._wd2 - self._wd * self._wd / w - self._sum_noise) / w
        return variance, math.sqrt(2.0 / w), variance * self._sum_g / self.scans

    def found(self) -> bool:
        """Whether the stamps clearly scatter, by enough to matter."""
        figures = self.estimate()
        if figures is None:
            return False
        variance, sigma, share = figures
        return variance > T_LIMIT * sigma and share >= MATERIAL_SHARE

    def save(self) -> tuple:
        return (self.scans, self._a, self._g, tuple(self._b), self._w, self._wd, self._wd2,
                self._sum_noise, self._sum_g)

    def restore(self, saved: tuple) -> None:
        (self.scans, self._a, self._g, b, self._w, self._wd, self._wd2, self._sum_noise,
         self._sum_g) = saved
        self._b = list(b)

    def report(self) -> dict[str, Any]:
        """JSON-ready figures (summary.json stamp_jitter, /diagnostics, the verdict)."""
        figures = self.estimate()
        if figures is None:
            return {'scans': self.scans, 'jitter_s': None, 'variance_t': None, 'share': None,
                    'found': False}
        variance, sigma, share = figures
        return {'scans': self.scans, 'jitter_s': math.sqrt(max(variance, 0.0)),
                'variance_t': variance / sigma, 'share': share, 'found': self.found()}
