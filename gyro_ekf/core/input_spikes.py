"""Single samples far from both their neighbours on the odometry or the gyro, left out.

A wheel encoder whose count wraps, a serial link that garbles a field, an IMU that glitches
on a bump: a stream that is otherwise fine sends one sample far from the ones before and
after it. The filter holds each input until the next sample (core/events.py), so one speed
sample 2 m/s off at 100 Hz moves the pose 2 cm at once, eight of its sigmas; the LiDARs
pull it back over the next scans and the run's figures hardly show it: twenty such samples
on a clean 120-s simulated trip gave a NEES share of 0.888, under the 0.9 bound, with the
verdict ok. One gyro sample 1 rad/s off turns the heading 0.3 deg.

A sample is a *suspect* when it lies farther from the value in use than the limit:
``SPIKE_SIGMAS`` standard deviations of a difference of two samples, plus what the platform
can change in the time between them (``max_change_per_s`` times it: a wheeled robot cannot
change its speed by more than its wheels' grip allows). The standard deviation is the
larger of the configured noise's and the one the stream shows: the mean absolute
difference of the samples taken so far, which for white noise is sqrt(2 / pi) of it (an
exponential mean over about ``SPREAD_SAMPLES`` samples). So a gyro noisier than configured
widens its own limit instead of losing its tails (a message's own variance is not looked
at: the spread the stream shows covers it). Nothing is judged before ``WARM_SAMPLES``
differences have been seen.

A suspect is held back for one sample; the value in use stays. The next sample decides:
back within the limit of the value in use and beyond it of the suspect, the suspect was a
spike, and is dropped and counted. Otherwise the change was real (a collision stops the
wheels at once) and the suspect is taken from the next sample on, one interval late: a
step the limit calls impossible costs that interval's share of it. Two or more bad samples
in a row are a change as far as this can tell: only a lone sample is a spike.

The gate also keeps the stream's white noise (``white_sigma``, from its second differences,
which a steady change such as an acceleration leaves untouched): the driver takes the
odometry's as its noise where it is well beyond the stated one (EkfConfig.learn_speed_noise).

The state is a few scalars: ``save`` and ``restore`` (on every event, core/lagged.py) are
O(1). ``admit`` runs at every IMU and odometry sample (89 000 of them in the 2016 log's
run, whose speed is a benchmark goal), so a sample within the limit less its time
allowance, refreshed every ``REFRESH_SAMPLES``, is taken after one comparison and the
spread's update; only the others are judged in full.
"""

from __future__ import annotations

import math
from typing import Any

SPIKE_SIGMAS = 10.0
"""A sample this many standard deviations of a difference away from the value in use is a
suspect. White noise reaches it once in 1e23 samples: only a glitch does."""

SPREAD_SAMPLES = 200
"""Samples the stream's own spread is averaged over (an exponential mean)."""

WARM_SAMPLES = 50
"""Differences seen before any sample is judged."""

REFRESH_SAMPLES = 16
"""Samples taken between two refreshes of the quick limit (the spread moves slowly)."""

_SIXTH_ROOT = math.sqrt(1.0 / 6.0)
"""A second difference of white noise has sqrt(6) times its standard deviation."""

_ABS_TO_SIGMA = math.sqrt(math.pi / 2.0)
"""Mean absolute value of a zero-mean normal variable, over its standard deviation: 1 / this."""


class SpikeGate:
    """One input stream's lone bad samples: held back, judged, dropped (module docstring).

    Attributes:
        spikes: samples dropped as spikes.
        largest: the largest spike, signed, against the value in use (stream units).
        steps: suspects the next sample showed were real changes (taken one interval late).
        last_limit: the limit the last suspect was judged against (stream units).
    """

    __slots__ = ('max_change_per_s', 'spikes', 'largest', 'steps', 'last_limit', '_floor',
                 '_value', '_stamp_s', '_started', '_suspect', '_mean_abs', '_abs_sum',
                 '_seen', '_armed', '_quick', '_countdown', 'white_variance', '_change',
                 '_abs2_sum', '_mean_abs2')

    def __init__(self, sigma: float, max_change_per_s: float) -> None:
        """Judge a stream against its noise and the change its platform can make.

        sigma: the stream's configured noise (standard deviation, stream units).
        max_change_per_s: most the true value can change per second (stream units / s).
        """
        self.max_change_per_s = max_change_per_s
        self.spikes = 0
        self.largest = 0.0
        self.steps = 0
        self.last_limit: float | None = None
        # The least standard deviation of a difference of two samples.
        self._floor = math.sqrt(2.0) * sigma
        self._value = 0.0  # the value in use (none before the first sample: _started)
        self._stamp_s = 0.0  # its stamp
        self._started = False
        self._suspect: float | None = None
        # The mean absolute change of the samples taken (SPREAD_SAMPLES' exponential mean),
        # and the changes taken since it was last updated, summed.
        self._mean_abs = 0.0
        self._abs_sum = 0.0
        self._seen = 0
        # The same of the change of the change (second differences: a steady acceleration
        # leaves none, white noise 6 times its variance), and the last change, signed.
        self._mean_abs2 = 0.0
        self._abs2_sum = 0.0
        self._change = 0.0
        # The white noise's variance the spread shows (white_sigma squared), -1 before it is
        # warm: the odometry's is compared at every sample (events.EventDriver.on_speed).
        self.white_variance = -1.0
        # The limit less its time allowance (inf until WARM_SAMPLES); the quick test's, which
        # is -1 while no sample has come or a suspect waits, so that admit's one comparison
        # sends those to _judge; and the samples to take before the limit is worked out again.
        self._armed = math.inf
        self._quick = -1.0
        self._countdown = 1

    def admit(self, stamp_s: float, value: float) -> float | None:
        """Judge a sample; return the value to use from now on, or None to keep the held one."""
        delta = value - self._value
        change = abs(delta)
        if change <= self._quick:
            # Within the limit whatever the time since the last sample: taken.
            self._abs_sum += change
            self._abs2_sum += abs(delta - self._change)
            self._change = delta
            self._value = value
            self._stamp_s = stamp_s
            self._countdown -= 1
            if not self._countdown:
                self._refresh()
            return value
        return self._judge(stamp_s, value)

    def _refresh(self) -> None:
        """Fold the changes taken since the last refresh into the spread; renew the limit."""
        warm = self._seen >= WARM_SAMPLES
        taken = REFRESH_SAMPLES if warm else 1
        self._seen += taken
        # An exponential mean over SPREAD_SAMPLES samples (a plain mean before that many),
        # updated once per refresh with the mean of its samples.
        weight = taken / min(self._seen, SPREAD_SAMPLES)
        self._mean_abs += weight * (self._abs_sum / taken - self._mean_abs)
        self._mean_abs2 += weight * (self._abs2_sum / taken - self._mean_abs2)
        self._abs_sum = self._abs2_sum = 0.0
        self._armed = self._quick = self._spread() if warm else math.inf
        self._countdown = taken
        self._set_white()

    def _set_white(self) -> None:
        sigma = self.white_sigma()
        self.white_variance = -1.0 if sigma is None else sigma * sigma

    def _spread(self) -> float:
        return SPIKE_SIGMAS * max(self._floor, _ABS_TO_SIGMA * self._mean_abs)

    def white_sigma(self) -> float | None:
        """Return the white noise the stream shows, its own units (None before it is warm).

        From second differences (x[k+1] - 2 x[k] + x[k-1]): their standard deviation over
        sqrt(6) is a white noise's sigma, and a change the platform makes at a steady rate
        (a robot accelerating) leaves none; only its changes of rate add to it.
        """
        if self._seen < WARM_SAMPLES:
            return None
        return _ABS_TO_SIGMA * self._mean_abs2 * _SIXTH_ROOT

    def _judge(self, stamp_s: float, value: float) -> float | None:
        if not self._started:
            self._started = True
            self._value, self._stamp_s, self._quick = value, stamp_s, self._armed
            return value
        held = self._value
        suspect = self._suspect
        if suspect is not None:
            self._suspect = None
            self._quick = self._armed
            limit = self._spread() + self.max_change_per_s * (stamp_s - self._stamp_s)
            if abs(value - held) <= limit < abs(value - suspect):
                self.spikes += 1
                if abs(suspect - held) > abs(self.largest):
                    self.largest = suspect - held
                self.last_limit = limit
                return self._take(stamp_s, value)
            # A real change: the suspect is the value in use from here.
            self.steps += 1
            held = self._value = suspect
        if self._seen >= WARM_SAMPLES:
            limit = self._spread() + self.max_change_per_s * (stamp_s - self._stamp_s)
            if abs(value - held) > limit:
                self._suspect = value
                self._quick = -1.0
                self.last_limit = limit
                return None if suspect is None else held
        return self._take(stamp_s, value)

    def _take(self, stamp_s: float, value: float) -> float:
        delta = value - self._value
        self._abs_sum += abs(delta)
        self._abs2_sum += abs(delta - self._change)
        self._change = delta
        self._value, self._stamp_s = value, stamp_s
        self._countdown -= 1
        if not self._countdown:
            self._refresh()
        return value

    def save(self) -> tuple:
        return (self.spikes, self.largest, self.steps, self.last_limit, self._value,
                self._stamp_s, self._started, self._suspect, self._mean_abs, self._abs_sum,
                self._seen, self._armed, self._quick, self._countdown, self._change,
                self._abs2_sum, self._mean_abs2)

    def restore(self, saved: tuple) -> None:
        (self.spikes, self.largest, self.steps, self.last_limit, self._value, self._stamp_s,
         self._started, self._suspect, self._mean_abs, self._abs_sum, self._seen,
         self._armed, self._quick, self._countdown, self._change, self._abs2_sum,
         self._mean_abs2) = saved
        self._set_white()

    def report(self) -> dict[str, Any]:
        """JSON-ready figures (summary.json ``input_spikes``, /diagnostics, the verdict)."""
        return {'spikes': self.spikes, 'largest': self.largest, 'steps': self.steps,
                'limit': self.last_limit}
