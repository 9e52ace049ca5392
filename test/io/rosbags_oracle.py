"""Test oracle: read a bag deserialising every message with rosbags, one by one.

`read_bag` decodes the sensor topics in batches with numpy (`bag_sinks`, `fast_cdr`);
this reads the same bag through `iter_bag_messages` and rosbags' own deserialisation,
about three times slower, so tests and the fuzzer (`fuzz/targets_bag.py`) can check that
both give the same Trip, bit for bit, and refuse the same bags. Times are header stamps, the
time zero and the dropping of exact duplicates as read_bag's (see its module docstring),
done here message by message with plain Python.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import numpy as np

from gyro_ekf import topics
from gyro_ekf.io import messages as msgs
from gyro_ekf.io.bag_open import (
    GROUND_TRUTH_TOPIC, IMU_TOPIC, INITIAL_POSE_TOPIC, MAP_TOPIC, ODOM_TOPIC, every_time,
    open_bag, topic_connections)
from gyro_ekf.io.bag_reader import (
    BagTrip, assemble_trip, initial_pose_of, iter_bag_messages, one_message, time_zero)
from gyro_ekf.io.bag_sinks import (
    SCAN_CHECKED, SCAN_GEOMETRY, ScanData, check_imu_axes, check_scans, has_acceleration,
    header_stamps_ns)
from gyro_ekf.io.errors import BagError
from gyro_ekf.io.sidecar import BagFingerprint, check_belongs, read_sidecar


class _Topic:
    """One stamped topic as read: header stamps, log times and what each message gives."""

    def __init__(self, topic: str) -> None:
        self.topic = topic
        self.stamps: list[int] = []
        self.log: list[int] = []
        self.rows: list[Any] = []

    def add(self, path: Path, log_ns: int, message: Any, row: Any) -> None:
        stamp = message.header.stamp
        self.stamps.append(int(header_stamps_ns(path, self.topic, len(self.stamps),
                                                np.array([stamp.sec]),
                                                np.array([stamp.nanosec]))[0]))
        self.log.append(log_ns)
        self.rows.append(row)

    @property
    def n(self) -> int:
        return len(self.stamps)

    def array(self, name: str) -> np.ndarray:
        return np.array(getattr(self, name), dtype=np.int64)

    def drop_duplicates(self, path: Path) -> int:
        """Drop exact copies (same header stamp, same raw bytes) of an earlier message.

        A different message with the stamp of the one before it is refused, unless the
        stamps went back before it (left to the validation boundary).
        """
        members: dict[int, list[int]] = {}
        raw: list[bytes] | None = None
        dropped = set()
        went_back = False
        for k, stamp in enumerate(self.stamps):
            earlier = members.setdefault(stamp, [])
            if earlier:
                if raw is None:
                    raw = _raw_payloads(path, self.topic)
                if any(raw[k] == raw[e] for e in earlier):
                    dropped.add(k)
                elif not went_back and self.stamps[k - 1] == stamp:
                    raise BagError(
                        f"{path}: topic '{self.topic}': message index {earlier[0]} and "
                        f'message index {k} have the same header.stamp ({stamp} ns) but '
                        'different contents; expected one message per stamp (an exact copy '
                        'would be dropped)')
            earlier.append(k)
            went_back = went_back or (k > 0 and stamp < self.stamps[k - 1])
        for name in ('stamps', 'log', 'rows'):
            values = getattr(self, name)
            setattr(self, name, [v for k, v in enumerate(values) if k not in dropped])
        return len(dropped)


def _raw_payloads(path: Path, topic: str) -> list[bytes]:
    """Every raw message of a topic, in the order read (rosbags' Reader, a second pass)."""
    reader = open_bag(path)
    try:
        connections = [c for c in reader.connections if c.topic == topic]
        return [bytes(d) for _, _, d in reader.messages(connections, *every_time(path))]
    finally:
        reader.close()


def read_bag_rosbags(path: Path | str, acceleration: bool = True) -> BagTrip:
    """Read a bag as `read_bag` does, deserialising every message with rosbags.

    Raises:
        BagError: as read_bag.
    """
    path = Path(path)
    reader = open_bag(path)
    try:
        params = read_sidecar(path, check=False)     # held to the messages read, below
        by_topic, counts = topic_connections(path, reader, params)
        start = reader.start_time if reader.message_count else 0
    finally:
        reader.close()
    scan_topics = [t for t, c in by_topic.items() if c.msgtype == topics.LASER_SCAN_TYPE]
    wanted = [IMU_TOPIC, ODOM_TOPIC, *scan_topics] + [
        t for t in (MAP_TOPIC, INITIAL_POSE_TOPIC, GROUND_TRUTH_TOPIC) if t in by_topic]
    # Lists, not arrays sized by the bag's counts: those are only hints.
    imu = _Topic(IMU_TOPIC)
    has_accel = False
    axes_known: tuple[bool, bool, bool] = (True, True, True)
    odom = _Topic(ODOM_TOPIC)
    truth = _Topic(GROUND_TRUTH_TOPIC)
    scans: dict[str, _Topic] = {t: _Topic(t) for t in scan_topics}
    singles: dict[str, list[Any]] = {MAP_TOPIC: [], INITIAL_POSE_TOPIC: []}
    log_times: list[int] = []
    for topic, _, log_ns, message in iter_bag_messages(path, wanted):
        log_times.append(log_ns)
        if topic == IMU_TOPIC:
            # Every message is judged, as by the reader (bag_sinks.check_imu_axes).
            axes_known = check_imu_axes(path, topic, imu.n,
                                        message.angular_velocity_covariance[None],
                                        axes_known if imu.n else None)
            if not imu.n:
                has_accel = has_acceleration(message)
            w, a = message.angular_velocity, message.linear_acceleration
            imu.add(path, log_ns, message, ((w.x, w.y, w.z),
                                            message.angular_velocity_covariance[8],
                                            (a.x, a.y, a.z)))
        elif topic == ODOM_TOPIC:
            odom.add(path, log_ns, message, (message.twist.twist.linear.x,
                                             message.twist.covariance[0]))
        elif topic in scans:
            scans[topic].add(path, log_ns, message, message)
        elif topic == GROUND_TRUTH_TOPIC:
            truth.add(path, log_ns, message, msgs.pose_of(message.pose.pose))
        elif topic in singles:
            singles[topic].append(message)
    # The messages the bag holds (before copies are dropped); topics not read as stated.
    unread = sum(n for topic, n in counts.items() if topic not in wanted)
    check_belongs(path, params, BagFingerprint(
        len(log_times) + unread, min(log_times, default=0), max(log_times, default=0)),
        'as its messages hold')
    stamped = [imu, odom, *scans.values()] + ([truth] if GROUND_TRUTH_TOPIC in by_topic else [])
    duplicates = {t.topic: n for t in stamped if (n := t.drop_duplicates(path))}
    zero = time_zero(path, params, [_Firsts(t) for t in (imu, odom, *scans.values())],
                     int(start))
    map_message = one_message(path, MAP_TOPIC, singles[MAP_TOPIC])
    pose_message = one_message(path, INITIAL_POSE_TOPIC, singles[INITIAL_POSE_TOPIC])
    landmarks = None if map_message is None else msgs.landmarks_of(map_message)
    initial_pose = None if pose_message is None else initial_pose_of(path, pose_message)

    def rows(values: list[Any], width: int) -> np.ndarray:
        return np.array(values, dtype=np.float64).reshape(len(values), width)

    bag_trip = assemble_trip(
        path, params, zero, imu_ns=imu.array('stamps'),
        rates=rows([r[0] for r in imu.rows], 3),
        rate_variances=np.array([r[1] for r in imu.rows], dtype=np.float64),
        accel=rows([r[2] for r in imu.rows], 3) if has_accel and acceleration else None,
        axes_known=axes_known, odom_ns=odom.array('stamps'),
        speeds=np.array([r[0] for r in odom.rows], dtype=np.float64),
        speed_variances=np.array([r[1] for r in odom.rows], dtype=np.float64),
        scans=[_scan_data(path, scans[t]) for t in scan_topics if scans[t].n],
        truth=((truth.array('stamps'), rows(truth.rows, 3))
               if GROUND_TRUTH_TOPIC in by_topic else None),
        landmarks=landmarks, initial_pose=initial_pose)
    return dataclasses.replace(bag_trip, duplicates=duplicates)


class _Firsts:
    """What time_zero needs of a topic: its count, header stamps and log times."""

    def __init__(self, topic: _Topic) -> None:
        self.topic = topic.topic
        self.n = topic.n
        self.stamps = topic.array('stamps')
        self.log_ns = topic.array('log')


def _scan_data(path: Path, scans: _Topic) -> ScanData:
    """Stack one topic's LaserScans after the reader's own geometry check."""
    topic = scans.topic
    messages = scans.rows
    first = messages[0]
    check_scans(path, topic, 0, first, np.array([len(m.ranges) for m in messages]),
                {name: np.array([getattr(m, name) for m in messages]) for name in SCAN_CHECKED},
                np.array([len(m.intensities) for m in messages]))
    beams = len(first.ranges)
    ranges = np.array([m.ranges for m in messages], dtype=np.float32).reshape(-1, beams)
    intensities = (np.array([m.intensities for m in messages], dtype=np.float32)
                   .reshape(-1, beams) if len(first.intensities) else None)
    return ScanData(topic, scans.array('stamps'), ranges,
                    intensities, tuple(getattr(first, name) for name in SCAN_GEOMETRY),
                    first.header.frame_id)
