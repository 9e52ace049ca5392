"""Decode a bag's sensor topics in batches into numpy arrays (`fast_cdr`), one sink per topic.

A sink takes the raw CDR messages of one topic in log-time order (one by one from rosbags,
or in batches from `mcap_chunks`), decodes them every `BATCH_MESSAGES` messages or
`_BATCH_BYTES` bytes and stores the columns it needs in arrays that grow as messages come:
message counts a bag states are only hints, bounded by what its files can hold. The values
equal those of rosbags' deserialisation (test/io/rosbags_oracle.py reads a bag that way).

Time: a message's time is its header.stamp, as the nodes take it; the log time (when the
recorder received it) only orders the reading and is kept to check it against the bag's
stated time range. Header stamps stay in the order read, going back or not: the validation
boundary judges them.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from gyro_ekf import topics
from gyro_ekf.core.angles import yaws_of_quaternions
from gyro_ekf.io import fast_cdr, messages as msgs
from gyro_ekf.io.bag_open import deserialize
from gyro_ekf.io.errors import BagError

__all__ = ['BATCH_MESSAGES', 'HEADER_STAMP', 'ImuSink', 'OdomSink', 'SCAN_CHECKED', 'ScanData',
           'ScanSink', 'Sink', 'TruthSink', 'check_imu_axes', 'check_scans', 'has_acceleration',
           'header_stamps_ns']

_MIN_MESSAGE_BYTES = 35
"""Bytes a stored message takes at least (an MCAP Message record head and a CDR header)."""

BATCH_MESSAGES = 1024
_BATCH_BYTES = 1 << 20
"""A topic's raw messages are decoded every this many messages or bytes, whichever first."""


class ScanData(NamedTuple):
    """What a ScanSeries is built from, whichever path decoded it."""

    topic: str
    stamps_ns: np.ndarray
    ranges: np.ndarray
    intensities: np.ndarray | None
    geometry: tuple[float, float, float, float]
    frame_id: str


def _capacity(hint: int, bag_bytes: int, message_bytes: int = 0) -> int:
    """Rows to allocate for a topic: its count hint, bounded by what the files can hold.

    A compressed bag can hold more messages than the bound; the arrays then grow.
    """
    return max(0, min(int(hint), 1024 + bag_bytes // (_MIN_MESSAGE_BYTES + message_bytes)))


def _grown(array: np.ndarray, used: int, needed: int) -> np.ndarray:
    """Array with room for `needed` rows, keeping its first `used` rows."""
    if needed <= array.shape[0]:
        return array
    bigger = np.zeros((max(needed, 2 * array.shape[0]),) + array.shape[1:], dtype=array.dtype)
    bigger[:used] = array[:used]
    return bigger


HEADER_STAMP = ('header.stamp.sec', 'header.stamp.nanosec')
"""The fast_cdr fields of a message's header stamp."""

_NS_PER_S = 1_000_000_000


def header_stamps_ns(path: Path, topic: str, first_row: int, sec: np.ndarray,
                     nanosec: np.ndarray) -> np.ndarray:
    """Integer ns of header stamps (sec, nanosec), refusing one that is no time.

    builtin_interfaces/Time keeps nanosec in [0, 1e9); a stamp of 0 is unset (a driver that
    does not stamp), and one before the epoch is damage: the reader times messages by their
    header stamps, so none of these has a time to give.

    Args:
        first_row: index (from 0) of the first message among the topic's messages.

    Raises:
        BagError: naming the bag, the topic, the field and the message index.
    """
    sec = np.asarray(sec, dtype=np.int64)
    nanosec = np.asarray(nanosec, dtype=np.int64)
    stamps = sec * _NS_PER_S + nanosec
    bad_nanosec = nanosec >= _NS_PER_S
    if bad_nanosec.any():
        i = int(np.argmax(bad_nanosec))
        raise BagError(f"{path}: topic '{topic}': message index {first_row + i}: "
                       f'header.stamp.nanosec = {int(nanosec[i])} is not below 1e9')
    unset = stamps <= 0
    if unset.any():
        i = int(np.argmax(unset))
        what = ('is 0 (unset)' if stamps[i] == 0 else
                f'= {int(sec[i])} s {int(nanosec[i])} ns lies before the epoch')
        raise BagError(f"{path}: topic '{topic}': message index {first_row + i}: header.stamp "
                       f'{what}; messages are timed by their header stamps')
    return stamps


class Sink:
    """Raw messages of one topic, decoded in batches into arrays that grow as needed.

    Attributes:
        stamps: header stamps, ns since the epoch, in the order read; the first n are filled.
        log_ns: log (receive) times, ns, in the order read (ascending).
        n: messages decoded so far.
        first: the first message, deserialised by rosbags (for per-topic constants).
    """

    msgtype = ''
    fields: tuple[str, ...] = ()
    grows: tuple[str, ...] = ('stamps', 'log_ns')
    """Attributes holding one row per message."""

    def __init__(self, path: Path, topic: str, hint: int, bag_bytes: int) -> None:
        """Allocate for `hint` messages (a count the bag states), as far as the files allow."""
        self.path = path
        self.topic = topic
        self.hint = hint
        self.bag_bytes = bag_bytes
        self.count = _capacity(hint, bag_bytes)
        self.n = 0
        self.stamps = np.zeros(self.count, dtype=np.int64)
        self.log_ns = np.zeros(self.count, dtype=np.int64)
        self.first: Any = None
        self._datas: list[bytes] = []
        self._stamps: list[int] = []
        self._bytes = 0

    def add_many(self, stamps: np.ndarray, datas: list[bytes | memoryview]) -> None:
        """Queue raw messages in stamp order and decode them (a batch of a fast reader)."""
        for start in range(0, len(datas), BATCH_MESSAGES):
            self._datas.extend(datas[start:start + BATCH_MESSAGES])
            self._stamps.extend(stamps[start:start + BATCH_MESSAGES].tolist())
            self.flush()

    def add(self, stamp: int, data: bytes) -> None:
        """Queue one raw message; decode the queue when it is full."""
        self._datas.append(data)
        self._stamps.append(stamp)
        self._bytes += len(data)
        if len(self._datas) >= BATCH_MESSAGES or self._bytes >= _BATCH_BYTES:
            self.flush()

    def flush(self) -> None:
        """Decode the queued messages into the arrays."""
        if not self._datas:
            return
        datas, stamps = self._datas, self._stamps
        self._datas, self._stamps, self._bytes = [], [], 0
        if self.first is None:
            self.first = deserialize(self.path, self.topic, self.msgtype, stamps[0], datas[0])
        k = len(datas)
        try:
            columns = fast_cdr.decode_columns(datas, self.msgtype, HEADER_STAMP + self.fields,
                                              msgs.TYPESTORE)
        except fast_cdr.CdrDecodeError as err:
            where = '' if err.index is None else f' at {stamps[err.index]} ns'
            raise BagError(f"{self.path}: topic '{self.topic}': message{where} does not "
                           f'decode as {self.msgtype}: {err.reason}') from None
        for name in self.grows:
            array = getattr(self, name)
            if array is not None and array.shape[0] < self.n + k:
                setattr(self, name, _grown(array, self.n, self.n + k))
        self.stamps[self.n:self.n + k] = header_stamps_ns(
            self.path, self.topic, self.n, columns.values['header.stamp.sec'],
            columns.values['header.stamp.nanosec'])
        self.log_ns[self.n:self.n + k] = stamps
        self.store(columns, slice(self.n, self.n + k))
        self.n += k

    def repeated_stamps(self) -> list[np.ndarray]:
        """Return the groups of row indexes (ascending) sharing a header stamp; usually none.

        Free when the stamps rise strictly (the usual bag): only then is nothing sorted.
        """
        stamps = self.stamps[:self.n]
        if stamps.size < 2 or bool((np.diff(stamps) > 0).all()):
            return []
        order = np.argsort(stamps, kind='stable')
        ordered = stamps[order]
        same = ordered[1:] == ordered[:-1]
        if not same.any():
            return []
        starts = np.flatnonzero(np.concatenate(([True], ~same)))
        groups = np.split(order, starts[1:])
        return [np.sort(g) for g in groups if g.size > 1]

    def keep_rows(self, keep: np.ndarray) -> None:
        """Keep only the rows marked in keep (shape (n,)), in their order."""
        rows = np.flatnonzero(keep)
        for name in self.grows:
            array = getattr(self, name)
            if array is not None:
                setattr(self, name, array[:self.n][rows])
        self.n = int(rows.size)

    def store(self, columns: fast_cdr.Columns, rows: slice) -> None:
        """Copy a decoded batch into the arrays at rows."""
        raise NotImplementedError


class ImuSink(Sink):
    msgtype = topics.IMU_TYPE
    grows = ('stamps', 'log_ns', 'rates', 'rate_variances', 'accel')

    def __init__(self, path: Path, topic: str, hint: int, bag_bytes: int,
                 acceleration: bool) -> None:
        super().__init__(path, topic, hint, bag_bytes)
        self.fields = ('angular_velocity', 'angular_velocity_covariance') + (
            ('linear_acceleration',) if acceleration else ())
        self.rates = np.zeros((self.count, 3))
        self.rate_variances = np.zeros(self.count)
        self.accel = np.zeros((self.count, 3)) if acceleration else None
        self.axes_known: tuple[bool, bool, bool] | None = None
        """The measured axes every message agrees on; None before the first message."""

    def store(self, columns: fast_cdr.Columns, rows: slice) -> None:
        self.axes_known = check_imu_axes(self.path, self.topic, rows.start,
                                         columns.values['angular_velocity_covariance'],
                                         self.axes_known)
        self.rates[rows] = columns.values['angular_velocity']
        self.rate_variances[rows] = columns.values['angular_velocity_covariance'][:, 8]
        if self.accel is not None:
            self.accel[rows] = columns.values['linear_acceleration']


class OdomSink(Sink):
    msgtype = topics.ODOMETRY_TYPE
    fields = ('twist.twist.linear', 'twist.covariance')
    grows = ('stamps', 'log_ns', 'speeds', 'speed_variances')

    def __init__(self, path: Path, topic: str, hint: int, bag_bytes: int) -> None:
        super().__init__(path, topic, hint, bag_bytes)
        self.speeds = np.zeros(self.count)
        self.speed_variances = np.zeros(self.count)

    def store(self, columns: fast_cdr.Columns, rows: slice) -> None:
        self.speeds[rows] = columns.values['twist.twist.linear'][:, 0]
        self.speed_variances[rows] = columns.values['twist.covariance'][:, 0]


class TruthSink(Sink):
    msgtype = topics.ODOMETRY_TYPE
    fields = ('pose.pose.position', 'pose.pose.orientation')
    grows = ('stamps', 'log_ns', 'poses')

    def __init__(self, path: Path, topic: str, hint: int, bag_bytes: int) -> None:
        super().__init__(path, topic, hint, bag_bytes)
        self.poses = np.zeros((self.count, 3))

    def store(self, columns: fast_cdr.Columns, rows: slice) -> None:
        position = columns.values['pose.pose.position']
        x, y, z, w = columns.values['pose.pose.orientation'].T
        self.poses[rows, 0] = position[:, 0]
        self.poses[rows, 1] = position[:, 1]
        self.poses[rows, 2] = yaws_of_quaternions(x, y, z, w)


class ScanSink(Sink):
    msgtype = topics.LASER_SCAN_TYPE
    fields = ('angle_min', 'angle_max', 'angle_increment', 'range_min', 'range_max', 'ranges',
              'intensities')
    grows = ('stamps', 'log_ns', 'ranges', 'intensities')

    def __init__(self, path: Path, topic: str, hint: int, bag_bytes: int) -> None:
        super().__init__(path, topic, hint, bag_bytes)
        self.ranges: np.ndarray | None = None
        self.intensities: np.ndarray | None = None

    def store(self, columns: fast_cdr.Columns, rows: slice) -> None:
        first = self.first
        beams = len(first.ranges)
        if self.ranges is None:
            # A scan stores 4 bytes per beam at least: that bounds the rows too.
            count = max(rows.stop, _capacity(self.hint, self.bag_bytes, 4 * beams))
            self.ranges = np.empty((count, beams), dtype=np.float32)
            if len(first.intensities):
                self.intensities = np.empty((count, beams), dtype=np.float32)
        values = columns.values
        check_scans(self.path, self.topic, rows.start, first, columns.counts['ranges'], values,
                    columns.counts['intensities'])
        self.ranges[rows] = values['ranges']
        if self.intensities is not None:
            self.intensities[rows] = values['intensities']

    def data(self) -> ScanData | None:
        """Return the scans read, or None when the topic had none."""
        first = self.first
        if first is None or self.ranges is None:
            return None
        return ScanData(
            self.topic, self.stamps[:self.n], self.ranges[:self.n],
            None if self.intensities is None else self.intensities[:self.n],
            tuple(getattr(first, name) for name in SCAN_GEOMETRY), first.header.frame_id)


def has_acceleration(imu_message: Any) -> bool:
    """Whether an IMU message gives its linear acceleration (REP-145: covariance[0] != -1)."""
    return bool(imu_message.linear_acceleration_covariance[0] != -1.0)


_AXES = 'xyz'


def _axes_text(known: np.ndarray) -> str:
    measured = [_AXES[i] for i in range(3) if known[i]]
    return ', '.join(measured) if measured else 'none'


def check_imu_axes(path: Path, topic: str, first_row: int, covariances: np.ndarray,
                   expected: tuple[bool, bool, bool] | None) -> tuple[bool, bool, bool]:
    """Refuse IMU messages that mark the yaw axis not measured or disagree on the axes.

    Every message is judged (messages.axes_known_rows), not the first alone: one odd first
    message would otherwise mark an axis unknown for the whole bag, and the values of an
    axis marked unknown are never checked. Logs converted by `gyro-ekf convert` mark their
    unmeasured x and y axes the same way in every message, so they pass.

    Args:
        first_row: index of the first message checked among the topic's messages.
        covariances: angular_velocity_covariance of each message checked, shape (k, 9).
        expected: the axes earlier messages marked measured, or None for the first batch.

    Returns:
        The measured axes every message checked agrees on.

    Raises:
        BagError: naming the bag, the topic, the field and the message index (from 0).
    """
    rows = np.asarray(covariances, dtype=np.float64).reshape(-1, 9)
    if not len(rows):
        return (True, True, True) if expected is None else expected
    known = msgs.axes_known_rows(rows)
    no_yaw = ~known[:, 2]
    if no_yaw.any():
        # The filter integrates the yaw rate: a bag without it has nothing to estimate.
        i = int(np.argmax(no_yaw))
        entry = ('[0] = -1 (REP-145: no angular velocity at all)' if rows[i, 0] == -1.0 else
                 f'[8] = {rows[i, 8]:g} (the variance marking an axis not measured)')
        raise BagError(f"{path}: topic '{topic}': message index {first_row + i}: "
                       f'angular_velocity_covariance{entry} says the yaw rate (z) is not '
                       'measured; the filter needs it')
    reference = known[0] if expected is None else np.array(expected)
    differ = (known != reference).any(axis=1)
    if differ.any():
        i = int(np.argmax(differ))
        raise BagError(f"{path}: topic '{topic}': message index {first_row + i}: "
                       f'angular_velocity_covariance marks the axes {_axes_text(known[i])} '
                       f'as measured, the messages before it {_axes_text(reference)}; '
                       'expected one IMU per topic')
    return (bool(reference[0]), bool(reference[1]), bool(reference[2]))


SCAN_GEOMETRY = ('angle_min', 'angle_increment', 'range_min', 'range_max')
"""The LaserScan fields every scan of a topic must share with its first."""

SCAN_CHECKED = SCAN_GEOMETRY + ('angle_max',)
"""The LaserScan fields check_scans needs of every scan."""


def check_scans(path: Path, topic: str, first_row: int, first: Any, range_counts: np.ndarray,
                geometry: dict[str, np.ndarray], intensity_counts: np.ndarray) -> None:
    """Refuse scans whose angles disagree with their ranges, or that change the first scan.

    Every scan must keep the first scan's beam count and geometry; intensities, when the
    first scan has any, must be one per beam as well. And REP-117's angle_max is the last
    beam's bearing: angle_min + (n - 1) * angle_increment must give it within half an
    increment (float32 fields round; a beam more or less does not).

    Args:
        first_row: index of the first scan checked among the topic's scans (for the message).
        first: the topic's first LaserScan message.
        range_counts, intensity_counts: beams of each scan checked.
        geometry: each SCAN_CHECKED field -> its value in each scan checked.

    Raises:
        BagError: naming the bag, the topic and the scan (counted from 1; angle_max: the
            message index, from 0).
    """
    beams = len(first.ranges)
    same = range_counts == beams
    for name in SCAN_GEOMETRY:
        same &= geometry[name] == getattr(first, name)
    if not same.all():
        raise BagError(f"{path}: topic '{topic}': scan {first_row + int(np.argmin(same)) + 1} "
                       'changes the beam count or geometry; expected one fixed LiDAR per topic')
    if len(first.intensities) and (intensity_counts != beams).any():
        wrong = int(np.argmax(intensity_counts != beams))
        raise BagError(f"{path}: topic '{topic}': scan {first_row + wrong + 1} has "
                       f'{int(intensity_counts[wrong])} intensities for {beams} beams')
    counts = np.asarray(range_counts, dtype=np.float64)
    increment = geometry['angle_increment'].astype(np.float64)
    last = geometry['angle_min'].astype(np.float64) + (counts - 1.0) * increment
    angle_max = geometry['angle_max'].astype(np.float64)
    with np.errstate(invalid='ignore'):
        # Written so that NaN anywhere is refused too.
        agree = (counts < 1) | (np.abs(last - angle_max) <= 0.5 * np.abs(increment))
    if not agree.all():
        i = int(np.argmin(agree))
        raise BagError(
            f"{path}: topic '{topic}': message index {first_row + i}: angle_max "
            f'{angle_max[i]:.6g} rad disagrees with its {int(counts[i])} ranges: angle_min '
            f'{geometry["angle_min"][i]:.6g} + ({int(counts[i])} - 1) * angle_increment '
            f'{increment[i]:.6g} = {last[i]:.6g} rad (more than half an increment apart)')
