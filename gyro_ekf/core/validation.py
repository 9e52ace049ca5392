"""The one validation boundary: checks of every value that enters the core.

Each check returns None for a good value or a short reason ("not finite", "|w| = 1e300 rad/s
exceeds 35 rad/s") for a bad one, so that the two edges can act on it their own way: offline
readers raise `InvalidInputError` naming file, field and index (or drop and count the sample
with --skip-bad); live nodes drop the message and count the reason in /diagnostics. The
limits are `core.config.InputLimits` (parameters with defaults, SI units).

Array versions return a boolean mask of the bad rows, so a million samples are checked in
one numpy pass.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
import dataclasses
from dataclasses import dataclass, field
import math
from typing import Any

import numpy as np
from numpy.typing import NDArray

from gyro_ekf.core.config import InputLimits
from gyro_ekf.core.errors import InvalidInputError
from gyro_ekf.core.time_offset import MAX_TIME_OFFSET_S
from gyro_ekf.core.types import (FloatArray, GroundTruth, ImuSeries, ScanSeries, SpeedSeries,
                                 Trip)

BoolArray = NDArray[np.bool_]

LIMITS = InputLimits()
"""The default limits."""

_SYMMETRY_TOLERANCE = 1e-9
"""Relative asymmetry of a covariance matrix still taken as rounding."""


def value_problem(value: float, limit: float, unit: str) -> str | None:
    """Why a scalar is not a finite value within +-limit, or None."""
    if not math.isfinite(value):
        return f'{value} is not finite'
    if abs(value) > limit:
        return f'|{value:.6g}| {unit} exceeds the limit {limit:g} {unit}'
    return None


def message_variance(value: float, limit: float) -> tuple[float | None, bool]:
    """Return a message's own variance as the filter takes it, and whether it was bad.

    Positive and at most limit^2 (limit: the value's own plausible range, so a sigma
    beyond it says nothing): used. 0 or -1 mean "not given" (REP-145; -1 also marks a
    field without data): the configured noise, silently. NaN, inf, other negatives or
    above limit^2: the configured noise too, and the caller counts it.
    """
    if 0.0 < value <= limit * limit:
        return value, False
    return None, not (value == 0.0 or value == -1.0)


def message_variances(values: NDArray | None, limit: float
                      ) -> tuple[FloatArray | None, int]:
    """message_variance of a whole series: NaN where not used (None if none is), bad count."""
    if values is None:
        return None, 0
    array = np.asarray(values, dtype=np.float64)
    with np.errstate(invalid='ignore'):
        used = (array > 0.0) & (array <= limit * limit)
        silent = (array == 0.0) | (array == -1.0)
    bad = int((~used & ~silent).sum())
    return (np.where(used, array, np.nan) if used.any() else None), bad


def rate_problem(rate_rad_s: float, limits: InputLimits = LIMITS) -> str | None:
    """Why an angular velocity (one axis, rad/s) is refused, or None."""
    return value_problem(rate_rad_s, limits.max_yaw_rate_rad_s, 'rad/s')


def speed_problem(speed_m_s: float, limits: InputLimits = LIMITS) -> str | None:
    """Why an odometry speed (m/s) is refused, or None."""
    return value_problem(speed_m_s, limits.max_speed_m_s, 'm/s')


def coordinate_problem(values: Sequence[float], limits: InputLimits = LIMITS) -> str | None:
    """Why map-frame coordinates (m) are refused, or None."""
    for value in values:
        problem = value_problem(float(value), limits.max_coordinate_m, 'm')
        if problem:
            return problem
    return None


def bad_values(values: NDArray, limit: float) -> BoolArray:
    """Return the mask of the rows of `values` (shape (n,) or (n, k)) that are bad.

    A row is bad when it holds a non-finite value or one beyond +-limit.
    """
    array = np.asarray(values, dtype=np.float64)
    with np.errstate(invalid='ignore'):
        bad = ~np.isfinite(array) | (np.abs(array) > limit)
    return bad if bad.ndim == 1 else bad.any(axis=tuple(range(1, bad.ndim)))


def quaternion_problem(x: float, y: float, z: float, w: float,
                       limits: InputLimits = LIMITS) -> str | None:
    """Why a quaternion is refused (not finite, or not of unit norm), or None."""
    if not all(math.isfinite(v) for v in (x, y, z, w)):
        return 'quaternion is not finite'
    norm = math.sqrt(x * x + y * y + z * z + w * w)
    if abs(norm - 1.0) > limits.quaternion_norm_tolerance:
        return f'quaternion norm {norm:.6g} is not 1 (within {limits.quaternion_norm_tolerance:g})'
    return None


def covariance_problem(matrix: NDArray) -> str | None:
    """Why a covariance matrix is refused (not finite, asymmetric, negative), or None."""
    m = np.asarray(matrix, dtype=np.float64)
    if m.ndim != 2 or m.shape[0] != m.shape[1]:
        return f'covariance of shape {m.shape} is not square'
    if not np.isfinite(m).all():
        return 'covariance is not finite'
    scale = max(float(np.abs(m).max()), 1e-300)
    if float(np.abs(m - m.T).max()) > _SYMMETRY_TOLERANCE * scale:
        return 'covariance is not symmetric'
    if float(np.linalg.eigvalsh(m).min()) < -_SYMMETRY_TOLERANCE * scale:
        return 'covariance has a negative variance (not positive semi-definite)'
    return None


def scan_geometry_problem(angle_min_rad: float, angle_max_rad: float,
                          angle_increment_rad: float, beam_count: int, range_min_m: float,
                          range_max_m: float) -> str | None:
    """Why a LaserScan's beam geometry is refused, or None.

    The bearings are angle_min + k * angle_increment; they must be finite, advance by a
    non-zero step, span at most one turn, and agree with the number of ranges (REP-117's
    angle_max is the last beam's bearing, so count = (max - min) / increment + 1, within one
    beam for rounding).
    """
    values = (angle_min_rad, angle_max_rad, angle_increment_rad, range_min_m, range_max_m)
    if not all(math.isfinite(v) for v in values):
        return 'beam geometry (angles, range limits) is not finite'
    if angle_increment_rad == 0.0:
        return 'angle_increment is 0'
    if beam_count < 1:
        return 'the scan has no ranges'
    span = angle_increment_rad * (beam_count - 1)
    if abs(span) > 2.0 * math.pi + abs(angle_increment_rad):
        return f'{beam_count} beams of {angle_increment_rad:.6g} rad span more than one turn'
    expected = (angle_max_rad - angle_min_rad) / angle_increment_rad + 1.0
    if abs(expected - beam_count) > 1.0 + 1e-6:
        return (f'{beam_count} ranges, but angle_min/max/increment give {expected:.1f} beams')
    if range_min_m < 0.0 or range_max_m <= range_min_m:
        return f'range limits [{range_min_m}, {range_max_m}] m are not a valid interval'
    return None


def mount_problem(x_m: float, y_m: float, yaw_rad: float,
                  limits: InputLimits = LIMITS) -> str | None:
    """Why a LiDAR mount (m, m, rad) is refused, or None."""
    if not all(math.isfinite(v) for v in (x_m, y_m, yaw_rad)):
        return 'mount is not finite'
    if math.hypot(x_m, y_m) > limits.max_mount_offset_m:
        return (f'mount offset {math.hypot(x_m, y_m):.6g} m exceeds the limit '
                f'{limits.max_mount_offset_m:g} m')
    return angle_problem(yaw_rad, limits)


def time_offset_problem(offset_s: float) -> str | None:
    """Why a LiDAR's configured time offset (s, `lidar.<topic>.time_offset_s`) is refused."""
    return value_problem(offset_s, MAX_TIME_OFFSET_S, 's')


MAX_RANGE_OFFSET_M = 1.0
"""Largest |range offset| a LiDAR may be configured with (`lidar.<topic>.range_offset_m`):
a few centimetres is a LiDAR's calibration; a metre is a mistake."""


def range_offset_problem(offset_m: float) -> str | None:
    """Why a LiDAR's configured range offset (m, `lidar.<topic>.range_offset_m`) is refused."""
    return value_problem(offset_m, MAX_RANGE_OFFSET_M, 'm')


MAX_YAW_SIGMA_RAD = math.radians(15.0)
"""Largest sigma a LiDAR's mount yaw may be stated with (`lidar.<topic>.yaw_sigma_rad`):
as far as calibrate-mounts searches; beyond it the mount is not known at all."""


def yaw_sigma_problem(sigma_rad: float) -> str | None:
    """Why a LiDAR's stated yaw sigma (rad, `lidar.<topic>.yaw_sigma_rad`) is refused."""
    if sigma_rad < 0.0:
        return f'{sigma_rad:g} rad is negative (a sigma)'
    return value_problem(sigma_rad, MAX_YAW_SIGMA_RAD, 'rad')


def angle_problem(angle_rad: float, limits: InputLimits = LIMITS) -> str | None:
    """Why a stated angle (rad; an initial or mount yaw) is refused, or None."""
    return value_problem(angle_rad, limits.max_angle_rad, 'rad')


def initial_pose_problem(x_m: float, y_m: float, yaw_rad: float,
                         limits: InputLimits = LIMITS) -> str | None:
    """Why an initial pose (m, m, rad in map) is refused, or None."""
    problem = coordinate_problem((x_m, y_m), limits)
    if problem:
        return problem
    problem = angle_problem(yaw_rad, limits)
    return None if problem is None else f'yaw {problem}'


DUPLICATE_LANDMARK_M = 1e-3
"""Two map landmarks closer than this are one pole listed twice (m)."""


def duplicate_landmark_problem(xy_m: NDArray) -> str | None:
    """Why a map (k, 2) is refused for listing a pole twice, or None.

    Two landmarks at one place make every detection of that pole ambiguous: association
    leaves it out (a duplicated point took a clean trip from 99.6 to 92 % associated).
    """
    xy = np.asarray(xy_m, dtype=np.float64).reshape(-1, 2)
    if len(xy) < 2:
        return None
    diff = xy[:, None, :] - xy[None, :, :]
    distance = np.hypot(diff[..., 0], diff[..., 1])
    distance[np.tril_indices(len(xy))] = np.inf
    distance[np.isnan(distance)] = np.inf  # a NaN landmark is refused by its own check
    i, j = np.unravel_index(int(np.argmin(distance)), distance.shape)
    if not distance[i, j] < DUPLICATE_LANDMARK_M:
        return None
    return (f'landmarks {i} and {j} are {distance[i, j] * 1e3:.3g} mm apart, at '
            f'({xy[i, 0]:.6g}, {xy[i, 1]:.6g}) m: one pole listed twice (the limit is '
            f'{DUPLICATE_LANDMARK_M * 1e3:g} mm)')


def duration_problem(duration_s: float, limits: InputLimits = LIMITS) -> str | None:
    """Why a stated duration (s, e.g. a static start) is refused, or None."""
    if not math.isfinite(duration_s) or duration_s < 0.0:
        return f'{duration_s} is not a finite non-negative duration'
    if duration_s > limits.max_duration_s:
        return f'{duration_s:.6g} s exceeds the limit {limits.max_duration_s:g} s'
    return None


# --- The offline boundary: a whole Trip, from a course log, a trip file or a bag. ---------

NOT_FINITE = 'not finite'
BEYOND_LIMIT = 'beyond limit'
NEGATIVE = 'negative'
TIME_WENT_BACK = 'time went back'
JUMPED_AHEAD = 'stamp jumped ahead'
SAME_STAMP = 'same stamp as the previous sample, other values'


@dataclass
class InputReport:
    """What the offline boundary found in one trip.

    Attributes:
        source: the file or bag the trip came from.
        skip_bad: whether bad samples were dropped (True) or refused (False).
        dropped: (field, reason) -> number of samples dropped for it; reasons are the short
            keys NOT_FINITE, BEYOND_LIMIT, NEGATIVE, TIME_WENT_BACK, JUMPED_AHEAD,
            SAME_STAMP. A sample is counted once, under the first check it failed.
        first_index: (field, reason) -> index of the first such sample in the source series.
        samples_dropped: stream ('imu', 'speed', 'scan', 'ground_truth') -> samples dropped.
        time_breaks: stream -> how many times its stamps went back (each a segment whose
            older samples were dropped).
        duplicates: stream -> samples dropped as exact repeats of the sample kept before
            them (same stamp, same values: a sample recorded twice), with or without
            skip_bad, as the bag reader drops a message recorded twice; no bad sample, so
            not in `dropped` or `samples_dropped` (summary.json `duplicates_dropped`).
        duplicate_first_index: stream -> index of the first such repeat in the source series.
        gaps: forward jumps beyond the limit that a stream stays after (a sensor silent for
            a while); kept, since the other streams carry the filter through them, and
            flagged: one text per gap.
        covariances_used: field -> samples whose own variance replaces the configured
            noise (imu.angular_velocity_covariance[8], speed.twist.covariance[0]).
        covariances_ignored: field -> samples whose variance was NaN, negative or beyond
            its limit: the configured noise is used for them (the sample itself is kept).
        converted: for a bag that `gyro-ekf convert --skip-bad` wrote, what that conversion
            dropped from the log (its source, dropped, first_index, samples_dropped and
            time_breaks; indexes in the log's series), as the bag's params sidecar records
            it; None otherwise. Those samples are not in the bag, so this check cannot see
            them again.
    """

    source: str
    skip_bad: bool = False
    dropped: dict[tuple[str, str], int] = field(default_factory=dict)
    first_index: dict[tuple[str, str], int] = field(default_factory=dict)
    samples_dropped: dict[str, int] = field(default_factory=dict)
    time_breaks: dict[str, int] = field(default_factory=dict)
    duplicates: dict[str, int] = field(default_factory=dict)
    duplicate_first_index: dict[str, int] = field(default_factory=dict)
    gaps: list[str] = field(default_factory=list)
    covariances_used: dict[str, int] = field(default_factory=dict)
    covariances_ignored: dict[str, int] = field(default_factory=dict)
    converted: InputReport | None = None

    @property
    def total_dropped(self) -> int:
        """Samples dropped over all streams."""
        return sum(self.samples_dropped.values())

    def dropped_text(self, indexes: bool = False) -> str:
        """Return 'dropped N samples: n field (reason), ...', with first indexes if asked."""
        parts = ', '.join(
            f'{n} {field_name} ({reason}' + (
                f', first at index {self.first_index[(field_name, reason)]}' if indexes
                else '') + ')'
            for (field_name, reason), n in self.dropped.items())
        return f'dropped {self.total_dropped} samples: {parts}'

    def count(self, field_name: str, reason: str, first: int, n: int) -> None:
        """Record n dropped samples of one field for one reason."""
        key = (field_name, reason)
        self.dropped[key] = self.dropped.get(key, 0) + n
        self.first_index.setdefault(key, first)

    def warning(self) -> str | None:
        """One line for the user when anything was dropped or flagged, else None."""
        lines = []
        if self.converted is not None and self.converted.total_dropped:
            lines.append(f'when {self.converted.source} was converted, --skip-bad '
                         + self.converted.dropped_text())
        if self.dropped:
            lines.append('--skip-bad ' + self.dropped_text())
        if self.duplicates:
            parts = ', '.join(f'{n} {stream} (first at index '
                              f'{self.duplicate_first_index[stream]})'
                              for stream, n in self.duplicates.items())
            lines.append(f'dropped {sum(self.duplicates.values())} exact repeat(s) of the '
                         f'sample before (same stamp and values, kept once): {parts}')
        if self.gaps:
            lines.append(f'{len(self.gaps)} long gap(s) in a stream: {"; ".join(self.gaps)}')
        if self.covariances_ignored:
            parts = ', '.join(f'{n} {name}' for name, n in self.covariances_ignored.items())
            lines.append(f'ignored bad message covariances ({parts}): NaN, negative or '
                         'beyond the limit; the configured noise is used for those samples')
        return f'{self.source}: ' + '; '.join(lines) if lines else None

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready view (the `input` section of summary.json).

        `duplicates_dropped` (stream -> exact repeats dropped) is there only when any were,
        as `gyro-ekf run` adds the bag reader's (topic -> messages recorded twice).
        """
        return {
            'source': self.source, 'skip_bad': self.skip_bad,
            'samples_dropped_total': self.total_dropped,
            'samples_dropped': dict(self.samples_dropped),
            'dropped': [{'field': f, 'reason': r, 'count': n,
                         'first_index': self.first_index[(f, r)]}
                        for (f, r), n in self.dropped.items()],
            'time_breaks': dict(self.time_breaks), 'gaps': list(self.gaps),
            'covariances_used': dict(self.covariances_used),
            'covariances_ignored': dict(self.covariances_ignored),
            'dropped_when_converted': None if self.converted is None else {
                'source': self.converted.source,
                'samples_dropped_total': self.converted.total_dropped,
                'samples_dropped': dict(self.converted.samples_dropped),
                'dropped': [{'field': f, 'reason': r, 'count': n,
                             'first_index': self.converted.first_index[(f, r)]}
                            for (f, r), n in self.converted.dropped.items()],
                'time_breaks': dict(self.converted.time_breaks)},
            **({'duplicates_dropped': dict(self.duplicates)} if self.duplicates else {})}


MANY_BEYOND = 10
"""Samples beyond a limit that, with ``MANY_BEYOND_SHARE`` of the series, read as a series
in other units rather than corrupt samples (the error says so)."""

MANY_BEYOND_SHARE = 0.01

UNITS_SHARE = 0.1
"""Share of a series beyond its limit that is refused even with skip_bad."""


def many_beyond(count: int, total: int) -> bool:
    """Whether ``count`` of ``total`` samples beyond a limit read as a series in other units."""
    return count >= max(MANY_BEYOND, MANY_BEYOND_SHARE * total)


def units_hint(count: int, of: str, largest: float, unit: str, setting: str = '') -> str:
    """Return what to add to a limit's problem once many samples are beyond it (many_beyond).

    of: what count is a share of ("of its 12001 samples"); setting: the limit's parameter.
    """
    limit_name = f' ({setting})' if setting else ''
    return (f'{limit_name}, and so do {count} {of}, up to {largest:.4g} {unit}: not a few '
            f'corrupt samples but the series in other units than {unit} (REP-103: SI '
            'units), or a limit too low for this platform')


class _Stream:
    """The checks of one series: a keep mask that bad rows leave, or the first error."""

    def __init__(self, name: str, stamps: NDArray, source: str, limits: InputLimits,
                 report: InputReport):
        self.name = name
        self.stamps = np.asarray(stamps, dtype=np.float64)
        self.keep = np.ones(self.stamps.shape[0], dtype=bool)
        self.source = source
        self.limits = limits
        self.report = report
        # (field, per-sample values) that tell two samples with one stamp apart.
        self.compared: list[tuple[str, NDArray]] = []
        self.repeats = 0

    def compare(self, field_name: str, values: NDArray | None) -> None:
        """Judge samples with one stamp by `values` too (first axis: the sample), if any."""
        if values is not None:
            self.compared.append((field_name, np.asarray(values)))

    def _differs(self, i: int, j: int) -> str | None:
        """Name the first compared field whose values differ between rows i and j, or None.

        NaN equals NaN here (no return in a scan, a variance not given): the values as
        read, the way the bag reader compares two messages byte for byte.
        """
        for field_name, values in self.compared:
            if not np.array_equal(values[i], values[j], equal_nan=True):
                return field_name
        return None

    def _same_stamp(self, i: int, previous: int) -> None:
        """Drop sample i, which has the stamp of the kept sample `previous`.

        Same values: an exact repeat (a sample recorded twice), dropped and counted in
        `InputReport.duplicates` with or without skip_bad, as the bag reader drops a message
        recorded twice. Other values: two values for one instant (the filter would take one
        and then the other after a prediction of length 0), refused naming both samples, or
        with skip_bad dropped and counted as SAME_STAMP.
        """
        field_name = f'{self.name}.stamp_s'
        differs = self._differs(i, previous)
        if differs is None:
            report = self.report
            report.duplicates[self.name] = report.duplicates.get(self.name, 0) + 1
            report.duplicate_first_index.setdefault(self.name, i)
            self.repeats += 1
        else:
            if not self.report.skip_bad:
                raise InvalidInputError(
                    self.source, field_name, i,
                    f'stamp {self.stamps[i]:.6f} s is that of sample {previous}, but '
                    f'{differs} differs: two values for one instant (an exact repeat would '
                    'be dropped)')
            self.report.count(field_name, SAME_STAMP, i, 1)
        self.keep[i] = False

    def flag(self, field_name: str, bad: BoolArray, reason: str,
             describe: Callable[[int], str]) -> None:
        """Drop (or, without skip_bad, refuse at the first of) the rows marked in `bad`."""
        new = bad & self.keep
        if not new.any():
            return
        first = int(np.argmax(new))
        if not self.report.skip_bad:
            raise InvalidInputError(self.source, field_name, first, describe(first))
        self.report.count(field_name, reason, first, int(new.sum()))
        self.keep &= ~new

    def values(self, field_name: str, values: NDArray, limit: float, unit: str,
               setting: str = '') -> None:
        """Rows of `values` (shape (n,)) must be finite and within +-limit.

        Many rows beyond the limit are no corrupt samples but a series in other units (a
        speed in cm/s, a rate in mrad/s) or a limit too low for the platform: the error
        says so, with how many and the largest (`setting` names the limit's parameter),
        and refuses the series even with skip_bad once ``UNITS_SHARE`` of it is beyond
        (dropping them would run the filter on the rest, scaled as wrongly).
        """
        array = np.asarray(values, dtype=np.float64)
        finite = np.isfinite(array)
        self.flag(field_name, ~finite, NOT_FINITE, lambda i: f'{array[i]} is not finite')
        with np.errstate(invalid='ignore'):
            beyond = finite & (np.abs(array) > limit)
        count = int((beyond & self.keep).sum())
        many = many_beyond(count, array.size)

        def describe(i: int) -> str:
            problem = value_problem(float(array[i]), limit, unit) or ''
            if not many:
                return problem
            return problem + units_hint(count, f'of its {array.size} samples',
                                        float(np.abs(array[beyond]).max()), unit, setting)

        if many and count >= UNITS_SHARE * array.size and self.report.skip_bad:
            first = int(np.argmax(beyond & self.keep))
            raise InvalidInputError(self.source, field_name, first,
                                    describe(first) + ' (too many to skip)')
        self.flag(field_name, beyond, BEYOND_LIMIT, describe)

    def time(self) -> None:
        """Stamps finite and non-decreasing, forward steps within max_stamp_jump_s.

        With skip_bad a sample older than the last kept one is dropped (the stream went
        back: a counted segment break, its older samples dropped until time passes the
        last kept stamp again) and a lone sample ahead of its neighbours (a flipped bit, a
        message logged out of place) is dropped, not the samples after it. A sample that
        comes back to the very stamp of the last kept one after samples were dropped in
        between (time went back, or a lone sample ahead) is dropped too, counted as time
        going back: it would give that instant a second value, which a bag refuses (two
        messages of a topic with one stamp). Equal stamps side by side are judged by the
        values (`_same_stamp`): an exact repeat is dropped and counted as a duplicate, with
        or without skip_bad, as is a repeat of the last kept sample after dropped ones;
        other values are refused, or with skip_bad the later sample is dropped (SAME_STAMP).
        A stream that jumps ahead and stays there is a sensor silent for a while: kept and
        flagged in the report; whether any stream covers the gap is checked on the whole
        trip (`_check_timeline`).
        """
        stamps = self.stamps
        self.flag(f'{self.name}.stamp_s', ~np.isfinite(stamps), NOT_FINITE,
                  lambda i: f'stamp {stamps[i]} is not finite')
        index = np.flatnonzero(self.keep)
        kept = stamps[index]
        steps = np.diff(kept)
        jump = self.limits.max_stamp_jump_s
        if not steps.size or (steps.min() > 0.0 and steps.max() <= jump):
            return
        field_name = f'{self.name}.stamp_s'
        times = kept.tolist()
        # before: the kept stamp before last (before_k its position), when known.
        last, last_k, before, before_k = times[0], 0, None, 0
        going_back = False
        # Whether the time checks dropped samples since the last kept one.
        skipped = False
        for k in range(1, len(times)):
            t = times[k]
            if t < last and not going_back and before is not None and before <= t:
                # One sample ahead of both its neighbours (a message logged out of place, a
                # bit flipped below the jump limit), not time going back: everything after
                # it would look older than it and be dropped. It is the one refused.
                i = int(index[last_k])
                reason = (f'stamp {last:.6f} s lies {last - t:.6g} s ahead of the samples '
                          f'around it ({before:.6f} s and {t:.6f} s)')
                if not self.report.skip_bad:
                    raise InvalidInputError(self.source, field_name, i, reason)
                self.report.count(field_name, JUMPED_AHEAD, i, 1)
                self.keep[i] = False
                if t > before:
                    last, last_k, skipped = t, k, False
                    continue
                # t repeats the stamp kept before the lone sample: judged below.
                last, last_k, before, skipped = before, before_k, None, True
            if t == last and (not skipped or self._differs(int(index[k]),
                                                           int(index[last_k])) is None):
                # Side by side with the last kept sample (or an exact repeat of it after
                # dropped samples): judged by the values.
                self._same_stamp(int(index[k]), int(index[last_k]))
                continue
            if t == last and skipped:
                # Back at the last kept stamp after dropped samples: a second value for
                # one instant.
                i = int(index[k])
                problem = (f'stamp {t:.6f} s repeats the last kept sample\'s after the '
                           'stream went back: a second value for one instant')
                if not self.report.skip_bad:
                    raise InvalidInputError(self.source, field_name, i, problem)
                self.report.count(field_name, TIME_WENT_BACK, i, 1)
                self.keep[i] = False
                continue
            if t < last:
                problem = (TIME_WENT_BACK, f'time went back {last - t:.6g} s '
                                           f'(from {last:.6f} s to {t:.6f} s)')
                if not going_back:
                    self.report.time_breaks[self.name] = \
                        self.report.time_breaks.get(self.name, 0) + 1
                going_back = True
            elif t - last > jump:
                after = times[k + 1] if k + 1 < len(times) else None
                reason = (f'stamp jumped ahead {t - last:.6g} s (from {last:.6f} s to '
                          f'{t:.6f} s; the limit is {jump:g} s)')
                if after is not None and t <= after <= t + jump:
                    self.report.gaps.append(f'{field_name}[{int(index[k])}]: {reason}')
                    before, before_k, last, last_k = last, last_k, t, k
                    going_back = skipped = False
                    continue
                problem = (JUMPED_AHEAD, reason)
            else:
                before, before_k, last, last_k = last, last_k, t, k
                going_back = skipped = False
                continue
            i = int(index[k])
            if not self.report.skip_bad:
                raise InvalidInputError(self.source, field_name, i, problem[1])
            self.report.count(field_name, problem[0], i, 1)
            self.keep[i] = False
            skipped = True

    def finish(self) -> NDArray | None:
        """Row indices to keep, or None when every row is kept; counts the dropped rows.

        Exact repeats are counted apart (`InputReport.duplicates`), not as dropped samples.
        """
        dropped = int((~self.keep).sum())
        if not dropped:
            return None
        bad = dropped - self.repeats
        if bad:
            self.report.samples_dropped[self.name] = \
                self.report.samples_dropped.get(self.name, 0) + bad
        return np.flatnonzero(self.keep)


def _refuse_empty(source: str, name: str, stamps: NDArray, report: InputReport) -> None:
    """Refuse a stream the filter needs when no sample of it is left."""
    if len(stamps):
        return
    dropped = report.samples_dropped.get(name, 0)
    _refuse(source, name, None, 'no samples' + (f' left ({dropped} dropped as bad)'
                                                if dropped else ''))


def _refuse(source: str, field_name: str, index: int | None, problem: str | None) -> None:
    if problem:
        raise InvalidInputError(source, field_name, index, problem)


_RATE_VARIANCE = 'imu.angular_velocity_covariance[8]'
_SPEED_VARIANCE = 'speed.twist.covariance[0]'


def _variances(values: NDArray | None, limit: float, name: str,
               report: InputReport) -> FloatArray | None:
    used, bad = message_variances(values, limit)
    if bad:
        report.covariances_ignored[name] = bad
    if used is not None:
        report.covariances_used[name] = int(np.isfinite(used).sum())
    return used


def _check_imu(imu: ImuSeries, stream: _Stream, limits: InputLimits) -> ImuSeries:
    rates = np.asarray(imu.angular_velocity_rad_s)
    variances = _variances(imu.yaw_rate_variance, limits.max_yaw_rate_rad_s, _RATE_VARIANCE,
                           stream.report)
    for axis, known in zip(range(3), imu.axes_known):
        if known:
            stream.values(f'imu.angular_velocity.{"xyz"[axis]}', rates[:, axis],
                          limits.max_yaw_rate_rad_s, 'rad/s', 'limits.max_yaw_rate_rad_s')
    if imu.linear_acceleration_m_s2 is not None:
        accel = np.asarray(imu.linear_acceleration_m_s2)
        for axis in range(3):
            stream.values(f'imu.linear_acceleration.{"xyz"[axis]}', accel[:, axis], math.inf,
                          'm/s^2')
    stream.compare('imu.angular_velocity', rates)
    stream.compare('imu.linear_acceleration', imu.linear_acceleration_m_s2)
    stream.compare(_RATE_VARIANCE, imu.yaw_rate_variance)
    stream.time()
    keep = stream.finish()
    if keep is None:
        if variances is imu.yaw_rate_variance:
            return imu
        return dataclasses.replace(imu, yaw_rate_variance=variances)
    return dataclasses.replace(
        imu, stamp_s=imu.stamp_s[keep], angular_velocity_rad_s=rates[keep],
        linear_acceleration_m_s2=None if imu.linear_acceleration_m_s2 is None
        else imu.linear_acceleration_m_s2[keep],
        yaw_rate_variance=None if variances is None else variances[keep])


def _check_scans(scan: ScanSeries, stream: _Stream, source: str,
                 limits: InputLimits) -> ScanSeries:
    prefix = f'lidar.{scan.topic}'
    n = scan.beam_count
    _refuse(source, f'{prefix}.geometry', None, scan_geometry_problem(
        scan.angle_min_rad, scan.angle_min_rad + scan.angle_increment_rad * (n - 1),
        scan.angle_increment_rad, n, scan.range_min_m, scan.range_max_m))
    mount = scan.mount
    _refuse(source, f'{prefix}.mount', None, mount_problem(mount.x_m, mount.y_m, mount.yaw_rad,
                                                           limits))
    ranges = scan.ranges_m
    # No return is +inf or NaN (REP-117); only a negative range is impossible.
    with np.errstate(invalid='ignore'):
        negative = ranges < 0.0
    stream.flag(f'{prefix}.ranges_m', negative.any(axis=1), NEGATIVE, lambda i: (
        f'range {ranges[i][negative[i]][0]} m at beam {int(np.argmax(negative[i]))} is '
        'negative'))
    if scan.intensities is not None:
        intensities = scan.intensities
        bad = ~np.isfinite(intensities)
        stream.flag(f'{prefix}.intensities', bad.any(axis=1), NOT_FINITE, lambda i: (
            f'intensity {intensities[i][bad[i]][0]} at beam {int(np.argmax(bad[i]))} is not '
            'finite'))
    stream.compare(f'{prefix}.ranges_m', ranges)
    stream.compare(f'{prefix}.intensities', scan.intensities)
    stream.time()
    keep = stream.finish()
    if keep is None:
        return scan
    return dataclasses.replace(
        scan, stamp_s=scan.stamp_s[keep], ranges_m=ranges[keep],
        intensities=None if scan.intensities is None else scan.intensities[keep])


def _check_fixed(trip: Trip, source: str, limits: InputLimits) -> None:
    """Refuse bad values with nothing to skip: map, initial pose, noise figures, bias."""
    if trip.landmarks is not None:
        xy = np.asarray(trip.landmarks.xy_m, dtype=np.float64).reshape(-1, 2)
        if not len(xy):
            _refuse(source, 'landmarks.xy_m', None, 'the map lists no landmark')
        bad = bad_values(xy, limits.max_coordinate_m)
        if bad.any():
            i = int(np.argmax(bad))
            _refuse(source, 'landmarks.xy_m', i, coordinate_problem(xy[i], limits))
        _refuse(source, 'landmarks.xy_m', None, duplicate_landmark_problem(xy))
    pose = np.asarray(trip.initial_pose, dtype=np.float64)
    if pose.shape != (3,):
        _refuse(source, 'initial_pose', None, f'has shape {pose.shape}, expected (3,)')
    _refuse(source, 'initial_pose', None, initial_pose_problem(*pose.tolist(), limits))
    for key in ('gyro_rad_s', 'speed_m_s', 'range_m', 'bearing_rad', 'landmark_m'):
        value = getattr(trip.noise, key)
        if value is not None and not (math.isfinite(value) and value >= 0.0):
            _refuse(source, f'noise.{key}', None,
                    f'{value} is not a finite non-negative standard deviation')
    if trip.true_gyro_bias_rad_s is not None:
        bias = np.asarray(trip.true_gyro_bias_rad_s, dtype=np.float64)
        bad = bad_values(bias, limits.max_yaw_rate_rad_s)
        if bad.any():
            i = int(np.argmax(bad))
            _refuse(source, 'true_gyro_bias_rad_s', i,
                    rate_problem(float(bias[i]), limits))
    _refuse(source, 'static_duration_s', None,
            duration_problem(float(trip.static_duration_s), limits))
    if trip.walls is not None and np.isinf(trip.walls).any():
        # NaN rows separate the polylines; an infinite vertex is damage.
        _refuse(source, 'walls', int(np.argmax(np.isinf(trip.walls).any(axis=1))),
                'vertex is infinite')


def _check_timeline(streams: list[tuple[str, FloatArray]], source: str,
                    limits: InputLimits) -> None:
    """Refuse a stretch without any sample longer than the jump limit.

    The filter would predict through it in 0.1 s steps.
    """
    stamps = np.concatenate([s for _, s in streams if len(s)] or [np.zeros(0)])
    if stamps.size < 2:
        return
    ordered = np.sort(stamps)
    steps = np.diff(ordered)
    k = int(np.argmax(steps))
    if steps[k] > limits.max_stamp_jump_s:
        raise InvalidInputError(
            source, 'stamps', None,
            f'no stream has a sample between {ordered[k]:.6f} s and {ordered[k + 1]:.6f} s, '
            f'a gap of {steps[k]:.6g} s (the limit is {limits.max_stamp_jump_s:g} s); split '
            'the log at the gap')


def validate_trip(trip: Trip, source: str, limits: InputLimits = LIMITS,
                  skip_bad: bool = False) -> tuple[Trip, InputReport]:
    """Check every value of a trip before it reaches the filter.

    Per sample (IMU rows, speed samples, scans, ground-truth poses): finite values within
    `limits`, ranges not negative (+inf/NaN mean no return), intensities finite, stamps
    finite and non-decreasing with forward steps within `limits.max_stamp_jump_s`, one
    sample per stamp in a stream (an exact repeat is dropped and counted as a duplicate;
    other values at the stamp of the sample before are refused). Once per trip: beam
    geometry, LiDAR mounts, landmark map, initial pose, stated noise figures, the known
    bias; these have nothing to skip, so they are always refused.

    Args:
        trip: the trip as read.
        source: file or bag name for messages ('trip2016.mat').
        limits: the plausible ranges.
        skip_bad: drop bad samples and count them instead of refusing the first.

    Returns:
        The trip (the same object when nothing was dropped and no message gives its own
        variance) and what was dropped.

    Raises:
        InvalidInputError: names source, field, index and reason, e.g.
            "IMU_dataC.mat: imu.angular_velocity.z[1234]: nan is not finite".
    """
    report = InputReport(source=source, skip_bad=skip_bad)
    _check_fixed(trip, source, limits)

    imu = _check_imu(trip.imu, _Stream('imu', trip.imu.stamp_s, source, limits, report), limits)
    # The gyro drives the filter: without a sample there is nothing to estimate.
    _refuse_empty(source, 'imu', imu.stamp_s, report)

    stream = _Stream('speed', trip.speed.stamp_s, source, limits, report)
    stream.values('speed.speed_m_s', trip.speed.speed_m_s, limits.max_speed_m_s, 'm/s',
                  'limits.max_speed_m_s')
    variances = _variances(trip.speed.speed_variance, limits.max_speed_m_s, _SPEED_VARIANCE,
                           report)
    stream.compare('speed.speed_m_s', trip.speed.speed_m_s)
    stream.compare(_SPEED_VARIANCE, trip.speed.speed_variance)
    stream.time()
    keep = stream.finish()
    speed = trip.speed if keep is None else SpeedSeries(
        stamp_s=trip.speed.stamp_s[keep], speed_m_s=trip.speed.speed_m_s[keep],
        speed_variance=None if variances is None else variances[keep])
    if keep is None and variances is not trip.speed.speed_variance:
        speed = dataclasses.replace(speed, speed_variance=variances)
    # The odometry moves the pose: without it the filter would hold the platform still
    # (a bag with /odom declared but empty once ran to a verdict with the pose 1.7 m off).
    _refuse_empty(source, 'speed', speed.stamp_s, report)

    scans = tuple(_check_scans(s, _Stream(f'lidar.{s.topic}', s.stamp_s, source, limits,
                                          report), source, limits) for s in trip.scans)

    truth = trip.ground_truth
    if truth is not None:
        stream = _Stream('ground_truth', truth.stamp_s, source, limits, report)
        pose = np.asarray(truth.pose, dtype=np.float64)
        for column, name, limit, unit in ((0, 'x', limits.max_coordinate_m, 'm'),
                                          (1, 'y', limits.max_coordinate_m, 'm'),
                                          (2, 'yaw', limits.max_angle_rad, 'rad')):
            stream.values(f'ground_truth.pose.{name}', pose[:, column], limit, unit)
        stream.compare('ground_truth.pose', pose)
        stream.time()
        keep = stream.finish()
        if keep is not None:
            truth = GroundTruth(stamp_s=truth.stamp_s[keep], pose=truth.pose[keep])

    _check_timeline([('imu', imu.stamp_s), ('speed', speed.stamp_s)]
                    + [(s.topic, s.stamp_s) for s in scans], source, limits)
    if (not report.samples_dropped and not report.duplicates and imu is trip.imu
            and speed is trip.speed):
        return trip, report
    return dataclasses.replace(trip, imu=imu, speed=speed, scans=scans,
                               ground_truth=truth), report
