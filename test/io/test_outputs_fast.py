"""The estimates bag, written from CDR templates in blocks, against per-message rosbags."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from rosbags.rosbag2 import Reader, StoragePlugin, Writer

from gyro_ekf import topics
from gyro_ekf.io import results
from gyro_ekf.io.errors import OutputError
from gyro_ekf.io import messages as msgs
from gyro_ekf.io.batch_write import enable_chunk_crcs

START_NS = 1_700_000_000_000_000_000


def reference_bag(path: Path, start_time_ns: int, stamp_s, state, covariance, speed_m_s,
                  yaw_rate_rad_s, storage: str) -> None:
    """Write the estimates bag as gyro_ekf did before: message objects, one write each."""
    Vector3Stamped = msgs.TYPESTORE.types[topics.VECTOR3_STAMPED_TYPE]
    stamps_ns = int(start_time_ns) + np.round(np.asarray(stamp_s) * 1e9).astype(np.int64)
    flat = np.array([a * 6 + b for a in (0, 1, 5) for b in (0, 1, 5)])
    plugin = {'mcap': StoragePlugin.MCAP, 'sqlite3': StoragePlugin.SQLITE3}[storage]
    writer = Writer(path, version=9, storage_plugin=plugin)
    enable_chunk_crcs(writer)  # as every bag the project writes
    with writer:
        pose_conn, odom_conn, bias_conn = (
            writer.add_connection(topics.bag_topic(topic), msgtype, typestore=msgs.TYPESTORE)
            for topic, msgtype in ((topics.EKF_POSE, topics.POSE_WITH_COVARIANCE_STAMPED_TYPE),
                                   (topics.EKF_ODOMETRY, topics.ODOMETRY_TYPE),
                                   (topics.EKF_BIAS, topics.VECTOR3_STAMPED_TYPE)))
        for k, stamp in enumerate(stamps_ns.tolist()):
            x, y, yaw, bias = state[k].tolist()
            pose_cov = np.zeros(36)
            pose_cov[flat] = covariance[k, :3, :3].ravel()
            pose = msgs.PoseWithCovariance(
                pose=msgs.Pose(position=msgs.Point(x=x, y=y, z=0.0),
                               orientation=msgs.yaw_quaternion(yaw)), covariance=pose_cov)
            map_header = msgs.header(stamp, topics.MAP_FRAME)
            writer.write(pose_conn, stamp, msgs.serialize(
                msgs.PoseWithCovarianceStamped(header=map_header, pose=pose)))
            twist = msgs.TwistWithCovariance(
                twist=msgs.Twist(linear=msgs.Vector3(x=float(speed_m_s[k]), y=0.0, z=0.0),
                                 angular=msgs.Vector3(x=0.0, y=0.0,
                                                      z=float(yaw_rate_rad_s[k]))),
                covariance=np.zeros(36))
            writer.write(odom_conn, stamp, msgs.serialize(msgs.Odometry(
                header=map_header, child_frame_id=topics.BASE_FRAME, pose=pose, twist=twist)))
            writer.write(bias_conn, stamp, msgs.serialize(Vector3Stamped(
                header=msgs.header(stamp, topics.IMU_FRAME),
                vector=msgs.Vector3(x=0.0, y=0.0, z=bias))))


def _history(n: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    stamps = np.cumsum(rng.uniform(0.004, 0.006, n))
    state = rng.normal(size=(n, 4)) * [50.0, 50.0, 4.0, 0.02]
    covariance = rng.normal(size=(n, 4, 4))
    covariance[:7, 0, 0] = [0.0, -0.0, math.nan, math.inf, -math.inf, 5e-324, 1e308]
    state[:3, 2] = [-0.0, math.pi, -math.pi]
    return stamps, state, covariance, rng.uniform(-1, 3, n), rng.normal(size=n)


@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
def test_estimates_bag_is_what_per_message_rosbags_writes(tmp_path, monkeypatch, storage):
    # Small blocks, so rows straddle blocks and MCAP chunks close mid-block.
    monkeypatch.setattr(results, '_BAG_BLOCK_ROWS', 1500)
    n = 4000
    history = _history(n)
    (tmp_path / 'new').mkdir()
    (tmp_path / 'old').mkdir()
    # The visual topics are checked against rosbags in test_estimates_bag_visual.py.
    new = results.write_estimates_bag(tmp_path / 'new' / 'estimates', START_NS, *history,
                                      storage=storage, visual=False)
    old = tmp_path / 'old' / 'estimates'
    reference_bag(old, START_NS, *history, storage=storage)
    if storage == 'mcap':
        assert (new / 'estimates.mcap').read_bytes() == (old / 'estimates.mcap').read_bytes()
    with Reader(new) as a, Reader(old) as b:
        got = [(c.topic, t, bytes(d)) for c, t, d in a.messages()]
        assert got == [(c.topic, t, bytes(d)) for c, t, d in b.messages()]
    assert len(got) == 3 * n


def test_estimates_bag_refuses_stamps_beyond_int32_seconds(tmp_path):
    stamps, state, covariance, speed, rate = _history(10)
    with pytest.raises(OutputError, match='int32 seconds'):
        results.write_estimates_bag(tmp_path / 'estimates', 2**31 * 1_000_000_000, stamps,
                                    state, covariance, speed, rate)
    assert not (tmp_path / 'estimates').exists()


def test_empty_history_writes_an_empty_bag(tmp_path):
    bag = results.write_estimates_bag(tmp_path / 'estimates', START_NS, np.zeros(0),
                                      np.zeros((0, 4)), np.zeros((0, 4, 4)), np.zeros(0),
                                      np.zeros(0))
    with Reader(bag) as reader:
        # Only the static transforms (base_link -> imu_link) with no trip given.
        assert reader.message_count == 1
        assert {c.topic for c in reader.connections if c.msgcount} == {'/tf_static'}


def test_a_chunk_closed_by_packing_is_what_rosbags_writes(tmp_path):
    # rosbags' own close_chunk against the packed one (batch_write._close_chunk, which every
    # bag the project writes uses): three channels interleaved unevenly, several chunks
    # (rosbags closes one past 1 MiB), and an empty tail chunk, with no CRCs in either.
    from gyro_ekf.io.batch_write import _chunk_closer

    rng = np.random.default_rng(3)
    payloads = [rng.integers(0, 256, size=int(size), dtype=np.uint8).tobytes()
                for size in rng.integers(8, 4000, size=1500)]
    written = {}
    for packed in (False, True):
        # One name: the bag's metadata, in the file, names it.
        path = tmp_path / ('packed' if packed else 'rosbags') / 'bag'
        writer = Writer(path, version=9, storage_plugin=StoragePlugin.MCAP)
        with writer:
            if packed:
                writer.storage.close_chunk = _chunk_closer(writer.storage)
            connections = [writer.add_connection(f'/t{i}', 'std_msgs/msg/String',
                                                 typestore=msgs.TYPESTORE) for i in range(3)]
            for k, payload in enumerate(payloads):
                writer.write(connections[(k * k) % 3], START_NS + 1000 * k, payload)
        written[packed] = (path / f'{path.name}.mcap').read_bytes()
    assert len(written[True]) > 2 * 2**20  # three chunks
    assert written[True] == written[False]
