"""Write many already-serialised messages to a rosbags Writer at once.

`rosbags.rosbag2.Writer.write` costs a few microseconds per message in Python (a record
built field by field in a BytesIO), which is most of the time of writing a long estimates
bag. For the MCAP storage, `write_rows` builds the message records of a whole block with
numpy and hands them to the pending chunk in slices, closing chunks exactly where per-message
writes would close them, so the file is byte for byte the one `Writer.write` produces
(the tests compare them). This reaches into rosbags' McapWriter (pinned: rosbags 0.11.9);
for any other storage, compression per message, or a McapWriter without the expected
attributes, it falls back to calling `Writer.write` per message.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray
from rosbags.rosbag2.enums import CompressionMode
from rosbags.rosbag2.errors import WriterError

__all__ = ['write_rows']

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
