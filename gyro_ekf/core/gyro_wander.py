"""The gyro's wander, measured from the heading the landmark updates correct.

A MEMS gyro's yaw-rate error is not a constant bias plus white noise alone: part of it
wanders over seconds (a first-order Gauss-Markov process of stationary sigma s and
correlation time tau: coloured noise, the bias instability of a datasheet). A filter that
models only a near-constant bias takes each excursion for a bias that moved: the bias
watch (``core/bias_watch.py``) sees a drift and re-opens the bias, which then follows the
excursion and ends the trip up to 0.04 deg/s off. Modelled as the fifth state c
(``models.py``), the wander is told apart from the bias by its mean reversion; but its size
differs from gyro to gyro, and a wander modelled where there is none makes the heading
less certain than it is. So it is measured, and modelled once it is beyond chance.

What measures it: each block of the bias watch (2 s of landmark updates while driving)
gives db, the error of the bias its yaw corrections imply. Taken against the bias alone
(the corrections plus what the modelled wander took out of the prediction, db_b = db +
integral(c dt) / L), a consistent filter's db_b^2 has the mean the filter allows for:
the bias's variance plus the heading noise its predictions added over the block, over
L^2. A wander adds its block mean's variance, s^2 g(tau, L) with
g = 2 (tau / L)^2 (L / tau - 1 + exp(-L / tau)). Over the blocks so far::

    s^2 = (sum db_b^2 - sum allowed) / sum g

once sum db_b^2 lies beyond what a consistent filter gives but with chance
``SIGNIFICANCE``, after at least ``MIN_BLOCKS`` blocks. There each db_b^2 is its allowed
a_k times a chi-square with 1 dof, and the sum is close to (sum a / nu) times a chi-square
with nu = (sum a)^2 / sum a^2 dof (Satterthwaite: the same mean and variance). Before
that, and on a gyro without wander, nothing is modelled. Blocks that are a drift of their
own, and blocks while the watch makes the bias a random walk (a step or ramp being
learnt), are left out: theirs is a bias that moved, not a wander; so are blocks over an
IMU gap and the block after one (the driver's choice, ``core/events.py``: the held rate's
heading error, not the gyro's). When the rate fit finds a ramp, the last
``RETRACTED_BLOCKS`` blocks are taken back (``retract``): a ramp's first blocks lean its
way by less than the watch's limits until it is found. So they are when the modelled
wander holds one sign (``held``, the driver's re-opening): a step taken for a wander.

What a block's corrections take back includes the heading error it started with
(``block_allowed``). Over a block the corrections sum to C = e_start + d - e_end (d the
gyro's heading error over it, bias included); for a consistent filter the end's error is
orthogonal to the estimate, so Var(C) = P_yaw(start) + Var(d) - P_yaw(end). While the
heading is held steadily the two ends' variances are about equal and the allowed is the
bias's variance and the predictions' heading noise over L^2, as above. When the heading
was uncertain at the start and a second pole comes into view, P_yaw(start) - P_yaw(end) is
corrected too and is allowed for. On the real 2016 trip one such block (at 94 s, after
18 s with a single pole in view: the heading sigma 0.44 deg at its start and 0.15 deg at
its end, its corrections 0.8 deg, 5.6 of the sigmas allowed without this) tipped the sums
into a wander of 0.0735 deg/s; allowed for, it is 1.9 sigmas and no wander is found. A
heading that grew less certain over a block (P_yaw(end) above the start) takes nothing
off the allowed: with one pole in view the corrections that are left share one
geometry's error, and a smaller allowed would read it as a wander.

**A prior wander, ruled out by the same sums.** The bias learnt before a wander can be
found (20 s of driving at least, 28-116 s on the simulator's wanders) takes the wander's
excursions in as bias, most of all at a static start, where the zero-rate updates see
b + c as b; the sigma it then reports does not say so. So the driver models a prior wander
(``gyro_wander_prior_rad_s``) from the first sample, and drops it once the blocks bound
the wander below it: with the sums above, the wander's upper bound at ``PRIOR_CONFIDENCE``
is ``s_up^2 = (nu sum db_b^2 / q - sum allowed) / sum g``, q the chi-square quantile with
nu dof and lower tail 1 - ``PRIOR_CONFIDENCE`` (``upper_sigma``). A wander found beyond
chance is modelled as before, whatever became of the prior. The blocks' evidence is the
same with and without the prior modelled: db_b is taken against the bias alone. A stop's
gyro samples may show a wander themselves (``core/stop_wander.py``): the largest so far is a
second prior (``seen_at_stop``), ruled out by the same bound.

On the simulator's trips (docs/stress.md): clean trips never reach the limit (their
db_b^2 / allowed over a trip: 0.6-1.2); trips with a wander of 0.01-0.04 deg/s and 0.5-5 s
read 0.6-1.5 times their true sigma, 28-116 s into the trip.

**A wander that holds one sign is a bias that moved** (``held``). A bias step too small
for one block of the bias watch to show (0.04-0.07 deg/s) can make the blocks' db_b
large before the watch's runs call it a drift: the wander is then found, of about the
step's size, and the modelled wander c takes the step in. c is held off zero by the
landmark updates scan after scan, while b, known to thousandths of a deg/s, hardly moves:
the trip ends with b 0.02-0.05 deg/s off, the step in c (stress seed 18 bias_step 5). A
wander reverts over tau; what the filter's c takes out of the predictions, averaged over
each block (the driver's integral of c over the block, over its length), then changes sign
from block to block. Over ``HELD_BLOCKS`` blocks (20 s: ten taus at the default tau of
2 s) those means are judged as the bias watch judges a slow drift: their mean, against
their own scatter, beyond the watch's Student's t (``T_LIMIT``) widened for the correlation a
wander of the modelled tau leaves from one block to the next (AR(1), rho = exp(-L /
tau): times sqrt((1 + rho) / (1 - rho))), and beyond three sigmas of the bias's own. Then
the mean is a bias error, taken as a drift of the bias watch's own (``BiasWatch.found``):
the bias is opened by its square, the filter moves the step from c to b over the next
blocks, and the watch's walk and a ramp's line count it (opened behind the watch's back,
a ramp the wander had taken in was never found: stress seed 18 bias_ramp 12 ended 0.099
deg/s off). The evidence the wander was found on stays (taking it back cost two coloured
trips of seeds 0-4 their final bias: there the wander was real). A real wander at or under
the modelled tau seldom holds (``test_gyro_wander.py``: 10 windows in 100 trips at tau);
one slower than modelled does more often (52 at 5 s), each time a wander-sized opening.
"""

from __future__ import annotations

import math

from gyro_ekf.core.bias_watch import NOISE_BLOCKS, T_LIMIT
from gyro_ekf.core.health import chi_square_upper

MIN_BLOCKS = 10
"""Fewest blocks (20 s of driving) before a wander may be found."""

RETRACTED_BLOCKS = 10
"""Blocks taken back when a ramp is found or the wander holds one sign: the bias watch's
window (bias_watch.NOISE_BLOCKS)."""

SIGNIFICANCE = 1e-4
"""Chance that the blocks of a consistent filter are taken for a wander, at each look."""

PRIOR_CONFIDENCE = 0.9
"""Confidence of the upper bound below which a prior wander is ruled out."""

HELD_BLOCKS = NOISE_BLOCKS
"""Blocks (20 s of driving) over which the modelled wander's block means are judged: the
bias watch's slow-drift window, judged with its Student's t (``bias_watch.T_LIMIT``)."""


def block_allowed(length_s: float, bias_variance_rad2_s2: float, heading_noise_rad2: float,
                  start_yaw_variance_rad2: float, end_yaw_variance_rad2: float) -> float:
    """Return what a consistent filter allows a block's db_b^2, (rad/s)^2 (module docstring).

    Args:
        length_s: L, s.
        bias_variance_rad2_s2: the bias's variance, (rad/s)^2.
        heading_noise_rad2: the heading noise the block's predictions added, rad^2.
        start_yaw_variance_rad2: the heading's variance where the block started, rad^2.
        end_yaw_variance_rad2: the heading's variance where it closed, rad^2.
    """
    taken_back = max(0.0, start_yaw_variance_rad2 - end_yaw_variance_rad2)
    return bias_variance_rad2_s2 + (heading_noise_rad2 + taken_back) / (length_s * length_s)


def block_mean_share(length_s: float, tau_s: float) -> float:
    """g: the variance of a unit Gauss-Markov process's mean over length_s seconds."""
    ratio = length_s / tau_s
    return 2.0 * (math.exp(-ratio) - 1.0 + ratio) / (ratio * ratio)


class GyroWander:
    """The blocks' evidence of a wander, and its sigma once found.

    Attributes:
        sigma_rad_s: the wander's stationary sigma found, rad/s (0: none found yet).
        found_at_s: stamp of the block that first found it, s (None: not found).
        prior_ruled_out_s: stamp of the block that ruled a prior wander out, s (None: not
            ruled out, or none judged: ``rule_out``).
        blocks: blocks taken so far.
    """

    __slots__ = ('tau_s', 'sigma_rad_s', 'found_at_s', 'prior_ruled_out_s', 'blocks',
                 'stop_sigma_rad_s', 'stop_seen_s', 'stop_ruled_out_s',
                 '_error_sq', '_allowed', '_allowed_sq', '_share', '_recent', '_held')

    def __init__(self, tau_s: float) -> None:
        """Start with no block; tau_s: the wander's correlation time, s."""
        self.tau_s = tau_s
        self.sigma_rad_s = 0.0
        self.found_at_s: float | None = None
        self.prior_ruled_out_s: float | None = None
        # The largest wander a stop showed (core/stop_wander.py), when, and when the
        # blocks ruled it out.
        self.stop_sigma_rad_s = 0.0
        self.stop_seen_s: float | None = None
        self.stop_ruled_out_s: float | None = None
        self.blocks = 0
        self._error_sq = self._allowed = self._allowed_sq = self._share = 0.0
        # The last blocks' terms (error^2, allowed, share), for retract().
        self._recent: list[tuple[float, float, float]] = []
        # (length s, mean of the modelled wander rad/s) of the last blocks, for held().
        self._held: list[tuple[float, float]] = []

    def copy(self) -> 'GyroWander':
        """Return an independent duplicate, for the driver's save and restore."""
        clone = GyroWander(self.tau_s)
        clone.sigma_rad_s, clone.found_at_s, clone.prior_ruled_out_s, clone.blocks = (
            self.sigma_rad_s, self.found_at_s, self.prior_ruled_out_s, self.blocks)
        clone.stop_sigma_rad_s, clone.stop_seen_s, clone.stop_ruled_out_s = (
            self.stop_sigma_rad_s, self.stop_seen_s, self.stop_ruled_out_s)
        clone._error_sq, clone._allowed, clone._allowed_sq, clone._share = (
            self._error_sq, self._allowed, self._allowed_sq, self._share)
        clone._recent = list(self._recent)
        clone._held = list(self._held)
        return clone

    def add_block(self, stamp_s: float, length_s: float, bias_error_rad_s: float,
                  allowed_rad2_s2: float) -> None:
        """Take one judged block of the bias watch (no drift, no walk).

        Args:
            stamp_s: when it closed, s.
            length_s: L, s.
            bias_error_rad_s: db_b, the bias error its corrections imply against the bias
                alone (the modelled wander's share of the prediction added back), rad/s.
            allowed_rad2_s2: what a consistent filter allows db_b^2 (``block_allowed``),
                (rad/s)^2.
        """
        if not (length_s > 0.0 and allowed_rad2_s2 > 0.0
                and math.isfinite(bias_error_rad_s)):
            return
        share = block_mean_share(length_s, self.tau_s)
        error_sq = bias_error_rad_s * bias_error_rad_s
        self._recent.append((error_sq, allowed_rad2_s2, share))
        if len(self._recent) > RETRACTED_BLOCKS:
            self._recent.pop(0)
        self._add(error_sq, allowed_rad2_s2, share, 1)
        self._judge(stamp_s)

    def retract(self, stamp_s: float) -> None:
        """Take back the last blocks: the bias watch found a drift in them (a bias that moved)."""
        for error_sq, allowed, share in self._recent:
            self._add(-error_sq, -allowed, -share, -1)
        self._recent.clear()
        self._judge(stamp_s, retracted=True)

    def held(self, length_s: float, wander_mean_rad_s: float, bias_variance_rad2_s2: float
             ) -> float | None:
        """Take one block's mean of the modelled wander; return the bias error on a held sign.

        Args:
            length_s: the block's length L, s.
            wander_mean_rad_s: the modelled wander's integral over the block, over L, rad/s.
            bias_variance_rad2_s2: P_bb now, (rad/s)^2.

        Returns:
            The last ``HELD_BLOCKS`` means' mean when they hold one sign (module docstring:
            the bias error, b too small by it, rad/s), else None.
        """
        held = self._held
        held.append((length_s, wander_mean_rad_s))
        if len(held) > HELD_BLOCKS:
            held.pop(0)
        if len(held) < HELD_BLOCKS:
            return None
        n = len(held)
        mean = sum(m for _, m in held) / n
        spread = math.sqrt(sum((m - mean) ** 2 for _, m in held) / (n - 1))
        rho = math.exp(-sum(length for length, _ in held) / n / self.tau_s)
        limit = T_LIMIT * math.sqrt((1.0 + rho) / (1.0 - rho))
        if (abs(mean) > limit * spread / math.sqrt(n)
                and mean * mean > 9.0 * bias_variance_rad2_s2):
            held.clear()
            return mean
        return None

    def clear_held(self) -> None:
        """Forget the held() blocks (the bias was opened: c and b share the error anew)."""
        self._held.clear()

    def upper_sigma(self, confidence: float = PRIOR_CONFIDENCE) -> float | None:
        """Return the wander's upper bound at ``confidence``, rad/s (None: too few blocks).

        From the blocks so far (module docstring): 0 when their sum of squares is smaller
        than a consistent filter with no wander gives but with chance 1 - ``confidence``.
        """
        if self.blocks < MIN_BLOCKS or self._share <= 0.0:
            return None
        dof = self._allowed * self._allowed / self._allowed_sq
        lower = chi_square_upper(confidence, dof)
        variance = (dof * self._error_sq / lower - self._allowed) / self._share
        return math.sqrt(max(variance, 0.0))

    def rule_out(self, stamp_s: float, prior_rad_s: float) -> bool:
        """Whether a prior wander of ``prior_rad_s`` is ruled out (for good, once it is).

        A wander a stop showed (``seen_at_stop``) is ruled out by the same bound.
        """
        checks = ((self.prior_ruled_out_s is None and prior_rad_s > 0.0)
                  or (self.stop_ruled_out_s is None and self.stop_sigma_rad_s > 0.0))
        upper = self.upper_sigma() if checks else None
        if upper is not None:
            if self.prior_ruled_out_s is None and upper < prior_rad_s:
                self.prior_ruled_out_s = stamp_s
            if self.stop_ruled_out_s is None and upper < self.stop_sigma_rad_s:
                self.stop_ruled_out_s = stamp_s
        return self.prior_ruled_out_s is not None

    def seen_at_stop(self, stamp_s: float, sigma_rad_s: float) -> None:
        """Take the wander a stop's samples showed (core/stop_wander.py), rad/s, as a prior.

        The largest so far counts; a larger one is judged again by the blocks of driving.
        """
        if sigma_rad_s > self.stop_sigma_rad_s:
            self.stop_sigma_rad_s = sigma_rad_s
            self.stop_seen_s = stamp_s
            self.stop_ruled_out_s = None

    def prior_rad_s(self, configured_rad_s: float) -> float:
        """Return the prior wander in force: the configured one and a stop's, not ruled out."""
        configured = configured_rad_s if self.prior_ruled_out_s is None else 0.0
        stop = self.stop_sigma_rad_s if self.stop_ruled_out_s is None else 0.0
        return max(configured, stop)

    def _add(self, error_sq: float, allowed: float, share: float, count: int) -> None:
        self.blocks += count
        self._error_sq += error_sq
        self._allowed += allowed
        self._allowed_sq += allowed * allowed
        self._share += share

    def _judge(self, stamp_s: float, retracted: bool = False) -> None:
        """Find the wander from the blocks taken so far (kept until a drift takes it back)."""
        beyond = False
        if self.blocks >= MIN_BLOCKS:
            dof = self._allowed * self._allowed / self._allowed_sq
            beyond = self._error_sq > self._allowed / dof * chi_square_upper(SIGNIFICANCE, dof)
        if beyond:
            self.sigma_rad_s = math.sqrt((self._error_sq - self._allowed) / self._share)
            if self.found_at_s is None:
                self.found_at_s = stamp_s
        elif retracted:
            # What the drift took back leaves no wander beyond chance.
            self.sigma_rad_s = 0.0
            self.found_at_s = None
