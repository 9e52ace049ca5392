"""The numpy CDR fast paths against rosbags: decoding, templates and batched MCAP writes."""

from __future__ import annotations

import math
import struct
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from rosbags.rosbag2 import Reader, StoragePlugin, Writer
from rosbags_oracle import read_bag_rosbags
from synthetic_logs import make_trip

from gyro_ekf import topics
from gyro_ekf.core.types import Trip
from gyro_ekf.io import bag_sinks
from gyro_ekf.io import messages as msgs
from gyro_ekf.io.bag_reader import read_bag
from gyro_ekf.io.bag_writer import write_trip_bag
from gyro_ekf.io.batch_write import enable_chunk_crcs, write_rows
from gyro_ekf.io.errors import BagError
from gyro_ekf.io.fast_cdr import CdrDecodeError, CdrTemplate, decode_columns, LAYOUTS

STORE = msgs.TYPESTORE
Vector3Stamped = STORE.types[topics.VECTOR3_STAMPED_TYPE]
SPECIAL = [0.0, -0.0, math.nan, math.inf, -math.inf, 5e-324, 1.7976931348623157e308]


def _value(message: Any, name: str) -> Any:
    for part in name.split('.'):
        message = getattr(message, part)
    if hasattr(message, 'x'):
        return [message.x, message.y, message.z] + ([message.w] if hasattr(message, 'w') else [])
    return message


def assert_columns_match(datas: list[bytes], msgtype: str) -> None:
    """Every numeric field decoded in one batch equals rosbags' decoding, bit for bit."""
    fields = [f.name for f in LAYOUTS[msgtype] if f.kind != 'string']
    columns = decode_columns(datas, msgtype, fields, STORE)
    for i, data in enumerate(datas):
        message = STORE.deserialize_cdr(data, msgtype)
        for name in fields:
            want = _value(message, name)
            if name in columns.counts:
                assert columns.counts[name][i] == len(want)
                if name not in columns.values:
                    continue
            got = columns.values[name][i]
            want = np.asarray(want, dtype=got.dtype)
            assert got.tobytes() == want.tobytes(), (name, i)


def _trip_arrays(trip: Trip) -> dict[str, Any]:
    arrays: dict[str, Any] = {
        'imu_t': trip.imu.stamp_s, 'imu_w': trip.imu.angular_velocity_rad_s,
        'imu_a': trip.imu.linear_acceleration_m_s2, 'axes': trip.imu.axes_known,
        'odom_t': trip.speed.stamp_s, 'odom_v': trip.speed.speed_m_s,
        'pose0': trip.initial_pose, 'name': trip.name,
        'map': None if trip.landmarks is None else trip.landmarks.xy_m}
    if trip.ground_truth is not None:
        arrays.update(gt_t=trip.ground_truth.stamp_s, gt_pose=trip.ground_truth.pose)
    for scan in trip.scans:
        arrays[scan.topic] = (scan.stamp_s, scan.ranges_m, scan.intensities, scan.angle_min_rad,
                              scan.angle_increment_rad, scan.range_min_m, scan.range_max_m,
                              scan.frame_id, scan.mount)
    return arrays


def assert_same_bits(a: Any, b: Any) -> None:
    """Recursively require equal values; arrays equal in dtype, shape and bytes."""
    if isinstance(a, dict):
        assert a.keys() == b.keys()
        for key in a:
            assert_same_bits(a[key], b[key])
    elif isinstance(a, tuple):
        assert len(a) == len(b)
        for x, y in zip(a, b):
            assert_same_bits(x, y)
    elif isinstance(a, np.ndarray):
        assert isinstance(b, np.ndarray) and a.dtype == b.dtype and a.shape == b.shape
        assert a.tobytes() == b.tobytes()
    else:
        assert a == b


def assert_fast_read_is_rosbags_read(bag: Path) -> None:
    fast, slow = read_bag(bag), read_bag_rosbags(bag)
    assert fast.start_time_ns == slow.start_time_ns
    assert_same_bits(_trip_arrays(fast.trip), _trip_arrays(slow.trip))


def test_fast_read_matches_rosbags_on_a_synthetic_bag(tmp_path, monkeypatch):
    # Two LiDARs (one without intensities), accel, ground truth; tiny batches so every
    # topic is decoded in several flushes.
    monkeypatch.setattr(bag_sinks, 'BATCH_MESSAGES', 7)
    bag = tmp_path / 'synthetic'
    write_trip_bag(make_trip(), bag)
    assert_fast_read_is_rosbags_read(bag)


@pytest.mark.parametrize('read', [read_bag, read_bag_rosbags], ids=['fast', 'rosbags'])
def test_acceleration_can_be_left_out(tmp_path, read):
    bag = tmp_path / 'synthetic'
    write_trip_bag(make_trip(), bag)
    full, lean = read(bag), read(bag, acceleration=False)
    assert full.trip.imu.linear_acceleration_m_s2 is not None
    assert lean.trip.imu.linear_acceleration_m_s2 is None
    without = _trip_arrays(full.trip)
    without['imu_a'] = None
    assert_same_bits(_trip_arrays(lean.trip), without)


@pytest.mark.shared_data
@pytest.mark.parametrize('key, parts', [
    ('p2016', ['2016_project1', '2021_aas01/MapMTRN4010.mat']), ('aas2021', ['2021_aas01'])])
def test_fast_read_matches_rosbags_on_real_logs(shared_data, converted, key, parts):
    _, bag = converted(key, [shared_data(p) for p in parts])
    assert_fast_read_is_rosbags_read(bag)


def _stamp(rng: np.random.Generator) -> int:
    return int(rng.integers(0, 2**31 - 1)) * 1_000_000_000 + int(rng.integers(0, 10**9))


def _imu_object(frame_id: str, rng: np.random.Generator) -> Any:
    return msgs.Imu(header=msgs.header(_stamp(rng), frame_id),
                    orientation=msgs.Quaternion(*rng.normal(size=4)),
                    orientation_covariance=rng.normal(size=9),
                    angular_velocity=msgs.Vector3(*rng.normal(size=3)),
                    angular_velocity_covariance=rng.normal(size=9),
                    linear_acceleration=msgs.Vector3(*rng.normal(size=3)),
                    linear_acceleration_covariance=rng.normal(size=9))


def _odometry(frame_id: str, child: str, rng: np.random.Generator) -> Any:
    pose = msgs.PoseWithCovariance(
        pose=msgs.Pose(position=msgs.Point(*rng.normal(size=3)),
                       orientation=msgs.Quaternion(*rng.normal(size=4))),
        covariance=rng.normal(size=36))
    twist = msgs.TwistWithCovariance(
        twist=msgs.Twist(linear=msgs.Vector3(*rng.normal(size=3)),
                         angular=msgs.Vector3(*rng.normal(size=3))),
        covariance=rng.normal(size=36))
    return msgs.Odometry(header=msgs.header(_stamp(rng), frame_id),
                         child_frame_id=child, pose=pose, twist=twist)


def _scan(frame_id: str, beams: int, intensities: int, rng: np.random.Generator) -> Any:
    return msgs.LaserScan(
        header=msgs.header(_stamp(rng), frame_id),
        angle_min=float(np.float32(rng.normal())), angle_max=float(np.float32(rng.normal())),
        angle_increment=float(np.float32(rng.normal())), time_increment=0.0, scan_time=0.0,
        range_min=float(np.float32(rng.uniform())), range_max=float(np.float32(30.0)),
        ranges=rng.uniform(0, 30, beams).astype(np.float32),
        intensities=rng.uniform(0, 9, intensities).astype(np.float32))


def _serialize(message: Any, little_endian: bool = True) -> bytes:
    return bytes(STORE.serialize_cdr(message, message.__msgtype__, little_endian=little_endian))


def test_imu_frame_ids_of_every_length_in_one_batch():
    # Lengths 0..17 put the first float64 at every alignment the 8-byte padding allows.
    rng = np.random.default_rng(0)
    datas = [_serialize(_imu_object('f' * (i % 18), rng)) for i in range(60)]
    assert len({len(d) for d in datas}) > 2
    assert_columns_match(datas, topics.IMU_TYPE)


def test_odometry_with_two_strings_of_varying_lengths():
    rng = np.random.default_rng(1)
    datas = [_serialize(_odometry('o' * (i % 7), 'c' * (i % 5), rng)) for i in range(70)]
    assert_columns_match(datas, topics.ODOMETRY_TYPE)


def test_scans_with_varying_beam_and_intensity_counts():
    rng = np.random.default_rng(2)
    uniform = [_serialize(_scan('laser' + 'x' * (i % 3), 361, 361, rng)) for i in range(9)]
    columns = decode_columns(uniform, topics.LASER_SCAN_TYPE, ['ranges', 'intensities'], STORE)
    assert columns.values['ranges'].shape == (9, 361)
    mixed = [_serialize(_scan('l' * (i % 4), 100 + i % 3, (i % 2) * 50, rng))
             for i in range(30)]
    assert_columns_match(mixed, topics.LASER_SCAN_TYPE)
    columns = decode_columns(mixed, topics.LASER_SCAN_TYPE, ['ranges', 'intensities'], STORE)
    assert 'ranges' not in columns.values and 'intensities' not in columns.values
    assert columns.counts['ranges'].tolist() == [100 + i % 3 for i in range(30)]


def test_big_endian_and_padded_messages_decode_as_rosbags_does():
    rng = np.random.default_rng(3)
    datas = [_serialize(_imu_object('imu_link', rng)) for _ in range(6)]
    datas[1] = _serialize(_imu_object('imu', rng), little_endian=False)
    datas[2] = datas[2] + b'\x00' * 3
    datas[4] = _serialize(_odometry('odom', 'base_link', rng), little_endian=False)
    assert_columns_match(datas[:4], topics.IMU_TYPE)
    assert_columns_match([datas[4]], topics.ODOMETRY_TYPE)


def test_special_float_values_keep_their_bits():
    rng = np.random.default_rng(4)
    message = _imu_object('imu_link', rng)
    message.angular_velocity_covariance[:7] = SPECIAL
    message.linear_acceleration.x = -0.0
    assert_columns_match([_serialize(message)] * 3, topics.IMU_TYPE)


def test_malformed_messages_name_the_message():
    rng = np.random.default_rng(5)
    good = _serialize(_imu_object('imu_link', rng))
    with pytest.raises(CdrDecodeError, match='message 1 of the batch') as info:
        decode_columns([good, good[:-20], good], topics.IMU_TYPE, ['angular_velocity'], STORE)
    assert info.value.index == 1
    with pytest.raises(CdrDecodeError, match='message 0 of the batch'):
        decode_columns([b'\x07\x07' + good[2:]], topics.IMU_TYPE, ['orientation'], STORE)
    with pytest.raises(CdrDecodeError, match='no numeric field'):
        decode_columns([good], topics.IMU_TYPE, ['header.frame_id'], STORE)
    with pytest.raises(CdrDecodeError, match='no fast CDR layout'):
        decode_columns([good], topics.POSE_ARRAY_TYPE, [], STORE)


def test_empty_batch_gives_empty_columns():
    columns = decode_columns([], topics.IMU_TYPE, ['angular_velocity', 'header.stamp.sec'],
                             STORE)
    assert columns.values['angular_velocity'].shape == (0, 3)
    assert columns.values['header.stamp.sec'].shape == (0,)


def test_read_bag_names_bag_topic_and_stamp_of_an_undecodable_message(tmp_path):
    bag = tmp_path / 'broken'
    write_trip_bag(make_trip(), bag)
    trip = read_bag(bag).trip
    broken = tmp_path / 'broken2'
    with Reader(bag) as reader, Writer(broken, version=9,
                                       storage_plugin=StoragePlugin.MCAP) as writer:
        out = {c.id: writer.add_connection(c.topic, c.msgtype, typestore=STORE)
               for c in reader.connections}
        imu_seen = 0
        for connection, stamp, data in reader.messages():
            if connection.topic == '/imu':
                imu_seen += 1
                if imu_seen == 40:
                    data, bad_stamp = data[:100], stamp
            writer.write(out[connection.id], stamp, data)
    (tmp_path / 'broken2.params.yaml').write_bytes(
        (tmp_path / 'broken.params.yaml').read_bytes())
    with pytest.raises(BagError, match=rf"broken2: topic '/imu': message at {bad_stamp} ns "
                                       r'does not decode as sensor_msgs/msg/Imu'):
        read_bag(broken)
    assert len(trip.imu.stamp_s) > 40


def test_templates_give_rosbags_bytes_for_every_row():
    rng = np.random.default_rng(6)
    n = 50
    values = rng.normal(size=(n, 7)) * 10.0 ** rng.integers(-300, 300, (n, 7))
    values[:len(SPECIAL), 0] = SPECIAL
    stamps = rng.integers(0, 2**31 - 1, n) * 1_000_000_000 + rng.integers(0, 10**9, n)
    template = CdrTemplate(Vector3Stamped(header=msgs.header(0, 'imu_link'),
                                          vector=msgs.Vector3(x=0.0, y=0.0, z=0.0)),
                           topics.VECTOR3_STAMPED_TYPE, STORE)
    rows = template.rows(n)
    template.set(rows, 'header.stamp.sec', stamps // 1_000_000_000)
    template.set(rows, 'header.stamp.nanosec', stamps % 1_000_000_000)
    template.set(rows, 'vector', values[:, 1:3], first=1)
    for k in range(n):
        want = Vector3Stamped(header=msgs.header(int(stamps[k]), 'imu_link'),
                              vector=msgs.Vector3(x=0.0, y=values[k, 1], z=values[k, 2]))
        assert rows[k].tobytes() == _serialize(want)
    odometry = _odometry('map', 'base_link', rng)
    template = CdrTemplate(odometry, topics.ODOMETRY_TYPE, STORE)
    rows = template.rows(n)
    template.set(rows, 'pose.covariance', values, first=29)
    template.set(rows, 'twist.twist.angular', values[:, 0], first=2)
    for k in range(n):
        odometry.pose.covariance[29:] = values[k]
        odometry.twist.twist.angular.z = values[k, 0]
        assert rows[k].tobytes() == _serialize(odometry)
    with pytest.raises(CdrDecodeError, match='36 elements'):
        template.set(rows, 'pose.covariance', values, first=30)


def _payloads(rng: np.random.Generator, m: int, sizes: list[int]) -> list[np.ndarray]:
    return [rng.integers(0, 256, (m, size), dtype=np.uint8) for size in sizes]


@pytest.mark.parametrize('crcs', [False, True], ids=['plain', 'crcs'])
@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
def test_write_rows_is_byte_identical_to_writer_write(tmp_path, storage, crcs):
    # Sizes and counts that close chunks mid-row and carry a pending chunk across calls.
    rng = np.random.default_rng(7)
    sizes = [364, 724, 60]
    blocks = [(np.sort(rng.integers(0, 2**62, m)), _payloads(rng, m, sizes))
              for m in (1, 900, 2500, 3, 1200)]
    plugin = {'mcap': StoragePlugin.MCAP, 'sqlite3': StoragePlugin.SQLITE3}[storage]
    for name, batched in (('one', False), ('batch', True)):
        (tmp_path / name).mkdir()
        with Writer(tmp_path / name / 'bag', version=9, storage_plugin=plugin) as writer:
            if crcs:
                assert enable_chunk_crcs(writer) == (storage == 'mcap')
            connections = [writer.add_connection(f'/t{j}', topics.VECTOR3_STAMPED_TYPE,
                                                 typestore=STORE) for j in range(len(sizes))]
            for stamps, payloads in blocks:
                if batched:
                    write_rows(writer, connections, stamps, payloads)
                    continue
                for k, stamp in enumerate(stamps.tolist()):
                    for connection, payload in zip(connections, payloads):
                        writer.write(connection, stamp, payload[k].tobytes())
    one, batch = tmp_path / 'one' / 'bag', tmp_path / 'batch' / 'bag'
    assert (one / 'metadata.yaml').read_text() == (batch / 'metadata.yaml').read_text()
    if storage == 'mcap':
        assert (one / 'bag.mcap').read_bytes() == (batch / 'bag.mcap').read_bytes()
        data_end = (one / 'bag.mcap').read_bytes().rfind(b'\x0f\x04' + bytes(7))
        assert data_end > 0
        data_crc = (one / 'bag.mcap').read_bytes()[data_end + 9:data_end + 13]
        assert (data_crc != bytes(4)) == crcs
    with Reader(one) as a, Reader(batch) as b:
        assert [(c.topic, t, bytes(d)) for c, t, d in a.messages()] == [
            (c.topic, t, bytes(d)) for c, t, d in b.messages()]


@pytest.mark.parametrize('compress', [False, True])
def test_mcap_bags_are_read_by_the_chunk_reader_in_batches(tmp_path, monkeypatch, compress):
    from gyro_ekf.core.simulator import SimulationConfig, simulate_trip
    from gyro_ekf.io import mcap_chunks
    batches = []
    stream = mcap_chunks.stream_topics

    def small_batches(path, topics, consumer, batch_messages=65_536):
        def count(topic, batch):
            batches.append(topic)
            consumer(topic, batch)
        return stream(path, topics, count, batch_messages=50)

    monkeypatch.setattr(mcap_chunks, 'stream_topics', small_batches)
    bag = tmp_path / 'simulated'
    # 60 s of 10 Hz scans fill several 1 MB chunks, so the reader hands over several batches.
    write_trip_bag(simulate_trip(SimulationConfig(duration_s=60.0), seed=3), bag,
                   compress=compress)
    assert_fast_read_is_rosbags_read(bag)
    assert batches.count('/scan') > 1


def test_a_bag_the_chunk_reader_refuses_midway_is_read_by_rosbags(tmp_path, monkeypatch):
    from gyro_ekf.io import mcap_chunks
    stream = mcap_chunks.stream_topics

    def refuse_after_a_batch(path, topics, consumer, batch_messages=65_536):
        def first_then_refuse(topic, batch):
            consumer(topic, batch)
            raise mcap_chunks.UnsupportedMcap(path, 'refused for the test')
        return stream(path, topics, first_then_refuse, batch_messages=20)

    monkeypatch.setattr(mcap_chunks, 'stream_topics', refuse_after_a_batch)
    bag = tmp_path / 'synthetic'
    write_trip_bag(make_trip(), bag)
    assert_fast_read_is_rosbags_read(bag)


def _sample_payloads() -> dict[str, bytes]:
    trip = make_trip()
    return {
        topics.IMU_TYPE: msgs.serialize(msgs.imu_message(10**18, np.ones(3), np.zeros(9),
                                                         np.ones(3))),
        topics.ODOMETRY_TYPE: msgs.serialize(msgs.speed_message(10**18, 1.0, np.zeros(36))),
        topics.LASER_SCAN_TYPE: msgs.serialize(msgs.scan_message(10**18, trip.scans[0], 0)),
    }


_NUMERIC = {topics.IMU_TYPE: ('angular_velocity',), topics.ODOMETRY_TYPE: ('twist.twist.linear',),
            topics.LASER_SCAN_TYPE: ('ranges', 'intensities', 'angle_min')}


@pytest.mark.parametrize('msgtype', sorted(_NUMERIC))
def test_every_truncation_of_a_payload_is_a_clean_error(msgtype):
    data = _sample_payloads()[msgtype]
    for length in range(len(data)):
        with pytest.raises(CdrDecodeError) as raised:
            decode_columns([data, data[:length]], msgtype, _NUMERIC[msgtype], STORE)
        assert raised.value.index == 1


def test_a_huge_sequence_length_is_a_clean_error():
    data = bytearray(_sample_payloads()[topics.LASER_SCAN_TYPE])
    scan = decode_columns([bytes(data)], topics.LASER_SCAN_TYPE, ('ranges',), STORE)
    beams = scan.values['ranges'].shape[1]
    ranges_at = bytes(data).find(struct.pack('<I', beams))
    for count in (beams + 1, 2**31 - 1, 2**32 - 1):
        data[ranges_at:ranges_at + 4] = struct.pack('<I', count)
        with pytest.raises(CdrDecodeError):
            decode_columns([bytes(data)], topics.LASER_SCAN_TYPE, ('ranges',), STORE)


def test_mutated_payloads_decode_or_fail_cleanly():
    # Seeded: cuts, bit flips, 0x7fffffff words and big-endian garbage (the rosbags path).
    rng = np.random.default_rng(11)
    outcomes = {'decoded': 0, 'refused': 0}
    for msgtype, data in _sample_payloads().items():
        for _ in range(150):
            mutated = bytearray(data)
            at = int(rng.integers(len(mutated)))
            kind = int(rng.integers(4))
            if kind == 0:
                del mutated[at:]
            elif kind == 1:
                mutated[at] ^= 1 << int(rng.integers(8))
            elif kind == 2:
                mutated[at:at + 4] = b'\xff\xff\xff\x7f'
            else:
                mutated[0:2] = b'\x00\x00'
                mutated[at] = int(rng.integers(256))
            try:
                decode_columns([data, bytes(mutated)], msgtype, _NUMERIC[msgtype], STORE)
                outcomes['decoded'] += 1
            except CdrDecodeError:
                outcomes['refused'] += 1
    assert outcomes['refused'] > 100 and outcomes['decoded'] > 100


def test_a_string_rosbags_refuses_is_refused_in_a_batch():
    # A frame id without its NUL, with a length of 0, or not UTF-8: rosbags raises
    # SerdeError; the fast walk must not read past it (it once returned the numbers).
    rng = np.random.default_rng(12)
    good = _serialize(_imu_object('imu_link', rng))
    start = 4 + 8 + 4  # header, stamp, length word: 'imu_link\0' begins here
    assert good[start:start + 9] == b'imu_link\x00'
    no_nul = bytearray(good)
    no_nul[start + 8] = ord('x')
    not_utf8 = bytearray(good)
    not_utf8[start + 1] = 0x8d
    empty = bytearray(good)
    empty[start - 4:start] = struct.pack('<I', 0)
    for data, reason in ((no_nul, 'Missing string terminator at offset 20'),
                         (not_utf8, "can't decode byte 0x8d"), (empty, 'Invalid string length 0')):
        with pytest.raises(CdrDecodeError, match=reason) as raised:
            decode_columns([good, bytes(data), good], topics.IMU_TYPE, ['angular_velocity'],
                           STORE)
        assert raised.value.index == 1
    utf8 = _serialize(_imu_object('imu_\u00e9', rng))
    assert_columns_match([good, utf8, utf8], topics.IMU_TYPE)
