"""Read a bag written by `bag_writer` back into a Trip, or stream its messages in stamp order.

Stamps of the returned Trip are seconds since the bag's first message (which the writer puts
at the log's time zero); `BagTrip.start_time_ns` is that message's stamp. What no message
carries (LiDAR mounts, stated noise, true bias) comes from the params sidecar beside the bag;
without a sidecar the mounts default to the platform origin and a warning says so.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from dataclasses import dataclass
import logging
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
import yaml
from rosbags.rosbag2 import Reader
from rosbags.rosbag2.errors import ReaderError
from rosbags.serde import SerdeError

from gyro_ekf import topics
from gyro_ekf.core.types import (
    GroundTruth, ImuSeries, LidarMount, NoiseFigures, ScanSeries, SpeedSeries, Trip)
from gyro_ekf.io import messages as msgs
from gyro_ekf.io.errors import BagError
from gyro_ekf.io.sidecar import BagParams, read_sidecar, sidecar_path

__all__ = ['BagMessage', 'BagSummary', 'BagTrip', 'TopicSummary', 'bag_summary',
           'iter_bag_messages', 'read_bag', 'read_trip_bag']

log = logging.getLogger(__name__)

IMU_TOPIC = topics.bag_topic(topics.IMU)
ODOM_TOPIC = topics.bag_topic(topics.ODOM)
MAP_TOPIC = topics.bag_topic(topics.LANDMARK_MAP)
INITIAL_POSE_TOPIC = topics.bag_topic(topics.INITIAL_POSE)
GROUND_TRUTH_TOPIC = topics.bag_topic(topics.GROUND_TRUTH)


class BagMessage(NamedTuple):
    """One deserialized message.

    Attributes:
        topic: bag topic name (absolute).
        msgtype: e.g. 'sensor_msgs/msg/Imu'.
        stamp_ns: bag (receive) stamp, ns since the epoch; the writer sets it equal to the
            header stamp.
        message: the rosbags message object.
    """

    topic: str
    msgtype: str
    stamp_ns: int
    message: Any


class TopicSummary(NamedTuple):
    """A topic of a bag: name, type, message count and offered durability."""

    name: str
    msgtype: str
    count: int
    durability: str


class BagSummary(NamedTuple):
    """What `gyro-ekf info` prints about a bag."""

    path: Path
    storage: str
    version: int
    start_time_ns: int
    duration_ns: int
    message_count: int
    topics: list[TopicSummary]
    sidecar: Path | None


@dataclass(frozen=True, slots=True)
class BagTrip:
    """A trip read back from a bag.

    Attributes:
        trip: the trip, stamps in s since the bag's first message.
        start_time_ns: stamp of the bag's first message, ns since the epoch.
        params: the sidecar contents, or None when the bag has none.
    """

    trip: Trip
    start_time_ns: int
    params: BagParams | None


def _open(path: Path) -> Reader:
    if not path.exists():
        raise BagError(f'{path}: no such bag')
    if path.is_dir() and not (path / 'metadata.yaml').exists():
        raise BagError(f'{path}: not a rosbag2 folder (no metadata.yaml)')
    try:
        reader = Reader(path)
        reader.open()
    except (ReaderError, OSError, KeyError, ValueError) as err:
        raise BagError(f'{path}: cannot read the bag: {err}') from None
    return reader


def bag_summary(path: Path | str) -> BagSummary:
    """Topics, types, counts, start time and duration of a bag (from its metadata).

    Raises:
        BagError: missing or unreadable bag.
    """
    path = Path(path)
    reader = _open(path)
    try:
        summaries = []
        for connection in reader.connections:
            qos = getattr(connection.ext, 'offered_qos_profiles', [])
            durability = ','.join(sorted({q.durability.name.lower() for q in qos})) or '-'
            summaries.append(TopicSummary(connection.topic, connection.msgtype,
                                          connection.msgcount, durability))
    finally:
        reader.close()
    meta = _metadata(path)
    try:
        return BagSummary(
            path=path, storage=str(meta['storage_identifier']), version=int(meta['version']),
            start_time_ns=int(meta['starting_time']['nanoseconds_since_epoch']),
            duration_ns=int(meta['duration']['nanoseconds']),
            message_count=int(meta['message_count']), topics=summaries,
            sidecar=sidecar_path(path) if sidecar_path(path).exists() else None)
    except (KeyError, TypeError, ValueError) as err:
        raise BagError(f'{path / "metadata.yaml"}: missing or invalid entry {err}') from None


def _metadata(path: Path) -> dict[str, Any]:
    """Read the rosbag2_bagfile_information mapping of a bag folder's metadata.yaml."""
    meta_path = path / 'metadata.yaml'
    try:
        document = yaml.safe_load(meta_path.read_text(encoding='utf-8'))
        return dict(document['rosbag2_bagfile_information'])
    except (OSError, yaml.YAMLError, KeyError, TypeError, ValueError) as err:
        raise BagError(f'{meta_path}: cannot read the bag metadata: {err}') from None


def iter_bag_messages(path: Path | str, topic_names: Iterable[str] | None = None
                      ) -> Iterator[BagMessage]:
    """Deserialized messages of a bag in stamp order (all topics merged), lazily.

    Args:
        path: the bag folder.
        topic_names: only these topics (absolute or relative names); None = all.

    Raises:
        BagError: missing or unreadable bag, a requested topic it lacks, or a message that
            does not deserialize.
    """
    path = Path(path)
    reader = _open(path)
    try:
        connections = reader.connections
        if topic_names is not None:
            wanted = {topics.bag_topic(t) for t in topic_names}
            present = {c.topic for c in connections}
            missing = sorted(wanted - present)
            if missing:
                raise BagError(f"{path}: no topic '{missing[0]}' (the bag has "
                               f'{sorted(present)})')
            connections = [c for c in connections if c.topic in wanted]
        for connection, stamp, data in reader.messages(connections=connections):
            try:
                message = msgs.deserialize(data, connection.msgtype)
            except (SerdeError, ValueError, KeyError, IndexError) as err:
                raise BagError(f"{path}: topic '{connection.topic}': message at {stamp} ns "
                               f'does not decode as {connection.msgtype}: {err}') from None
            yield BagMessage(connection.topic, connection.msgtype, stamp, message)
    except ReaderError as err:
        raise BagError(f'{path}: cannot read the bag: {err}') from None
    finally:
        reader.close()


class _ScanCollector:
    """Preallocated arrays of one LaserScan topic."""

    def __init__(self, topic: str, count: int) -> None:
        self.topic = topic
        self.count = count
        self.n = 0
        self.stamps = np.zeros(count, dtype=np.int64)
        self.ranges: np.ndarray | None = None
        self.intensities: np.ndarray | None = None
        self.first: Any = None

    def add(self, path: Path, stamp: int, message: Any) -> None:
        beams = len(message.ranges)
        if self.first is None:
            self.first = message
            self.ranges = np.empty((self.count, beams), dtype=np.float32)
            if len(message.intensities):
                self.intensities = np.empty((self.count, beams), dtype=np.float32)
        first = self.first
        assert self.ranges is not None
        geometry = (message.angle_min, message.angle_increment, message.range_min,
                    message.range_max)
        if beams != self.ranges.shape[1] or geometry != (
                first.angle_min, first.angle_increment, first.range_min, first.range_max):
            raise BagError(f"{path}: topic '{self.topic}': scan {self.n + 1} changes the beam "
                           'count or geometry; expected one fixed LiDAR per topic')
        if self.n >= self.count:
            raise BagError(f"{path}: topic '{self.topic}' has more messages than its "
                           'metadata counts')
        self.stamps[self.n] = stamp
        self.ranges[self.n] = message.ranges
        if self.intensities is not None:
            if len(message.intensities) != beams:
                raise BagError(f"{path}: topic '{self.topic}': scan {self.n + 1} has "
                               f'{len(message.intensities)} intensities for {beams} beams')
            self.intensities[self.n] = message.intensities
        self.n += 1


def read_bag(path: Path | str) -> BagTrip:
    """Read everything the bag writer writes, including the sidecar, into a Trip.

    Args:
        path: the bag folder.

    Returns:
        The trip (stamps in s since the first message), the bag start time and the sidecar.

    Raises:
        BagError: missing or unreadable bag, no /imu or /odom topic, or inconsistent scans.
    """
    path = Path(path)
    reader = _open(path)
    try:
        by_topic = {c.topic: c for c in reader.connections}
        counts = {c.topic: c.msgcount for c in reader.connections}
        start = reader.start_time if reader.message_count else 0
    finally:
        reader.close()
    params = read_sidecar(path)
    for needed, msgtype in ((IMU_TOPIC, topics.IMU_TYPE), (ODOM_TOPIC, topics.ODOMETRY_TYPE)):
        if needed not in by_topic:
            raise BagError(f"{path}: no topic '{needed}' (the bag has {sorted(by_topic)})")
        if by_topic[needed].msgtype != msgtype:
            raise BagError(f"{path}: topic '{needed}' has type {by_topic[needed].msgtype}, "
                           f'expected {msgtype}')
    scan_topics = [t for t, c in by_topic.items() if c.msgtype == topics.LASER_SCAN_TYPE]
    wanted = [IMU_TOPIC, ODOM_TOPIC, *scan_topics] + [
        t for t in (MAP_TOPIC, INITIAL_POSE_TOPIC, GROUND_TRUTH_TOPIC) if t in by_topic]

    n_imu = counts[IMU_TOPIC]
    imu_ns = np.zeros(n_imu, dtype=np.int64)
    rates = np.zeros((n_imu, 3))
    accel = np.zeros((n_imu, 3))
    has_accel = False
    axes_known: tuple[bool, bool, bool] = (True, True, True)
    n_odom = counts[ODOM_TOPIC]
    odom_ns = np.zeros(n_odom, dtype=np.int64)
    speeds = np.zeros(n_odom)
    n_truth = counts.get(GROUND_TRUTH_TOPIC, 0)
    truth_ns = np.zeros(n_truth, dtype=np.int64)
    truth = np.zeros((n_truth, 3))
    scans = {t: _ScanCollector(t, counts[t]) for t in scan_topics}
    landmarks = None
    initial_pose = None
    i_imu = i_odom = i_truth = 0
    for topic, _, stamp, message in iter_bag_messages(path, wanted):
        if topic == IMU_TOPIC:
            if i_imu == 0:
                axes_known = msgs.axes_known_of(message.angular_velocity_covariance)
                has_accel = message.linear_acceleration_covariance[0] != -1.0
            w, a = message.angular_velocity, message.linear_acceleration
            imu_ns[i_imu] = stamp
            rates[i_imu] = (w.x, w.y, w.z)
            accel[i_imu] = (a.x, a.y, a.z)
            i_imu += 1
        elif topic == ODOM_TOPIC:
            odom_ns[i_odom] = stamp
            speeds[i_odom] = message.twist.twist.linear.x
            i_odom += 1
        elif topic in scans:
            scans[topic].add(path, stamp, message)
        elif topic == GROUND_TRUTH_TOPIC:
            truth_ns[i_truth] = stamp
            truth[i_truth] = msgs.pose_of(message.pose.pose)
            i_truth += 1
        elif topic == MAP_TOPIC:
            landmarks = msgs.landmarks_of(message)
        elif topic == INITIAL_POSE_TOPIC:
            initial_pose = np.array(msgs.pose_of(message.pose.pose))

    def seconds(stamps: np.ndarray) -> np.ndarray:
        return (stamps - np.int64(start)) / float(msgs.NS_PER_S)

    if params is None:
        log.warning('%s: no params sidecar %s; LiDAR mounts default to the platform origin',
                    path, sidecar_path(path).name)
    series = []
    for topic in scan_topics:
        collector = scans[topic]
        first = collector.first
        if first is None or collector.ranges is None:
            continue
        name = topic.lstrip('/')
        frame_id, mount = (params.lidars.get(name) if params is not None else None) or (
            first.header.frame_id, LidarMount())
        series.append(ScanSeries(
            stamp_s=seconds(collector.stamps[:collector.n]),
            ranges_m=collector.ranges[:collector.n],
            intensities=None if collector.intensities is None else collector.intensities[
                :collector.n],
            angle_min_rad=float(first.angle_min), angle_increment_rad=float(
                first.angle_increment),
            range_min_m=float(first.range_min), range_max_m=float(first.range_max),
            mount=mount, topic=name, frame_id=first.header.frame_id or frame_id))
    if initial_pose is None:
        initial_pose = params.initial_pose if params is not None else np.zeros(3)
    trip = Trip(
        name=params.name if params is not None else path.name,
        imu=ImuSeries(stamp_s=seconds(imu_ns[:i_imu]), angular_velocity_rad_s=rates[:i_imu],
                      axes_known=axes_known,
                      linear_acceleration_m_s2=accel[:i_imu] if has_accel else None),
        speed=SpeedSeries(stamp_s=seconds(odom_ns[:i_odom]), speed_m_s=speeds[:i_odom]),
        scans=tuple(series),
        landmarks=landmarks,
        initial_pose=initial_pose,
        ground_truth=GroundTruth(seconds(truth_ns[:i_truth]), truth[:i_truth]) if n_truth
        else None,
        true_gyro_bias_rad_s=None if params is None else params.true_gyro_bias_rad_s,
        noise=NoiseFigures() if params is None else params.noise,
        static_duration_s=0.0 if params is None else params.static_duration_s)
    return BagTrip(trip=trip, start_time_ns=int(start), params=params)


def read_trip_bag(path: Path | str) -> Trip:
    """Read a bag written by write_trip_bag (and its sidecar) into a Trip.

    Stamps are s since the bag's first message; read_bag also returns that message's stamp.

    Raises:
        BagError: missing or unreadable bag, no /imu or /odom topic, inconsistent scans.
    """
    return read_bag(path).trip
