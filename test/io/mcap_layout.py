"""Where things are in an MCAP file, for tests that damage bags on purpose (from the spec)."""

from __future__ import annotations

from pathlib import Path
import struct
from typing import NamedTuple

import numpy as np
import pytest

from gyro_ekf.io import mcap_chunks

MAGIC = b'\x89MCAP0\r\n'


class Record(NamedTuple):
    """A top-level record: its offset, opcode and content length."""

    offset: int
    opcode: int
    length: int

    @property
    def end(self) -> int:
        return self.offset + 9 + self.length


def read_topics(path: Path | str, topics: list[str]) -> dict[str, mcap_chunks.TopicMessages]:
    """Every message of some topics, through mcap_chunks.stream_topics as read_bag reads them.

    The batches of each topic are joined; a topic with a channel but no message comes back
    with empty arrays, one without a channel is absent.
    """
    batches: dict[str, list[mcap_chunks.TopicMessages]] = {}
    msgtypes = mcap_chunks.stream_topics(
        path, topics, lambda topic, batch: batches.setdefault(topic, []).append(batch))
    joined = {}
    for topic, msgtype in msgtypes.items():
        parts = batches.get(topic, [])
        times = (np.concatenate([b.log_time_ns for b in parts]) if parts
                 else np.zeros(0, dtype=np.int64))
        joined[topic] = mcap_chunks.TopicMessages(
            msgtype, times, [payload for b in parts for payload in b.payloads])
    return joined


def top_records(data: bytes) -> list[Record]:
    """Every top-level record of a complete file, DataEnd, summary and Footer included."""
    records, pos = [], len(MAGIC)
    while pos < len(data) - len(MAGIC):
        opcode, length = struct.unpack_from('<BQ', data, pos)
        records.append(Record(pos, opcode, length))
        pos += 9 + length
    return records


def chunks(data: bytes) -> list[Record]:
    return [r for r in top_records(data) if r.opcode == 0x06]


def chunk_compression(data: bytes, chunk: Record) -> str:
    size = struct.unpack_from('<I', data, chunk.offset + 9 + 28)[0]
    return data[chunk.offset + 9 + 32:chunk.offset + 9 + 32 + size].decode()


def chunk_records_at(data: bytes, chunk: Record) -> int:
    """File offset of an uncompressed chunk's records."""
    assert chunk_compression(data, chunk) == ''
    return chunk.offset + 9 + 28 + 4 + 8


def messages_in_chunk(data: bytes, chunk: Record) -> list[tuple[int, int]]:
    """(file offset, channel id) of every Message record of an uncompressed chunk."""
    begin = chunk_records_at(data, chunk)
    end = begin + struct.unpack_from('<Q', data, begin - 8)[0]
    found, pos = [], begin
    while pos < end:
        opcode, length = struct.unpack_from('<BQ', data, pos)
        if opcode == 0x05:
            found.append((pos, struct.unpack_from('<H', data, pos + 9)[0]))
        pos += 9 + length
    return found


def data_end(data: bytes) -> Record:
    return next(r for r in top_records(data) if r.opcode == 0x0F)


def crcs(data: bytes) -> tuple[list[int], int, int]:
    """Chunk CRCs, the data-section CRC and the summary CRC of a file."""
    chunk_crcs = [struct.unpack_from('<I', data, c.offset + 9 + 24)[0] for c in chunks(data)]
    data_crc = struct.unpack_from('<I', data, data_end(data).offset + 9)[0]
    summary_crc = struct.unpack_from('<I', data, len(data) - len(MAGIC) - 4)[0]
    return chunk_crcs, data_crc, summary_crc


def mcap_of(bag: Path) -> Path:
    return next(bag.glob('*.mcap'))


def flip(path: Path, offset: int, bit: int = 0) -> None:
    data = bytearray(path.read_bytes())
    data[offset] ^= 1 << bit
    path.write_bytes(bytes(data))


def put(path: Path, offset: int, value: bytes) -> None:
    data = bytearray(path.read_bytes())
    data[offset:offset + len(value)] = value
    path.write_bytes(bytes(data))


@pytest.fixture
def crc_writer(monkeypatch):
    """Make write_trip_bag's Writer carry CRCs, as the wired-in enable_chunk_crcs will."""
    from gyro_ekf.io import bag_writer
    from gyro_ekf.io.batch_write import enable_chunk_crcs

    real = bag_writer.Writer

    def writer_with_crcs(*args, **kwargs):
        writer = real(*args, **kwargs)
        assert enable_chunk_crcs(writer)
        return writer
    monkeypatch.setattr(bag_writer, 'Writer', writer_with_crcs)


def assert_trips_equal(got, want) -> None:
    """Require two Trips read from bags to be identical, field by field, bit for bit."""
    assert type(got) is type(want)
    for name in got.__dataclass_fields__:
        a, b = getattr(got, name), getattr(want, name)
        if hasattr(a, '__dataclass_fields__'):
            assert_trips_equal(a, b)
        elif isinstance(a, tuple) and a and hasattr(a[0], '__dataclass_fields__'):
            assert len(a) == len(b)
            for x, y in zip(a, b):
                assert_trips_equal(x, y)
        elif isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
            assert isinstance(a, np.ndarray) and isinstance(b, np.ndarray), name
            assert a.dtype == b.dtype and a.shape == b.shape, name
            assert np.array_equal(a, b, equal_nan=True), name
        else:
            assert a == b, name
