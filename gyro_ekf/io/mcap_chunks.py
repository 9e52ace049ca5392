"""Read the raw messages of chosen topics from an MCAP file, fast.

A minimal reader written from the MCAP specification (https://mcap.dev/spec), for the one
thing `bag_reader` needs: per topic, the log times and the raw CDR payloads in log-time
order. It walks the data section once: chunks are decompressed whole ('zstd', 'lz4' or
none), a tight Python loop only follows the record lengths, and numpy then picks the opcode,
channel id and log time of every record at once, so a message costs a few hundred
nanoseconds where rosbags' Reader spends several microseconds.

Anything it does not handle, or a file that is not intact (bad magic, a record running past
its end, an unknown chunk compression, no DataEnd/Footer or trailing magic), raises
`UnsupportedMcap` instead of returning partial data; the caller then falls back to rosbags,
which reports the problem in its own words if the file really is broken.

The summary section (indexes, statistics) is not read: the data section alone says which
messages exist, and reading it is what costs anyway. CRCs are not checked.

The file is memory-mapped and the payloads are memoryviews into the map (or into a
decompressed chunk), so nothing is copied; the map lives as long as any payload does. As
with any mmap, the file must not be truncated while its payloads are in use.
"""

from __future__ import annotations

from collections.abc import Callable, Collection
from dataclasses import dataclass
import gc
import mmap
from pathlib import Path
import struct
from typing import Any

import numpy as np
from numpy.typing import NDArray

__all__ = ['MAGIC', 'TopicMessages', 'UnsupportedMcap', 'read_topics', 'stream_topics']

MAGIC = b'\x89MCAP0\r\n'
"""Leading and trailing magic of an MCAP (major version 0) file."""

_FOOTER, _SCHEMA, _CHANNEL, _MESSAGE, _CHUNK, _DATA_END = 0x02, 0x03, 0x04, 0x05, 0x06, 0x0F

_RECORD = struct.Struct('<BQ')
_RECORD_HEAD_SIZE = _RECORD.size
_U16 = struct.Struct('<H')
_U32 = struct.Struct('<I')
_U64 = struct.Struct('<Q')
_CHUNK_HEAD = struct.Struct('<QQQI')
_CHANNEL_HEAD = struct.Struct('<HH')
# A Message's content: channel_id u16, sequence u32, log_time u64, publish_time u64, data.
_CHANNEL_ID_AT = _RECORD_HEAD_SIZE
_LOG_TIME_AT = _RECORD_HEAD_SIZE + 6
_DATA_AT = _RECORD_HEAD_SIZE + 22

# Values of the channel table besides topic indexes (>= 0).
_UNKNOWN = -2
_UNWANTED = -1


class UnsupportedMcap(Exception):
    """The file uses something this reader does not handle; the caller falls back to rosbags."""


@dataclass(frozen=True, slots=True)
class TopicMessages:
    """The messages of one topic, in ascending log time (ties keep file order).

    Attributes:
        msgtype: schema name of the topic's channel(s), e.g. 'sensor_msgs/msg/Imu'.
        log_time_ns: log times in ns, shape (n,), int64.
        payloads: raw message data (CDR with its 4-byte encapsulation header), same order;
            memoryviews into the file or a decompressed chunk.
    """

    msgtype: str
    log_time_ns: NDArray[np.int64]
    payloads: list[bytes | memoryview]


@dataclass(slots=True)
class _Channel:
    topic: str
    schema_id: int


class _Scan:
    """One pass over a file: its schemas, channels and the wanted topics' messages."""

    def __init__(self, path: Path, topics: Collection[str],
                 consumer: Callable[[str, TopicMessages], None] | None = None,
                 batch_messages: int = 0) -> None:
        self.path = path
        # With a consumer, messages are handed over every batch_messages (after a chunk), so
        # a long bag never holds all its payloads at once.
        self.consumer = consumer
        self.batch_messages = batch_messages
        self.pending = 0
        self.topics = sorted(set(topics))
        self.topic_index = {topic: i for i, topic in enumerate(self.topics)}
        self.schemas: dict[int, str] = {}
        self.channels: dict[int, _Channel] = {}
        # Channel id -> index of its topic in self.topics, _UNWANTED or _UNKNOWN: one numpy
        # lookup sorts every message of a chunk.
        self.table = np.full(1 << 16, _UNKNOWN, dtype=np.int32)
        self.times: list[list[NDArray[np.uint64]]] = [[] for _ in self.topics]
        self.payloads: list[list[bytes | memoryview]] = [[] for _ in self.topics]
        # Ids that messages used before their Channel record appeared (invalid per the spec):
        # if such a channel turns out to be wanted, messages were missed, so refuse the file.
        self.orphans: set[int] = set()
        self.zstd: Any = None
        self.last_time = [-1] * len(self.topics)
        self.mapped: mmap.mmap | None = None

    def fail(self, what: str) -> UnsupportedMcap:
        return UnsupportedMcap(f'{self.path}: {what}')

    # -- records other than messages ---------------------------------------------------

    def string(self, buf: bytes | memoryview, pos: int, end: int) -> tuple[str, int]:
        if pos + 4 > end:
            raise self.fail('a string length runs past its record')
        size = _U32.unpack_from(buf, pos)[0]
        start = pos + 4
        if start + size > end:
            raise self.fail('a string runs past its record')
        try:
            return str(buf[start:start + size], 'utf-8'), start + size
        except UnicodeDecodeError as error:
            raise self.fail(f'a string is not UTF-8 ({error})') from None

    def schema(self, buf: bytes | memoryview, body: int, end: int) -> None:
        if body + 2 > end:
            raise self.fail('Schema record too short')
        schema_id = _U16.unpack_from(buf, body)[0]
        name, _ = self.string(buf, body + 2, end)
        if self.schemas.setdefault(schema_id, name) != name:
            raise self.fail(f'schema {schema_id} ({self.schemas[schema_id]}) redefined as {name}')

    def channel(self, buf: bytes | memoryview, body: int, end: int) -> None:
        if body + 4 > end:
            raise self.fail('Channel record too short')
        channel_id, schema_id = _CHANNEL_HEAD.unpack_from(buf, body)
        topic, pos = self.string(buf, body + 4, end)
        encoding, _ = self.string(buf, pos, end)
        known = self.channels.get(channel_id)
        if known is not None:
            # Writers may repeat a Channel record (e.g. in every chunk); only a change is wrong.
            if known.topic != topic or known.schema_id != schema_id:
                raise self.fail(f'channel {channel_id} ({known.topic}) redefined as {topic}')
            return
        self.channels[channel_id] = _Channel(topic, schema_id)
        index = self.topic_index.get(topic)
        if index is None:
            self.table[channel_id] = _UNWANTED
            return
        if channel_id in self.orphans:
            raise self.fail(f'messages of channel {channel_id} ({topic}) precede its Channel '
                            'record')
        if encoding != 'cdr':
            raise self.fail(f'topic {topic} has message encoding {encoding!r}, not cdr')
        self.table[channel_id] = index

    def chunk(self, buf: bytes | memoryview, body: int, end: int) -> None:
        if body + _CHUNK_HEAD.size > end:
            raise self.fail('Chunk record too short')
        uncompressed_size = _CHUNK_HEAD.unpack_from(buf, body)[2]
        compression, pos = self.string(buf, body + _CHUNK_HEAD.size, end)
        if pos + 8 > end:
            raise self.fail('a chunk\'s records length runs past the chunk')
        size = _U64.unpack_from(buf, pos)[0]
        start = pos + 8
        if start + size > end:
            raise self.fail('a chunk\'s records run past the chunk')
        if compression == '':
            if size != uncompressed_size:
                raise self.fail(f'an uncompressed chunk holds {size} bytes, its header says '
                                f'{uncompressed_size}')
            self.records(buf, start, start + size, top_level=False)
            return
        data = memoryview(buf)[start:start + size]
        if compression == 'zstd':
            records = self.unzstd(data, uncompressed_size)
        elif compression == 'lz4':
            records = self.unlz4(data)
        else:
            raise self.fail(f'chunk compression {compression!r} is not supported')
        if len(records) != uncompressed_size:
            raise self.fail(f'a chunk holds {len(records)} bytes, its header says '
                            f'{uncompressed_size}')
        self.records(memoryview(records), 0, len(records), top_level=False)

    def unzstd(self, data: memoryview, uncompressed_size: int) -> bytes:
        import zstandard
        if not data:
            return b''
        if self.zstd is None:
            self.zstd = zstandard.ZstdDecompressor()
        try:
            # max_output_size bounds frames that do not state their content size.
            return self.zstd.decompress(data, max_output_size=uncompressed_size)
        except zstandard.ZstdError as error:
            raise self.fail(f'bad zstd chunk ({error})') from None

    def unlz4(self, data: memoryview) -> bytes:
        import lz4.frame
        if not data:
            return b''
        try:
            return lz4.frame.decompress(data)
        except RuntimeError as error:
            raise self.fail(f'bad lz4 chunk ({error})') from None

    # -- the walk ---------------------------------------------------------------------

    def walk(self, buf: bytes | memoryview, begin: int, end: int, top_level: bool) -> list[int]:
        """Return the offsets of the records in buf[begin:end] and, last, where the walk ended.

        At top level the walk stops at DataEnd or Footer and fails if neither comes.
        """
        offsets: list[int] = []
        # Hot loop: only the lengths are read here; numpy reads the rest afterwards. A header
        # straddling `end` cannot go unnoticed: the position after it lies beyond `end`.
        append = offsets.append
        head = _RECORD.unpack_from
        length_at = _U64.unpack_from
        pos = begin
        try:
            if top_level:
                while pos < end:
                    opcode, length = head(buf, pos)
                    if opcode == _DATA_END or opcode == _FOOTER:
                        break
                    append(pos)
                    pos += _RECORD_HEAD_SIZE + length
                else:
                    if pos == end:
                        raise self.fail('no DataEnd or Footer record: the file is incomplete')
            else:
                while pos < end:
                    append(pos)
                    pos += _RECORD_HEAD_SIZE + length_at(buf, pos + 1)[0]
        except struct.error:
            raise self.fail('a record header runs past the end of its '
                            + ('file' if top_level else 'chunk')) from None
        if pos > end:
            raise self.fail('a record (opcode {:#04x}) runs past the end of its {}'.format(
                buf[offsets[-1]], 'file' if top_level else 'chunk'))
        offsets.append(pos)
        return offsets

    def records(self, buf: bytes | memoryview, begin: int, end: int, top_level: bool) -> None:
        """Take in the records of buf[begin:end] in file order: messages in batches."""
        bounds = np.array(self.walk(buf, begin, end, top_level), dtype=np.int64)
        starts, ends = bounds[:-1], bounds[1:]
        octets = np.frombuffer(buf, dtype=np.uint8)
        opcodes = octets[starts]
        # Row p is buf[p:p + 8]: indexing rows gathers unaligned u64 fields in one call.
        words = (np.lib.stride_tricks.sliding_window_view(octets, 8) if octets.size >= 8
                 else np.zeros((0, 8), dtype=np.uint8))
        first = 0
        for i in np.flatnonzero(opcodes != _MESSAGE).tolist():
            if i > first:
                self.messages(buf, octets, words, starts[first:i], ends[first:i])
            opcode, body, end = int(opcodes[i]), int(starts[i]) + _RECORD_HEAD_SIZE, int(ends[i])
            if opcode == _CHUNK:
                if not top_level:
                    raise self.fail('a chunk inside a chunk')
                self.chunk(buf, body, end)
                if self.consumer is not None and self.pending >= self.batch_messages:
                    self.emit()
                    self.release(end)
            elif opcode == _CHANNEL:
                self.channel(buf, body, end)
            elif opcode == _SCHEMA:
                self.schema(buf, body, end)
            # Anything else (Header, indexes, attachments, metadata, unknown opcodes) is
            # skipped, as the spec asks of readers.
            first = i + 1
        if first < starts.size:
            self.messages(buf, octets, words, starts[first:], ends[first:])

    def messages(self, buf: bytes | memoryview, octets: NDArray[np.uint8],
                 words: NDArray[np.uint8], starts: NDArray[np.int64],
                 ends: NDArray[np.int64]) -> None:
        """Take in a run of Message records (record offsets `starts`, ends `ends`)."""
        if np.any(ends - starts < _DATA_AT):
            raise self.fail('a Message record is too short')
        channel_ids = (octets[starts + _CHANNEL_ID_AT].astype(np.int32)
                       | (octets[starts + _CHANNEL_ID_AT + 1].astype(np.int32) << 8))
        indexes = self.table[channel_ids]
        unknown = indexes == _UNKNOWN
        if np.any(unknown):
            self.orphans.update(channel_ids[unknown].tolist())
        for index in np.unique(indexes[indexes >= 0]).tolist():
            mine = indexes == index
            at = starts[mine]
            self.times[index].append(words[at + _LOG_TIME_AT].view('<u8').ravel())
            # Measured: a comprehension beats map(buf.__getitem__, map(slice, ...)) by a third.
            firsts, lasts = (at + _DATA_AT).tolist(), ends[mine].tolist()
            self.payloads[index].extend([buf[first:last] for first, last in zip(firsts, lasts)])
            self.pending += len(firsts)

    # -- the result -------------------------------------------------------------------

    def emit(self) -> None:
        """Hand every held message to the consumer, topic by topic, and forget it."""
        msgtypes = self.msgtypes()
        for topic, index in self.topic_index.items():
            if not self.times[index]:
                continue
            batch = self.ordered(topic, msgtypes[topic])
            if batch.log_time_ns[0] < self.last_time[index]:
                raise self.fail(f'messages of {topic} are not in log-time order across '
                                'chunks')
            self.last_time[index] = int(batch.log_time_ns[-1])
            self.times[index] = []
            self.payloads[index] = []
            self.consumer(topic, batch)
        self.pending = 0

    def release(self, end: int) -> None:
        """Let go of the mapped pages before `end` (their messages were handed over).

        Resident pages of a file mapping count in the process's memory; without this a
        one-hour bag read through the map would stay resident as a whole.
        """
        if self.mapped is not None and hasattr(mmap, 'MADV_DONTNEED'):
            self.mapped.madvise(mmap.MADV_DONTNEED, 0, end - end % mmap.PAGESIZE)

    def msgtypes(self) -> dict[str, str]:
        """Wanted topic -> its message type, for every wanted topic with a channel."""
        msgtypes: dict[str, str] = {}
        for channel_id, channel in self.channels.items():
            if channel.topic not in self.topic_index:
                continue
            name = self.schemas.get(channel.schema_id)
            if name is None:
                raise self.fail(f'channel {channel_id} ({channel.topic}) has no known schema '
                                f'(schema id {channel.schema_id})')
            if msgtypes.setdefault(channel.topic, name) != name:
                raise self.fail(f'topic {channel.topic} has channels of two types, '
                                f'{msgtypes[channel.topic]} and {name}')
        return msgtypes

    def result(self) -> dict[str, TopicMessages]:
        return {topic: self.ordered(topic, msgtype)
                for topic, msgtype in self.msgtypes().items()}

    def ordered(self, topic: str, msgtype: str) -> TopicMessages:
        index = self.topic_index[topic]
        parts = self.times[index]
        times = np.concatenate(parts) if parts else np.zeros(0, dtype=np.uint64)
        if times.size and times.max() > np.iinfo(np.int64).max:
            raise self.fail(f'topic {topic} has a log time beyond int64')
        times = times.astype(np.int64)
        payloads = self.payloads[index]
        if times.size > 1 and not np.all(np.diff(times) >= 0):
            order = np.argsort(times, kind='stable')
            times = times[order]
            payloads = [payloads[i] for i in order.tolist()]
        return TopicMessages(msgtype, times, payloads)


def _map(path: Path) -> tuple[memoryview, mmap.mmap | None]:
    """Map the file read-only (reading 100 MB into fresh memory costs more than parsing)."""
    with open(path, 'rb') as stream:
        size = stream.seek(0, 2)
        if size == 0:
            return memoryview(b''), None
        try:
            mapped = mmap.mmap(stream.fileno(), 0, access=mmap.ACCESS_READ)
        except (OSError, ValueError):
            stream.seek(0)
            return memoryview(stream.read()), None
    if hasattr(mmap, 'MADV_SEQUENTIAL'):
        mapped.madvise(mmap.MADV_SEQUENTIAL)
    return memoryview(mapped), mapped


def read_topics(path: Path | str, topics: Collection[str]) -> dict[str, TopicMessages]:
    """Read the log times and raw payloads of some topics of an MCAP file.

    Args:
        path: the .mcap file.
        topics: topic names wanted (absolute, e.g. '/imu').

    Returns:
        topic -> its messages in ascending log time (stable), for every wanted topic that has
        a channel in the file (with empty arrays if it has no message); topics without a
        channel are absent. Messages of one topic on several channels are merged.

    Raises:
        UnsupportedMcap: bad magic, an unsupported chunk compression, a truncated or corrupt
            record, no DataEnd/Footer, a wanted topic not in CDR or without a schema, or
            channels of two types on one topic.
        OSError: the file cannot be read.
    """
    scan = _Scan(Path(path), topics)
    _scan_file(scan)
    return scan.result()


def stream_topics(path: Path | str, topics: Collection[str],
                  consumer: Callable[[str, TopicMessages], None],
                  batch_messages: int = 65_536) -> dict[str, str]:
    """Hand the messages of some topics to consumer in batches, in log-time order per topic.

    Like read_topics, but the messages go to ``consumer(topic, batch)`` whenever about
    batch_messages have been read (at a chunk boundary), so memory stays bounded on long
    bags. Batches of one topic come in ascending log time; a file whose chunks are not in
    that order raises UnsupportedMcap (batches already handed over stay with the consumer,
    who should start over with another reader). Batches handed over during the scan reach
    the consumer while the garbage collector is paused (see read_topics); keep it short.

    Returns:
        topic -> message type, for every wanted topic with a channel in the file.

    Raises:
        UnsupportedMcap: as read_topics, or chunks out of log-time order.
        OSError: the file cannot be read.
    """
    scan = _Scan(Path(path), topics, consumer, batch_messages)
    _scan_file(scan)
    scan.emit()
    return scan.msgtypes()


def _scan_file(scan: _Scan) -> None:
    path = scan.path
    data, scan.mapped = _map(path)
    size = len(data)
    if size < 2 * len(MAGIC) or data[:len(MAGIC)] != MAGIC:
        raise scan.fail('not an MCAP file (bad leading magic)')
    if data[size - len(MAGIC):] != MAGIC:
        raise scan.fail('no trailing magic: the file is truncated or incomplete')
    # A payload is one new object per message, never part of a cycle; the collector's passes
    # over them (triggered every few hundred allocations) would add about a third to the time.
    collecting = gc.isenabled()
    gc.disable()
    try:
        # The trailing magic is left out so that no record may run into it.
        scan.records(data, len(MAGIC), size - len(MAGIC), top_level=True)
    finally:
        if collecting:
            gc.enable()
