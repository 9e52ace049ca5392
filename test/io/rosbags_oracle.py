"""Test oracle: read a bag deserialising every message with rosbags, one by one.

`read_bag` decodes the sensor topics in batches with numpy (`bag_sinks`, `fast_cdr`);
this reads the same bag through `iter_bag_messages` and rosbags' own deserialisation,
about three times slower, so tests and the fuzzer (`fuzz/targets_bag.py`) can check that
both give the same Trip, bit for bit, and refuse the same bags.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from gyro_ekf import topics
from gyro_ekf.io import messages as msgs
from gyro_ekf.io.bag_open import (
    GROUND_TRUTH_TOPIC, IMU_TOPIC, INITIAL_POSE_TOPIC, MAP_TOPIC, ODOM_TOPIC, open_bag,
    topic_connections)
from gyro_ekf.io.bag_reader import (
    BagTrip, assemble_trip, initial_pose_of, iter_bag_messages, one_message)
from gyro_ekf.io.bag_sinks import (
    SCAN_CHECKED, SCAN_GEOMETRY, ScanData, check_imu_axes, check_scans, has_acceleration)
from gyro_ekf.io.sidecar import read_sidecar


def read_bag_rosbags(path: Path | str, acceleration: bool = True) -> BagTrip:
    """Read a bag as `read_bag` does, deserialising every message with rosbags.

    Raises:
        BagError: as read_bag.
    """
    path = Path(path)
    reader = open_bag(path)
    try:
        params = read_sidecar(path)
        by_topic, _ = topic_connections(path, reader, params)
        start = reader.start_time if reader.message_count else 0
    finally:
        reader.close()
    scan_topics = [t for t, c in by_topic.items() if c.msgtype == topics.LASER_SCAN_TYPE]
    wanted = [IMU_TOPIC, ODOM_TOPIC, *scan_topics] + [
        t for t in (MAP_TOPIC, INITIAL_POSE_TOPIC, GROUND_TRUTH_TOPIC) if t in by_topic]
    # Lists, not arrays sized by the bag's counts: those are only hints.
    imu_ns: list[int] = []
    rates: list[tuple[float, float, float]] = []
    rate_variances: list[float] = []
    accel: list[tuple[float, float, float]] = []
    has_accel = False
    axes_known: tuple[bool, bool, bool] = (True, True, True)
    odom_ns: list[int] = []
    speeds: list[float] = []
    speed_variances: list[float] = []
    truth_ns: list[int] = []
    truth: list[tuple[float, float, float]] = []
    scans: dict[str, list[tuple[int, Any]]] = {t: [] for t in scan_topics}
    singles: dict[str, list[Any]] = {MAP_TOPIC: [], INITIAL_POSE_TOPIC: []}
    for topic, _, stamp, message in iter_bag_messages(path, wanted):
        if topic == IMU_TOPIC:
            # Every message is judged, as by the reader (bag_sinks.check_imu_axes).
            axes_known = check_imu_axes(path, topic, len(imu_ns),
                                        message.angular_velocity_covariance[None],
                                        axes_known if imu_ns else None)
            if not imu_ns:
                has_accel = has_acceleration(message)
            w, a = message.angular_velocity, message.linear_acceleration
            imu_ns.append(stamp)
            rates.append((w.x, w.y, w.z))
            rate_variances.append(message.angular_velocity_covariance[8])
            accel.append((a.x, a.y, a.z))
        elif topic == ODOM_TOPIC:
            odom_ns.append(stamp)
            speeds.append(message.twist.twist.linear.x)
            speed_variances.append(message.twist.covariance[0])
        elif topic in scans:
            scans[topic].append((stamp, message))
        elif topic == GROUND_TRUTH_TOPIC:
            truth_ns.append(stamp)
            truth.append(msgs.pose_of(message.pose.pose))
        elif topic in singles:
            singles[topic].append(message)
    map_message = one_message(path, MAP_TOPIC, singles[MAP_TOPIC])
    pose_message = one_message(path, INITIAL_POSE_TOPIC, singles[INITIAL_POSE_TOPIC])
    landmarks = None if map_message is None else msgs.landmarks_of(map_message)
    initial_pose = None if pose_message is None else initial_pose_of(path, pose_message)

    def rows(values: list[Any], width: int) -> np.ndarray:
        return np.array(values, dtype=np.float64).reshape(len(values), width)

    return assemble_trip(
        path, params, int(start), imu_ns=np.array(imu_ns, dtype=np.int64),
        rates=rows(rates, 3), rate_variances=np.array(rate_variances, dtype=np.float64),
        accel=rows(accel, 3) if has_accel and acceleration else None,
        axes_known=axes_known, odom_ns=np.array(odom_ns, dtype=np.int64),
        speeds=np.array(speeds, dtype=np.float64),
        speed_variances=np.array(speed_variances, dtype=np.float64),
        scans=[_scan_data(path, t, scans[t]) for t in scan_topics if scans[t]],
        truth=((np.array(truth_ns, dtype=np.int64), rows(truth, 3))
               if GROUND_TRUTH_TOPIC in by_topic else None),
        landmarks=landmarks, initial_pose=initial_pose)


def _scan_data(path: Path, topic: str, scans: list[tuple[int, Any]]) -> ScanData:
    """Stack one topic's LaserScans after the reader's own geometry check."""
    first = scans[0][1]
    messages = [message for _, message in scans]
    check_scans(path, topic, 0, first, np.array([len(m.ranges) for m in messages]),
                {name: np.array([getattr(m, name) for m in messages]) for name in SCAN_CHECKED},
                np.array([len(m.intensities) for m in messages]))
    beams = len(first.ranges)
    ranges = np.array([m.ranges for m in messages], dtype=np.float32).reshape(-1, beams)
    intensities = (np.array([m.intensities for m in messages], dtype=np.float32)
                   .reshape(-1, beams) if len(first.intensities) else None)
    return ScanData(topic, np.array([stamp for stamp, _ in scans], dtype=np.int64), ranges,
                    intensities, tuple(getattr(first, name) for name in SCAN_GEOMETRY),
                    first.header.frame_id)
