"""Just enough MCAP (https://mcap.dev/spec) to take a file apart and put it back together.

The fuzzer needs mutations that keep a file *consistent* (chunk sizes, CRCs, the summary's
offsets and times) so that a change inside a chunk reaches the message decoders instead of
being stopped at the first check. This module is written from the specification and shares
no code with `gyro_ekf.io.mcap_chunks`, so a bug there is not copied here.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
import struct
from zlib import crc32

MAGIC = b'\x89MCAP0\r\n'
FOOTER, CHUNK, MESSAGE, MESSAGE_INDEX, CHUNK_INDEX = 0x02, 0x06, 0x05, 0x07, 0x08
METADATA_INDEX, SUMMARY_OFFSET, DATA_END = 0x0D, 0x0E, 0x0F

_U16 = struct.Struct('<H')
_U32 = struct.Struct('<I')
_U64 = struct.Struct('<Q')


@dataclass
class Record:
    """A top-level record: where it was in the original file, its opcode and body."""

    offset: int
    opcode: int
    body: bytes

    def encode(self) -> bytes:
        return bytes([self.opcode]) + _U64.pack(len(self.body)) + self.body


@dataclass
class Chunk:
    """The fields of a Chunk record's body, records decompressed."""

    start_time: int
    end_time: int
    crc: int
    compression: str
    records: bytes

    @classmethod
    def decode(cls, body: bytes) -> 'Chunk':
        start, end, size, crc = struct.unpack_from('<QQQI', body, 0)
        (n,) = _U32.unpack_from(body, 28)
        compression = body[32:32 + n].decode()
        (csize,) = _U64.unpack_from(body, 32 + n)
        data = body[40 + n:40 + n + csize]
        if compression == 'zstd':
            import zstandard
            records = zstandard.ZstdDecompressor().decompress(data, max_output_size=size)
        elif compression == '':
            records = bytes(data)
        else:
            raise ValueError(f'compression {compression!r}')
        return cls(start, end, crc, compression, records)

    def encode(self, with_crc: bool) -> bytes:
        if self.compression == 'zstd':
            import zstandard
            data = zstandard.ZstdCompressor(level=3, write_content_size=True).compress(
                self.records)
        else:
            data = self.records
        crc = crc32(self.records) if with_crc else 0
        name = self.compression.encode()
        return (struct.pack('<QQQI', self.start_time, self.end_time, len(self.records), crc)
                + _U32.pack(len(name)) + name + _U64.pack(len(data)) + data)


def split(data: bytes) -> list[Record]:
    """The top-level records of an intact file (raises ValueError otherwise)."""
    if data[:8] != MAGIC or data[-8:] != MAGIC:
        raise ValueError('no magic')
    records, pos, end = [], 8, len(data) - 8
    while pos < end:
        opcode = data[pos]
        (length,) = _U64.unpack_from(data, pos + 1)
        body = data[pos + 9:pos + 9 + length]
        if len(body) != length:
            raise ValueError('record past the end')
        records.append(Record(pos, opcode, bytes(body)))
        pos += 9 + length
    return records


def inner_records(records: bytes) -> list[tuple[int, int, int]]:
    """(offset, opcode, total length) of the records inside a chunk, as far as they parse."""
    out, pos = [], 0
    while pos + 9 <= len(records):
        (length,) = _U64.unpack_from(records, pos + 1)
        if pos + 9 + length > len(records):
            break
        out.append((pos, records[pos], 9 + length))
        pos += 9 + length
    return out


def message_times(records: bytes) -> list[int]:
    return [_U64.unpack_from(records, pos + 15)[0]
            for pos, opcode, size in inner_records(records) if opcode == MESSAGE and size >= 31]


def join(records: list[Record], crcs: bool | None = None) -> bytes:
    """Write records back with every offset, length, time and CRC of the summary made true.

    Args:
        records: top-level records; their `offset` is where they were (the key by which the
            summary refers to them), their body may have changed.
        crcs: True computes every CRC, False zeroes them, None keeps a CRC field's presence
            (a non-zero CRC is recomputed, a zero one stays zero).
    """
    moved: dict[int, int] = {}
    pos = 8
    for record in records:
        moved[record.offset] = pos
        pos += 9 + len(record.body)
    by_old = {r.offset: r for r in records}
    chunks = {r.offset: r for r in records if r.opcode == CHUNK}

    def where(old: int) -> int:
        if old in moved:
            return moved[old]
        # An offset into the middle of nothing known (or past the end): shift it as the
        # record before it moved.
        before = max((o for o in moved if o <= old), default=8)
        return moved[before] + old - before

    out = bytearray(MAGIC)
    for record in records:
        body = record.body
        if record.opcode == CHUNK_INDEX:
            body = _chunk_index(body, chunks, where)
        elif record.opcode == METADATA_INDEX:
            (offset, length) = struct.unpack_from('<QQ', body, 0)
            body = struct.pack('<QQ', where(offset), len(by_old[offset].body) + 9
                               if offset in by_old else length) + body[16:]
        elif record.opcode == SUMMARY_OFFSET:
            (start, length) = struct.unpack_from('<QQ', body, 1)
            body = body[:1] + struct.pack('<QQ', where(start),
                                          where(start + length) - where(start)) + body[17:]
        elif record.opcode == DATA_END:
            (crc,) = _U32.unpack_from(body, 0)
            if crcs or (crcs is None and crc):
                crc = crc32(out)
            elif crcs is False:
                crc = 0
            body = _U32.pack(crc) + body[4:]
        elif record.opcode == FOOTER:
            summary_start, offsets_start, crc = struct.unpack_from('<QQI', body, 0)
            summary_start = where(summary_start) if summary_start else 0
            offsets_start = where(offsets_start) if offsets_start else 0
            head = struct.pack('<QQ', summary_start, offsets_start)
            if summary_start and (crcs or (crcs is None and crc)):
                # The summary CRC covers the summary section and the footer up to the CRC.
                tail = bytes(out[summary_start:]) + bytes([FOOTER]) + _U64.pack(20) + head
                crc = crc32(tail)
            elif crcs is False:
                crc = 0
            body = head + _U32.pack(crc) + body[20:]
        out += bytes([record.opcode]) + _U64.pack(len(body)) + body
    return bytes(out + MAGIC)


def _chunk_index(body: bytes, chunks: dict[int, Record], where: Callable[[int], int]
                 ) -> bytes:
    start, end, chunk_offset, chunk_length = struct.unpack_from('<QQQQ', body, 0)
    (n,) = _U32.unpack_from(body, 32)
    entries = [struct.unpack_from('<HQ', body, 36 + 10 * i) for i in range(n // 10)]
    pos = 36 + n
    (index_length,) = _U64.unpack_from(body, pos)
    (name_n,) = _U32.unpack_from(body, pos + 8)
    name = body[pos + 12:pos + 12 + name_n]
    chunk = chunks.get(chunk_offset)
    if chunk is None:
        return body
    fields = _decode_header(chunk.body)
    new_entries = b''.join(struct.pack('<HQ', cid, where(off)) for cid, off in entries)
    index_end_old = chunk_offset + chunk_length + index_length
    new_chunk_length = 9 + len(chunk.body)
    new_index_length = where(index_end_old) - (where(chunk_offset) + new_chunk_length)
    return (struct.pack('<QQQQ', fields[0], fields[1], where(chunk_offset), new_chunk_length)
            + _U32.pack(len(new_entries)) + new_entries + _U64.pack(new_index_length)
            + _U32.pack(name_n) + name + struct.pack('<QQ', fields[3], fields[2]))


def _decode_header(body: bytes) -> tuple[int, int, int, int]:
    """start_time, end_time, uncompressed_size, compressed_size of a Chunk body."""
    start, end, size, _ = struct.unpack_from('<QQQI', body, 0)
    (n,) = _U32.unpack_from(body, 28)
    (csize,) = _U64.unpack_from(body, 32 + n)
    return start, end, size, csize


def with_crcs(data: bytes, on: bool) -> bytes:
    """The same file with every chunk, data-section and summary CRC computed (or zeroed)."""
    records = split(data)
    for record in records:
        if record.opcode == CHUNK:
            chunk = Chunk.decode(record.body)
            crc = crc32(chunk.records) if on else 0
            record.body = record.body[:24] + _U32.pack(crc) + record.body[28:]
    return join(records, crcs=on)


def replace_chunk(data: bytes, index: int, records: bytes, retime: bool = True) -> bytes:
    """Return the file with chunk `index`'s records replaced.

    The chunk is recompressed, its CRC kept (or left 0) as the original had it, and its
    sizes, times and the summary's offsets made consistent.
    """
    parts = split(data)
    chunk_records = [r for r in parts if r.opcode == CHUNK]
    record = chunk_records[index]
    chunk = Chunk.decode(record.body)
    had_crc = chunk.crc != 0
    chunk.records = records
    if retime:
        times = message_times(records)
        if times:
            chunk.start_time, chunk.end_time = min(times), max(times)
    record.body = chunk.encode(with_crc=had_crc)
    return join(parts)


def chunks_of(data: bytes) -> list[Chunk]:
    return [Chunk.decode(r.body) for r in split(data) if r.opcode == CHUNK]
