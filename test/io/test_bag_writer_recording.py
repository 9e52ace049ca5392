"""The bag `gyro-ekf record` writes (io.recording): readable on disk at every checkpoint.

A copy of the folder taken between two writes is what a `kill -9` at that moment leaves.
"""

from __future__ import annotations

import io
import shutil
from pathlib import Path

import pytest
import yaml
from mcap.exceptions import McapError
from mcap.records import Message
from mcap.stream_reader import StreamReader

from gyro_ekf import topics
from gyro_ekf.io import messages as msgs
from gyro_ekf.io.bag_info import bag_summary
from gyro_ekf.io.bag_reader import iter_bag_messages
from gyro_ekf.io.bag_writer import SENSOR_QOS
from gyro_ekf.io.errors import BagError
from gyro_ekf.io.recording import RecordingBag

TYPE = topics.VECTOR3_STAMPED_TYPE
T0 = 1_700_000_000_000_000_000


def _message(i: int) -> bytes:
    vector = msgs.TYPESTORE.types[TYPE]
    return msgs.serialize(vector(header=msgs.header(T0 + i, 'imu_link'),
                                 vector=msgs.Vector3(x=float(i), y=0.0, z=0.0)))


def _values(bag: Path) -> list[float]:
    return [m.message.vector.x for m in iter_bag_messages(bag)]


@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
def test_every_checkpoint_leaves_a_readable_bag(tmp_path, storage):
    bag = RecordingBag(tmp_path / 'rec', storage, flush_s=3600.0)
    assert bag_summary(tmp_path / 'rec').message_count == 0   # readable from the start
    snapshots = {}
    for i in range(9000):
        bag.write('/v', TYPE, T0 + i, _message(i), SENSOR_QOS)
        if i % 2500 == 0:
            bag.checkpoint()
            snapshots[i + 1] = shutil.copytree(tmp_path / 'rec', tmp_path / f'kill{i}')
    killed = shutil.copytree(tmp_path / 'rec', tmp_path / 'killed')
    assert bag.close() == tmp_path / 'rec'
    assert _values(tmp_path / 'rec') == [float(i) for i in range(9000)]
    for count, copy in snapshots.items():
        assert bag_summary(copy).message_count == count
        assert _values(copy) == [float(i) for i in range(count)]
    # Killed after the last checkpoint: what came before it is there.
    assert _values(killed) == [float(i) for i in range(7501)]


def test_a_full_chunk_is_made_readable_at_once(tmp_path):
    """rosbags closes a chunk at 1 MiB; the summary after it is written in the same call."""
    bag = RecordingBag(tmp_path / 'rec', 'mcap', flush_s=3600.0)
    i = 0
    while bag.checkpoints < 3:
        bag.write('/v', TYPE, T0 + i, _message(i), SENSOR_QOS)
        i += 1
    copy = shutil.copytree(tmp_path / 'rec', tmp_path / 'killed')
    assert _values(copy) == [float(k) for k in range(i)]
    bag.close()


def test_a_torn_checkpoint_keeps_the_metadata_and_every_earlier_chunk(tmp_path):
    """Killed while writing a chunk over the last summary: the file ends torn (for
    `gyro-ekf reindex`), metadata.yaml is still there and the chunks before are intact."""
    bag = RecordingBag(tmp_path / 'rec', 'mcap', flush_s=3600.0)
    for i in range(4000):
        bag.write('/v', TYPE, T0 + i, _message(i), SENSOR_QOS)
    bag.checkpoint()
    complete = bag.storage_file.read_bytes()
    metadata = (tmp_path / 'rec' / 'metadata.yaml').read_text()
    for i in range(4000, 8000):
        bag.write('/v', TYPE, T0 + i, _message(i), SENSOR_QOS)
    bag.checkpoint()
    longer = bag.storage_file.read_bytes()
    bag.close()
    # The second checkpoint's chunk starts where the first summary started.
    data_end = next(k for k in range(len(complete)) if complete[k] != longer[k])
    torn = longer[:data_end + 5000]
    folder = tmp_path / 'torn'
    folder.mkdir()
    (folder / 'torn.mcap').write_bytes(torn)
    (folder / 'metadata.yaml').write_text(metadata.replace('rec.mcap', 'torn.mcap'))
    meta = yaml.safe_load((folder / 'metadata.yaml').read_text())
    assert meta['rosbag2_bagfile_information']['message_count'] == 4000
    values = []
    with pytest.raises((McapError, EOFError, ValueError, AssertionError)):
        for record in StreamReader(io.BytesIO(torn), skip_magic=False).records:
            if isinstance(record, Message):
                values.append(record.log_time - T0)
    assert values == list(range(4000))
    with pytest.raises(BagError, match='cannot read the bag'):  # one line, no traceback
        list(iter_bag_messages(folder))


def test_an_existing_folder_is_refused(tmp_path):
    (tmp_path / 'rec').mkdir()
    with pytest.raises(BagError, match='exists already'):
        RecordingBag(tmp_path / 'rec')


def test_recorded_chunks_carry_crcs_and_a_flipped_byte_is_refused(tmp_path):
    """The recording's chunks carry CRCs (its summary is rewritten at every checkpoint, so
    the data-section CRC stays 0, i.e. absent); a flipped byte in a chunk is an error."""
    from mcap_layout import chunk_records_at, chunks, crcs
    bag = RecordingBag(tmp_path / 'rec', 'mcap', flush_s=3600.0)
    for i in range(9000):
        bag.write('/v', TYPE, T0 + i, _message(i), SENSOR_QOS)
        if i % 2500 == 0:
            bag.checkpoint()
    bag.close()
    data = bag.storage_file.read_bytes()
    chunk_crcs, data_crc, _ = crcs(data)
    assert len(chunk_crcs) >= 4 and all(chunk_crcs)
    assert data_crc == 0
    assert _values(tmp_path / 'rec') == [float(i) for i in range(9000)]
    damaged = bytearray(data)
    damaged[chunk_records_at(data, chunks(data)[1]) + 40] ^= 0x10
    bag.storage_file.write_bytes(bytes(damaged))
    with pytest.raises(BagError):
        _values(tmp_path / 'rec')
