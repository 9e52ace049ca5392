"""A simulator Trip saved as a self-describing .npz file (numpy arrays only, no pickles).

Keys (arrays; strings are 0-d unicode arrays):

- `format` = 'gyro_ekf.trip', `format_version` = 1 (checked on load).
- `name`, `initial_pose` (3,), `static_duration_s` (), `noise` (5,): gyro rad/s, speed m/s,
  range m, bearing rad, landmark map sigma m, NaN = not stated (files with 4 state no map
  sigma).
- `imu.stamp_s` (n,), `imu.angular_velocity_rad_s` (n, 3), `imu.axes_known` (3,) bool and,
  optionally, `imu.linear_acceleration_m_s2` (n, 3).
- `speed.stamp_s` (n,), `speed.speed_m_s` (n,).
- `scans.count` (); per scan series i: `scans.i.stamp_s` (m,), `scans.i.ranges_m` (m, beams)
  float32, optional `scans.i.intensities`, `scans.i.geometry` [angle_min_rad,
  angle_increment_rad, range_min_m, range_max_m], `scans.i.mount` [x_m, y_m, yaw_rad],
  `scans.i.topic`, `scans.i.frame_id`.
- optional `landmarks.xy_m` (k, 2), `ground_truth.stamp_s` (g,), `ground_truth.pose` (g, 3),
  `true_gyro_bias_rad_s` (3,), `walls` (w, 2).
"""

from __future__ import annotations

import logging
import os
from pathlib import Path
import tempfile
from typing import Any
import zipfile

import numpy as np

from gyro_ekf.core.types import (
    GroundTruth, ImuSeries, LandmarkMap, LidarMount, NoiseFigures, ScanSeries, SpeedSeries,
    Trip)
from gyro_ekf.io.errors import LogFormatError

log = logging.getLogger(__name__)

FORMAT = 'gyro_ekf.trip'
FORMAT_VERSION = 1
SUFFIX = '.npz'


def _nan_if_none(value: float | None) -> float:
    return float('nan') if value is None else float(value)


def _none_if_nan(value: float) -> float | None:
    return None if np.isnan(value) else float(value)


def trip_arrays(trip: Trip) -> dict[str, np.ndarray]:
    """Map a trip to the key -> array dict a trip file stores (see the module docstring)."""
    noise = trip.noise
    out: dict[str, np.ndarray] = {
        'format': np.array(FORMAT),
        'format_version': np.array(FORMAT_VERSION),
        'name': np.array(trip.name),
        'initial_pose': np.asarray(trip.initial_pose, dtype=np.float64),
        'static_duration_s': np.array(float(trip.static_duration_s)),
        'noise': np.array([_nan_if_none(noise.gyro_rad_s), _nan_if_none(noise.speed_m_s),
                           _nan_if_none(noise.range_m), _nan_if_none(noise.bearing_rad),
                           _nan_if_none(noise.landmark_m)]),
        'imu.stamp_s': np.asarray(trip.imu.stamp_s, dtype=np.float64),
        'imu.angular_velocity_rad_s': np.asarray(trip.imu.angular_velocity_rad_s,
                                                 dtype=np.float64),
        'imu.axes_known': np.array(trip.imu.axes_known, dtype=bool),
        'speed.stamp_s': np.asarray(trip.speed.stamp_s, dtype=np.float64),
        'speed.speed_m_s': np.asarray(trip.speed.speed_m_s, dtype=np.float64),
        'scans.count': np.array(len(trip.scans)),
    }
    if trip.imu.linear_acceleration_m_s2 is not None:
        out['imu.linear_acceleration_m_s2'] = np.asarray(trip.imu.linear_acceleration_m_s2,
                                                         dtype=np.float64)
    for i, scan in enumerate(trip.scans):
        key = f'scans.{i}.'
        out[key + 'stamp_s'] = np.asarray(scan.stamp_s, dtype=np.float64)
        out[key + 'ranges_m'] = np.asarray(scan.ranges_m, dtype=np.float32)
        if scan.intensities is not None:
            out[key + 'intensities'] = np.asarray(scan.intensities, dtype=np.float32)
        out[key + 'geometry'] = np.array([scan.angle_min_rad, scan.angle_increment_rad,
                                          scan.range_min_m, scan.range_max_m])
        out[key + 'mount'] = np.array([scan.mount.x_m, scan.mount.y_m, scan.mount.yaw_rad])
        out[key + 'topic'] = np.array(scan.topic)
        out[key + 'frame_id'] = np.array(scan.frame_id)
    if trip.landmarks is not None:
        out['landmarks.xy_m'] = np.asarray(trip.landmarks.xy_m, dtype=np.float64)
    if trip.ground_truth is not None:
        out['ground_truth.stamp_s'] = np.asarray(trip.ground_truth.stamp_s, dtype=np.float64)
        out['ground_truth.pose'] = np.asarray(trip.ground_truth.pose, dtype=np.float64)
    if trip.true_gyro_bias_rad_s is not None:
        out['true_gyro_bias_rad_s'] = np.asarray(trip.true_gyro_bias_rad_s, dtype=np.float64)
    if trip.walls is not None:
        out['walls'] = np.asarray(trip.walls, dtype=np.float64)
    return out


def save_trip(trip: Trip, path: Path | str, force: bool = False) -> Path:
    """Write a trip file (written aside, then renamed into place).

    Args:
        trip: the trip.
        path: the .npz file to write.
        force: replace an existing file.

    Returns:
        The path written.

    Raises:
        LogFormatError: the file exists and force is False.
    """
    path = Path(path)
    if path.exists() and not force:
        raise LogFormatError(f'{path}: exists already; use --force to replace it')
    path.parent.mkdir(parents=True, exist_ok=True)
    handle, tmp_name = tempfile.mkstemp(prefix=f'.{path.name}.', suffix='.tmp', dir=path.parent)
    try:
        with os.fdopen(handle, 'wb') as stream:
            np.savez_compressed(stream, **trip_arrays(trip))
        os.replace(tmp_name, path)
    except BaseException:
        Path(tmp_name).unlink(missing_ok=True)
        raise
    return path


def is_trip_file(path: Path | str) -> bool:
    """Whether `path` is a .npz file that says it is a gyro_ekf trip."""
    path = Path(path)
    if path.suffix != SUFFIX or not path.is_file():
        return False
    try:
        with np.load(path, allow_pickle=False) as data:
            return 'format' in data.files and str(data['format']) == FORMAT
    except (OSError, ValueError, zipfile.BadZipFile, EOFError):
        return False


class _Keys:
    """Checked access to the arrays of one trip file."""

    def __init__(self, path: Path, data: Any) -> None:
        self.path = path
        self.data = data

    def has(self, key: str) -> bool:
        return key in self.data.files

    def get(self, key: str, ndim: int | None = None, columns: int | None = None
            ) -> np.ndarray:
        if key not in self.data.files:
            raise LogFormatError(f"{self.path.name}: key '{key}' is missing")
        value = self.data[key]
        if (ndim is not None and value.ndim != ndim) or (
                columns is not None and value.shape[-1] != columns):
            raise LogFormatError(f"{self.path.name}: key '{key}' has shape {value.shape}, "
                                 f'expected {ndim} dimension(s)'
                                 + (f' with {columns} columns' if columns else ''))
        return value

    def same_length(self, key: str, value: np.ndarray, other: str, n: int) -> None:
        if value.shape[0] != n:
            raise LogFormatError(f"{self.path.name}: key '{key}' has {value.shape[0]} rows "
                                 f"but '{other}' has {n}")


def load_trip(path: Path | str) -> Trip:
    """Read a trip file written by save_trip.

    Raises:
        LogFormatError: missing, unreadable, not a trip file, a newer format version, or a
            key that is missing or has the wrong shape (the message names file and key).
    """
    path = Path(path)
    try:
        data = np.load(path, allow_pickle=False)
    except FileNotFoundError:
        raise LogFormatError(f'{path}: no such file') from None
    except EOFError:
        # numpy's reader on an empty file.
        raise LogFormatError(f'{path}: not a readable .npz trip file: the file is empty'
                             ) from None
    except (OSError, ValueError, zipfile.BadZipFile) as err:
        # numpy takes bytes that are neither a zip archive nor .npy for a pickle, and its
        # message then suggests loading the file unsafely.
        reason = (err if zipfile.is_zipfile(path)
                  else 'no zip archive (truncated, or not a .npz file at all?)')
        raise LogFormatError(f'{path.name}: not a readable .npz trip file: {reason}') from err
    with data:
        try:
            return _load(_Keys(path, data))
        except (OSError, ValueError, zipfile.BadZipFile, EOFError) as err:
            raise LogFormatError(f'{path.name}: corrupt trip file: {err}') from err


def _load(keys: _Keys) -> Trip:
    name = keys.path.name
    if not keys.has('format') or str(keys.get('format')) != FORMAT:
        raise LogFormatError(f"{name}: key 'format' is missing or not '{FORMAT}'; not a "
                             'gyro_ekf trip file')
    version = int(keys.get('format_version'))
    if version != FORMAT_VERSION:
        raise LogFormatError(f"{name}: key 'format_version' is {version}, this gyro_ekf "
                             f'reads version {FORMAT_VERSION}')
    imu_s = keys.get('imu.stamp_s', 1)
    rates = keys.get('imu.angular_velocity_rad_s', 2, 3)
    keys.same_length('imu.angular_velocity_rad_s', rates, 'imu.stamp_s', imu_s.size)
    accel = None
    if keys.has('imu.linear_acceleration_m_s2'):
        accel = keys.get('imu.linear_acceleration_m_s2', 2, 3)
        keys.same_length('imu.linear_acceleration_m_s2', accel, 'imu.stamp_s', imu_s.size)
    axes = keys.get('imu.axes_known', 1, 3)
    speed_s = keys.get('speed.stamp_s', 1)
    speed = keys.get('speed.speed_m_s', 1)
    keys.same_length('speed.speed_m_s', speed, 'speed.stamp_s', speed_s.size)
    scans = []
    for i in range(int(keys.get('scans.count'))):
        key = f'scans.{i}.'
        stamps = keys.get(key + 'stamp_s', 1)
        ranges = keys.get(key + 'ranges_m', 2)
        keys.same_length(key + 'ranges_m', ranges, key + 'stamp_s', stamps.size)
        intensities = None
        if keys.has(key + 'intensities'):
            intensities = keys.get(key + 'intensities', 2)
            if intensities.shape != ranges.shape:
                raise LogFormatError(f"{name}: key '{key}intensities' has shape "
                                     f'{intensities.shape}, expected {ranges.shape}')
        geometry = keys.get(key + 'geometry', 1, 4)
        mount = keys.get(key + 'mount', 1, 3)
        scans.append(ScanSeries(
            stamp_s=stamps, ranges_m=ranges.astype(np.float32, copy=False),
            intensities=intensities, angle_min_rad=float(geometry[0]),
            angle_increment_rad=float(geometry[1]), range_min_m=float(geometry[2]),
            range_max_m=float(geometry[3]), mount=LidarMount(*map(float, mount)),
            topic=str(keys.get(key + 'topic')), frame_id=str(keys.get(key + 'frame_id'))))
    truth = None
    if keys.has('ground_truth.stamp_s'):
        truth_s = keys.get('ground_truth.stamp_s', 1)
        pose = keys.get('ground_truth.pose', 2, 3)
        keys.same_length('ground_truth.pose', pose, 'ground_truth.stamp_s', truth_s.size)
        truth = GroundTruth(stamp_s=truth_s, pose=pose)
    noise = keys.get('noise', 1)
    if noise.size not in (4, 5):
        raise LogFormatError(f"{keys.path.name}: key 'noise' has shape {noise.shape}, "
                             'expected 4 or 5 figures')
    if noise.size == 4:
        log.warning('%s: written by an older gyro_ekf, it states no map figure and may state '
                    "per-beam range and bearing figures; simulate it again for today's",
                    keys.path.name)
    return Trip(
        name=str(keys.get('name')),
        imu=ImuSeries(stamp_s=imu_s, angular_velocity_rad_s=rates,
                      axes_known=tuple(bool(a) for a in axes),  # type: ignore[arg-type]
                      linear_acceleration_m_s2=accel),
        speed=SpeedSeries(stamp_s=speed_s, speed_m_s=speed),
        scans=tuple(scans),
        landmarks=LandmarkMap(keys.get('landmarks.xy_m', 2, 2)) if keys.has(
            'landmarks.xy_m') else None,
        initial_pose=keys.get('initial_pose', 1, 3),
        ground_truth=truth,
        true_gyro_bias_rad_s=keys.get('true_gyro_bias_rad_s', 1, 3) if keys.has(
            'true_gyro_bias_rad_s') else None,
        noise=NoiseFigures(*(_none_if_nan(v) for v in noise)),
        walls=keys.get('walls', 2, 2) if keys.has('walls') else None,
        static_duration_s=float(keys.get('static_duration_s')))
