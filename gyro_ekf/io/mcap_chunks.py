"""Read the raw messages of chosen topics from an MCAP file, fast, and verify them.

A minimal reader written from the MCAP specification (https://mcap.dev/spec), for the one
thing `bag_reader` needs: per topic, the log times and the raw CDR payloads in log-time
order. It walks the data section once: chunks are decompressed whole ('zstd', 'lz4' or
none), a tight Python loop only follows the record lengths, and numpy then picks the opcode,
channel id and log time of every record at once, so a message costs a few hundred
nanoseconds where rosbags' Reader spends several microseconds.

Nothing it returns is silently wrong. Every length is bounded by the bytes present before
anything is sliced or allocated (a chunk's declared uncompressed size also by a sane ratio
and an absolute cap, and checked after decompression); the data section must end with a
DataEnd record exactly where the Footer puts the next section; every message log time must
lie in its chunk's [start, end] range; and the CRCs the file carries are checked: the
data-section CRC of DataEnd, the summary CRC of the Footer and, where no data-section CRC
covers them, the chunks' uncompressed CRCs. CRCs are computed on a worker thread (zlib
releases the GIL) while the walk goes on, and checked before the scan returns.

Two kinds of refusal:
- `CorruptMcap`: the file is damaged (a CRC mismatch, a length running past its end, a
  truncated file, a log time outside its chunk). Final: reading it another way would only
  give other numbers.
- `UnsupportedMcap`: the file uses something this reader does not handle (an unknown chunk
  compression, a codec that is not installed, chunks out of log-time order when streaming);
  the caller falls back to rosbags.
Both name the file, where in it (byte offset) and why.

The summary section (indexes, statistics) is not read, only its CRC: the data section alone
says which messages exist, and reading it is what costs anyway.

The file is memory-mapped and the payloads are memoryviews into the map (or into a
decompressed chunk), so nothing is copied; the map lives as long as any payload does. As
with any mmap, the file must not be truncated while its payloads are in use.
"""

from __future__ import annotations

from collections.abc import Callable, Collection
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
import gc
import mmap
from pathlib import Path
import struct
from typing import Any, TypeVar
import zlib

import numpy as np
from numpy.typing import NDArray

__all__ = ['ChannelInfo', 'CorruptMcap', 'MAGIC', 'McapError', 'TopicMessages',
           'UnsupportedMcap', 'Verified', 'read_records', 'stream_topics', 'verify_file']

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
_FOOTER_BODY = struct.Struct('<QQI')
_FOOTER_SIZE = _RECORD_HEAD_SIZE + _FOOTER_BODY.size
# The summary CRC covers the Footer up to (not including) its own CRC field.
_FOOTER_CRC_AT = _RECORD_HEAD_SIZE + 16
# A Message's content: channel_id u16, sequence u32, log_time u64, publish_time u64, data.
_CHANNEL_ID_AT = _RECORD_HEAD_SIZE
_LOG_TIME_AT = _RECORD_HEAD_SIZE + 6
_DATA_AT = _RECORD_HEAD_SIZE + 22

_MAX_CHUNK_BYTES = 1 << 30
"""Largest uncompressed chunk accepted (writers close chunks at about 1 MiB)."""
_MAX_RATIO = 4096
_MIN_ALLOWANCE = 1 << 24
"""A compressed chunk may declare up to max(_MIN_ALLOWANCE, _MAX_RATIO x its size) bytes."""

_T = TypeVar('_T')

# Values of the channel table besides topic indexes (>= 0).
_UNKNOWN = -2
_UNWANTED = -1


class McapError(Exception):
    """A file this reader refuses.

    Attributes:
        path: the file.
        where: the place in it, e.g. 'chunk at offset 1234' ('' for the whole file).
        reason: what is wrong.
        offset: file offset of the top-level record at fault, when one is.
    """

    def __init__(self, path: Path, reason: str, where: str = '',
                 offset: int | None = None) -> None:
        """Name the file, the place and the reason."""
        super().__init__(f'{path}: {where}: {reason}' if where else f'{path}: {reason}')
        self.path = path
        self.where = where
        self.reason = reason
        self.offset = offset


class UnsupportedMcap(McapError):
    """The file uses something this reader does not handle; the caller falls back to rosbags."""


class CorruptMcap(McapError):
    """The file is damaged (CRC, bounds, truncation, times); no other reader should be tried."""


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


@dataclass(frozen=True, slots=True)
class ChannelInfo:
    """A topic's channel as the file declares it (what `reindex` needs to write it again).

    Attributes:
        msgtype: its schema name.
        metadata: the channel's metadata map, serialised as in the file (without its length).
        compressions: the chunk compressions of the file ('' for none).
    """

    msgtype: str
    metadata: bytes
    compressions: frozenset[str] = frozenset()


@dataclass(frozen=True, slots=True)
class Verified:
    """What verify_file checked in a file that passed.

    Attributes:
        chunks: Chunk records read (each decompressed and walked).
        chunk_crcs: of those, the chunks that carry their own CRC.
        data_crc: the DataEnd record carries a data-section CRC (it covers every chunk).
        summary_crc: the Footer carries a summary CRC.
        counts: topic -> Message records of it in the data section (the walk's own count,
            not the summary's statistics, which are not checked against the data).
        log_times: the first and last message log time in ns, or None without messages.
    """

    chunks: int
    chunk_crcs: int
    data_crc: bool
    summary_crc: bool
    counts: dict[str, int]
    log_times: tuple[int, int] | None


@dataclass(slots=True)
class _Channel:
    topic: str
    schema_id: int
    metadata: bytes = b''


class _Crcs:
    """CRC32s computed on one worker thread while the walk goes on; checked at the end.

    The data section's CRC covers nearly the whole file: it is taken piece by piece behind
    the walk (`advance`), so its pages are released with the walk's instead of all being
    resident at once (a one-hour bag is 750 MB).
    """

    def __init__(self) -> None:
        self.pool: ThreadPoolExecutor | None = None
        self.pending: list[tuple[Future[int], int, str, int]] = []
        self.running: _RunningCrc | None = None

    def _submit(self, function: Callable[..., int], data: bytes | memoryview) -> Future[int]:
        if self.pool is None:
            self.pool = ThreadPoolExecutor(1, thread_name_prefix='mcap-crc')
        return self.pool.submit(function, data)

    def check(self, data: bytes | memoryview, expected: int, where: str, offset: int) -> None:
        self.pending.append((self._submit(zlib.crc32, data), expected, where, offset))

    def check_in_pieces(self, data: bytes | memoryview, end: int, expected: int, where: str,
                        offset: int) -> None:
        """Check the CRC of data[:end], fed in order by advance() and finished by failure()."""
        self.running = _RunningCrc(data, end, expected, where, offset)

    def advance(self, upto: int) -> None:
        """Queue the running CRC's next piece, up to `upto` (the walk is done with it)."""
        running = self.running
        if running is None:
            return
        upto = min(upto, running.end)
        if upto > running.pos:
            # One worker: pieces are taken in the order they are queued.
            running.last = self._submit(running.add, running.data[running.pos:upto])
            running.pos = upto

    def failure(self, path: Path) -> CorruptMcap | None:
        """Wait for every CRC; return the error of the first mismatch, or None."""
        running = self.running
        if running is not None:
            self.advance(running.end)
            self.running = None
            if running.last is not None:
                self.pending.append((running.last, running.expected, running.where,
                                     running.offset))
        try:
            for future, expected, where, offset in self.pending:
                computed = future.result()
                if computed != expected:
                    return CorruptMcap(path, f'CRC mismatch (stored {expected:#010x}, '
                                       f'computed {computed:#010x})', where, offset)
            return None
        finally:
            self.pending = []
            if self.pool is not None:
                self.pool.shutdown(wait=True)
                self.pool = None


class _RunningCrc:
    """The CRC32 of data[:end] so far (pos bytes taken), one piece after another."""

    def __init__(self, data: bytes | memoryview, end: int, expected: int, where: str,
                 offset: int) -> None:
        self.data, self.end, self.expected, self.where, self.offset = (
            data, end, expected, where, offset)
        self.pos = 0
        self.value = 0
        self.last: Future[int] | None = None

    def add(self, piece: bytes | memoryview) -> int:
        self.value = zlib.crc32(piece, self.value)
        return self.value


def _zstd_module() -> Any:
    try:
        from compression import zstd  # type: ignore[import-not-found]  # Python 3.14+
    except ImportError:
        from backports import zstd  # type: ignore[import-not-found,no-redef]
    return zstd


class _Scan:
    """One pass over a file: its schemas, channels and the wanted topics' messages."""

    def __init__(self, path: Path, topics: Collection[str] | None,
                 consumer: Callable[[str, TopicMessages], None] | None = None,
                 batch_messages: int = 0) -> None:
        self.path = path
        # None: every topic, as its Channel record comes.
        self.every_topic = topics is None
        topics = () if topics is None else topics
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
        # Ids that messages used before their Channel record appeared (invalid per the spec),
        # with the first such message's place: if such a channel turns out to be wanted,
        # messages were missed, so refuse the file; if none ever appears, the id is damage.
        self.orphans: dict[int, tuple[str, int | None]] = {}
        self.last_time = [-1] * len(self.topics)
        self.mapped: mmap.mmap | None = None
        self.crcs = _Crcs()
        self.compressions: set[str] = set()
        # True once a data-section CRC covers every byte of the chunks (then their own
        # CRCs add nothing).
        self.data_crc = False
        # What the file carries: chunks read, chunks with a CRC, a summary CRC.
        self.chunk_count = 0
        self.chunk_crc_count = 0
        self.summary_crc = False
        # The chunk being read: its file offset and [start, end] log-time range.
        self.chunk_at: int | None = None
        self.chunk_times: tuple[int, int] | None = None
        # verify_file only: messages per channel id and the log-time range of every message,
        # what the data holds, for `info` to hold metadata.yaml to.
        self.tally: NDArray[np.int64] | None = None
        self.log_times: tuple[int, int] | None = None

    def check_orphans(self) -> None:
        """Refuse messages of a channel no Channel record in the data section defines.

        Such a message cannot be told apart from damage (a flipped bit in its channel id,
        or in the id of its Channel record): dropping it would lose, say, every /odom
        message without a word.
        """
        undefined = sorted(set(self.orphans) - set(self.channels))
        if undefined:
            where, offset = self.orphans[undefined[0]]
            raise CorruptMcap(self.path, f'a message refers to channel {undefined[0]}, which no '
                                         'Channel record defines', where, offset)

    def where(self, pos: int) -> str:
        """Describe position pos of the buffer being read."""
        if self.chunk_at is None:
            return f'offset {pos}'
        return f'chunk at offset {self.chunk_at}, byte {pos} of its records'

    def corrupt(self, reason: str, pos: int | None = None) -> CorruptMcap:
        """Return the error for damage at pos (None: the chunk being read, or the file)."""
        return CorruptMcap(self.path, reason, *self.place(pos))

    def unsupported(self, reason: str, pos: int | None = None) -> UnsupportedMcap:
        return UnsupportedMcap(self.path, reason, *self.place(pos))

    def place(self, pos: int | None) -> tuple[str, int | None]:
        """Describe pos, and the offset of the top-level record it lies in."""
        if self.chunk_at is not None:
            if pos is None:
                return f'chunk at offset {self.chunk_at}', self.chunk_at
            return self.where(pos), self.chunk_at
        return ('', None) if pos is None else (self.where(pos), pos)

    # -- the ends of the file -----------------------------------------------------------

    def check_ends(self, buf: memoryview, data_end: int, size: int) -> None:
        """Check DataEnd and Footer agree on where the data section ends; queue their CRCs.

        data_end is where the top-level walk stopped (a DataEnd or Footer record).
        """
        footer = size - len(MAGIC) - _FOOTER_SIZE
        if footer < len(MAGIC) or _RECORD.unpack_from(buf, footer) != (
                _FOOTER, _FOOTER_BODY.size):
            raise CorruptMcap(self.path, 'no Footer record before the trailing magic',
                              f'offset {max(footer, 0)}')
        summary_start, summary_offset_start, summary_crc = _FOOTER_BODY.unpack_from(
            buf, footer + _RECORD_HEAD_SIZE)
        if summary_start > footer or summary_offset_start > footer:
            raise CorruptMcap(self.path, f'the Footer puts the summary at {summary_start} '
                              f'and its offsets at {summary_offset_start}, past the Footer',
                              f'offset {footer}')
        opcode, length = _RECORD.unpack_from(buf, data_end)
        if opcode == _FOOTER:
            if data_end != footer:
                raise CorruptMcap(self.path, 'a Footer record inside the data section',
                                  f'offset {data_end}')
        else:
            after = data_end + _RECORD_HEAD_SIZE + length
            if length < 4:
                raise CorruptMcap(self.path, 'DataEnd record too short', f'offset {data_end}')
            following = summary_start or summary_offset_start or footer
            if after != following:
                raise CorruptMcap(self.path, f'the data section ends at {after} but the '
                                  f'Footer puts the next section at {following}',
                                  f'offset {data_end}')
            data_crc = _U32.unpack_from(buf, data_end + _RECORD_HEAD_SIZE)[0]
            if data_crc:
                self.data_crc = True
                self.crcs.check_in_pieces(buf, data_end, data_crc,
                                          f'data section (bytes 0 to {data_end})', 0)
        if summary_crc:
            self.summary_crc = True
            begin = summary_start or footer
            self.crcs.check(buf[begin:footer + _FOOTER_CRC_AT], summary_crc,
                            f'summary section at offset {begin}', begin)

    # -- records other than messages ---------------------------------------------------

    def string(self, buf: bytes | memoryview, pos: int, end: int) -> tuple[str, int]:
        if pos + 4 > end:
            raise self.corrupt('a string length runs past its record', pos)
        size = _U32.unpack_from(buf, pos)[0]
        start = pos + 4
        if start + size > end:
            raise self.corrupt('a string runs past its record', pos)
        try:
            return str(buf[start:start + size], 'utf-8'), start + size
        except UnicodeDecodeError as error:
            raise self.corrupt(f'a string is not UTF-8 ({error})', start) from None

    def schema(self, buf: bytes | memoryview, body: int, end: int) -> None:
        if body + 2 > end:
            raise self.corrupt('Schema record too short', body - _RECORD_HEAD_SIZE)
        schema_id = _U16.unpack_from(buf, body)[0]
        name, _ = self.string(buf, body + 2, end)
        if self.schemas.setdefault(schema_id, name) != name:
            raise self.corrupt(f'schema {schema_id} ({self.schemas[schema_id]}) redefined as '
                               f'{name}', body - _RECORD_HEAD_SIZE)

    def channel(self, buf: bytes | memoryview, body: int, end: int) -> None:
        at = body - _RECORD_HEAD_SIZE
        if body + 4 > end:
            raise self.corrupt('Channel record too short', at)
        channel_id, schema_id = _CHANNEL_HEAD.unpack_from(buf, body)
        topic, pos = self.string(buf, body + 4, end)
        encoding, pos = self.string(buf, pos, end)
        known = self.channels.get(channel_id)
        if known is not None:
            # Writers may repeat a Channel record (e.g. in every chunk); only a change is wrong.
            if known.topic != topic or known.schema_id != schema_id:
                raise self.corrupt(f'channel {channel_id} ({known.topic}) redefined as {topic}',
                                   at)
            return
        self.channels[channel_id] = _Channel(topic, schema_id)
        if self.every_topic:
            self.channels[channel_id].metadata = bytes(buf[pos + 4:end])
            if topic not in self.topic_index:
                self.topic_index[topic] = len(self.topics)
                self.topics.append(topic)
                self.times.append([])
                self.payloads.append([])
                self.last_time.append(-1)
        index = self.topic_index.get(topic)
        if index is None:
            self.table[channel_id] = _UNWANTED
            return
        if channel_id in self.orphans:
            raise self.unsupported(f'messages of channel {channel_id} ({topic}) precede its '
                                   'Channel record', at)
        if encoding != 'cdr':
            raise self.unsupported(f'topic {topic} has message encoding {encoding!r}, not cdr',
                                   at)
        self.table[channel_id] = index

    def chunk(self, buf: bytes | memoryview, at: int, end: int) -> None:
        """Read the Chunk record at offset `at` (ending at `end`) of the file."""
        self.chunk_at = at
        try:
            records = self.chunk_records(buf, at, end)
            view = memoryview(records)
            self.records(view, 0, len(view), top_level=False)
        finally:
            self.chunk_at = None
            self.chunk_times = None

    def chunk_records(self, buf: bytes | memoryview, at: int, end: int) -> bytes | memoryview:
        """Check a Chunk record's header, queue its CRC and return its records, decompressed."""
        body = at + _RECORD_HEAD_SIZE
        if body + _CHUNK_HEAD.size > end:
            raise self.corrupt('Chunk record too short')
        start_time, end_time, uncompressed_size, crc = _CHUNK_HEAD.unpack_from(buf, body)
        try:
            compression, pos = self.string(buf, body + _CHUNK_HEAD.size, end)
        except CorruptMcap as error:
            raise self.corrupt(f'its compression name: {error.reason}') from None
        if pos + 8 > end:
            raise self.corrupt('a chunk\'s records length runs past the chunk')
        size = _U64.unpack_from(buf, pos)[0]
        start = pos + 8
        if start + size > end:
            raise self.corrupt('a chunk\'s records run past the chunk')
        if compression == '':
            if size != uncompressed_size:
                raise self.corrupt(f'an uncompressed chunk holds {size} bytes, its header '
                                   f'says {uncompressed_size}')
            records: bytes | memoryview = memoryview(buf)[start:start + size]
        else:
            limit = min(_MAX_CHUNK_BYTES, max(_MIN_ALLOWANCE, _MAX_RATIO * size))
            if uncompressed_size > limit:
                raise self.corrupt(f'the chunk declares {uncompressed_size} uncompressed '
                                   f'bytes for {size} compressed (at most {limit} accepted)')
            data = memoryview(buf)[start:start + size]
            if compression == 'zstd':
                records = self.unzstd(data, uncompressed_size)
            elif compression == 'lz4':
                records = self.unlz4(data, uncompressed_size)
            else:
                raise self.unsupported(f'chunk compression {compression!r} is not supported')
            if len(records) != uncompressed_size:
                raise self.corrupt(f'the chunk holds {len(records)} bytes, its header says '
                                   f'{uncompressed_size}')
        self.compressions.add(compression)
        self.chunk_count += 1
        self.chunk_crc_count += bool(crc)
        if crc and not self.data_crc:
            self.crcs.check(records, crc, f'chunk at offset {at}', at)
        # (0, 0) is what the spec asks of a chunk without messages; some writers leave it
        # so for every chunk, which then gives no range to check against.
        self.chunk_times = (start_time, end_time) if start_time or end_time else None
        return records

    def unzstd(self, data: memoryview, expected: int) -> bytes:
        """Decompress a zstd chunk (one or more frames) into at most `expected` bytes."""
        if not data:
            return b''
        try:
            zstd = _zstd_module()
        except ImportError as error:
            raise self.unsupported(f'zstd chunks need backports.zstd ({error})') from None
        parts: list[bytes] = []
        produced = 0
        rest: bytes | memoryview = data
        try:
            while rest:
                decompressor = zstd.ZstdDecompressor()
                # One byte more than may come: a chunk larger than declared is then seen.
                part = decompressor.decompress(rest, max_length=expected - produced + 1)
                produced += len(part)
                parts.append(part)
                if produced > expected:
                    raise self.corrupt(f'the zstd data holds more than the {expected} bytes '
                                       'the chunk declares')
                if not decompressor.eof:
                    raise self.corrupt('the zstd data ends inside a frame')
                rest = decompressor.unused_data
        except zstd.ZstdError as error:
            raise self.corrupt(f'bad zstd chunk ({error})') from None
        return parts[0] if len(parts) == 1 else b''.join(parts)

    def unlz4(self, data: memoryview, expected: int) -> bytes:
        """Decompress an lz4-frame chunk into at most `expected` bytes."""
        if not data:
            return b''
        try:
            import lz4.frame
        except ImportError as error:
            raise self.unsupported(f'lz4 chunks need the lz4 package ({error})') from None
        decompressor = lz4.frame.LZ4FrameDecompressor()
        try:
            records = decompressor.decompress(data, max_length=expected + 1)
        except RuntimeError as error:
            raise self.corrupt(f'bad lz4 chunk ({error})') from None
        if len(records) > expected:
            raise self.corrupt(f'the lz4 data holds more than the {expected} bytes the chunk '
                               'declares')
        if not decompressor.eof:
            raise self.corrupt('the lz4 data ends inside a frame')
        return bytes(records)

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
                        raise self.corrupt('no DataEnd or Footer record: the file is '
                                           'incomplete', pos)
            else:
                while pos < end:
                    append(pos)
                    pos += _RECORD_HEAD_SIZE + length_at(buf, pos + 1)[0]
        except struct.error:
            raise self.corrupt('a record header runs past the end of its '
                               + ('file' if top_level else 'chunk'), pos) from None
        if pos > end or (top_level and pos + _RECORD_HEAD_SIZE > end):
            last = offsets[-1] if offsets else pos
            raise self.corrupt('a record (opcode {:#04x}) runs past the end of its {}'.format(
                buf[last], 'file' if top_level else 'chunk'), last)
        offsets.append(pos)
        return offsets

    def records(self, buf: bytes | memoryview, begin: int, end: int, top_level: bool,
                offsets: list[int] | None = None) -> None:
        """Take in the records of buf[begin:end] in file order: messages in batches.

        offsets: from walk(buf, begin, end, top_level), if already known.
        """
        if offsets is None:
            offsets = self.walk(buf, begin, end, top_level)
        bounds = np.array(offsets, dtype=np.int64)
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
            opcode, at, end = int(opcodes[i]), int(starts[i]), int(ends[i])
            body = at + _RECORD_HEAD_SIZE
            if opcode == _CHUNK:
                if not top_level:
                    raise self.corrupt('a chunk inside a chunk', at)
                self.chunk(buf, at, end)
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
        short = ends - starts < _DATA_AT
        if np.any(short):
            raise self.corrupt('a Message record is too short',
                               int(starts[int(np.argmax(short))]))
        times = None
        if self.chunk_times is not None:
            # A message outside its chunk's time range is damage (one flipped bit in a log
            # time would otherwise become a gap of years).
            low, high = self.chunk_times
            times = words[starts + _LOG_TIME_AT].view('<u8').ravel()
            outside = (times < low) | (times > high)
            if np.any(outside):
                k = int(np.argmax(outside))
                raise self.corrupt(f'message log time {int(times[k])} ns lies outside its '
                                   f'chunk\'s range [{low}, {high}]', int(starts[k]))
        channel_ids = (octets[starts + _CHANNEL_ID_AT].astype(np.int32)
                       | (octets[starts + _CHANNEL_ID_AT + 1].astype(np.int32) << 8))
        if self.tally is not None and starts.size:
            if times is None:
                times = words[starts + _LOG_TIME_AT].view('<u8').ravel()
            counts = np.bincount(channel_ids)
            self.tally[:counts.size] += counts
            first, last = int(times.min()), int(times.max())
            if self.log_times is not None:
                first, last = min(first, self.log_times[0]), max(last, self.log_times[1])
            self.log_times = (first, last)
        indexes = self.table[channel_ids]
        unknown = indexes == _UNKNOWN
        if np.any(unknown):
            for k in np.flatnonzero(unknown).tolist():
                self.orphans.setdefault(int(channel_ids[k]), self.place(int(starts[k])))
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
        assert self.consumer is not None
        msgtypes = self.msgtypes()
        for topic, index in self.topic_index.items():
            if not self.times[index]:
                continue
            batch = self.ordered(topic, msgtypes[topic])
            if batch.log_time_ns[0] < self.last_time[index]:
                raise self.unsupported(f'messages of {topic} are not in log-time order across '
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
        self.crcs.advance(end)
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
                raise self.corrupt(f'channel {channel_id} ({channel.topic}) has no known '
                                   f'schema (schema id {channel.schema_id})')
            if msgtypes.setdefault(channel.topic, name) != name:
                raise self.corrupt(f'topic {channel.topic} has channels of two types, '
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
            raise self.corrupt(f'topic {topic} has a log time beyond int64')
        times = times.astype(np.int64)
        payloads = self.payloads[index]
        if times.size > 1 and not np.all(np.diff(times) >= 0):
            order = np.argsort(times, kind='stable')
            times = times[order]
            payloads = [payloads[i] for i in order.tolist()]
        return TopicMessages(msgtype, times, payloads)


def read_records(path: Path | str, data: bytes | memoryview, end: int
                 ) -> tuple[dict[str, TopicMessages], dict[str, ChannelInfo]]:
    """Read every message of the records in data[len(MAGIC):end], e.g. of a file cut short.

    The records must be complete (the caller cuts before a partial one); no DataEnd or
    Footer is needed, chunk CRCs are checked.

    Returns:
        topic -> its messages, and topic -> its channel, for every topic with a channel.

    Raises:
        CorruptMcap, UnsupportedMcap: as stream_topics; `offset` says which record is at
            fault.
    """
    scan = _Scan(Path(path), None)
    view = memoryview(data)
    try:
        offsets = scan.walk(view, len(MAGIC), end, top_level=False)
        scan.records(view, len(MAGIC), end, top_level=True, offsets=offsets)
        result = scan.result()
    except Exception:
        mismatch = scan.crcs.failure(scan.path)
        if mismatch is not None:
            raise mismatch from None
        raise
    mismatch = scan.crcs.failure(scan.path)
    if mismatch is not None:
        raise mismatch
    msgtypes = scan.msgtypes()
    channels = {}
    for channel in scan.channels.values():
        channels.setdefault(channel.topic, ChannelInfo(msgtypes[channel.topic], channel.metadata,
                                                       frozenset(scan.compressions)))
    return result, channels


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


def stream_topics(path: Path | str, topics: Collection[str],
                  consumer: Callable[[str, TopicMessages], None],
                  batch_messages: int = 65_536) -> dict[str, str]:
    """Hand the messages of some topics to consumer in batches, in log-time order per topic.

    The log times and raw payloads of the wanted topics go to ``consumer(topic, batch)``
    whenever about batch_messages have been read (at a chunk boundary), so memory stays
    bounded on long bags; within a batch, messages are in ascending log time (ties keep file
    order) and messages of one topic on several channels are merged. Batches of one topic
    come in ascending log time; a file whose chunks are not in that order raises
    UnsupportedMcap (batches already handed over stay with the consumer, who should start
    over with another reader). The file's CRCs are only known good when this returns: on any
    error, batches already handed over must be thrown away. Batches handed over during the
    scan reach the consumer while the garbage collector is paused; keep it short.

    Args:
        path: the .mcap file.
        topics: topic names wanted (absolute, e.g. '/imu').
        consumer: called with (topic, TopicMessages) for each batch.
        batch_messages: messages held before a batch is handed over.

    Returns:
        topic -> message type, for every wanted topic with a channel in the file (a topic
        without messages gets no batch).

    Raises:
        CorruptMcap: bad magic, a CRC mismatch, a truncated or corrupt record, a length past
            the bytes present, no DataEnd/Footer, a log time outside its chunk, a wanted topic
            without a schema or with channels of two types; it also replaces an error raised
            by the consumer when a CRC fails.
        UnsupportedMcap: an unsupported chunk compression or codec, a wanted topic not in CDR,
            or chunks out of log-time order.
        OSError: the file cannot be read.
    """
    scan = _Scan(Path(path), topics, consumer, batch_messages)
    _scan_file(scan, scan.emit)
    return scan.msgtypes()


def verify_file(path: Path | str) -> Verified:
    """Check a whole MCAP file as stream_topics does, keeping no message.

    Every chunk is decompressed and walked, and every check of stream_topics applies: the
    CRCs the file carries (data section, summary, and each chunk's where no data-section
    CRC covers it), lengths within the bytes present, DataEnd and Footer, log times within
    their chunk's range, channels and schemas. Pages are released chunk by chunk, so a
    long bag is never resident as a whole.

    Returns:
        What the file carries (how many chunks, which CRCs) and holds (messages per topic,
        first and last log time).

    Raises:
        CorruptMcap, UnsupportedMcap: as stream_topics (a damaged chunk is named by offset).
        OSError: the file cannot be read.
    """
    scan = _Scan(Path(path), (), lambda topic, batch: None, batch_messages=0)
    scan.tally = np.zeros(1 << 16, dtype=np.int64)
    _scan_file(scan, scan.emit)
    counts: dict[str, int] = {}
    # check_orphans has refused messages of a channel no record defines.
    for channel_id in np.flatnonzero(scan.tally).tolist():
        topic = scan.channels[channel_id].topic
        counts[topic] = counts.get(topic, 0) + int(scan.tally[channel_id])
    return Verified(scan.chunk_count, scan.chunk_crc_count, scan.data_crc, scan.summary_crc,
                    counts, scan.log_times)


def _scan_file(scan: _Scan, finish: Callable[[], _T]) -> _T:
    """Walk the whole file, return finish() once the CRCs are checked.

    A CRC mismatch wins over any other error: damage explains whatever else went wrong.
    """
    path = scan.path
    data, scan.mapped = _map(path)
    size = len(data)
    if size < 2 * len(MAGIC) or data[:len(MAGIC)] != MAGIC:
        raise scan.corrupt('not an MCAP file (bad leading magic)')
    if data[size - len(MAGIC):] != MAGIC:
        raise scan.corrupt('no trailing magic: the file is truncated or incomplete')
    # A payload is one new object per message, never part of a cycle; the collector's passes
    # over them (triggered every few hundred allocations) would add about a third to the time.
    collecting = gc.isenabled()
    gc.disable()
    offsets = [len(MAGIC)]
    try:
        # The trailing magic is left out so that no record may run into it.
        offsets = scan.walk(data, len(MAGIC), size - len(MAGIC), top_level=True)
        scan.check_ends(data, offsets[-1], size)
        scan.records(data, len(MAGIC), offsets[-1], top_level=True, offsets=offsets)
        scan.check_orphans()
        result = finish()
    except Exception:
        mismatch = scan.crcs.failure(path)
        if mismatch is not None:
            raise _located(mismatch, data, offsets[-1]) from None
        raise
    finally:
        if collecting:
            gc.enable()
    mismatch = scan.crcs.failure(path)
    if mismatch is not None:
        raise _located(mismatch, data, offsets[-1])
    return result


def _located(mismatch: CorruptMcap, data: memoryview, data_end: int) -> CorruptMcap:
    """Name the damaged chunk behind a data-section CRC mismatch, where its own CRC can.

    The data-section CRC spares checking each chunk; once it fails, the chunks' CRCs say
    which one holds the damage.
    """
    if mismatch.offset != 0:
        return mismatch
    scan = _Scan(mismatch.path, ())
    try:
        offsets = scan.walk(data, len(MAGIC), data_end, top_level=False)
        scan.records(data, len(MAGIC), data_end, top_level=True, offsets=offsets)
    except McapError as error:
        found = scan.crcs.failure(mismatch.path) or error
    else:
        found = scan.crcs.failure(mismatch.path)
    if found is None:
        return mismatch
    return CorruptMcap(found.path, f'{found.reason}; the data-section CRC fails too',
                       found.where, found.offset)
