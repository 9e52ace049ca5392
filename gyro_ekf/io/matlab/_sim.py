"""The event table shared by the 2022 and 2023 simulated logs.

`data.table` is (3, n) uint32: per event [time in 0.1 ms; 1-based index; sensor type], type 1
a LiDAR scan (index into the scan arrays and `verify.poseL`), type 2 a speed+gyro sample
(index into `data.vw`). `data.vw` row 1 is speed in m/s, row 2 the raw yaw rate in rad/s.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from gyro_ekf.core.types import FloatArray, GroundTruth, ImuSeries, SpeedSeries
from gyro_ekf.io.errors import LogFormatError
from gyro_ekf.io.matlab import _common as mat

LIDAR_EVENT = 1
SAMPLE_EVENT = 2


@dataclass(frozen=True, slots=True)
class SimEvents:
    """What the event table of a simulated log says, in SI.

    Attributes:
        imu: gyro (yaw only) samples.
        speed: speed samples (same stamps as imu).
        scan_stamp_s: LiDAR event times, shape (m,), s.
        scan_columns: 0-based column of each LiDAR event in the scan arrays, shape (m,).
        ground_truth: `verify.poseL` at the LiDAR events.
    """

    imu: ImuSeries
    speed: SpeedSeries
    scan_stamp_s: FloatArray
    scan_columns: np.ndarray
    ground_truth: GroundTruth


def read_events(path: Path, variables: dict[str, Any], scan_field: str,
                strict_time: bool = True) -> SimEvents:
    """Check and decode `data.table`, `data.vw` and `data.verify.poseL`.

    Args:
        path: the file, for messages.
        variables: its variables (from load_mat).
        scan_field: the scan array the LiDAR indices point into, e.g. 'data.scans'.

    Raises:
        LogFormatError: wrong shapes, unknown event types, indices out of range or stamps
            that go back in time.
    """
    table = mat.array(variables, 'data.table', path, (3, None), 'iu')
    vw = mat.array(variables, 'data.vw', path, (2, None), 'f')
    scans = mat.array(variables, scan_field, path, (None, None), 'u')
    poses = mat.array(variables, 'data.verify.poseL', path, (3, None), 'f')
    mat.check_length(path, 'data.verify.poseL', poses.shape[1], scan_field, scans.shape[1])
    if table.shape[1] == 0:
        raise LogFormatError(f"{path.name}: field 'data.table' holds no events")
    times, indices, kinds = table[0], table[1], table[2]
    mat.check_stamps(path, 'data.table(1,:)', times, strict_time)
    unknown = (kinds != LIDAR_EVENT) & (kinds != SAMPLE_EVENT)
    if unknown.any():
        i = int(np.argmax(unknown))
        raise LogFormatError(
            f"{path.name}: field 'data.table(3,:)' has sensor type {int(kinds[i])} at event "
            f'{i + 1}, expected {LIDAR_EVENT} (LiDAR) or {SAMPLE_EVENT} (speed+gyro)')
    zero = int(times[0])
    is_sample = kinds == SAMPLE_EVENT
    is_scan = kinds == LIDAR_EVENT
    sample_columns = mat.check_indices(path, 'data.table(2,:)', indices[is_sample],
                                       'data.vw', vw.shape[1])
    scan_columns = mat.check_indices(path, 'data.table(2,:)', indices[is_scan], scan_field,
                                     scans.shape[1])
    sample_s = mat.stamps_s(times[is_sample], zero)
    scan_s = mat.stamps_s(times[is_scan], zero)
    rates = np.zeros((sample_s.size, 3))
    rates[:, 2] = vw[1, sample_columns]
    return SimEvents(
        imu=ImuSeries(stamp_s=sample_s, angular_velocity_rad_s=rates,
                      axes_known=(False, False, True)),
        speed=SpeedSeries(stamp_s=sample_s,
                          speed_m_s=vw[0, sample_columns].astype(np.float64)),
        scan_stamp_s=scan_s,
        scan_columns=scan_columns,
        ground_truth=GroundTruth(stamp_s=scan_s,
                                 pose=poses[:, scan_columns].T.astype(np.float64)))


def points(path: Path, variables: dict[str, Any], dotted: str) -> FloatArray:
    """Read a (2, k) point or polyline field as shape (k, 2) float64, m."""
    return mat.array(variables, dotted, path, (2, None), 'f').T.astype(np.float64)


def pose(path: Path, variables: dict[str, Any], dotted: str) -> FloatArray:
    """Read a (3,) pose field (x m, y m, heading rad) as float64."""
    return mat.array(variables, dotted, path, (3,), 'f').astype(np.float64)
