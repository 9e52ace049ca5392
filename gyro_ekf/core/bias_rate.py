"""Follow a gyro bias that ramps: its rate, fitted outside the state, drives the prediction.

The bias watch (``bias_watch.py``) sees a bias that moves and re-opens it, so the filter
learns it again; but a bias that keeps moving (a gyro warming up: up to 1 deg/s per minute)
is then always behind: the filter catches up on a ramp with a lag of seconds, its final
bias is off by the rate times that lag, and its heading meanwhile drifts more than its
covariance says. Following it takes the rate.

Why outside the state, and not a fifth state b' (b += T b'): the fast kernel
(``_ekf_kernel.py``) covers the report's four states, and a fifth would cost every step of
every trip (the 2016 log's run must stay >= 150x real time), for a rate that is zero but
on a warming gyro; and a rate state with a random walk small enough to stay out of a clean
trip's way learns a ramp as slowly as the bias itself does. A rate is seen much more
directly in what the bias watch already measures: each of its 2-s blocks of driving gives
the bias the filter used during the block plus the bias error that block's yaw corrections
imply (``BiasWatch.block``), an estimate of the true bias m = b + db that does not lag
(scatter about 0.03 deg/s on the simulator). A line fitted to the last ``window_s`` of
those is the rate, with the standard error of its slope from the line's own residuals.
Where that line shows no rate, one through the last ``LONG_WINDOWS`` windows is tried: a
slow ramp's slope lies within the short line's scatter (over 40 s, 20 blocks of 0.03 deg/s
bound a slope to 0.035 deg/s per minute, so 4 of its standard errors miss ramps under 0.14
deg/s per minute, which end a 2-minute trip up to 0.03 deg/s behind), while the long line's
standard error is LONG_WINDOWS^1.5 times smaller. The short line comes first because it
follows a ramp that changes (a gyro warming up slows down).

The rate is used, and only then, when:

- it is significant: |slope| beyond ``T_ON`` standard errors (it stays in use while beyond
  ``T_OFF``), with at least ``MIN_BLOCKS`` blocks in the window;
- the bias watch has seen the heading drift the same way within its walk window (a drift
  whose implied error shares the rate's sign: the bias changed, and in that direction), or
  a rate of that sign was in use within the last ``window_s`` (a rate followed leaves no
  drift to see: when one fit of a slow ramp took two levels for a better fit than the line
  and dropped it, 63 s after the drift that had allowed it, nothing brought it back and
  the bias ended the trip 0.025 deg/s behind);
- the blocks are a ramp, not a step: the line leaves smaller residuals than the best split
  of the window into two constant levels (a bias step, which the watch re-opens once, fits
  two levels; a ramp fits the line).

In use, the prediction moves the bias by T r as a known input (``GyroBiasEkf.bias_rate_found``)
and the rate's uncertainty is added honestly: a rate error e makes the bias error grow as
e t, which the bias variance takes as a random walk of sigma_r^2 ``window_s`` per second
(``walk``: over one window it adds (sigma_r window)^2, what the rate error costs by then).
When the rate comes into use, the bias is opened by the squared distance between the
filter's bias and the line's present value (the lag the filter built up), as the watch
opens it on a drift. Nothing is silent: the watch's drifts that allowed the rate keep the
verdict degraded, and the run's summary reports the rate (``online_bias``).

**A ramp at rest.** Standing still, each gyro sample measures the bias itself (the driver's
zero-rate updates), and the zero-rate updates take the bias as constant over the stop: on
a gyro warming up while the platform waits, the filter's bias is a running mean that lags
the ramp by half the stop, and the heading drifts by that lag. A 20 s static start on a
ramp of 0.2-1 deg/s per minute (the stress suite's ``--static-s 20``) left 14 of 25 such
trips outside the NEES band. The samples of a stop say it directly: their means over blocks
of ``REST_BLOCK_S``, over the stop's last ``window_s``, get the same line (and the same
test for a step) as the blocks of driving; a slope beyond ``REST_T_ON`` standard errors
comes into use with no drift to confirm it (the blocks are the bias, not a heading that
may drift for other reasons), the bias is opened by the lag as above, and the verdict is
degraded (``rate_found``). Once the platform moves, the rate stays until the blocks of
driving are enough for a line (``MIN_BLOCKS``), which then judges it as any rate in use.
"""

from __future__ import annotations

import math

T_ON = 4.0
"""Standard errors of the slope beyond which a rate comes into use (a clean trip's fit lies
beyond them about once in 16 000 fits, and also needs the watch's drift)."""

T_OFF = 2.0
"""Standard errors of the slope below which a rate in use is dropped."""

LONG_WINDOWS = 3.0
"""The long line's window, in windows (120 s by default), tried where the short line shows
no rate: its slope's standard error is 3^1.5 = 5.2 times smaller on the same scatter."""

MIN_BLOCKS = 10
"""Fewest blocks in the window before a line is fitted (20 s of driving)."""

REST_BLOCK_S = 0.5
"""Length of the blocks of a stop's gyro samples whose means the line at rest takes, s (100
samples at 200 Hz: the simulator's means scatter 0.018 deg/s)."""

REST_MIN_BLOCKS = 10
"""Fewest blocks of a stop before a line is fitted at rest (5 s of zero-rate updates)."""

REST_T_ON = 6.0
"""Standard errors of the slope beyond which a rate found at rest comes into use. No drift
confirms it, so the line's own t is the only guard: Student's t with 8 dof lies beyond 6
once in 3000 fits, and 400 simulated 20-s stops of a still gyro found no rate."""


class BiasRate:
    """A line through the last blocks' true-bias estimates; its slope, when it is a ramp.

    Attributes:
        window_s: length of the fit window, s (0: off, never a rate); the long line's is
            LONG_WINDOWS times it.
        rate_rad_s2: the rate in use, rad/s^2 (0 when none).
        sigma_rad_s2: its standard error, rad/s^2 (0 when none).
        found: times a rate came into use.
        largest_rad_s2: the largest rate in use so far (signed), rad/s^2.
    """

    __slots__ = ('window_s', '_blocks', 'rate_rad_s2', 'sigma_rad_s2', 'found',
                 'largest_rad_s2', '_in_use', '_rest', '_rest_open', '_from_rest', '_window_used')

    def __init__(self, window_s: float) -> None:
        """Start with no blocks and no rate."""
        self.window_s = float(window_s)
        # (block middle s, bias estimate b + db rad/s) of the last window_s.
        self._blocks: list[tuple[float, float]] = []
        self.rate_rad_s2 = 0.0
        self.sigma_rad_s2 = 0.0
        self.found = 0
        self.largest_rad_s2 = 0.0
        # (sign, block middle s) of the rate when it was last in use; (0, 0) before one.
        self._in_use = (0.0, 0.0)
        # At rest: (block middle s, mean gyro rate rad/s) of the stop's closed blocks, the
        # open block as [first s, last s, sum of rates, count] (None: none open), and
        # whether the rate in use was found at rest (not yet judged by a line of driving).
        self._rest: list[tuple[float, float]] = []
        self._rest_open: list[float] | None = None
        self._from_rest = False
        self._window_used = self.window_s

    def copy(self) -> 'BiasRate':
        """Return an independent duplicate, for the driver's save and restore."""
        clone = BiasRate(self.window_s)
        clone._blocks = list(self._blocks)
        clone.rate_rad_s2, clone.sigma_rad_s2 = self.rate_rad_s2, self.sigma_rad_s2
        clone.found, clone.largest_rad_s2 = self.found, self.largest_rad_s2
        clone._in_use = self._in_use
        clone._rest = list(self._rest)
        clone._rest_open = None if self._rest_open is None else list(self._rest_open)
        clone._from_rest = self._from_rest
        clone._window_used = self._window_used
        return clone

    @property
    def walk(self) -> float:
        """Variance per second the rate's uncertainty adds to the bias, (rad/s)^2 / s."""
        return self.sigma_rad_s2 * self.sigma_rad_s2 * self._window_used

    def add(self, stamp_s: float, bias_rad_s: float, error_rad_s: float, drift_sign: float,
            bias_now_rad_s: float) -> float | None:
        """Add one judged block of the bias watch; return a variance to open the bias by.

        Args:
            stamp_s: the block's middle, s.
            bias_rad_s: the filter's bias during the block (mean of its ends), rad/s.
            error_rad_s: the bias error the block's yaw corrections imply (db), rad/s.
            drift_sign: sign of the bias watch's last drift within its walk window (0: none).
            bias_now_rad_s: the filter's bias now, rad/s.

        Returns:
            When a rate comes into use: the squared distance of the filter's bias from the
            line's present value, (rad/s)^2, for the bias variance; else None.
        """
        if self.window_s <= 0.0:
            return None
        blocks = self._blocks
        blocks.append((stamp_s, bias_rad_s + error_rad_s))
        long_s = LONG_WINDOWS * self.window_s
        while blocks[0][0] < stamp_s - long_s:
            blocks.pop(0)
        short = [b for b in blocks if b[0] >= stamp_s - self.window_s]
        was = self.rate_rad_s2 != 0.0
        if (was and self._from_rest and len(short) < MIN_BLOCKS
                and stamp_s - self._in_use[1] <= self.window_s):
            # Found at a stop: too few blocks of driving yet to judge it.
            return None
        self._from_rest = False
        # The window's line first (it follows a ramp that changes); the long one where it
        # shows none (a slow ramp's slope lies within the short line's scatter).
        fit = self._judge(short, stamp_s, drift_sign, was) if len(short) >= MIN_BLOCKS else None
        window_s = self.window_s
        if fit is None and len(blocks) > len(short) >= MIN_BLOCKS:
            fit, window_s = self._judge(blocks, stamp_s, drift_sign, was), long_s
            # Not where the window's own line departs from it by as much as a new rate
            # must lie from zero: a ramp that paused or changed (the long line would go
            # on at the old rate).
            line = _fit(short, step=False)
            if fit is not None and abs(line[0] - fit[0]) > T_ON * line[1]:
                fit = None
        if fit is None:
            self.rate_rad_s2 = self.sigma_rad_s2 = 0.0
            return None
        self._window_used = window_s
        return self._use(stamp_s, *fit, bias_now_rad_s, was)

    def _judge(self, blocks: list[tuple[float, float]], stamp_s: float, drift_sign: float,
               was: bool) -> tuple[float, float, float] | None:
        """Return the line through ``blocks`` when its rate is to be used (module), else None."""
        fit = _fit(blocks)
        if fit is None:
            return None
        slope, sigma = fit[0], fit[1]
        t = abs(slope) / sigma if sigma > 0.0 else math.inf
        if was:
            keep = t > T_OFF and math.copysign(1.0, slope) == math.copysign(
                1.0, self.rate_rad_s2)
        else:
            sign, last_s = self._in_use
            if stamp_s - last_s > self.window_s:
                sign = 0.0
            keep = t > T_ON and (drift_sign * slope > 0.0 or sign * slope > 0.0)
        return fit if keep else None

    def add_rest(self, stamp_s: float, rate_rad_s: float, bias_now_rad_s: float
                 ) -> float | None:
        """Add a gyro sample of a stop (a zero-rate update's); return a variance as ``add``.

        Args:
            stamp_s: the sample's stamp, s.
            rate_rad_s: the measured yaw rate, bias included (standing still: the bias and
                noise), rad/s.
            bias_now_rad_s: the filter's bias now, rad/s.
        """
        if self.window_s <= 0.0:
            return None
        block = self._rest_open
        if block is None or stamp_s - block[0] < REST_BLOCK_S:
            if block is None:
                self._rest_open = [stamp_s, stamp_s, rate_rad_s, 1]
            else:
                block[1] = stamp_s
                block[2] += rate_rad_s
                block[3] += 1
            return None
        self._rest_open = [stamp_s, stamp_s, rate_rad_s, 1]
        blocks = self._rest
        blocks.append((0.5 * (block[0] + block[1]), block[2] / block[3]))
        while blocks[0][0] < stamp_s - self.window_s:
            blocks.pop(0)
        if len(blocks) < REST_MIN_BLOCKS:
            return None
        fit = _fit(blocks)
        if fit is None:
            # Two levels fit better: no new rate. One in use stays (on a ramp a chance
            # split of a few noisy blocks wins now and then; dropping and finding it again
            # would open the bias each time), judged by the next line.
            return None
        slope, sigma, level_now = fit
        was = self.rate_rad_s2 != 0.0
        if was and self._from_rest and not (abs(slope) > T_OFF * sigma
                                            and slope * self.rate_rad_s2 > 0.0):
            # The stop's line no longer shows the ramp it found.
            self.rate_rad_s2 = self.sigma_rad_s2 = 0.0
            self._from_rest = False
            return None
        if not abs(slope) > REST_T_ON * sigma:
            return None
        self._from_rest = True
        self._window_used = self.window_s
        return self._use(stamp_s, slope, sigma, level_now, bias_now_rad_s, was)

    def end_rest(self) -> None:
        """Forget the stop's blocks (moving again, or not known to stand still)."""
        self._rest = []
        self._rest_open = None

    def _use(self, stamp_s: float, slope: float, sigma: float, level_now: float,
             bias_now_rad_s: float, was: bool) -> float | None:
        """Put a rate in use; return the lag to open the bias by when it is new."""
        self.rate_rad_s2, self.sigma_rad_s2 = slope, sigma
        self._in_use = (math.copysign(1.0, slope), stamp_s)
        if abs(slope) > abs(self.largest_rad_s2):
            self.largest_rad_s2 = slope
        if was:
            return None
        self.found += 1
        # The line's value at the last block's middle: where the filter's bias should be.
        return (level_now - bias_now_rad_s) ** 2


def _fit(blocks: list[tuple[float, float]], step: bool = True
         ) -> tuple[float, float, float] | None:
    """Least-squares line through (t, m): slope, its standard error and the last level.

    None when two constant levels (the best split of the blocks in time) leave smaller
    residuals than the line: a step, not a ramp (tested unless ``step`` is False).
    """
    n = len(blocks)
    t0 = blocks[0][0]
    ts = [b[0] - t0 for b in blocks]
    ms = [b[1] for b in blocks]
    t_mean = sum(ts) / n
    m_mean = sum(ms) / n
    sxx = sum((t - t_mean) ** 2 for t in ts)
    if sxx <= 0.0:
        return None
    slope = sum((t - t_mean) * (m - m_mean) for t, m in zip(ts, ms)) / sxx
    residuals = [m - m_mean - slope * (t - t_mean) for t, m in zip(ts, ms)]
    rss_line = sum(r * r for r in residuals)
    sigma = math.sqrt(rss_line / (n - 2) / sxx)
    level_now = m_mean + slope * (ts[-1] - t_mean)
    if not step:
        return slope, sigma, level_now
    # Two levels split at every place (running sums: n splits cost O(n)).
    total_sq = sum(m * m for m in ms)
    total = m_mean * n
    left_sum = left_sq = 0.0
    rss_step = math.inf
    for k in range(1, n - 1):
        left_sum += ms[k - 1]
        left_sq += ms[k - 1] ** 2
        if k < 2:
            continue
        right_sum, right_sq = total - left_sum, total_sq - left_sq
        rss = (left_sq - left_sum ** 2 / k) + (right_sq - right_sum ** 2 / (n - k))
        rss_step = min(rss_step, rss)
    if rss_step <= rss_line:
        return None
    return slope, sigma, level_now
