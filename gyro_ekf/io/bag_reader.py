"""Read a bag written by `bag_writer` back into a Trip, or stream its messages in stamp order.

Stamps of the returned Trip are seconds since the bag's first message (which the writer puts
at the log's time zero); `BagTrip.start_time_ns` is that message's stamp. What no message
carries (LiDAR mounts, stated noise, true bias) comes from the params sidecar beside the bag;
without a sidecar the mounts default to the platform origin and a warning says so.

`read_bag` takes the raw messages of a single-file MCAP bag from `mcap_chunks` (a small
chunk reader, several times faster), of any other bag, or one that reader refuses, from
rosbags' Reader, and decodes the sensor topics in batches with numpy (`fast_cdr`), which
gives the values rosbags' deserialisation gives (`read_bag(fast=False)` is that reference
path); `iter_bag_messages` yields rosbags message objects one by one.

Bags are verified, never silently wrong: `mcap_chunks` checks the MCAP file's CRCs, bounds
and chunk time ranges (a damaged file is a final BagError; only a file it cannot handle, e.g.
an unknown chunk compression, goes to rosbags, with the reason logged); each known topic must
have the type the reader expects for it (`EXPECTED_TYPES`, plus the sidecar's LiDAR topics);
every stamp must lie in the bag's stated time range; message counts from the metadata or
the MCAP statistics are only hints (arrays grow as messages come); and whatever rosbags
raises on damaged bytes becomes a BagError naming the bag.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
import logging
import math
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
import yaml
from rosbags.rosbag2 import Reader

from gyro_ekf import topics
from gyro_ekf.core.types import (
    GroundTruth, ImuSeries, LandmarkMap, LidarMount, NoiseFigures, ScanSeries, SpeedSeries,
    Trip)
from gyro_ekf.errors import GyroEkfError
from gyro_ekf.io import fast_cdr, mcap_chunks, messages as msgs
from gyro_ekf.io.errors import BagError
from gyro_ekf.io.sidecar import BagParams, read_sidecar, sidecar_path

__all__ = ['BagMessage', 'BagSummary', 'BagTrip', 'EXPECTED_TYPES', 'TopicSummary',
           'bag_summary', 'iter_bag_messages', 'read_bag', 'read_trip_bag']

log = logging.getLogger(__name__)

IMU_TOPIC = topics.bag_topic(topics.IMU)
ODOM_TOPIC = topics.bag_topic(topics.ODOM)
MAP_TOPIC = topics.bag_topic(topics.LANDMARK_MAP)
INITIAL_POSE_TOPIC = topics.bag_topic(topics.INITIAL_POSE)
GROUND_TRUTH_TOPIC = topics.bag_topic(topics.GROUND_TRUTH)

EXPECTED_TYPES = {
    IMU_TOPIC: topics.IMU_TYPE,
    ODOM_TOPIC: topics.ODOMETRY_TYPE,
    topics.bag_topic(topics.SCAN): topics.LASER_SCAN_TYPE,
    topics.bag_topic(topics.SCAN2): topics.LASER_SCAN_TYPE,
    GROUND_TRUTH_TOPIC: topics.ODOMETRY_TYPE,
    MAP_TOPIC: topics.POSE_ARRAY_TYPE,
    INITIAL_POSE_TOPIC: topics.POSE_WITH_COVARIANCE_STAMPED_TYPE,
}
"""Topic -> the only type the reader accepts on it (the sidecar's LiDAR topics: LaserScan)."""

_MIN_MESSAGE_BYTES = 35
"""Bytes a stored message takes at least (an MCAP Message record head and a CDR header)."""


class BagMessage(NamedTuple):
    """One deserialized message.

    Attributes:
        topic: bag topic name (absolute).
        msgtype: e.g. 'sensor_msgs/msg/Imu'.
        stamp_ns: bag (receive) stamp, ns since the epoch; the writer sets it equal to the
            header stamp.
        message: the rosbags message object.
    """

    topic: str
    msgtype: str
    stamp_ns: int
    message: Any


class TopicSummary(NamedTuple):
    """A topic of a bag: name, type, message count and offered durability."""

    name: str
    msgtype: str
    count: int
    durability: str


class BagSummary(NamedTuple):
    """What `gyro-ekf info` prints about a bag."""

    path: Path
    storage: str
    version: int
    start_time_ns: int
    duration_ns: int
    message_count: int
    topics: list[TopicSummary]
    sidecar: Path | None


@dataclass(frozen=True, slots=True)
class BagTrip:
    """A trip read back from a bag.

    Attributes:
        trip: the trip, stamps in s since the bag's first message.
        start_time_ns: stamp of the bag's first message, ns since the epoch.
        params: the sidecar contents, or None when the bag has none.
    """

    trip: Trip
    start_time_ns: int
    params: BagParams | None


@contextmanager
def _reading(path: Path) -> Iterator[None]:
    """Turn whatever reading a bag's bytes raises into a BagError naming the bag.

    rosbags parses bytes it cannot trust: a damaged bag makes it raise nearly anything
    (ReaderError, struct.error, ZstdError, OverflowError, MemoryError, KeyError, ...).
    """
    try:
        yield
    except GyroEkfError:
        raise
    except mcap_chunks.McapError as err:
        raise BagError(str(err)) from None
    except Exception as err:
        reason = str(err) or type(err).__name__
        raise BagError(f'{path}: cannot read the bag ({type(err).__name__}): {reason}'
                       f'{_reindex_hint(path)}') from None


def _reindex_hint(path: Path) -> str:
    from gyro_ekf.io.reindex import needs_reindex

    reason = needs_reindex(path)
    return '' if reason is None else f'; {reason}: run `gyro-ekf reindex {path}`'


def _open(path: Path) -> Reader:
    if not path.exists():
        raise BagError(f'{path}: no such bag')
    if path.is_dir() and not (path / 'metadata.yaml').exists():
        if any(path.glob('*.mcap')):
            raise BagError(f'{path}: no metadata.yaml (was its recorder killed?); run '
                           f'`gyro-ekf reindex {path}`')
        raise BagError(f'{path}: not a rosbag2 folder (no metadata.yaml)')
    with _reading(path):
        reader = Reader(path)
        reader.open()
    files = _metadata(path).get('relative_file_paths')
    # rosbags reads a bag listing no file as an empty bag, and one listed twice twice over.
    problem = ('lists no storage file' if not files else
               'lists a storage file twice' if len(set(map(str, files))) != len(files) else None)
    if problem:
        reader.close()
        raise BagError(f"{path / 'metadata.yaml'}: relative_file_paths {problem} "
                       f'({files!r})')
    try:
        _check_storage_connections(path, reader)
    except BagError:
        reader.close()
        raise
    return reader


def _check_storage_connections(path: Path, reader: Reader) -> None:
    """Refuse a topic of metadata.yaml that its storage files describe otherwise.

    rosbags yields a topic's messages only from storage connections equal to the metadata's
    (topic, type, serialization and QoS, type hash); one damaged byte in the type an MCAP
    summary states would drop every message of the topic without a word.
    """
    storages = getattr(reader.storage, 'storages', None)
    if not storages:
        return
    stored = [c for storage in storages for c in storage.connections]
    for wanted in reader.connections:
        if any(c.topic == wanted.topic and c.msgtype == wanted.msgtype and c.ext == wanted.ext
               and (not c.digest or not wanted.digest or c.digest == wanted.digest)
               for c in stored):
            continue
        other = next((c for c in stored if c.topic == wanted.topic), None)
        detail = ('no connection' if other is None else f'type {other.msgtype!r}'
                  if other.msgtype != wanted.msgtype
                  else 'another serialization, QoS or type hash')
        raise BagError(f"{path}: topic '{wanted.topic}' has {detail} in its storage file, "
                       f"but {wanted.msgtype} in metadata.yaml; rosbags would drop its messages")


def bag_summary(path: Path | str) -> BagSummary:
    """Topics, types, counts, start time and duration of a bag (from its metadata).

    Raises:
        BagError: missing or unreadable bag.
    """
    path = Path(path)
    reader = _open(path)
    try:
        summaries = []
        for connection in reader.connections:
            qos = getattr(connection.ext, 'offered_qos_profiles', [])
            durability = ','.join(sorted({q.durability.name.lower() for q in qos})) or '-'
            summaries.append(TopicSummary(connection.topic, connection.msgtype,
                                          connection.msgcount, durability))
    finally:
        reader.close()
    meta = _metadata(path)
    try:
        return BagSummary(
            path=path, storage=str(meta['storage_identifier']), version=int(meta['version']),
            start_time_ns=int(meta['starting_time']['nanoseconds_since_epoch']),
            duration_ns=int(meta['duration']['nanoseconds']),
            message_count=int(meta['message_count']), topics=summaries,
            sidecar=sidecar_path(path) if sidecar_path(path).exists() else None)
    except (KeyError, TypeError, ValueError) as err:
        raise BagError(f'{path / "metadata.yaml"}: missing or invalid entry {err}') from None


_YAML_LOADER = getattr(yaml, 'CSafeLoader', yaml.SafeLoader)
"""libyaml's safe loader where PyYAML has it: the same documents, about 9x faster (a bag's
metadata.yaml is read two or three times per read)."""


def _metadata(path: Path) -> dict[str, Any]:
    """Read the rosbag2_bagfile_information mapping of a bag folder's metadata.yaml."""
    meta_path = path / 'metadata.yaml'
    try:
        document = yaml.load(meta_path.read_text(encoding='utf-8'), Loader=_YAML_LOADER)
        return dict(document['rosbag2_bagfile_information'])
    except (OSError, yaml.YAMLError, KeyError, TypeError, ValueError) as err:
        raise BagError(f'{meta_path}: cannot read the bag metadata: {err}') from None


def iter_bag_messages(path: Path | str, topic_names: Iterable[str] | None = None
                      ) -> Iterator[BagMessage]:
    """Deserialized messages of a bag in stamp order (all topics merged), lazily.

    Args:
        path: the bag folder.
        topic_names: only these topics (absolute or relative names); None = all.

    Raises:
        BagError: missing or unreadable bag, a requested topic it lacks, or a message that
            does not deserialize.
    """
    path = Path(path)
    reader = _open(path)
    try:
        connections = reader.connections
        _check_types(path, connections, None)
        if topic_names is not None:
            wanted = {topics.bag_topic(t) for t in topic_names}
            present = {c.topic for c in connections}
            missing = sorted(wanted - present)
            if missing:
                raise BagError(f"{path}: no topic '{missing[0]}' (the bag has "
                               f'{sorted(present)})')
            connections = [c for c in connections if c.topic in wanted]
        span = _time_span(reader)
        messages = reader.messages(connections, *_every_time(path))
        while True:
            with _reading(path):
                item = next(messages, None)
            if item is None:
                break
            connection, stamp, data = item
            _check_stamp(path, connection.topic, stamp, span)
            message = _deserialize(path, connection.topic, connection.msgtype, stamp, data)
            yield BagMessage(connection.topic, connection.msgtype, stamp, message)
    finally:
        reader.close()


_BATCH_MESSAGES = 1024
_BATCH_BYTES = 1 << 20
"""A topic's raw messages are decoded every this many messages or bytes, whichever first."""


class _ScanData(NamedTuple):
    """What a ScanSeries is built from, whichever path decoded it."""

    topic: str
    stamps_ns: np.ndarray
    ranges: np.ndarray
    intensities: np.ndarray | None
    geometry: tuple[float, float, float, float]
    frame_id: str


def _deserialize(path: Path, topic: str, msgtype: str, stamp: int,
                 data: bytes | memoryview) -> Any:
    try:
        return msgs.deserialize(data, msgtype)
    except fast_cdr.DECODE_FAILURES as err:
        raise BagError(f"{path}: topic '{topic}': message at {stamp} ns does not decode as "
                       f'{msgtype}: {err}') from None


def _check_types(path: Path, connections: Iterable[Any], params: BagParams | None) -> None:
    """Refuse a bag where a topic the reader knows has another type than it expects."""
    expected = dict(EXPECTED_TYPES)
    if params is not None:
        expected.update({topics.bag_topic(name): topics.LASER_SCAN_TYPE
                         for name in params.lidars})
    for connection in connections:
        wanted = expected.get(connection.topic)
        if wanted is not None and connection.msgtype != wanted:
            raise BagError(f"{path}: topic '{connection.topic}' has type "
                           f'{connection.msgtype}, expected {wanted}')


def _topics(path: Path, reader: Reader, params: BagParams | None
            ) -> tuple[dict[str, Any], dict[str, int]]:
    """Return connections and message-count hints by topic; check names and types."""
    _check_types(path, reader.connections, params)
    by_topic: dict[str, Any] = {}
    counts: dict[str, int] = {}
    for connection in reader.connections:
        known = by_topic.setdefault(connection.topic, connection)
        if known.msgtype != connection.msgtype:
            raise BagError(f"{path}: topic '{connection.topic}' has connections of two types, "
                           f'{known.msgtype} and {connection.msgtype}')
        counts[connection.topic] = counts.get(connection.topic, 0) + _count_hint(
            connection.msgcount)
    for needed in (IMU_TOPIC, ODOM_TOPIC):
        if needed not in by_topic:
            raise BagError(f"{path}: no topic '{needed}' (the bag has {sorted(by_topic)})")
    return by_topic, counts


def _count_hint(value: Any) -> int:
    """Return a topic's message count as the metadata states it, or 0 when it is no count.

    Only a hint for the first allocation (the arrays grow), so a damaged one (None, a
    string, inf) costs nothing but a regrowth.
    """
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(
            value):
        return 0
    return max(0, int(value))


_NO_MESSAGES = (0, 0)
"""The span of a bag whose metadata states no messages: any message contradicts it."""


def _time_span(reader: Reader) -> tuple[int, int]:
    """Return the bag's stated [start, end) in ns (MCAP statistics or metadata).

    A bag that states no messages (message_count 0 or none) gets an empty span: rosbags then
    gives no start time, and stamps would count from the epoch (1.7e9 s) unnoticed.
    """
    if not reader.message_count:
        return _NO_MESSAGES
    return int(reader.start_time), int(reader.end_time)


def _every_time(path: Path) -> tuple[int, int]:
    """Return the start and stop for reader.messages that let every message through.

    By default rosbags yields only the messages of an MCAP chunk inside the chunk's own time
    range, so a damaged log time would silently drop its message; asked for every time, it
    yields it and the stated time range refuses it. sqlite3 stores signed 64-bit stamps.
    """
    if _metadata(path).get('storage_identifier') == 'mcap':
        return 0, 2**64
    return 0, 2**63 - 1


def _check_stamp(path: Path, topic: str, stamp: int, span: tuple[int, int]) -> None:
    if span == _NO_MESSAGES:
        raise BagError(f"{path / 'metadata.yaml'}: message_count states no messages, but "
                       f"topic '{topic}' has a message at {stamp} ns")
    if not span[0] <= stamp < span[1]:
        raise BagError(f"{path}: topic '{topic}': message at {stamp} ns lies outside the "
                       f'time range the bag states, [{span[0]}, {span[1]}) ns')


def _check_stamps(path: Path, topic: str, stamps: np.ndarray, span: tuple[int, int]) -> None:
    """Refuse stamps outside the bag's stated time range (a damaged time or statistics)."""
    if not stamps.size:
        return
    outside = (stamps < span[0]) | (stamps >= span[1])
    if outside.any():
        _check_stamp(path, topic, int(stamps[int(np.argmax(outside))]), span)


def _bag_bytes(path: Path) -> int:
    try:
        return sum(f.stat().st_size for f in path.iterdir() if f.is_file())
    except OSError:
        return 0


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


class _Sink:
    """Raw messages of one topic, decoded in batches into arrays that grow as needed.

    Attributes:
        stamps: bag stamps, ns; the first n are filled.
        n: messages decoded so far.
        first: the first message, deserialised by rosbags (for per-topic constants).
    """

    msgtype = ''
    fields: tuple[str, ...] = ()
    grows: tuple[str, ...] = ('stamps',)
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
        self.first: Any = None
        self._datas: list[bytes] = []
        self._stamps: list[int] = []
        self._bytes = 0

    def add_many(self, stamps: np.ndarray, datas: list[bytes | memoryview]) -> None:
        """Queue raw messages in stamp order and decode them (a batch of a fast reader)."""
        for start in range(0, len(datas), _BATCH_MESSAGES):
            self._datas.extend(datas[start:start + _BATCH_MESSAGES])
            self._stamps.extend(stamps[start:start + _BATCH_MESSAGES].tolist())
            self.flush()

    def add(self, stamp: int, data: bytes) -> None:
        """Queue one raw message; decode the queue when it is full."""
        self._datas.append(data)
        self._stamps.append(stamp)
        self._bytes += len(data)
        if len(self._datas) >= _BATCH_MESSAGES or self._bytes >= _BATCH_BYTES:
            self.flush()

    def flush(self) -> None:
        """Decode the queued messages into the arrays."""
        if not self._datas:
            return
        datas, stamps = self._datas, self._stamps
        self._datas, self._stamps, self._bytes = [], [], 0
        if self.first is None:
            self.first = _deserialize(self.path, self.topic, self.msgtype, stamps[0], datas[0])
        k = len(datas)
        try:
            columns = fast_cdr.decode_columns(datas, self.msgtype, self.fields, msgs.TYPESTORE)
        except fast_cdr.CdrDecodeError as err:
            where = '' if err.index is None else f' at {stamps[err.index]} ns'
            raise BagError(f"{self.path}: topic '{self.topic}': message{where} does not "
                           f'decode as {self.msgtype}: {err.reason}') from None
        for name in self.grows:
            array = getattr(self, name)
            if array is not None and array.shape[0] < self.n + k:
                setattr(self, name, _grown(array, self.n, self.n + k))
        self.stamps[self.n:self.n + k] = stamps
        self.store(columns, slice(self.n, self.n + k))
        self.n += k

    def store(self, columns: fast_cdr.Columns, rows: slice) -> None:
        """Copy a decoded batch into the arrays at rows."""
        raise NotImplementedError


class _ImuSink(_Sink):
    msgtype = topics.IMU_TYPE
    grows = ('stamps', 'rates', 'rate_variances', 'accel')

    def __init__(self, path: Path, topic: str, hint: int, bag_bytes: int,
                 acceleration: bool) -> None:
        super().__init__(path, topic, hint, bag_bytes)
        self.fields = ('angular_velocity', 'angular_velocity_covariance') + (
            ('linear_acceleration',) if acceleration else ())
        self.rates = np.zeros((self.count, 3))
        self.rate_variances = np.zeros(self.count)
        self.accel = np.zeros((self.count, 3)) if acceleration else None

    def store(self, columns: fast_cdr.Columns, rows: slice) -> None:
        self.rates[rows] = columns.values['angular_velocity']
        self.rate_variances[rows] = columns.values['angular_velocity_covariance'][:, 8]
        if self.accel is not None:
            self.accel[rows] = columns.values['linear_acceleration']


class _OdomSink(_Sink):
    msgtype = topics.ODOMETRY_TYPE
    fields = ('twist.twist.linear', 'twist.covariance')
    grows = ('stamps', 'speeds', 'speed_variances')

    def __init__(self, path: Path, topic: str, hint: int, bag_bytes: int) -> None:
        super().__init__(path, topic, hint, bag_bytes)
        self.speeds = np.zeros(self.count)
        self.speed_variances = np.zeros(self.count)

    def store(self, columns: fast_cdr.Columns, rows: slice) -> None:
        self.speeds[rows] = columns.values['twist.twist.linear'][:, 0]
        self.speed_variances[rows] = columns.values['twist.covariance'][:, 0]


class _TruthSink(_Sink):
    msgtype = topics.ODOMETRY_TYPE
    fields = ('pose.pose.position', 'pose.pose.orientation')
    grows = ('stamps', 'poses')

    def __init__(self, path: Path, topic: str, hint: int, bag_bytes: int) -> None:
        super().__init__(path, topic, hint, bag_bytes)
        self.poses = np.zeros((self.count, 3))

    def store(self, columns: fast_cdr.Columns, rows: slice) -> None:
        position = columns.values['pose.pose.position']
        x, y, z, w = columns.values['pose.pose.orientation'].T
        self.poses[rows, 0] = position[:, 0]
        self.poses[rows, 1] = position[:, 1]
        # msgs.quaternion_yaw, element by element: numpy's + and * round as Python's do, and
        # math.atan2 keeps the result identical to the per-message path.
        numerator = (2.0 * (w * z + x * y)).tolist()
        denominator = (1.0 - 2.0 * (y * y + z * z)).tolist()
        self.poses[rows, 2] = np.fromiter(map(math.atan2, numerator, denominator),
                                          dtype=np.float64, count=len(numerator))


class _ScanArrays:
    """What both scan readers fill (stamps, ranges, intensities, first message)."""

    topic: str
    n: int
    stamps: np.ndarray
    ranges: np.ndarray | None
    intensities: np.ndarray | None
    first: Any

    def data(self) -> _ScanData | None:
        """Return the scans read, or None when the topic had none."""
        first = self.first
        if first is None or self.ranges is None:
            return None
        return _ScanData(
            self.topic, self.stamps[:self.n], self.ranges[:self.n],
            None if self.intensities is None else self.intensities[:self.n],
            (first.angle_min, first.angle_increment, first.range_min, first.range_max),
            first.header.frame_id)


class _ScanSink(_ScanArrays, _Sink):
    msgtype = topics.LASER_SCAN_TYPE
    fields = ('angle_min', 'angle_increment', 'range_min', 'range_max', 'ranges',
              'intensities')
    grows = ('stamps', 'ranges', 'intensities')

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
        same = (columns.counts['ranges'] == beams)
        for name, value in (('angle_min', first.angle_min),
                            ('angle_increment', first.angle_increment),
                            ('range_min', first.range_min), ('range_max', first.range_max)):
            same &= values[name] == value
        if not same.all():
            raise BagError(f"{self.path}: topic '{self.topic}': scan "
                           f'{rows.start + int(np.argmin(same)) + 1} changes the beam count or '
                           'geometry; expected one fixed LiDAR per topic')
        self.ranges[rows] = values['ranges']
        if self.intensities is not None:
            given = columns.counts['intensities']
            if (given != beams).any():
                wrong = int(np.argmax(given != beams))
                raise BagError(f"{self.path}: topic '{self.topic}': scan "
                               f'{rows.start + wrong + 1} has {int(given[wrong])} intensities '
                               f'for {beams} beams')
            self.intensities[rows] = values['intensities']


def read_bag(path: Path | str, fast: bool = True, acceleration: bool = True) -> BagTrip:
    """Read everything the bag writer writes, including the sidecar, into a Trip.

    Args:
        path: the bag folder.
        fast: decode /imu, /odom, the scans and /ground_truth in batches with numpy
            (`fast_cdr`, bit-identical values); False deserialises every message with
            rosbags, about three times slower.
        acceleration: read the IMU's linear acceleration where the bag has it; False
            leaves it None (the EKF does not use it; 48 bytes per sample saved).

    Returns:
        The trip (stamps in s since the first message), the bag start time and the sidecar.

    Raises:
        BagError: missing or unreadable bag, no /imu or /odom topic, or inconsistent scans.
    """
    path = Path(path)
    if not fast:
        return _read_bag_rosbags(path, acceleration)
    reader = _open(path)
    try:
        params = read_sidecar(path)
        by_topic, counts = _topics(path, reader, params)
        start = reader.start_time if reader.message_count else 0
        span = _time_span(reader)
        scan_topics = [t for t, c in by_topic.items() if c.msgtype == topics.LASER_SCAN_TYPE]
        mcap_file = _single_mcap_file(path)
        size = _bag_bytes(path)
        while True:
            imu = _ImuSink(path, IMU_TOPIC, counts[IMU_TOPIC], size, acceleration)
            odom = _OdomSink(path, ODOM_TOPIC, counts[ODOM_TOPIC], size)
            scans = {t: _ScanSink(path, t, counts[t], size) for t in scan_topics}
            sinks: dict[str, _Sink] = {IMU_TOPIC: imu, ODOM_TOPIC: odom, **scans}
            truth = None
            if GROUND_TRUTH_TOPIC in by_topic:
                truth = _TruthSink(path, GROUND_TRUTH_TOPIC, counts[GROUND_TRUTH_TOPIC], size)
                sinks[GROUND_TRUTH_TOPIC] = truth
            singles: dict[str, Any] = {}
            if mcap_file is None:
                with _reading(path):
                    _read_with_rosbags(path, reader, sinks, singles)
                break
            try:
                _read_mcap_fast(path, mcap_file, by_topic, sinks, singles)
                break
            except mcap_chunks.UnsupportedMcap as err:
                # rosbags reads what the fast reader cannot handle; damage (CorruptMcap) is
                # final and never gets here.
                log.info('%s; reading it with rosbags instead', err)
                mcap_file = None
        for sink in sinks.values():
            sink.flush()
            _check_stamps(path, sink.topic, sink.stamps[:sink.n], span)
        for topic, (stamp, _) in singles.items():
            _check_stamp(path, topic, stamp, span)
    finally:
        reader.close()
    landmark_message = singles[MAP_TOPIC][1] if MAP_TOPIC in singles else None
    pose_message = singles[INITIAL_POSE_TOPIC][1] if INITIAL_POSE_TOPIC in singles else None
    imu_first = imu.first
    return _bag_trip(
        path, params, int(start),
        imu_ns=imu.stamps[:imu.n], rates=imu.rates[:imu.n],
        rate_variances=imu.rate_variances[:imu.n],
        accel=imu.accel[:imu.n] if imu.accel is not None and imu_first is not None
        and _has_accel(imu_first) else None,
        axes_known=(True, True, True) if imu_first is None else msgs.axes_known_of(
            imu_first.angular_velocity_covariance),
        odom_ns=odom.stamps[:odom.n], speeds=odom.speeds[:odom.n],
        speed_variances=odom.speed_variances[:odom.n],
        scans=[d for d in (scans[t].data() for t in scan_topics) if d is not None],
        truth=None if truth is None else (truth.stamps[:truth.n], truth.poses[:truth.n]),
        landmarks=None if landmark_message is None else msgs.landmarks_of(landmark_message),
        initial_pose=None if pose_message is None else np.array(
            msgs.pose_of(pose_message.pose.pose)))


def _single_mcap_file(path: Path) -> Path | None:
    """Return the bag's one .mcap file when mcap_chunks may read it, else None."""
    meta = _metadata(path)
    files = meta.get('relative_file_paths') or []
    if (meta.get('storage_identifier') != 'mcap' or meta.get('compression_mode')
            or len(files) != 1 or not str(files[0]).endswith('.mcap')):
        return None
    return path / str(files[0])


def _read_with_rosbags(path: Path, reader: Reader, sinks: dict[str, _Sink],
                       singles: dict[str, tuple[int, Any]]) -> None:
    """Fill the sinks, and singles with topic -> (stamp, last message), through rosbags."""
    wanted = [c for c in reader.connections
              if c.topic in sinks or c.topic in (MAP_TOPIC, INITIAL_POSE_TOPIC)]
    for connection, stamp, data in reader.messages(wanted, *_every_time(path)):
        sink = sinks.get(connection.topic)
        if sink is not None:
            sink.add(stamp, data)
        else:
            singles[connection.topic] = (stamp, _deserialize(
                path, connection.topic, connection.msgtype, stamp, data))


def _read_mcap_fast(path: Path, mcap_file: Path, by_topic: dict[str, Any],
                    sinks: dict[str, _Sink], singles: dict[str, tuple[int, Any]]) -> None:
    """Read the sink topics with mcap_chunks: the same bytes, a few times faster, verified.

    Raises:
        BagError: the file is damaged (CRC, bounds, times), or its channels disagree with
            the types rosbags read from its summary.
        UnsupportedMcap: mcap_chunks cannot handle the file; read it with rosbags.
    """
    def consume(topic: str, batch: mcap_chunks.TopicMessages) -> None:
        sink = sinks.get(topic)
        if sink is not None:
            sink.add_many(batch.log_time_ns, batch.payloads)
        elif len(batch.payloads):
            stamp = int(batch.log_time_ns[-1])
            singles[topic] = (stamp, _deserialize(path, topic, by_topic[topic].msgtype, stamp,
                                                  bytes(batch.payloads[-1])))

    wanted = [t for t in by_topic if t in sinks or t in (MAP_TOPIC, INITIAL_POSE_TOPIC)]
    try:
        msgtypes = mcap_chunks.stream_topics(mcap_file, wanted, consume)
    except OSError as err:
        raise BagError(f'{path}: cannot read the bag: {err}') from None
    except mcap_chunks.CorruptMcap as err:
        raise BagError(str(err)) from None
    for topic, msgtype in msgtypes.items():
        if msgtype != by_topic[topic].msgtype:
            raise BagError(f"{mcap_file}: topic '{topic}' has type {msgtype} in the data "
                           f'section and {by_topic[topic].msgtype} in the summary')


def _has_accel(imu_message: Any) -> bool:
    return bool(imu_message.linear_acceleration_covariance[0] != -1.0)


def _given(variances: np.ndarray) -> np.ndarray | None:
    # Raw as the messages hold them (0 and -1 included); core.validation decides which
    # are used. None when no message gives one: the usual case needs no per-sample check.
    return None if not np.any(variances) else variances


def _bag_trip(path: Path, params: BagParams | None, start: int, *, imu_ns: np.ndarray,
              rates: np.ndarray, rate_variances: np.ndarray, accel: np.ndarray | None,
              axes_known: tuple[bool, bool, bool], odom_ns: np.ndarray, speeds: np.ndarray,
              speed_variances: np.ndarray, scans: list[_ScanData],
              truth: tuple[np.ndarray, np.ndarray] | None, landmarks: LandmarkMap | None,
              initial_pose: np.ndarray | None) -> BagTrip:
    """Assemble the Trip of a bag from its decoded arrays (stamps in ns) and its sidecar."""
    def seconds(stamps: np.ndarray) -> np.ndarray:
        return (stamps - np.int64(start)) / float(msgs.NS_PER_S)

    if params is None:
        log.warning('%s: no params sidecar %s; LiDAR mounts default to the platform origin',
                    path, sidecar_path(path).name)
    series = []
    for scan in scans:
        name = scan.topic.lstrip('/')
        frame_id, mount = (params.lidars.get(name) if params is not None else None) or (
            scan.frame_id, LidarMount())
        angle_min, angle_increment, range_min, range_max = scan.geometry
        series.append(ScanSeries(
            stamp_s=seconds(scan.stamps_ns), ranges_m=scan.ranges,
            intensities=scan.intensities, angle_min_rad=float(angle_min),
            angle_increment_rad=float(angle_increment), range_min_m=float(range_min),
            range_max_m=float(range_max), mount=mount, topic=name,
            frame_id=scan.frame_id or frame_id))
    if initial_pose is None:
        initial_pose = params.initial_pose if params is not None else np.zeros(3)
    trip = Trip(
        name=params.name if params is not None else path.name,
        imu=ImuSeries(stamp_s=seconds(imu_ns), angular_velocity_rad_s=rates,
                      axes_known=axes_known, linear_acceleration_m_s2=accel,
                      yaw_rate_variance=_given(rate_variances)),
        speed=SpeedSeries(stamp_s=seconds(odom_ns), speed_m_s=speeds,
                          speed_variance=_given(speed_variances)),
        scans=tuple(series),
        landmarks=landmarks,
        initial_pose=initial_pose,
        ground_truth=None if truth is None else GroundTruth(seconds(truth[0]), truth[1]),
        true_gyro_bias_rad_s=None if params is None else params.true_gyro_bias_rad_s,
        noise=NoiseFigures() if params is None else params.noise,
        static_duration_s=0.0 if params is None else params.static_duration_s)
    return BagTrip(trip=trip, start_time_ns=int(start), params=params)


def _read_bag_rosbags(path: Path, acceleration: bool = True) -> BagTrip:
    """Read a bag deserialising every message with rosbags (the reference path).

    Raises:
        BagError: as read_bag.
    """
    reader = _open(path)
    try:
        params = read_sidecar(path)
        by_topic, _ = _topics(path, reader, params)
        start = reader.start_time if reader.message_count else 0
    finally:
        reader.close()
    scan_topics = [t for t, c in by_topic.items() if c.msgtype == topics.LASER_SCAN_TYPE]
    wanted = [IMU_TOPIC, ODOM_TOPIC, *scan_topics] + [
        t for t in (MAP_TOPIC, INITIAL_POSE_TOPIC, GROUND_TRUTH_TOPIC) if t in by_topic]
    # Lists, not arrays sized by the bag's counts: those are only hints.
    imu_ns: list[int] = []
    rates: list[tuple[float, float, float]] = []
    rate_variances: list[float] = []
    accel: list[tuple[float, float, float]] = []
    has_accel = False
    axes_known: tuple[bool, bool, bool] = (True, True, True)
    odom_ns: list[int] = []
    speeds: list[float] = []
    speed_variances: list[float] = []
    truth_ns: list[int] = []
    truth: list[tuple[float, float, float]] = []
    scans = {t: _ScanCollector(path, t) for t in scan_topics}
    landmarks = None
    initial_pose = None
    for topic, _, stamp, message in iter_bag_messages(path, wanted):
        if topic == IMU_TOPIC:
            if not imu_ns:
                axes_known = msgs.axes_known_of(message.angular_velocity_covariance)
                has_accel = _has_accel(message)
            w, a = message.angular_velocity, message.linear_acceleration
            imu_ns.append(stamp)
            rates.append((w.x, w.y, w.z))
            rate_variances.append(message.angular_velocity_covariance[8])
            accel.append((a.x, a.y, a.z))
        elif topic == ODOM_TOPIC:
            odom_ns.append(stamp)
            speeds.append(message.twist.twist.linear.x)
            speed_variances.append(message.twist.covariance[0])
        elif topic in scans:
            scans[topic].add(stamp, message)
        elif topic == GROUND_TRUTH_TOPIC:
            truth_ns.append(stamp)
            truth.append(msgs.pose_of(message.pose.pose))
        elif topic == MAP_TOPIC:
            landmarks = msgs.landmarks_of(message)
        elif topic == INITIAL_POSE_TOPIC:
            initial_pose = np.array(msgs.pose_of(message.pose.pose))

    def rows(values: list[Any], width: int) -> np.ndarray:
        return np.array(values, dtype=np.float64).reshape(len(values), width)

    return _bag_trip(
        path, params, int(start), imu_ns=np.array(imu_ns, dtype=np.int64),
        rates=rows(rates, 3), rate_variances=np.array(rate_variances, dtype=np.float64),
        accel=rows(accel, 3) if has_accel and acceleration else None,
        axes_known=axes_known, odom_ns=np.array(odom_ns, dtype=np.int64),
        speeds=np.array(speeds, dtype=np.float64),
        speed_variances=np.array(speed_variances, dtype=np.float64),
        scans=[d for d in (scans[t].data() for t in scan_topics) if d is not None],
        truth=((np.array(truth_ns, dtype=np.int64), rows(truth, 3))
               if GROUND_TRUTH_TOPIC in by_topic else None),
        landmarks=landmarks, initial_pose=initial_pose)


class _ScanCollector(_ScanArrays):
    """Arrays of one LaserScan topic, filled message by message (growing as needed)."""

    def __init__(self, path: Path, topic: str) -> None:
        self.path = path
        self.topic = topic
        self.n = 0
        self.stamps = np.zeros(0, dtype=np.int64)
        self.ranges: np.ndarray | None = None
        self.intensities: np.ndarray | None = None
        self.first: Any = None

    def add(self, stamp: int, message: Any) -> None:
        beams = len(message.ranges)
        if self.first is None:
            self.first = message
            self.ranges = np.empty((0, beams), dtype=np.float32)
            if len(message.intensities):
                self.intensities = np.empty((0, beams), dtype=np.float32)
        first = self.first
        assert self.ranges is not None
        geometry = (message.angle_min, message.angle_increment, message.range_min,
                    message.range_max)
        if beams != self.ranges.shape[1] or geometry != (
                first.angle_min, first.angle_increment, first.range_min, first.range_max):
            raise BagError(f"{self.path}: topic '{self.topic}': scan {self.n + 1} changes the "
                           'beam count or geometry; expected one fixed LiDAR per topic')
        if self.intensities is not None and len(message.intensities) != beams:
            raise BagError(f"{self.path}: topic '{self.topic}': scan {self.n + 1} has "
                           f'{len(message.intensities)} intensities for {beams} beams')
        needed = self.n + 1
        self.stamps = _grown(self.stamps, self.n, needed)
        self.ranges = _grown(self.ranges, self.n, needed)
        self.stamps[self.n] = stamp
        self.ranges[self.n] = message.ranges
        if self.intensities is not None:
            self.intensities = _grown(self.intensities, self.n, needed)
            self.intensities[self.n] = message.intensities
        self.n += 1


def read_trip_bag(path: Path | str) -> Trip:
    """Read a bag written by write_trip_bag (and its sidecar) into a Trip.

    Stamps are s since the bag's first message; read_bag also returns that message's stamp.

    Raises:
        BagError: missing or unreadable bag, no /imu or /odom topic, inconsistent scans.
    """
    return read_bag(path).trip
