"""Verified bags: damage is a clean BagError naming bag, offset and reason, never other numbers.

One test per case of issue 10's "Verified bags": a bit flip in an IMU value or a log time,
metadata and statistics counts of 10^12, a scan topic typed Imu, zstd garbage, record and
string lengths past the end; and CRCs the project writes, read by rosbags and the mcap
package.
"""

from __future__ import annotations

import dataclasses
import functools
import logging
import struct
import sys
import zlib

from mcap.reader import make_reader
from mcap.stream_reader import StreamReader
from mcap_layout import (
    assert_trips_equal, chunk_compression, chunk_records_at, chunks, crc_writer, crcs, data_end,
    flip, mcap_of, messages_in_chunk, put, read_topics, top_records)
import numpy as np
import pytest
from rosbags.rosbag2 import Reader, StoragePlugin, Writer
from rosbags_oracle import read_bag_rosbags
from synthetic_logs import make_trip
import yaml

from gyro_ekf import topics
from gyro_ekf.io import mcap_chunks, messages as msgs
from gyro_ekf.io.bag_reader import iter_bag_messages, read_bag
from gyro_ekf.io.bag_writer import write_trip_bag
from gyro_ekf.io.batch_write import enable_chunk_crcs
from gyro_ekf.io.errors import BagError

__all__ = ['crc_writer']


@functools.lru_cache(maxsize=1)
def big_trip():
    """A synthetic trip long enough for a few 1 MiB chunks."""
    return make_trip(n=6000, m=600)


def imu_value_offset(data: bytes, trip, k: int = 5) -> int:
    """Offset in the file of IMU sample k's angular velocity (x, y, z doubles)."""
    value = struct.pack('<3d', *trip.imu.angular_velocity_rad_s[k])
    offset = data.find(value)
    assert offset > 0 and data.find(value, offset + 1) < 0
    return offset


@pytest.fixture
def crc_bag(tmp_path, crc_writer):
    """A plain (uncompressed) bag of the synthetic trip, written with CRCs."""
    return write_trip_bag(big_trip(), tmp_path / 'crc')


@pytest.fixture
def plain_bag(tmp_path, monkeypatch):
    """The same bag as rosbags writes it: every CRC 0 (also once the writers add CRCs)."""
    from gyro_ekf.io import batch_write

    with monkeypatch.context() as patch:
        patch.setattr(batch_write, '_add_crcs', lambda storage: False)
        bag = write_trip_bag(big_trip(), tmp_path / 'plain')
    chunk_crcs, data_crc, summary_crc = crcs(mcap_of(bag).read_bytes())
    assert not any(chunk_crcs) and not data_crc and not summary_crc
    return bag


# -- the CRCs the project writes -------------------------------------------------------


@pytest.mark.parametrize('compress', [False, True], ids=['plain', 'zstd'])
def test_written_bags_carry_every_crc_and_other_readers_check_them(tmp_path, crc_writer,
                                                                   compress):
    bag = write_trip_bag(big_trip(), tmp_path / 'bag', compress=compress)
    data = mcap_of(bag).read_bytes()
    chunk_crcs, data_crc, summary_crc = crcs(data)
    assert len(chunk_crcs) > 1 and all(chunk_crcs) and data_crc and summary_crc
    assert data_crc == zlib.crc32(data[:data_end(data).offset])
    with open(mcap_of(bag), 'rb') as stream:
        records = list(StreamReader(stream, validate_crcs=True, emit_chunks=True).records)
    assert sum(type(r).__name__ == 'Chunk' for r in records) == len(chunk_crcs)
    with open(mcap_of(bag), 'rb') as stream:
        by_mcap = [(c.topic, m.log_time, m.data) for _, c, m in
                   make_reader(stream, validate_crcs=True).iter_messages(log_time_order=False)]
    with Reader(bag) as reader:
        by_rosbags = [(c.topic, t, bytes(d)) for c, t, d in reader.messages()]
    assert sorted(by_mcap) == sorted(by_rosbags) and len(by_mcap) > 500
    assert_trips_equal(read_bag(bag).trip, read_bag_rosbags(bag).trip)
    # The mcap package finds the flipped byte through the CRCs we wrote, as we do.
    middle = chunks(data)[1]
    flip(mcap_of(bag), middle.offset + middle.length // 2)
    with open(mcap_of(bag), 'rb') as stream, pytest.raises(Exception, match='(?i)crc'):
        list(StreamReader(stream, validate_crcs=True, emit_chunks=False).records)
    with pytest.raises(BagError, match='CRC mismatch'):
        read_bag(bag)


def test_crcs_can_be_enabled_before_open_and_sqlite3_is_left_alone(tmp_path):
    for plugin, expected in ((StoragePlugin.MCAP, True), (StoragePlugin.SQLITE3, False)):
        writer = Writer(tmp_path / plugin.name, version=9, storage_plugin=plugin)
        assert enable_chunk_crcs(writer) == expected
        with writer:
            connection = writer.add_connection('/v', topics.VECTOR3_STAMPED_TYPE,
                                               typestore=msgs.TYPESTORE)
            for k in range(3):
                writer.write(connection, 10 + k, b'\x00\x01\x00\x00' + bytes(36))
    chunk_crcs, data_crc, summary_crc = crcs(mcap_of(tmp_path / 'MCAP').read_bytes())
    assert all(chunk_crcs) and data_crc and summary_crc
    with Reader(tmp_path / 'SQLITE3') as reader:
        assert len(list(reader.messages())) == 3


# -- one test per case of the issue ---------------------------------------------------


def test_a_flipped_bit_in_an_imu_value_is_a_crc_error(crc_bag):
    trip = big_trip()
    mcap = mcap_of(crc_bag)
    value = imu_value_offset(mcap.read_bytes(), trip)
    chunk = next(c for c in chunks(mcap.read_bytes()) if c.offset < value < c.end)
    flip(mcap, value + 7, bit=6)
    with pytest.raises(BagError, match=rf'crc\.mcap: chunk at offset {chunk.offset}: CRC '
                                       'mismatch .*; the data-section CRC fails too'):
        read_bag(crc_bag)


def test_without_a_data_section_crc_the_chunk_crc_names_the_chunk(crc_bag):
    trip = big_trip()
    mcap = mcap_of(crc_bag)
    data = mcap.read_bytes()
    put(mcap, data_end(data).offset + 9, bytes(4))       # DataEnd: "no CRC"
    value = imu_value_offset(data, trip)
    chunk = next(c for c in chunks(data) if c.offset < value < c.end)
    flip(mcap, value + 7, bit=6)
    with pytest.raises(BagError, match=f'chunk at offset {chunk.offset}: CRC mismatch'):
        read_bag(crc_bag)


def _info(capsys, bag, *flags) -> tuple[int, str, str]:
    from gyro_ekf.cli.main import main
    code = main(['-q', 'info', str(bag), *flags])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


@pytest.mark.parametrize('data_crc', [True, False], ids=['data-section CRC', 'chunk CRCs only'])
def test_info_refuses_a_bag_with_a_flipped_bit_as_run_does(crc_bag, capsys, data_crc):
    # A user checks a bag with info: it used to print the summary of a bag run refuses.
    trip = big_trip()
    mcap = mcap_of(crc_bag)
    data = mcap.read_bytes()
    if not data_crc:
        put(mcap, data_end(data).offset + 9, bytes(4))       # DataEnd: "no CRC"
    value = imu_value_offset(data, trip)
    chunk = next(c for c in chunks(data) if c.offset < value < c.end)
    flip(mcap, value + 7, bit=6)
    code, out, err = _info(capsys, crc_bag)
    assert code == 1 and out == ''
    lines = err.strip().splitlines()
    assert len(lines) == 1 and 'Traceback' not in err, err
    assert f'crc.mcap: chunk at offset {chunk.offset}: CRC mismatch (stored ' in lines[0]
    assert lines[0].startswith(f'gyro-ekf info: error: {mcap}: ')
    with pytest.raises(BagError) as raised:      # what run says
        read_bag(crc_bag)
    assert str(raised.value) in lines[0]


@pytest.mark.parametrize('data_crc', [True, False], ids=['data-section CRC', 'chunk CRCs only'])
def test_info_says_which_crcs_it_checked(crc_bag, capsys, data_crc):
    mcap = mcap_of(crc_bag)
    data = mcap.read_bytes()
    n = len(chunks(data))
    if not data_crc:
        put(mcap, data_end(data).offset + 9, bytes(4))
    code, out, _ = _info(capsys, crc_bag)
    assert code == 0
    said = ('data section (covers every chunk), summary' if data_crc
            else f'{n} of {n} chunks, summary')
    assert f'checked:   crc.mcap: {n} chunks read; CRCs match: {said}' in out.splitlines()
    # Asked not to read the data, info reads the metadata only, and says so.
    flip(mcap, imu_value_offset(data, big_trip()) + 7, bit=6)
    code, out, _ = _info(capsys, crc_bag, '--no-verify')
    assert code == 0 and 'checked:   not checked (--no-verify)' in out.splitlines()


def test_info_on_a_bag_without_crcs_checks_lengths_and_log_times(plain_bag, capsys):
    mcap = mcap_of(plain_bag)
    data = mcap.read_bytes()
    offset, _ = messages_in_chunk(data, chunks(data)[1])[10]
    flip(mcap, offset + 9 + 6 + 5, bit=3)       # log time += 2^43 ns (about 2.4 h)
    code, out, err = _info(capsys, plain_bag)
    assert code == 1 and out == '' and len(err.strip().splitlines()) == 1, err
    assert f"plain.mcap: chunk at offset {chunks(data)[1].offset}" in err
    assert "outside its chunk's range" in err
    mcap.write_bytes(data)
    code, out, _ = _info(capsys, plain_bag)
    assert code == 0
    assert ('the file carries no CRCs, so only lengths and log times were checked'
            in out), out


def _held(bag) -> tuple[dict[str, int], int, int]:
    """Messages per topic and the first and last log time, as the mcap package reads them."""
    with open(mcap_of(bag), 'rb') as stream:
        messages = [(c.topic, m.log_time) for _, c, m in
                    make_reader(stream).iter_messages(log_time_order=False)]
    counts: dict[str, int] = {}
    for topic, _ in messages:
        counts[topic] = counts.get(topic, 0) + 1
    times = [t for _, t in messages]
    return counts, min(times), max(times)


def _topic_entry(info, topic):
    return next(e for e in info['topics_with_message_count']
                if e['topic_metadata']['name'] == topic)


@pytest.mark.parametrize('edit', ['imu count', 'total', 'duration', 'start', 'topic left out'])
def test_info_refuses_metadata_the_data_contradicts(crc_bag, capsys, edit):
    # info used to print what metadata.yaml stated (a duration run then refused, a count
    # other than the messages run reads) and exit 0.
    counts, first, last = _held(crc_bag)
    n = big_trip().imu.stamp_s.size
    assert counts['/imu'] == n and _info(capsys, crc_bag)[0] == 0
    stated = first + (last - first) // 2
    if edit == 'imu count':
        _edit_metadata(crc_bag, lambda info: _topic_entry(info, '/imu').update(
            message_count=n - 1000))
        said = [f"topic '/imu': message_count {n - 1000}, but the data holds {n}"]
    elif edit == 'total':
        _edit_metadata(crc_bag, lambda info: info.update(message_count=sum(counts.values())
                                                         + 1))
        said = [f'message_count {sum(counts.values()) + 1}, but the data holds '
                f'{sum(counts.values())}']
    elif edit == 'duration':
        _edit_metadata(crc_bag, lambda info: info.update(duration={'nanoseconds': stated - first}))
        said = [f'duration {stated - first} ns, but the messages span {last - first} ns',
                f'the last message, at {last} ns, lies outside the time range the bag states, '
                f'[{first}, {stated + 1}) ns, which run refuses']
    elif edit == 'start':
        _edit_metadata(crc_bag, lambda info: info.update(
            starting_time={'nanoseconds_since_epoch': first + 1}))
        said = [f'starting_time {first + 1} ns, but the first message is at {first} ns',
                f'the first message, at {first} ns, lies outside the time range the bag '
                f'states, [{first + 1}, {last + 2}) ns, which run refuses']
    else:
        _edit_metadata(crc_bag, lambda info: info['topics_with_message_count'].remove(
            _topic_entry(info, '/ground_truth')))
        said = ["topic '/ground_truth' is not in topics_with_message_count, but the data "
                f"holds {counts['/ground_truth']} messages of it"]
    code, out, err = _info(capsys, crc_bag)
    assert code == 1 and out == '', out
    lines = err.strip().splitlines()
    assert len(lines) == 1 and 'Traceback' not in err, err
    assert lines[0].startswith(f"gyro-ekf info: error: {crc_bag / 'metadata.yaml'}: states "
                               'what the storage files do not hold: ')
    assert lines[0].endswith('; '.join(said)), lines[0]
    if edit in ('duration', 'start'):
        with pytest.raises(BagError, match='outside the time range the bag states'):
            read_bag(crc_bag)
    elif edit == 'imu count':
        assert read_bag(crc_bag).trip.imu.stamp_s.size == n     # what run reads
    # --no-verify reads the metadata only, as its help says; a count or time range edited
    # there states another bag than the one the sidecar was written with, and it says so.
    code, _, err = _info(capsys, crc_bag, '--no-verify')
    if edit in ('total', 'duration', 'start'):
        assert code == 1 and 'as its metadata.yaml states' in err, err
    else:
        assert code == 0, err


@pytest.mark.parametrize('which, match', [('crc_bag', 'CRC mismatch'),
                                          ('plain_bag', "outside its chunk's range")])
def test_a_flipped_log_time_is_refused_with_or_without_crcs(request, which, match):
    bag = request.getfixturevalue(which)
    mcap = mcap_of(bag)
    data = mcap.read_bytes()
    chunk = chunks(data)[1]
    offset, _ = messages_in_chunk(data, chunk)[10]
    flip(mcap, offset + 9 + 6 + 5, bit=3)       # log time += 2^43 ns (about 2.4 h)
    with pytest.raises(BagError, match=match):
        read_bag(bag)
    with pytest.raises(BagError, match='outside the time range the bag states|Chunk checksum '
                                       'mismatch'):
        list(iter_bag_messages(bag))


@pytest.mark.parametrize('bit', [4, 7])
def test_a_flipped_log_time_far_ahead_is_refused_by_the_rosbags_path_too(plain_bag, bit):
    mcap = mcap_of(plain_bag)
    data = mcap.read_bytes()
    offset, _ = messages_in_chunk(data, chunks(data)[1])[3]
    flip(mcap, offset + 9 + 6 + 7, bit=bit)          # log time += 2^60 or 2^63 ns
    with pytest.raises(BagError, match='outside the time range the bag states'):
        read_bag_rosbags(plain_bag)


def test_a_count_of_10_to_the_12_in_the_metadata_is_only_a_hint(plain_bag):
    want = read_bag(plain_bag).trip
    meta_path = plain_bag / 'metadata.yaml'
    meta = yaml.safe_load(meta_path.read_text())
    info = meta['rosbag2_bagfile_information']
    info['message_count'] = 10**12
    for entry in info['topics_with_message_count']:
        entry['message_count'] = 10**12
    meta_path.write_text(yaml.safe_dump(meta))
    assert_trips_equal(read_bag(plain_bag).trip, want)
    assert_trips_equal(read_bag_rosbags(plain_bag).trip, want)


def _edit_metadata(bag, change) -> None:
    meta_path = bag / 'metadata.yaml'
    meta = yaml.safe_load(meta_path.read_text())
    change(meta['rosbag2_bagfile_information'])
    meta_path.write_text(yaml.safe_dump(meta))


@pytest.mark.parametrize('count', [None, 'many', float('inf'), -3])
def test_a_topic_count_that_is_no_count_is_only_a_hint(plain_bag, count):
    want = read_bag(plain_bag).trip

    def change(info):
        for entry in info['topics_with_message_count']:
            entry['message_count'] = count
    _edit_metadata(plain_bag, change)
    assert_trips_equal(read_bag(plain_bag).trip, want)
    assert_trips_equal(read_bag_rosbags(plain_bag).trip, want)


@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
@pytest.mark.parametrize('read', [read_bag, read_bag_rosbags], ids=['fast', 'rosbags'])
def test_messages_in_a_bag_stating_none_are_refused(tmp_path, storage, read):
    # rosbags gives such a bag no start time: stamps would count from 1970 (1.7e9 s).
    bag = write_trip_bag(make_trip(), tmp_path / 'bag', storage=storage)
    _edit_metadata(bag, lambda info: info.update(message_count=0))
    with pytest.raises(BagError, match=r"metadata.yaml: message_count states no messages, "
                                       r"but topic '/\w+' has a message at \d+ ns"):
        read(bag)
    with pytest.raises(BagError, match='states no messages'):
        list(iter_bag_messages(bag))


@pytest.mark.parametrize('files, reason', [([], 'lists no storage file'),
                                           (['plain.mcap', 'plain.mcap'],
                                            'lists a storage file twice')])
def test_metadata_listing_no_file_or_one_twice_is_refused(plain_bag, files, reason):
    # rosbags reads the first as an empty bag and the second as every message twice.
    _edit_metadata(plain_bag, lambda info: info.update(relative_file_paths=files))
    for read in (read_bag, read_bag_rosbags):
        with pytest.raises(BagError, match=f'metadata.yaml: relative_file_paths {reason}'):
            read(plain_bag)


def statistics_counts_at(data: bytes) -> list[int]:
    """Offsets of the per-channel message counts in the Statistics record."""
    stats = next(r for r in top_records(data) if r.opcode == 0x0B)
    at = stats.offset + 9 + 42
    size = struct.unpack_from('<I', data, at)[0]
    return [at + 4 + k + 2 for k in range(0, size, 10)]


@pytest.mark.parametrize('which', ['crc_bag', 'plain_bag'])
def test_a_count_of_10_to_the_12_in_the_mcap_statistics_is_only_a_hint(request, which):
    bag = request.getfixturevalue(which)
    want = read_bag(bag).trip
    mcap = mcap_of(bag)
    offsets = statistics_counts_at(mcap.read_bytes())
    assert len(offsets) == 7
    for offset in offsets:
        put(mcap, offset, struct.pack('<Q', 10**12))
    if which == 'crc_bag':
        with pytest.raises(BagError, match='summary section .*CRC mismatch'):
            read_bag(bag)
        return
    assert_trips_equal(read_bag(bag).trip, want)
    assert_trips_equal(read_bag_rosbags(bag).trip, want)


def test_a_scan_topic_typed_imu_is_refused_naming_the_topic(tmp_path):
    bag = tmp_path / 'typed'
    imu = msgs.serialize(msgs.imu_message(10**18, np.zeros(3), np.zeros(9), None))
    odom = msgs.serialize(msgs.speed_message(10**18, 1.0, np.zeros(36)))
    with Writer(bag, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        for topic, msgtype, data in (('/imu', topics.IMU_TYPE, imu),
                                     ('/odom', topics.ODOMETRY_TYPE, odom),
                                     ('/scan', topics.IMU_TYPE, imu)):
            connection = writer.add_connection(topic, msgtype, typestore=msgs.TYPESTORE)
            writer.write(connection, 10**18, data)
    for read in (read_bag, read_bag_rosbags):
        with pytest.raises(BagError, match="topic '/scan' has type sensor_msgs/msg/Imu, "
                                           'expected sensor_msgs/msg/LaserScan'):
            read(bag)


@pytest.mark.parametrize('read', [read_bag, read_bag_rosbags], ids=['fast', 'rosbags'])
def test_a_type_damaged_in_the_mcap_summary_is_refused(plain_bag, read):
    # Found by `make fuzz`: rosbags matches the summary's channels against metadata.yaml and
    # silently dropped every message of a topic whose schema name there had one bad byte.
    mcap = mcap_of(plain_bag)
    data = mcap.read_bytes()
    at = data.rfind(topics.IMU_TYPE.encode())
    assert at > data.find(topics.IMU_TYPE.encode()) > 0    # the summary's copy, not the data's
    put(mcap, at + len(topics.IMU_TYPE) - 1, b'x')
    with pytest.raises(BagError, match="plain: topic '/imu' has type 'sensor_msgs/msg/Imx' in "
                                       'its storage file, but sensor_msgs/msg/Imu in '
                                       'metadata.yaml; rosbags would drop its messages'):
        read(plain_bag)


def test_a_lidar_topic_named_by_the_sidecar_must_be_a_laser_scan(tmp_path):
    trip = big_trip()
    bag = write_trip_bag(trip, tmp_path / 'renamed')
    sidecar = tmp_path / 'renamed.params.yaml'
    text = sidecar.read_text()
    assert 'scan2' in text
    sidecar.write_text(text.replace('scan2', 'odom'))
    with pytest.raises(BagError, match="topic '/odom' has type nav_msgs/msg/Odometry, "
                                       'expected sensor_msgs/msg/LaserScan'):
        read_bag(bag)


def test_zstd_garbage_is_a_bag_error(tmp_path):
    bag = write_trip_bag(big_trip(), tmp_path / 'z', compress=True)
    mcap = mcap_of(bag)
    data = mcap.read_bytes()
    chunk = chunks(data)[1]
    assert chunk_compression(data, chunk) == 'zstd'
    records = chunk.offset + 9 + 28 + 4 + 4 + 8
    put(mcap, records + 20, b'\xa5' * 64)
    with pytest.raises(BagError, match=f'z.mcap: chunk at offset {chunk.offset}: (bad zstd '
                                       'chunk|the chunk holds)'):
        read_bag(bag)


def test_a_huge_declared_uncompressed_size_is_refused_before_decompressing(tmp_path):
    bag = write_trip_bag(big_trip(), tmp_path / 'z', compress=True)
    mcap = mcap_of(bag)
    chunk = chunks(mcap.read_bytes())[0]
    put(mcap, chunk.offset + 9 + 16, struct.pack('<Q', 1 << 45))
    with pytest.raises(BagError, match='declares 35184372088832 uncompressed bytes'):
        read_bag(bag)


@pytest.mark.parametrize('where', ['chunk length', 'message length', 'string length',
                                   'records length', 'cut'])
def test_lengths_past_the_bytes_present_are_bag_errors(plain_bag, where):
    mcap = mcap_of(plain_bag)
    data = mcap.read_bytes()
    chunk = chunks(data)[0]
    huge = struct.pack('<Q', (1 << 62) + 5)
    if where == 'chunk length':
        put(mcap, chunk.offset + 1, huge)
    elif where == 'message length':
        put(mcap, messages_in_chunk(data, chunk)[4][0] + 1, huge)
    elif where == 'string length':
        first = chunk_records_at(data, chunk)       # the first Schema record: its name
        assert data[first] == 0x03
        put(mcap, first + 9 + 2, struct.pack('<I', 0xFFFFFFF0))
    elif where == 'records length':
        put(mcap, chunk_records_at(data, chunk) - 8, huge)
    else:
        mcap.write_bytes(data[:chunk.offset + chunk.length // 2])
    with pytest.raises(BagError, match=str(plain_bag)):
        read_bag(plain_bag)


# -- reading without what a plain install lacks, and falling back ----------------------


def test_zstd_bags_are_read_without_the_zstandard_package(tmp_path, monkeypatch):
    bag = write_trip_bag(big_trip(), tmp_path / 'z', compress=True)
    monkeypatch.setitem(sys.modules, 'zstandard', None)    # import zstandard fails
    got = read_topics(mcap_of(bag), ['/imu'])['/imu']
    assert len(got.payloads) == len(big_trip().imu.stamp_s)


def test_a_missing_codec_falls_back_to_rosbags_with_the_reason_logged(
        tmp_path, monkeypatch, caplog):
    bag = write_trip_bag(big_trip(), tmp_path / 'z', compress=True)
    want = read_bag(bag).trip

    def no_zstd():
        raise ImportError('no zstd here')
    monkeypatch.setattr(mcap_chunks, '_zstd_module', no_zstd)
    with caplog.at_level(logging.INFO, logger='gyro_ekf.io.bag_reader'):
        got = read_bag(bag).trip
    assert 'zstd chunks need backports.zstd (no zstd here); reading it with rosbags' in (
        caplog.text)
    assert_trips_equal(got, want)


def test_a_damaged_file_is_never_handed_to_rosbags(plain_bag, monkeypatch):
    mcap = mcap_of(plain_bag)
    data = mcap.read_bytes()
    flip(mcap, messages_in_chunk(data, chunks(data)[1])[2][0] + 9 + 6 + 7, bit=2)
    from gyro_ekf.io import bag_reader

    def no_fallback(*args, **kwargs):
        raise AssertionError('fell back to rosbags')
    monkeypatch.setattr(bag_reader, '_read_with_rosbags', no_fallback)
    with pytest.raises(BagError, match="outside its chunk's range"):
        read_bag(plain_bag)


# -- a small mutation loop --------------------------------------------------------------


def mutants(data: bytes, rng: np.random.Generator, count: int):
    """Yield (what, mutated bytes): bit flips, random bytes, 0xff runs, cuts, zeroed words."""
    for _ in range(count):
        kind = int(rng.integers(5))
        at = int(rng.integers(len(data)))
        mutated = bytearray(data)
        if kind == 0:
            mutated[at] ^= 1 << int(rng.integers(8))
        elif kind == 1:
            mutated[at] = int(rng.integers(256))
        elif kind == 2:
            mutated[at:at + 8] = b'\xff' * len(mutated[at:at + 8])
        elif kind == 3:
            del mutated[at:]
        else:
            mutated[at:at + 4] = bytes(len(mutated[at:at + 4]))
        yield f'kind {kind} at {at}', bytes(mutated)


@pytest.mark.parametrize('compress', [False, True], ids=['plain', 'zstd'])
def test_mutated_bags_with_crcs_give_the_trip_or_a_bag_error(tmp_path, crc_writer, compress):
    trip = make_trip(seed=4, n=120, m=8)
    bag = write_trip_bag(trip, tmp_path / 'm', compress=compress)
    mcap = mcap_of(bag)
    original = mcap.read_bytes()
    want = read_bag(bag).trip
    outcomes = {'error': 0, 'same': 0}
    for what, data in mutants(original, np.random.default_rng(20 + compress), 100):
        if data == original:
            continue
        mcap.write_bytes(data)
        try:
            got = read_bag(bag).trip
        except BagError as err:
            assert str(bag) in str(err), what
            outcomes['error'] += 1
            continue
        assert_trips_equal(got, want)
        outcomes['same'] += 1
    assert outcomes['error'] > 50


@pytest.mark.parametrize('change, message', [
    ('beams', 'scan 2 changes the beam count or geometry'),
    ('increment', 'scan 2 changes the beam count or geometry'),
    ('range_max', 'scan 2 changes the beam count or geometry'),
    ('intensities', 'scan 2 has 90 intensities for 181 beams')])
@pytest.mark.parametrize('read', [read_bag, read_bag_rosbags], ids=['fast', 'rosbags'])
def test_a_scan_that_changes_the_lidar_is_refused_naming_it(tmp_path, change, message, read):
    # One LiDAR per topic: both readers share one check (bag_sinks.check_scans).
    scans = make_trip().scans[0]
    assert scans.beam_count == 181 and scans.intensities is not None
    stamp = 10**18
    imu = msgs.serialize(msgs.imu_message(stamp, np.zeros(3), np.zeros(9), None))
    odom = msgs.serialize(msgs.speed_message(stamp, 1.0, np.zeros(36)))
    laser = [msgs.scan_message(stamp + k, scans, k) for k in range(3)]
    laser[1] = dataclasses.replace(laser[1], **{
        'beams': {'ranges': laser[1].ranges[:-1]},
        'increment': {'angle_increment': 2 * laser[1].angle_increment},
        'range_max': {'range_max': laser[1].range_max + 1.0},
        'intensities': {'intensities': laser[1].intensities[:90]}}[change])
    bag = tmp_path / 'changing'
    with Writer(bag, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        for topic, msgtype, datas in (
                ('/imu', topics.IMU_TYPE, [imu]), ('/odom', topics.ODOMETRY_TYPE, [odom]),
                ('/scan', topics.LASER_SCAN_TYPE, [msgs.serialize(m) for m in laser])):
            connection = writer.add_connection(topic, msgtype, typestore=msgs.TYPESTORE)
            for k, data in enumerate(datas):
                writer.write(connection, stamp + k, data)
    with pytest.raises(BagError, match=f"changing: topic '/scan': {message}"):
        read(bag)
