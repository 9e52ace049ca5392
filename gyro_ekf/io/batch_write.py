"""Write many already-serialised messages to a rosbags Writer at once.

`rosbags.rosbag2.Writer.write` costs a few microseconds per message in Python (a record
built field by field in a BytesIO), which is most of the time of writing a long estimates
bag. For the MCAP storage, `write_rows` builds the message records of a whole block with
numpy and hands them to the pending chunk in slices, closing chunks exactly where per-message
writes would close them, so the file is byte for byte the one `Writer.write` produces
(the tests compare them). This reaches into rosbags' McapWriter (pinned: rosbags 0.11.9);
for any other storage, compression per message, or a McapWriter without the expected
attributes, it falls back to calling `Writer.write` per message.

Closing a chunk, rosbags writes its message index 8 bytes per call; every bag the project
writes closes its chunks with `_close_chunk` instead, which packs each channel's index at
once and writes the same bytes (a test compares it with rosbags' own).

rosbags' McapWriter leaves every CRC of the file at 0 ("not given"), so a flipped byte goes
unnoticed by any reader. `enable_chunk_crcs` makes a Writer's MCAP file carry them all: each
chunk's uncompressed CRC, the data-section CRC in DataEnd and the summary CRC in the Footer
(as the MCAP specification defines them). It wraps the storage's file object, so every byte
goes to disk once, already with its CRC, and the file is otherwise byte for byte what
rosbags writes.
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Callable, Sequence
from io import BytesIO
from itertools import chain
from pathlib import Path
import struct
from typing import Any
import zlib

import numpy as np
from numpy.typing import NDArray
from rosbags.rosbag2.enums import CompressionMode
from rosbags.rosbag2.errors import WriterError

__all__ = ['enable_chunk_crcs', 'write_rows']

_CHUNK_LIMIT = 2**20
"""McapWriter closes its pending chunk once it holds more than this many bytes."""

_RECORD_HEAD = 31
"""Bytes of an MCAP message record before its data: opcode 1, length 8, channel id 2,
sequence 4, log time 8, publish time 8."""

_MCAP_ATTRIBUTES = ('chunk', 'close_chunk', 'channel_stats', 'message_start_time',
                    'message_end_time')


def write_rows(writer: Any, connections: Sequence[Any], stamps_ns: NDArray[np.int64],
               payloads: Sequence[NDArray[np.uint8]]) -> None:
    """Write row k of every payload at stamps_ns[k], connection by connection, row by row.

    Equivalent to `for k: for j: writer.write(connections[j], stamps_ns[k], payloads[j][k])`.

    Args:
        writer: an open rosbags Writer.
        connections: one per payload, added to writer.
        stamps_ns: shape (m,), ns since the epoch, >= 0.
        payloads: per connection, shape (m, size_j) uint8: one serialised message per row.

    Raises:
        WriterError: a connection is not the writer's, or the shapes do not match.
    """
    stamps = np.asarray(stamps_ns, dtype=np.int64)
    m = len(stamps)
    if len(payloads) != len(connections) or any(p.shape[0] != m for p in payloads):
        raise WriterError(f'{len(connections)} connections, {len(payloads)} payload blocks '
                          f'and {m} stamps do not match')
    for connection in connections:
        if connection not in writer.connections:
            raise WriterError(f'tried to write to unknown connection {connection!r}')
    if m == 0 or not connections:
        return
    if not _can_batch(writer):
        views = [(c, memoryview(np.ascontiguousarray(p)).cast('B'), p.shape[1])
                 for c, p in zip(connections, payloads)]
        for k, stamp in enumerate(stamps.tolist()):
            for connection, view, size in views:
                writer.write(connection, stamp, view[k * size:(k + 1) * size])
        return
    if stamps.min() < 0:
        raise WriterError('negative stamps cannot be written')
    _write_mcap(writer, connections, stamps, payloads)


def _can_batch(writer: Any) -> bool:
    storage = writer.storage
    return (type(storage).__name__ == 'McapWriter'
            and writer.compression_mode in (CompressionMode.NONE, CompressionMode.STORAGE)
            and all(hasattr(storage, name) for name in _MCAP_ATTRIBUTES))


def _write_mcap(writer: Any, connections: Sequence[Any], stamps: NDArray[np.int64],
                payloads: Sequence[NDArray[np.uint8]]) -> None:
    storage = writer.storage
    m, count = len(stamps), len(connections)
    sizes = [int(p.shape[1]) for p in payloads]
    record_sizes = np.array([_RECORD_HEAD + size for size in sizes], dtype=np.int64)
    rows = np.empty((m, int(record_sizes.sum())), dtype=np.uint8)
    column = 0
    for connection, payload, size in zip(connections, payloads, sizes):
        rows[:, column] = 0x05
        rows[:, column + 1:column + 9].view('<u8')[:, 0] = 22 + size
        rows[:, column + 9:column + 11].view('<u2')[:, 0] = connection.id
        rows[:, column + 11:column + 15] = 0
        rows[:, column + 15:column + 23].view('<u8')[:, 0] = stamps
        rows[:, column + 23:column + 31].view('<u8')[:, 0] = stamps
        rows[:, column + 31:column + 31 + size] = payload
        column += _RECORD_HEAD + size
    data = memoryview(rows).cast('B')
    # Message i = row i // count, connection i % count, at data[starts[i]:ends[i]].
    firsts = np.concatenate([[0], np.cumsum(record_sizes)[:-1]])
    starts = (np.arange(m, dtype=np.int64)[:, None] * rows.shape[1] + firsts).ravel()
    ends = starts + np.tile(record_sizes, m)
    message_stamps = np.repeat(stamps, count)
    total = m * count
    done = 0
    while done < total:
        base = storage.chunk.bio.tell()
        # The chunk closes after the first message that takes it past the limit.
        last = int(np.searchsorted(ends, _CHUNK_LIMIT - base + starts[done], side='right'))
        last = min(max(last, done), total - 1)
        _append(writer, connections, data, starts, ends, message_stamps, done, last, base)
        if storage.chunk.bio.tell() > _CHUNK_LIMIT:
            storage.close_chunk()
        done = last + 1


def _append(writer: Any, connections: Sequence[Any], data: memoryview,
            starts: NDArray[np.int64], ends: NDArray[np.int64],
            message_stamps: NDArray[np.int64], done: int, last: int, base: int) -> None:
    """Put messages done..last into the pending chunk and account for them as write does."""
    storage = writer.storage
    chunk = storage.chunk
    count = len(connections)
    offsets = base + starts[done:last + 1] - starts[done]
    chosen = message_stamps[done:last + 1]
    low, high = int(chosen.min()), int(chosen.max())
    chunk.message_start_time = min(low, chunk.message_start_time)
    chunk.message_end_time = max(high, chunk.message_end_time)
    storage.message_start_time = min(low, storage.message_start_time)
    storage.message_end_time = max(high, storage.message_end_time)
    writer.min_timestamp = min(low, writer.min_timestamp)
    writer.max_timestamp = max(high, writer.max_timestamp)
    # Index lists in order of first appearance, as per-message writes create them.
    for shift in range(min(count, last - done + 1)):
        j = (done + shift) % count
        connection = connections[j]
        picked = slice(shift, None, count)
        entries = list(zip(chosen[picked].tolist(), offsets[picked].tolist()))
        chunk.msgs[connection.id].extend(entries)
        storage.channel_stats[connection.id] += len(entries)
        writer.counts[connection.id] += len(entries)
    chunk.bio.write(data[int(starts[done]):int(ends[last])])


# -- Closing a chunk ----------------------------------------------------------------------

_CHUNK_CLOSE_ATTRIBUTES = ('bio', 'chunk', 'chunks', 'compressor', 'compression')


def _close_chunk(storage: Any) -> None:
    """McapWriter.close_chunk, with each message index packed at once: the same bytes.

    rosbags writes a chunk's message index 8 bytes at a time (two calls per message: 40 ms
    of the 2016 log's estimates bag); here each channel's (log time, offset) pairs are
    packed in one call. The records, as the MCAP specification lays them out: Chunk (0x06:
    start and end time, uncompressed size, uncompressed CRC (0 here: ``enable_chunk_crcs``
    patches it), compression, records), then one MessageIndex (0x07: channel id, the
    pairs) per channel in order of first message; the ChunkIndex body (times, the chunk's
    offset and length, each index's offset, the indexes' length, compression, compressed
    and uncompressed size) is kept for the summary, as rosbags keeps it.
    """
    chunk = storage.chunk
    records = chunk.bio.getvalue()
    compressed = storage.compressor(records)
    compression = storage.compression.encode()
    body = b''.join((struct.pack('<QQQII', chunk.message_start_time, chunk.message_end_time,
                                 len(records), 0, len(compression)),
                     compression, struct.pack('<Q', len(compressed)), compressed))
    out = storage.bio
    chunk_start = out.tell()
    out.write(struct.pack('<BQ', 0x06, len(body)))
    out.write(body)
    chunk_end = out.tell()
    index_offsets = []
    for channel, entries in chunk.msgs.items():
        index_offsets.append(struct.pack('<HQ', channel, out.tell()))
        pairs = struct.pack(f'<{2 * len(entries)}Q', *chain.from_iterable(entries))
        out.write(struct.pack('<BQHI', 0x07, 6 + len(pairs), channel, len(pairs)))
        out.write(pairs)
    offsets = b''.join(index_offsets)
    chunk_index = BytesIO()  # at its end: the summary takes tell() for its length
    chunk_index.write(b''.join((
        struct.pack('<QQQQI', chunk.message_start_time, chunk.message_end_time, chunk_start,
                    chunk_end - chunk_start, len(offsets)),
        offsets, struct.pack('<QI', out.tell() - chunk_end, len(compression)), compression,
        struct.pack('<QQ', len(compressed), len(records)))))
    storage.chunks.append(chunk_index)
    storage.chunk = type(chunk)(2**63 - 1, 0, BytesIO(), defaultdict(list))


def _chunk_closer(storage: Any) -> Callable[[], None]:
    """Return the storage's close_chunk: the packed one where the storage is rosbags' MCAP."""
    if all(hasattr(storage, name) for name in _CHUNK_CLOSE_ATTRIBUTES):
        return lambda: _close_chunk(storage)
    return storage.close_chunk


# -- CRCs -------------------------------------------------------------------------------

_CHUNK_CRC_AT = 9 + 24
"""Offset of uncompressed_crc in a Chunk record: opcode, length, start, end, size."""
_FOOTER_SIZE = 9 + 20
_DATA_END_SIZE = 9 + 4
_MAGIC_SIZE = 8


def enable_chunk_crcs(writer: Any, sections: bool = True) -> bool:
    """Make the MCAP file of a rosbags Writer carry chunk, data-section and summary CRCs.

    Call it once, right after creating the Writer (before or after `open()`, before the
    first message). Sqlite3 bags have no CRCs; for them (and for a storage without the
    attributes of rosbags 0.11.9's McapWriter) nothing changes.

    Args:
        writer: the rosbags Writer.
        sections: also the data-section and summary CRCs. A bag whose summary is written
            and then overwritten while recording (`io.recording`) cannot have them (the
            data-section CRC would cover a summary that is no longer there); its chunks
            still carry their own CRCs, which the reader checks.

    Returns:
        True when the bag will carry CRCs.
    """
    add = _add_crcs if sections else _add_chunk_crcs_only
    storage = getattr(writer, 'storage', None)
    if storage is not None:
        return add(storage)
    if getattr(writer, 'storage_plugin', None) is None or (
            writer.storage_plugin.name.lower() != 'mcap'):
        return False
    opened = writer.open

    def open_with_crcs() -> None:
        opened()
        add(writer.storage)
    # An instance attribute: `with writer:` and writer.open() both call it.
    writer.open = open_with_crcs
    return True


def _add_chunk_crcs_only(storage: Any) -> bool:
    if (type(storage).__name__ != 'McapWriter'
            or not all(hasattr(storage, name) for name in ('bio', 'chunk', 'close_chunk'))):
        return False
    close_chunk = _chunk_closer(storage)

    def close_chunk_with_crc() -> None:
        with storage.chunk.bio.getbuffer() as records:
            crc = zlib.crc32(records)
        stream = storage.bio
        start = stream.tell()
        close_chunk()
        end = stream.tell()
        stream.seek(start + _CHUNK_CRC_AT)
        stream.write(struct.pack('<I', crc))
        stream.seek(end)

    storage.close_chunk = close_chunk_with_crc
    return True


def _add_crcs(storage: Any) -> bool:
    if (type(storage).__name__ != 'McapWriter'
            or not all(hasattr(storage, name) for name in ('bio', 'chunk', 'close_chunk',
                                                           'close', 'path'))):
        return False
    if isinstance(storage.bio, _CrcFile):
        return True
    storage.bio = _CrcFile(storage.bio, Path(storage.path))
    close_chunk, close = _chunk_closer(storage), storage.close

    def close_chunk_with_crc() -> None:
        with storage.chunk.bio.getbuffer() as records:
            crc = zlib.crc32(records)
        storage.bio.patch(storage.bio.tell() + _CHUNK_CRC_AT, struct.pack('<I', crc))
        close_chunk()

    def close_with_crcs(version: int, metadata: str) -> None:
        # DataEnd and the Footer come last; hold them back to fill in their CRCs.
        storage.bio.hold()
        close(version, metadata)

    storage.close_chunk = close_chunk_with_crc
    storage.close = close_with_crcs
    return True


class _CrcFile:
    """The McapWriter's file: keeps the running CRC of every byte and patches CRC fields.

    Bytes written go straight to the file, with any patch for their offsets applied, except
    after hold(): the tail (last chunk, summary, Footer) is then kept until close(), which
    fills in the data-section CRC (of every byte before DataEnd, leading magic included) and
    the summary CRC (from the summary's start up to the Footer's own CRC field).
    """

    def __init__(self, raw: Any, path: Path) -> None:
        raw.flush()
        self.raw = raw
        self.offset = raw.tell()
        with open(path, 'rb') as written:
            self.crc = zlib.crc32(written.read(self.offset))
        self.patches: list[tuple[int, bytes]] = []
        self.held: list[bytes] | None = None
        self.held_at = 0

    def tell(self) -> int:
        return self.offset

    def patch(self, offset: int, value: bytes) -> None:
        """Write value at offset instead of what will be written there."""
        self.patches.append((offset, value))

    def hold(self) -> None:
        self.held = []
        self.held_at = self.offset

    def write(self, data: Any) -> int:
        view = memoryview(data).cast('B')
        size = len(view)
        if self.patches:
            view = self._patched(view)
        if self.held is not None:
            self.held.append(bytes(view))
        else:
            self.crc = zlib.crc32(view, self.crc)
            self.raw.write(view)
        self.offset += size
        return size

    def _patched(self, view: memoryview) -> memoryview:
        begin, end = self.offset, self.offset + len(view)
        out: bytearray | None = None
        for at, value in self.patches:
            low, high = max(at, begin), min(at + len(value), end)
            if low < high:
                if out is None:
                    out = bytearray(view)
                out[low - begin:high - begin] = value[low - at:high - at]
        self.patches = [(at, value) for at, value in self.patches if at + len(value) > end]
        return view if out is None else memoryview(out)

    def close(self) -> None:
        if self.held is not None:
            tail = bytearray(b''.join(self.held))
            self.held = None
            self._seal(tail)
            self.raw.write(tail)
        self.raw.close()

    def _seal(self, tail: bytearray) -> None:
        """Fill in the DataEnd and Footer CRCs of the held tail (left as is if not found)."""
        footer = len(tail) - _MAGIC_SIZE - _FOOTER_SIZE
        if footer < 0 or tail[footer] != 0x02:
            return
        summary_start = struct.unpack_from('<Q', tail, footer + 9)[0]
        data_end = summary_start - _DATA_END_SIZE - self.held_at
        if data_end < 0 or tail[data_end] != 0x0F or struct.unpack_from(
                '<Q', tail, data_end + 1)[0] != 4:
            return
        struct.pack_into('<I', tail, data_end + 9, zlib.crc32(tail[:data_end], self.crc))
        summary = summary_start - self.held_at
        struct.pack_into('<I', tail, footer + 25, zlib.crc32(tail[summary:footer + 25]))

    def __getattr__(self, name: str) -> Any:
        return getattr(self.raw, name)
