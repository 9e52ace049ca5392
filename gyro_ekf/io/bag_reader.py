"""Read a bag written by `bag_writer` back into a Trip, or stream its messages in stamp order.

Time, as the nodes take it: each stamped message (/imu, /odom, the LaserScan topics,
/ground_truth) is timed by its header.stamp; the log time (the recorder's receive time) only
orders the reading, per topic, and must lie in the bag's stated time range. So receive
latency and jitter, a bag recorded from a faster replay or a recorder on another clock
change nothing. A topic whose header stamps go back stays in the order read: the validation
boundary refuses it (or drops and counts with --skip-bad). The time zero (`time_zero_ns`)
is the sidecar's trip.log_time_zero_ns, the zero the nodes are given, or without a sidecar
the header stamp of the first /imu, /odom or scan message read (what a node takes: the
first one it receives). Stamps of the returned Trip are seconds since it.

Duplicates: a message recorded twice (same topic, header stamp and bytes) is dropped and
counted (`BagTrip.duplicates`, logged); two messages of a topic with one header stamp and
different bytes are refused, naming both.

What no message carries (LiDAR mounts, stated noise, true bias) comes from the params
sidecar beside the bag; without a sidecar the mounts default to the platform origin and a
warning says so. So does what `convert --skip-bad` dropped from the log the bag was written
from: `validate_bag` puts it on the validation's report (`InputReport.converted`), so a run
counts those samples as if it had dropped them itself. A sidecar written with another bag
(its `trip.bag` fingerprint is not the count, first and last log time of the messages read)
is refused naming both (`io.sidecar`).

`read_bag` takes the raw messages of a single-file MCAP bag from `mcap_chunks` (a small
chunk reader, several times faster), of any other bag, or one that reader refuses, from
rosbags' Reader, and decodes the sensor topics in batches with numpy (`bag_sinks`), which
gives the values rosbags' deserialisation gives (test/io/rosbags_oracle.py reads a bag that
way); `iter_bag_messages` yields rosbags message objects one by one (replay, record, tests).

`mcap_chunks` checks the MCAP file's CRCs, bounds and chunk time ranges: a damaged file is a
final BagError; only a file it cannot handle, e.g. an unknown chunk compression, goes to
rosbags, with the reason logged. The checks every reader shares are in `bag_open`.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field, replace
import logging
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
from rosbags.rosbag2 import Reader

from gyro_ekf import topics
from gyro_ekf.core.stamps import seconds_since
from gyro_ekf.core.types import (
    GroundTruth, ImuSeries, LandmarkMap, LidarMount, NoiseFigures, ScanSeries, SpeedSeries,
    Trip)
from gyro_ekf.core.config import InputLimits
from gyro_ekf.core.validation import InputReport, quaternion_problem, validate_trip
from gyro_ekf.io import mcap_chunks, messages as msgs
from gyro_ekf.io.bag_open import (
    GROUND_TRUTH_TOPIC, IMU_TOPIC, INITIAL_POSE_TOPIC, MAP_TOPIC, ODOM_TOPIC, bag_bytes,
    check_stamp, check_stamps, check_types, deserialize, every_time, metadata, open_bag,
    reading, time_span, topic_connections)
from gyro_ekf.io.bag_sinks import (
    ImuSink, OdomSink, ScanData, ScanSink, Sink, TruthSink, has_acceleration)
from gyro_ekf.io.errors import BagError
from gyro_ekf.io.sidecar import (
    BagFingerprint, BagParams, check_belongs, read_sidecar, sidecar_path)

__all__ = ['BagMessage', 'BagTrip', 'ZERO_TOLERANCE_NS', 'assemble_trip', 'initial_pose_of',
           'iter_bag_messages', 'one_message', 'read_bag', 'read_trip_bag', 'time_zero',
           'validate_bag']

log = logging.getLogger(__name__)


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


@dataclass(frozen=True, slots=True)
class BagTrip:
    """A trip read back from a bag.

    Attributes:
        trip: the trip, stamps in s since the time zero (header stamps, see the module).
        start_time_ns: the time zero, ns since the epoch (header-stamp clock).
        params: the sidecar contents, or None when the bag has none.
        duplicates: topic -> messages dropped as exact copies of an earlier one (same
            header stamp and bytes); only topics that had any.
        pose_from_message: whether the trip's initial pose is the bag's /initialpose
            message's (else the sidecar's, or the origin).
    """

    trip: Trip
    start_time_ns: int
    params: BagParams | None
    duplicates: dict[str, int] = field(default_factory=dict)
    pose_from_message: bool = False

    @property
    def converted(self) -> InputReport | None:
        """What `convert --skip-bad` dropped from the bag's log (sidecar), or None."""
        return None if self.params is None else self.params.converted


def validate_bag(bag: BagTrip, source: str, limits: InputLimits | None = None,
                 skip_bad: bool = False) -> tuple[Trip, InputReport]:
    """Pass a bag's trip through the validation boundary (`core.validation.validate_trip`).

    The report also carries what `convert --skip-bad` dropped from the log the bag was
    written from (`InputReport.converted`, from the sidecar): those samples are missing
    from the bag, and a run on it is as degraded as one that dropped them itself.

    Raises:
        InvalidInputError: as validate_trip.
    """
    trip, report = validate_trip(bag.trip, source, limits or InputLimits(), skip_bad=skip_bad)
    report.converted = bag.converted
    return trip, report


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
    reader = open_bag(path)
    try:
        connections = reader.connections
        check_types(path, connections, None)
        if topic_names is not None:
            wanted = {topics.bag_topic(t) for t in topic_names}
            present = {c.topic for c in connections}
            missing = sorted(wanted - present)
            if missing:
                raise BagError(f"{path}: no topic '{missing[0]}' (the bag has "
                               f'{sorted(present)})')
            connections = [c for c in connections if c.topic in wanted]
        span = time_span(reader)
        messages = reader.messages(connections, *every_time(path))
        while True:
            with reading(path):
                item = next(messages, None)
            if item is None:
                break
            connection, stamp, data = item
            check_stamp(path, connection.topic, stamp, span)
            message = deserialize(path, connection.topic, connection.msgtype, stamp, data)
            yield BagMessage(connection.topic, connection.msgtype, stamp, message)
    finally:
        reader.close()


def read_bag(path: Path | str, acceleration: bool = True) -> BagTrip:
    """Read everything the bag writer writes, including the sidecar, into a Trip.

    Args:
        path: the bag folder.
        acceleration: read the IMU's linear acceleration where the bag has it; False
            leaves it None (the EKF does not use it; 48 bytes per sample saved).

    Returns:
        The trip (header stamps in s since the time zero), the time zero, the sidecar and
        the exact duplicates dropped.

    Raises:
        BagError: missing or unreadable bag, no /imu or /odom topic, inconsistent scans, a
            header stamp that is no time, two messages of a topic with one header stamp
            and different bytes, a sidecar time zero on another clock than the header
            stamps, or a sidecar written with another bag (its fingerprint, `trip.bag`, is
            not the count, first and last log time of the messages read).
    """
    path = Path(path)
    reader = open_bag(path)
    try:
        # Held to the bag once its messages are read (below), not to metadata.yaml's count,
        # which a run takes as a hint only.
        params = read_sidecar(path, check=False)
        by_topic, counts = topic_connections(path, reader, params)
        start = reader.start_time if reader.message_count else 0
        span = time_span(reader)
        scan_topics = [t for t, c in by_topic.items() if c.msgtype == topics.LASER_SCAN_TYPE]
        mcap_file = _single_mcap_file(path)
        size = bag_bytes(path)
        while True:
            imu = ImuSink(path, IMU_TOPIC, counts[IMU_TOPIC], size, acceleration)
            odom = OdomSink(path, ODOM_TOPIC, counts[ODOM_TOPIC], size)
            scans = {t: ScanSink(path, t, counts[t], size) for t in scan_topics}
            sinks: dict[str, Sink] = {IMU_TOPIC: imu, ODOM_TOPIC: odom, **scans}
            truth = None
            if GROUND_TRUTH_TOPIC in by_topic:
                truth = TruthSink(path, GROUND_TRUTH_TOPIC, counts[GROUND_TRUTH_TOPIC], size)
                sinks[GROUND_TRUTH_TOPIC] = truth
            singles: dict[str, list[tuple[int, Any]]] = {}
            if mcap_file is None:
                with reading(path):
                    _read_with_rosbags(path, reader, sinks, singles)
                break
            try:
                _read_mcap_fast(path, mcap_file, by_topic, sinks, singles)
                break
            except mcap_chunks.UnsupportedMcap as err:
                # rosbags reads what the fast reader cannot handle; damage (CorruptMcap) is
                # final and never gets here.
                log.info('%s; reading it with rosbags instead', err)
                mcap_file = None
        for sink in sinks.values():
            sink.flush()
            check_stamps(path, sink.topic, sink.log_ns[:sink.n], span)
        for topic, items in singles.items():
            for stamp, _ in items:
                check_stamp(path, topic, stamp, span)
        # Before duplicates are dropped: the fingerprint counts what the bag holds.
        check_belongs(path, params, _fingerprint(sinks, singles, counts),
                      'as its messages hold')
        duplicates = {}
        for sink in sinks.values():
            dropped = _drop_duplicates(path, sink, lambda topic, rows: _payloads(
                path, reader, mcap_file, by_topic[topic], rows))
            if dropped:
                duplicates[sink.topic] = dropped
    finally:
        reader.close()
    # Not /ground_truth: the nodes do not take it, and it is only compared against.
    start = time_zero(path, params, [imu, odom, *scans.values()], int(start))
    landmark_message = one_message(path, MAP_TOPIC, [m for _, m in singles.get(MAP_TOPIC, [])])
    pose_message = one_message(path, INITIAL_POSE_TOPIC,
                               [m for _, m in singles.get(INITIAL_POSE_TOPIC, [])])
    imu_first = imu.first
    bag_trip = assemble_trip(
        path, params, int(start),
        imu_ns=imu.stamps[:imu.n], rates=imu.rates[:imu.n],
        rate_variances=imu.rate_variances[:imu.n],
        accel=imu.accel[:imu.n] if imu.accel is not None and imu_first is not None
        and has_acceleration(imu_first) else None,
        axes_known=imu.axes_known or (True, True, True),
        odom_ns=odom.stamps[:odom.n], speeds=odom.speeds[:odom.n],
        speed_variances=odom.speed_variances[:odom.n],
        scans=[d for d in (scans[t].data() for t in scan_topics) if d is not None],
        truth=None if truth is None else (truth.stamps[:truth.n], truth.poses[:truth.n]),
        landmarks=None if landmark_message is None else msgs.landmarks_of(landmark_message),
        initial_pose=None if pose_message is None else initial_pose_of(path, pose_message))
    return replace(bag_trip, duplicates=duplicates, pose_from_message=pose_message is not None)


def _fingerprint(sinks: dict[str, Sink], singles: dict[str, list[tuple[int, Any]]],
                 counts: dict[str, int]) -> BagFingerprint:
    """Return the fingerprint of a bag from the messages read: count, first and last log time.

    Topics not read count as metadata.yaml states them, and their stamps are not known: a
    bag the writer wrote has none (it writes only topics the reader reads).
    """
    read = [sink.log_ns[:sink.n] for sink in sinks.values() if sink.n]
    read += [np.array([stamp for stamp, _ in items], dtype=np.int64)
             for items in singles.values() if items]
    unread = sum(n for topic, n in counts.items()
                 if topic not in sinks and topic not in (MAP_TOPIC, INITIAL_POSE_TOPIC))
    if not read:
        return BagFingerprint(unread, 0, 0)
    return BagFingerprint(sum(int(stamps.size) for stamps in read) + unread,
                          min(int(stamps.min()) for stamps in read),
                          max(int(stamps.max()) for stamps in read))


ZERO_TOLERANCE_NS = 3600 * 1_000_000_000
"""How far the sidecar's time zero may lie from the first header stamp (a trip trimmed at
its start, `replay --from`, starts after its zero); farther, the two are on different clocks."""


def time_zero(path: Path, params: BagParams | None, sinks: list[Any], fallback: int) -> int:
    """Return the time zero of a bag's header stamps, ns since the epoch.

    The sidecar's trip.log_time_zero_ns when there is one: the nodes are given the same, so a
    node and an offline run compute the same seconds. Without one, the header stamp of the
    first message of the given topics read (smallest log time; the earlier stamp on a tie):
    a node takes the first stamp it receives. `fallback` (the bag's start) when none exists.

    Args:
        sinks: the topics the nodes take (/imu, /odom, the scans): objects with topic, n,
            stamps and log_ns (header stamps and log times, ns, in the order read).

    Raises:
        BagError: the sidecar's zero lies more than ZERO_TOLERANCE_NS from the first header
            stamp: the header stamps run on another clock (a bag recorded with use_sim_time
            stamps its messages in the simulation's time), and every time would be off by
            that much.
    """
    firsts = [(int(s.log_ns[0]), int(s.stamps[0]), s.topic) for s in sinks if s.n]
    if not firsts:
        return fallback if params is None else int(params.log_time_zero_ns)
    _, stamp, topic = min(firsts)
    if params is None:
        return stamp
    zero = int(params.log_time_zero_ns)
    if abs(stamp - zero) > ZERO_TOLERANCE_NS:
        raise BagError(
            f"{sidecar_path(path)}: trip.log_time_zero_ns = {zero} lies "
            f"{(stamp - zero) / 1e9:.6g} s from the header stamp of the first message read "
            f"(topic '{topic}' message index 0, header.stamp {stamp} ns); the header stamps "
            'run on another clock (recorded with use_sim_time?): set trip.log_time_zero_ns to '
            'the header stamp of the trip\'s start, or remove it to start at the first message')
    return zero


def _drop_duplicates(path: Path, sink: Any,
                     payloads: Callable[[str, list[int]], dict[int, bytes]]) -> int:
    """Drop the rows of a sink that repeat an earlier message exactly; return how many.

    Messages of one topic sharing a header stamp are compared byte for byte (their raw
    payloads, read again: this happens only when stamps repeat). An exact copy of an earlier
    one (a message recorded twice) is dropped, the first kept where it was read. A different
    message with the stamp of the one before it gives two values for one instant, and is
    refused, unless the topic's time went back earlier: the stamps are then kept in the
    order read for the validation boundary, which refuses the first step back (naming its
    index) or, with --skip-bad, drops and counts it.

    Raises:
        BagError: two messages of the topic with one header stamp and different bytes, the
            later one right after a message of that stamp, and the topic's stamps not going
            back before it; naming both message indexes (from 0, in the order read).
    """
    groups = sink.repeated_stamps()
    if not groups:
        return 0
    data = payloads(sink.topic, sorted({int(i) for group in groups for i in group}))
    stamps = sink.stamps[:sink.n]
    back = np.diff(stamps) < 0
    first_back = int(np.argmax(back)) + 1 if back.any() else sink.n
    keep = np.ones(sink.n, dtype=bool)
    for group in groups:
        members = group.tolist()
        for k, other in enumerate(members[1:], 1):
            if any(data[other] == data[earlier] for earlier in members[:k]):
                keep[other] = False
            elif other < first_back and stamps[other - 1] == stamps[other]:
                raise BagError(
                    f"{path}: topic '{sink.topic}': message index {members[0]} and message "
                    f'index {other} have the same header.stamp ({int(stamps[other])} ns) '
                    'but different contents; expected one message per stamp (an exact copy '
                    'would be dropped)')
    dropped = int((~keep).sum())
    if dropped:
        sink.keep_rows(keep)
        log.warning("%s: topic '%s': dropped %d exact duplicate message(s) (same header stamp "
                    'and bytes as an earlier one; first: message index %d)', path, sink.topic,
                    dropped, int(np.argmin(keep)))
    return dropped


def _payloads(path: Path, reader: Reader, mcap_file: Path | None, connection: Any,
              rows: list[int]) -> dict[int, bytes]:
    """Raw payloads of a topic's messages at some indexes (in the order read), read again."""
    wanted = set(rows)
    found: dict[int, bytes] = {}
    if mcap_file is not None:
        count = 0

        def consume(topic: str, batch: mcap_chunks.TopicMessages) -> None:
            nonlocal count
            for k in wanted.intersection(range(count, count + len(batch.payloads))):
                found[k] = bytes(batch.payloads[k - count])
            count += len(batch.payloads)

        try:
            mcap_chunks.stream_topics(mcap_file, [connection.topic], consume)
        except (OSError, mcap_chunks.McapError) as err:
            raise BagError(f'{path}: cannot read the bag again: {err}') from None
        return found
    connections = [c for c in reader.connections if c.topic == connection.topic]
    with reading(path):
        for k, (_, _, data) in enumerate(reader.messages(connections, *every_time(path))):
            if k in wanted:
                found[k] = bytes(data)
    return found


def _content(topic: str, message: Any) -> np.ndarray:
    """Return the values the reader takes from a /landmark_map or /initialpose message."""
    if topic == MAP_TOPIC:
        return np.array([[p.position.x, p.position.y] for p in message.poses],
                        dtype=np.float64).reshape(-1, 2)
    pose = message.pose.pose
    return np.array([pose.position.x, pose.position.y, pose.position.z, pose.orientation.x,
                     pose.orientation.y, pose.orientation.z, pose.orientation.w])


def one_message(path: Path, topic: str, messages: list[Any]) -> Any:
    """Return the one message of a topic that must hold one (map, initial pose), or None.

    Copies are fine (a latched topic recorded twice, a map published again with a new
    stamp): what counts is the content the reader takes. Two different ones leave no way to
    tell which is meant; taking the last would be a silent guess.

    Raises:
        BagError: naming the topic and the indexes (from 0) of two messages that differ.
    """
    if not messages:
        return None
    first = _content(topic, messages[0])
    for k, message in enumerate(messages[1:], 1):
        other = _content(topic, message)
        if first.shape != other.shape or not np.array_equal(first, other, equal_nan=True):
            raise BagError(f"{path}: topic '{topic}': message index 0 and message index {k} "
                           'differ; the topic must hold one message (identical copies are '
                           'fine)')
    return messages[0]


def initial_pose_of(path: Path, message: Any) -> np.ndarray:
    """(x m, y m, yaw rad) of an /initialpose message, refusing a quaternion that is none.

    A zero or far from unit quaternion has no yaw to take (atan2 of zeros gives 0 rad).

    Raises:
        BagError: naming the topic and the field; the limit is core.validation's.
    """
    q = message.pose.pose.orientation
    problem = quaternion_problem(float(q.x), float(q.y), float(q.z), float(q.w))
    if problem:
        raise BagError(f"{path}: topic '{INITIAL_POSE_TOPIC}': pose.pose.orientation: "
                       f'{problem}')
    return np.array(msgs.pose_of(message.pose.pose))


def _single_mcap_file(path: Path) -> Path | None:
    """Return the bag's one .mcap file when mcap_chunks may read it, else None."""
    meta = metadata(path)
    files = meta.get('relative_file_paths') or []
    if (meta.get('storage_identifier') != 'mcap' or meta.get('compression_mode')
            or len(files) != 1 or not str(files[0]).endswith('.mcap')):
        return None
    return path / str(files[0])


def _read_with_rosbags(path: Path, reader: Reader, sinks: dict[str, Sink],
                       singles: dict[str, list[tuple[int, Any]]]) -> None:
    """Fill the sinks, and singles with topic -> every (stamp, message), through rosbags."""
    wanted = [c for c in reader.connections
              if c.topic in sinks or c.topic in (MAP_TOPIC, INITIAL_POSE_TOPIC)]
    for connection, stamp, data in reader.messages(wanted, *every_time(path)):
        sink = sinks.get(connection.topic)
        if sink is not None:
            sink.add(stamp, data)
        else:
            singles.setdefault(connection.topic, []).append((stamp, deserialize(
                path, connection.topic, connection.msgtype, stamp, data)))


def _read_mcap_fast(path: Path, mcap_file: Path, by_topic: dict[str, Any],
                    sinks: dict[str, Sink], singles: dict[str, list[tuple[int, Any]]]
                    ) -> None:
    """Read the sink topics with mcap_chunks: the same bytes, a few times faster, verified.

    Raises:
        BagError: the file is damaged (CRC, bounds, times), or its channels disagree with
            the types rosbags read from its summary.
        UnsupportedMcap: mcap_chunks cannot handle the file; read it with rosbags.
    """
    def consume(topic: str, batch: mcap_chunks.TopicMessages) -> None:
        sink = sinks.get(topic)
        if sink is not None:
            sink.add_many(batch.log_time_ns, batch.payloads)
        else:
            for stamp, data in zip(batch.log_time_ns.tolist(), batch.payloads):
                singles.setdefault(topic, []).append((stamp, deserialize(
                    path, topic, by_topic[topic].msgtype, stamp, bytes(data))))

    wanted = [t for t in by_topic if t in sinks or t in (MAP_TOPIC, INITIAL_POSE_TOPIC)]
    try:
        msgtypes = mcap_chunks.stream_topics(mcap_file, wanted, consume)
    except OSError as err:
        raise BagError(f'{path}: cannot read the bag: {err}') from None
    except mcap_chunks.CorruptMcap as err:
        raise BagError(str(err)) from None
    for topic, msgtype in msgtypes.items():
        if msgtype != by_topic[topic].msgtype:
            raise BagError(f"{mcap_file}: topic '{topic}' has type {msgtype} in the data "
                           f'section and {by_topic[topic].msgtype} in the summary')


def _given(variances: np.ndarray) -> np.ndarray | None:
    # Raw as the messages hold them (0 and -1 included); core.validation decides which
    # are used. None when no message gives one: the usual case needs no per-sample check.
    return None if not np.any(variances) else variances


def assemble_trip(path: Path, params: BagParams | None, start: int, *, imu_ns: np.ndarray,
                  rates: np.ndarray, rate_variances: np.ndarray, accel: np.ndarray | None,
                  axes_known: tuple[bool, bool, bool], odom_ns: np.ndarray,
                  speeds: np.ndarray, speed_variances: np.ndarray, scans: list[ScanData],
                  truth: tuple[np.ndarray, np.ndarray] | None, landmarks: LandmarkMap | None,
                  initial_pose: np.ndarray | None) -> BagTrip:
    """Assemble the Trip of a bag from its decoded arrays (stamps in ns) and its sidecar."""
    def seconds(stamps: np.ndarray) -> np.ndarray:
        return seconds_since(stamps, start)

    if params is None:
        log.warning('%s: no params sidecar %s; LiDAR mounts default to the platform origin',
                    path, sidecar_path(path).name)
    series = []
    for scan in scans:
        name = scan.topic.lstrip('/')
        frame_id, mount = (params.lidars.get(name) if params is not None else None) or (
            scan.frame_id, LidarMount())
        angle_min, angle_increment, range_min, range_max = scan.geometry
        series.append(ScanSeries(
            stamp_s=seconds(scan.stamps_ns), ranges_m=scan.ranges,
            intensities=scan.intensities, angle_min_rad=float(angle_min),
            angle_increment_rad=float(angle_increment), range_min_m=float(range_min),
            range_max_m=float(range_max), mount=mount, topic=name,
            frame_id=scan.frame_id or frame_id))
    if initial_pose is None:
        initial_pose = params.initial_pose if params is not None else np.zeros(3)
    trip = Trip(
        name=params.name if params is not None else path.name,
        imu=ImuSeries(stamp_s=seconds(imu_ns), angular_velocity_rad_s=rates,
                      axes_known=axes_known, linear_acceleration_m_s2=accel,
                      yaw_rate_variance=_given(rate_variances)),
        speed=SpeedSeries(stamp_s=seconds(odom_ns), speed_m_s=speeds,
                          speed_variance=_given(speed_variances)),
        scans=tuple(series),
        landmarks=landmarks,
        initial_pose=initial_pose,
        ground_truth=None if truth is None else GroundTruth(seconds(truth[0]), truth[1]),
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
