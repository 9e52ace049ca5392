"""The fuzzer's own MCAP surgery: a CRC-aware mutation must leave a file rosbags accepts.

If fuzz/mcap.py broke a file's CRCs or summary offsets, every 'mcap_chunk' input would stop
at the first check and the fuzzer would test nothing deeper; these tests read the results
back with rosbags' Reader, which checks chunk CRCs and follows the summary's offsets.
"""

import struct

import pytest
from rosbags.rosbag2 import Reader
from rosbags.rosbag2.errors import ReaderError

from fuzz import mcap
from fuzz.targets_bag import BAG, MCAP, write_seed_bag


def _imu_payloads(bag):
    with Reader(bag) as reader:
        return [bytes(d) for c, _, d in reader.messages() if c.topic == '/imu']


@pytest.fixture(params=[False, True], ids=['plain', 'zstd'])
def seed(request, tmp_path):
    write_seed_bag(tmp_path, tiny=True, compress=request.param)
    return tmp_path / BAG, tmp_path / MCAP


def test_split_and_join_give_the_same_bytes(seed):
    _, path = seed
    data = path.read_bytes()
    assert mcap.join(mcap.split(data)) == data


def test_crcs_added_are_checked_by_rosbags(seed):
    bag, path = seed
    original = _imu_payloads(bag)
    path.write_bytes(mcap.with_crcs(path.read_bytes(), True))
    assert all(c.crc != 0 for c in mcap.chunks_of(path.read_bytes()))
    assert _imu_payloads(bag) == original
    # Damage one IMU payload inside the chunk without fixing the CRC: rosbags must notice.
    chunk = mcap.chunks_of(path.read_bytes())[0]
    records = bytearray(chunk.records)
    at = chunk.records.index(original[0]) + 60
    records[at] ^= 0x10
    parts = mcap.split(path.read_bytes())
    record = next(r for r in parts if r.opcode == mcap.CHUNK)
    crc = struct.unpack_from('<I', record.body, 24)[0]
    damaged = mcap.Chunk.decode(record.body)
    damaged.records = bytes(records)
    record.body = damaged.encode(with_crc=False)[:24] + struct.pack('<I', crc) + \
        damaged.encode(with_crc=False)[28:]
    path.write_bytes(mcap.join(parts))
    with pytest.raises(ReaderError, match='checksum'):
        _imu_payloads(bag)


def test_replace_chunk_keeps_the_file_consistent(seed):
    bag, path = seed
    data = mcap.with_crcs(path.read_bytes(), True)
    original = _imu_payloads(bag)
    chunk = mcap.chunks_of(data)[0]
    records = bytearray(chunk.records)
    at = chunk.records.index(original[0]) + 60
    records[at] ^= 0x10
    path.write_bytes(mcap.replace_chunk(data, 0, bytes(records)))
    changed = _imu_payloads(bag)
    assert len(changed) == len(original)
    assert changed[0] != original[0] and changed[1:] == original[1:]
