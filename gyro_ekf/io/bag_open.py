"""Open a rosbag2 folder and verify what every reader of it relies on.

Bags are verified, never silently wrong: metadata.yaml must list its storage files once
each and describe each topic as its storage files do; each known topic must have the type
the readers expect for it (`EXPECTED_TYPES`, plus the sidecar's LiDAR topics); every stamp
must lie in the bag's stated time range; message counts from the metadata are only hints;
and whatever rosbags raises on damaged bytes becomes a BagError naming the bag (`reading`).
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from contextlib import contextmanager
import math
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from rosbags.rosbag2 import Reader

from gyro_ekf import topics
from gyro_ekf.errors import GyroEkfError, one_line
from gyro_ekf.io import fast_cdr, mcap_chunks, messages as msgs
from gyro_ekf.io.errors import BagError
from gyro_ekf.io.sidecar import BagParams

__all__ = ['EXPECTED_TYPES', 'GROUND_TRUTH_TOPIC', 'IMU_TOPIC', 'INITIAL_POSE_TOPIC',
           'MAP_TOPIC', 'NO_MESSAGES', 'ODOM_TOPIC', 'bag_bytes', 'check_stamp',
           'check_stamps', 'check_types', 'deserialize', 'every_time', 'metadata', 'open_bag',
           'reading', 'time_span', 'topic_connections']

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


@contextmanager
def reading(path: Path) -> Iterator[None]:
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
        # One line: a YAML error in metadata.yaml comes with a multi-line pointer.
        reason = one_line(err) or type(err).__name__
        raise BagError(f'{path}: cannot read the bag ({type(err).__name__}): {reason}'
                       f'{_reindex_hint(path)}') from None


def _reindex_hint(path: Path) -> str:
    from gyro_ekf.io.reindex import needs_reindex

    reason = needs_reindex(path)
    return '' if reason is None else f'; {reason}: run `gyro-ekf reindex {path}`'


def _not_a_file(path: Path) -> None:
    """Refuse a file given for a bag: rosbags would say 'Unrecognized storage format'."""
    if path.is_file():
        inside = (path.parent / 'metadata.yaml').exists()
        raise BagError(f'{path}: is a file; give the bag folder'
                       + (f' that holds it, {path.parent}' if inside
                          else ' (the one holding metadata.yaml)'))


def open_bag(path: Path) -> Reader:
    """Open a bag folder with rosbags after checking its metadata and storage connections."""
    if not path.exists():
        raise BagError(f'{path}: no such bag')
    _not_a_file(path)
    if path.is_dir() and not (path / 'metadata.yaml').exists():
        if any(path.glob('*.mcap')):
            raise BagError(f'{path}: no metadata.yaml (was its recorder killed?); run '
                           f'`gyro-ekf reindex {path}`')
        raise BagError(f'{path}: not a rosbag2 folder (no metadata.yaml)')
    with reading(path):
        reader = Reader(path)
        reader.open()
    files = metadata(path).get('relative_file_paths')
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


_YAML_LOADER = getattr(yaml, 'CSafeLoader', yaml.SafeLoader)
"""libyaml's safe loader where PyYAML has it: the same documents, about 9x faster (a bag's
metadata.yaml is read two or three times per read)."""


def metadata(path: Path) -> dict[str, Any]:
    """Read the rosbag2_bagfile_information mapping of a bag folder's metadata.yaml."""
    _not_a_file(path)
    meta_path = path / 'metadata.yaml'
    try:
        document = yaml.load(meta_path.read_text(encoding='utf-8'), Loader=_YAML_LOADER)
        return dict(document['rosbag2_bagfile_information'])
    except (OSError, yaml.YAMLError, KeyError, TypeError, ValueError) as err:
        raise BagError(f'{meta_path}: cannot read the bag metadata: {err}') from None


def deserialize(path: Path, topic: str, msgtype: str, stamp: int,
                data: bytes | memoryview) -> Any:
    """Deserialise one message with rosbags; damage is a BagError naming topic and stamp."""
    try:
        return msgs.deserialize(data, msgtype)
    except fast_cdr.DECODE_FAILURES as err:
        raise BagError(f"{path}: topic '{topic}': message at {stamp} ns does not decode as "
                       f'{msgtype}: {err}') from None


def check_types(path: Path, connections: Iterable[Any], params: BagParams | None) -> None:
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


def topic_connections(path: Path, reader: Reader, params: BagParams | None
                      ) -> tuple[dict[str, Any], dict[str, int]]:
    """Return connections and message-count hints by topic; check names and types."""
    check_types(path, reader.connections, params)
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


NO_MESSAGES = (0, 0)
"""The span of a bag whose metadata states no messages: any message contradicts it."""


def time_span(reader: Reader) -> tuple[int, int]:
    """Return the bag's stated [start, end) in ns (MCAP statistics or metadata).

    A bag that states no messages (message_count 0 or none) gets an empty span: rosbags then
    gives no start time, and stamps would count from the epoch (1.7e9 s) unnoticed.
    """
    if not reader.message_count:
        return NO_MESSAGES
    return int(reader.start_time), int(reader.end_time)


def every_time(path: Path) -> tuple[int, int]:
    """Return the start and stop for reader.messages that let every message through.

    By default rosbags yields only the messages of an MCAP chunk inside the chunk's own time
    range, so a damaged log time would silently drop its message; asked for every time, it
    yields it and the stated time range refuses it. sqlite3 stores signed 64-bit stamps.
    """
    if metadata(path).get('storage_identifier') == 'mcap':
        return 0, 2**64
    return 0, 2**63 - 1


def check_stamp(path: Path, topic: str, stamp: int, span: tuple[int, int]) -> None:
    if span == NO_MESSAGES:
        raise BagError(f"{path / 'metadata.yaml'}: message_count states no messages, but "
                       f"topic '{topic}' has a message at {stamp} ns")
    if not span[0] <= stamp < span[1]:
        raise BagError(f"{path}: topic '{topic}': message at {stamp} ns lies outside the "
                       f'time range the bag states, [{span[0]}, {span[1]}) ns')


def check_stamps(path: Path, topic: str, stamps: np.ndarray, span: tuple[int, int]) -> None:
    """Refuse stamps outside the bag's stated time range (a damaged time or statistics)."""
    if not stamps.size:
        return
    outside = (stamps < span[0]) | (stamps >= span[1])
    if outside.any():
        check_stamp(path, topic, int(stamps[int(np.argmax(outside))]), span)


def bag_bytes(path: Path) -> int:
    try:
        return sum(f.stat().st_size for f in path.iterdir() if f.is_file())
    except OSError:
        return 0
