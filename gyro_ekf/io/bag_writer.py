"""Write a Trip as a ROS 2 bag (metadata version 9, Jazzy types, mcap or sqlite3).

Topics, types and conventions are described in `gyro_ekf.io.messages`. Messages of all topics
go into the bag in stamp order: one lazy generator per topic, merged with heapq.merge, so only
the trip's own arrays are held in memory, never all messages at once. At equal stamps the order
is /landmark_map, /initialpose, /imu, /odom, scans, /ground_truth.

Time: the trip's time zero (the log's first stamp) becomes `start_time_ns` (default
DEFAULT_EPOCH_NS, 2023-11-14T22:13:20Z, never 0, which ROS reads as "unset"); every stamp is
start_time_ns + round(stamp_s * 1e9), exact to the nanosecond for course logs (counts of 0.1 ms
turned into seconds by one correctly rounded division). /landmark_map and /initialpose are
stamped at time zero (or at the first sample if a trip starts before zero).

The bag is written into a hidden temporary sibling folder and renamed into place only when
complete, together with its params sidecar (`gyro_ekf.io.sidecar`), which records the bag's
fingerprint (message count, first and last stamp) so that a reader refuses it beside another
bag; a failure or interrupt removes the temporary files and leaves any previous output
untouched. With force, an existing output is replaced only when it is a bag folder holding
nothing but a bag's own files (`claim_bag_target`); a read-only or full file system is one
BagError naming the bag.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass
import heapq
import logging
import os
from pathlib import Path
import shutil
import tempfile
from typing import Any

import numpy as np
from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability
from rosbags.interfaces import QosTime
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.rosbag2.enums import CompressionFormat, CompressionMode
from rosbags.rosbag2.errors import WriterError

from gyro_ekf import topics
from gyro_ekf.core.stamps import NS_PER_S, ns_at
from gyro_ekf.core.types import Trip
from gyro_ekf.core.validation import InputReport
from gyro_ekf.io import messages as msgs
from gyro_ekf.io.defaults import DEFAULT_EPOCH_NS, STORAGE_NAMES
from gyro_ekf.io.batch_write import enable_chunk_crcs
from gyro_ekf.io.errors import BagError
from gyro_ekf.io.products import BAG_FILES, first_foreign, os_reason
from gyro_ekf.io.sidecar import check_finite, params_of_trip, read_sidecar, sidecar_path
from gyro_ekf.io.sidecar import BagFingerprint, to_yaml

__all__ = ['DEFAULT_EPOCH_NS', 'STORAGES', 'ProgressCallback', 'TopicPlan', 'claim_bag_target',
           'read_sidecar', 'sidecar_path', 'write_trip_bag']

log = logging.getLogger(__name__)

BAG_VERSION = 9
STORAGES = dict(zip(STORAGE_NAMES, (StoragePlugin.MCAP, StoragePlugin.SQLITE3)))

ProgressCallback = Callable[[int, int], None]
"""Called as progress(messages_written, messages_total) now and then and at the end."""

_UNSET = QosTime(sec=0, nsec=0)


def _qos(depth: int, durability: QosDurability) -> Qos:
    return Qos(history=QosHistory.KEEP_LAST, depth=depth, reliability=QosReliability.RELIABLE,
               durability=durability, deadline=_UNSET, lifespan=_UNSET,
               liveliness=QosLiveliness.AUTOMATIC, liveliness_lease_duration=_UNSET,
               avoid_ros_namespace_conventions=False)


SENSOR_QOS = _qos(10, QosDurability.VOLATILE)
"""Offered QoS of the sensor topics: reliable (matches best-effort and reliable readers)."""
LATCHED_QOS = _qos(1, QosDurability.TRANSIENT_LOCAL)
"""Offered QoS of /landmark_map and /initialpose: late joiners still get the one message."""

_PROGRESS_EVERY = 2000


@dataclass(frozen=True)
class TopicPlan:
    """One topic to write: its messages as a lazy sequence over integer stamps.

    Attributes:
        topic: bag topic name (absolute).
        msgtype: message type name.
        qos: offered QoS profile.
        stamps_ns: shape (n,), int64, ns since the epoch, non-decreasing.
        build: index -> message object.
    """

    topic: str
    msgtype: str
    qos: Qos
    stamps_ns: np.ndarray
    build: Callable[[int], Any]


def _stamps_ns(stamp_s: np.ndarray, start_time_ns: int, what: str) -> np.ndarray:
    stamp_s = np.asarray(stamp_s, dtype=np.float64)
    if not np.all(np.isfinite(stamp_s)):
        raise BagError(f"topic '{what}': stamps are not all finite")
    stamps = ns_at(start_time_ns, stamp_s)
    steps = np.diff(stamps)
    if steps.size and steps.min() < 0:
        i = int(np.argmax(steps < 0))
        raise BagError(f"topic '{what}': stamp went back {-steps[i] / NS_PER_S:.6f} s at "
                       f'message {i + 1}; expected stamps in time order')
    if stamps.size and stamps[0] <= 0:
        raise BagError(f"topic '{what}': first stamp {int(stamps[0])} ns is not after the "
                       'epoch; choose a later start time')
    return stamps


def _own_variances(name: str, values: np.ndarray | None, n: int) -> np.ndarray | None:
    if values is None:
        return None
    _same_length(name, len(values), n)
    return np.nan_to_num(np.asarray(values, dtype=np.float64), nan=0.0)


def plan_topics(trip: Trip, start_time_ns: int) -> list[TopicPlan]:
    """Plan the topics of a trip's bag, in tie-break order, each with stamps and builder.

    Raises:
        BagError: stamps that are not finite, go back in time or fall before the epoch;
            arrays of inconsistent length.
    """
    zero_s = min(0.0, trip.start_s)
    zero = _stamps_ns(np.array([zero_s]), start_time_ns, topics.INITIAL_POSE)
    plans: list[TopicPlan] = []
    if trip.landmarks is not None:
        landmarks = trip.landmarks
        plans.append(TopicPlan(topics.bag_topic(topics.LANDMARK_MAP), topics.POSE_ARRAY_TYPE,
                               LATCHED_QOS, zero,
                               lambda i: msgs.landmark_map_message(int(zero[0]), landmarks)))
    pose = np.asarray(trip.initial_pose, dtype=np.float64)
    plans.append(TopicPlan(topics.bag_topic(topics.INITIAL_POSE),
                           topics.POSE_WITH_COVARIANCE_STAMPED_TYPE, LATCHED_QOS, zero,
                           lambda i: msgs.initial_pose_message(int(zero[0]), pose)))

    imu = trip.imu
    rates = np.asarray(imu.angular_velocity_rad_s, dtype=np.float64)
    accel = imu.linear_acceleration_m_s2
    _same_length('imu.angular_velocity_rad_s', rates.shape[0], imu.stamp_s.size)
    if accel is not None:
        _same_length('imu.linear_acceleration_m_s2', accel.shape[0], imu.stamp_s.size)
    imu_ns = _stamps_ns(imu.stamp_s, start_time_ns, topics.IMU)
    # The stated noise in every message; a trip read from a bag keeps each message's own
    # variance (NaN there: not given, written as 0).
    rate_cov = msgs.angular_velocity_covariance(imu.axes_known, trip.noise.gyro_rad_s)
    rate_vars = _own_variances('imu.yaw_rate_variance', imu.yaw_rate_variance,
                               imu.stamp_s.size)

    def imu_covariance(i: int) -> np.ndarray:
        if rate_vars is None:
            return rate_cov
        own = rate_cov.copy()
        own[8] = rate_vars[i]
        return own

    plans.append(TopicPlan(
        topics.bag_topic(topics.IMU), topics.IMU_TYPE, SENSOR_QOS, imu_ns,
        lambda i: msgs.imu_message(int(imu_ns[i]), rates[i], imu_covariance(i),
                                   None if accel is None else accel[i])))

    speed = trip.speed
    _same_length('speed.speed_m_s', speed.speed_m_s.size, speed.stamp_s.size)
    speed_ns = _stamps_ns(speed.stamp_s, start_time_ns, topics.ODOM)
    twist_cov = msgs.speed_covariance(trip.noise.speed_m_s)
    speed_vars = _own_variances('speed.speed_variance', speed.speed_variance,
                                speed.stamp_s.size)

    def twist_covariance(i: int) -> np.ndarray:
        if speed_vars is None:
            return twist_cov
        own = twist_cov.copy()
        own[0] = speed_vars[i]
        return own

    plans.append(TopicPlan(
        topics.bag_topic(topics.ODOM), topics.ODOMETRY_TYPE, SENSOR_QOS, speed_ns,
        lambda i: msgs.speed_message(int(speed_ns[i]), float(speed.speed_m_s[i]),
                                     twist_covariance(i))))

    seen: set[str] = set()
    for series in trip.scans:
        if series.topic in seen:
            raise BagError(f"two scan series share topic '{series.topic}'")
        seen.add(series.topic)
        _same_length(f'{series.topic}.ranges_m', series.ranges_m.shape[0], series.stamp_s.size)
        if series.intensities is not None and series.intensities.shape != series.ranges_m.shape:
            raise BagError(f"scan series '{series.topic}': intensities have shape "
                           f'{series.intensities.shape}, ranges {series.ranges_m.shape}')
        scan_ns = _stamps_ns(series.stamp_s, start_time_ns, series.topic)
        plans.append(TopicPlan(
            topics.bag_topic(series.topic), topics.LASER_SCAN_TYPE, SENSOR_QOS, scan_ns,
            lambda i, s=series, ns=scan_ns: msgs.scan_message(int(ns[i]), s, i)))

    if trip.ground_truth is not None:
        truth = trip.ground_truth
        _same_length('ground_truth.pose', truth.pose.shape[0], truth.stamp_s.size)
        truth_ns = _stamps_ns(truth.stamp_s, start_time_ns, topics.GROUND_TRUTH)
        plans.append(TopicPlan(
            topics.bag_topic(topics.GROUND_TRUTH), topics.ODOMETRY_TYPE, SENSOR_QOS, truth_ns,
            lambda i: msgs.ground_truth_message(int(truth_ns[i]), truth.pose[i])))
    return plans


def _same_length(what: str, length: int, stamps: int) -> None:
    if length != stamps:
        raise BagError(f"trip field '{what}' has {length} rows but {stamps} stamps")


def merged(plans: list[TopicPlan]) -> Iterator[tuple[int, int, int]]:
    """(stamp_ns, plan index, message index) of every message, in stamp order, lazily."""
    def stream(order: int, stamps: np.ndarray) -> Iterator[tuple[int, int, int]]:
        for i, stamp in enumerate(stamps.tolist()):
            yield stamp, order, i
    return heapq.merge(*(stream(k, p.stamps_ns) for k, p in enumerate(plans)))


def write_trip_bag(trip: Trip, path: Path | str, storage: str = 'mcap',
                   start_time_ns: int = DEFAULT_EPOCH_NS, force: bool = False,
                   progress: ProgressCallback | None = None, compress: bool = False,
                   converted: InputReport | None = None) -> Path:
    """Write a trip as a rosbag2 folder plus its params sidecar beside it.

    Args:
        trip: the trip (stamps in s since its time zero).
        path: the bag folder to create.
        storage: 'mcap' (the Jazzy default) or 'sqlite3'.
        start_time_ns: bag stamp of the trip's time zero, ns since the epoch, > 0.
        force: replace an existing bag folder and sidecar.
        progress: optional progress(messages_written, messages_total) callback.
        compress: zstd-compress the storage (mcap chunks, as rosbag2's zstd presets do;
            sqlite3 compresses each message). Deterministic for the pinned libraries.
        converted: the report of the validation the trip passed when read from a log;
            what it dropped (--skip-bad) goes into the sidecar, so a run on the bag still
            counts it.

    Returns:
        The bag folder.

    Raises:
        BagError: unknown storage, a start time <= 0, an existing output without force,
            stamps out of order, or a write failure. Nothing is left behind on failure.
    """
    path = Path(path)
    if storage not in STORAGES:
        raise BagError(f'{path}: unknown storage {storage!r}; expected one of {list(STORAGES)}')
    if int(start_time_ns) <= 0:
        raise BagError(f'{path}: start time {start_time_ns} ns must be after the epoch '
                       '(0 reads as "unset" in ROS)')
    params_path = claim_bag_target(path, force)
    plans = plan_topics(trip, int(start_time_ns))
    params = params_of_trip(trip, int(start_time_ns), converted, fingerprint(plans))
    check_finite(params)
    total = sum(p.stamps_ns.size for p in plans)

    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        aside = Path(tempfile.mkdtemp(prefix=f'.{path.name}.', suffix='.tmp',
                                      dir=path.parent))
    except OSError as err:
        raise BagError(f'{path}: cannot write the bag: {os_reason(err)}') from None
    try:
        staged = aside / path.name
        _write(plans, staged, STORAGES[storage], total, progress, compress)
        staged_params = aside / params_path.name
        staged_params.write_text(to_yaml(params), encoding='utf-8')
        _replace([(staged, path), (staged_params, params_path)], aside)
    except OSError as err:
        raise BagError(f'{path}: cannot write the bag: {os_reason(err)}') from None
    finally:
        shutil.rmtree(aside, ignore_errors=True)
    log.info('%s: %d messages on %d topics (%s)', path, total, len(plans), storage)
    return path


def fingerprint(plans: list[TopicPlan]) -> BagFingerprint:
    """Return the fingerprint of the bag the plans make: count, first and last log time.

    What rosbags then states in metadata.yaml (message_count, starting_time, duration),
    so every reader of the sidecar finds its bag's (`sidecar.check_belongs`).
    """
    stamps = [p.stamps_ns for p in plans if p.stamps_ns.size]
    if not stamps:
        return BagFingerprint(0, 0, 0)
    return BagFingerprint(sum(s.size for s in stamps), min(int(s[0]) for s in stamps),
                          max(int(s[-1]) for s in stamps))


def _write(plans: list[TopicPlan], staged: Path, plugin: StoragePlugin, total: int,
           progress: ProgressCallback | None, compress: bool = False) -> None:
    try:
        writer = Writer(staged, version=BAG_VERSION, storage_plugin=plugin)
        enable_chunk_crcs(writer)
        if compress:
            # mcap compresses whole chunks (what `ros2 bag record` does); sqlite3 cannot.
            mode = (CompressionMode.STORAGE if plugin is StoragePlugin.MCAP
                    else CompressionMode.MESSAGE)
            writer.set_compression(mode, CompressionFormat.ZSTD)
        with writer:
            connections = [
                writer.add_connection(p.topic, p.msgtype, typestore=msgs.TYPESTORE,
                                      offered_qos_profiles=[p.qos])
                for p in plans]
            done = 0
            for stamp, order, index in merged(plans):
                message = plans[order].build(index)
                writer.write(connections[order], stamp, msgs.serialize(message))
                done += 1
                if progress is not None and done % _PROGRESS_EVERY == 0:
                    progress(done, total)
    except WriterError as err:
        raise BagError(f'{staged.name}: cannot write the bag: {err}') from err
    if progress is not None:
        progress(total, total)


def claim_bag_target(path: Path, force: bool, sidecar: bool = True) -> Path:
    """Check that a bag folder (and its params sidecar) may be written; return the sidecar.

    sidecar=False: only the bag folder is written (`gyro-ekf record`), an existing sidecar
    beside it is none of this writer's business.

    With force, an existing bag folder is replaced only when it holds nothing but a bag's
    own files (metadata.yaml, *.mcap, *.db3, ...): a user's notes or sub-folders in it are
    never deleted.

    Raises:
        BagError: the folder or sidecar exists without force, is of the wrong kind, or
            holds a file that is not part of a bag (named).
    """
    params_path = sidecar_path(path)
    ours = (path, params_path) if sidecar else (path,)
    existing = [p for p in ours if p.exists() or p.is_symlink()]
    if existing and not force:
        raise BagError(f'{existing[0]}: exists already; use --force to replace it')
    if path.is_symlink() or (path.exists() and not path.is_dir()):
        raise BagError(f'{path}: exists and is not a bag folder; --force replaces only a bag '
                       'folder')
    if sidecar and (params_path.is_symlink()
                    or (params_path.exists() and not params_path.is_file())):
        raise BagError(f'{params_path}: exists and is not a params file; --force replaces '
                       'only a file')
    if path.is_dir():
        foreign = first_foreign(path, BAG_FILES)
        if foreign is not None:
            raise BagError(f'{foreign}: is not part of a bag; --force replaces only a bag '
                           'folder (metadata.yaml, *.mcap, *.db3): move it away first')
    return params_path


def _replace(moves: list[tuple[Path, Path]], aside: Path) -> None:
    """Rename each finished (staged, target) into place; old targets go into aside.

    If a rename fails, the targets already replaced get their old versions back, so a
    failure leaves the previous output as it was.
    """
    done: list[tuple[Path, Path | None]] = []
    try:
        for staged, target in moves:
            old = None
            if target.exists() or target.is_symlink():
                old = aside / (target.name + '.old')
                os.replace(target, old)
            done.append((target, old))
            os.replace(staged, target)
    except OSError:
        for target, old in reversed(done):
            try:
                if target.is_dir() and not target.is_symlink():
                    shutil.rmtree(target)
                elif target.exists() or target.is_symlink():
                    target.unlink()
                if old is not None:
                    os.replace(old, target)
            except OSError:
                log.warning('%s: could not restore the previous version from %s', target, old)
        raise
