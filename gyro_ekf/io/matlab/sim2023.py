"""Reader of the 2023 simulated two-LiDAR log (DataUsr_006k.mat, variable `data`).

- `data.scans`, `data.scans2` (301, M): range in cm = word & 16383 (0 = no return, +inf),
  intensity = word >> 14 (3 = reflective pole); beams from `LidarsCfg.LidarN.FoV`
  ([first, last, step] in deg; -75..+75 at 0.5), 0 = forward, counter-clockwise.
- `data.LidarsCfg.Lidar1/Lidar2` Lx, Ly m and Alpha in RADIANS: Lidar1 -> topic 'scan' frame
  'laser', Lidar2 -> topic 'scan2' frame 'laser2'. Both scan arrays share the LiDAR events.
- Ground truth `data.verify.poseL`; initial pose `data.pose0`; map `data.Context.Landmarks`
  (the sparser `Landmarks2`/`Landmarks4` are not converted); walls `data.Context.Walls`.
- The log states no sensor noise figures and no bias value, so those stay unknown. Its map
  is the one the simulator drew the scans from, so it is stated exact (landmark_m = 0).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from gyro_ekf.core.types import LandmarkMap, LidarMount, NoiseFigures, ScanSeries, Trip
from gyro_ekf.io.errors import LogFormatError
from gyro_ekf.io.matlab import _common as mat
from gyro_ekf.io.matlab import _sim
from gyro_ekf.topics import LASER2_FRAME, LASER_FRAME, SCAN, SCAN2

FORMAT = 'sim2023'
RANGE_BITS = 0x3FFF
INTENSITY_SHIFT = 14
RANGE_MIN_M = 0.01
RANGE_MAX_M = RANGE_BITS / 100.0
LIDARS = (('data.scans', 'Lidar1', SCAN, LASER_FRAME),
          ('data.scans2', 'Lidar2', SCAN2, LASER2_FRAME))


def is_this_format(variables: dict) -> bool:
    """Whether a `data` log is the 2023 vintage (`LidarsCfg`, `scans2`)."""
    return mat.has_field(variables, 'data.LidarsCfg') and mat.has_field(
        variables, 'data.scans2')


def _scan(path: Path, variables: dict, columns: np.ndarray, stamp_s: np.ndarray,
          scan_field: str, lidar: str, topic: str, frame_id: str) -> ScanSeries:
    config = f'data.LidarsCfg.{lidar}'
    first_deg, last_deg, step_deg = (float(v) for v in mat.array(
        variables, f'{config}.FoV', path, (3,), 'iuf'))
    if not all(math.isfinite(v) for v in (first_deg, last_deg, step_deg)):
        raise LogFormatError(f"{path.name}: field '{config}.FoV' = "
                             f'[{first_deg}, {last_deg}, {step_deg}] deg is not finite')
    beams = round((last_deg - first_deg) / step_deg) + 1 if step_deg > 0 else 0
    words = mat.array(variables, scan_field, path, (None, None), 'u')
    if words.dtype != np.uint16:
        # Range and intensity share each 16-bit word: another width is not this format.
        raise LogFormatError(
            f"{path.name}: field '{scan_field}' has type {words.dtype}, expected uint16 words")
    if beams != words.shape[0]:
        raise LogFormatError(
            f"{path.name}: field '{scan_field}' has {words.shape[0]} beams per scan but "
            f"'{config}.FoV' = [{first_deg}, {last_deg}, {step_deg}] deg gives {beams}")
    rows = words[:, columns].T
    range_cm = rows & RANGE_BITS
    return ScanSeries(
        stamp_s=stamp_s, ranges_m=mat.decode_ranges(range_cm, range_cm == 0),
        intensities=(rows >> INTENSITY_SHIFT).astype(np.float32),
        angle_min_rad=math.radians(first_deg), angle_increment_rad=math.radians(step_deg),
        range_min_m=RANGE_MIN_M, range_max_m=RANGE_MAX_M,
        mount=LidarMount(mat.scalar(variables, f'{config}.Lx', path),
                         mat.scalar(variables, f'{config}.Ly', path),
                         mat.scalar(variables, f'{config}.Alpha', path)),
        topic=topic, frame_id=frame_id)


def read(path: Path, variables: dict | None = None, strict_time: bool = True) -> Trip:
    """Read DataUsr_006k.mat-style logs into a Trip.

    Args:
        path: the .mat file.
        variables: its variables if already loaded.

    Raises:
        LogFormatError: a field is missing or inconsistent.
    """
    variables = mat.load_mat(path) if variables is None else variables
    events = _sim.read_events(path, variables, 'data.scans', strict_time)
    first = mat.array(variables, 'data.scans', path, (None, None), 'u')
    second = mat.array(variables, 'data.scans2', path, (None, None), 'u')
    if second.shape != first.shape:
        raise LogFormatError(
            f"{path.name}: field 'data.scans2' has shape {second.shape}, expected "
            f"{first.shape} like 'data.scans'")
    scans = tuple(
        _scan(path, variables, events.scan_columns, events.scan_stamp_s, *lidar)
        for lidar in LIDARS)
    walls = 'data.Context.Walls'
    return Trip(
        name=path.stem,
        imu=events.imu,
        speed=events.speed,
        scans=scans,
        landmarks=LandmarkMap(_sim.points(path, variables, 'data.Context.Landmarks')),
        initial_pose=_sim.pose(path, variables, 'data.pose0'),
        ground_truth=events.ground_truth,
        walls=_sim.points(path, variables, walls) if mat.has_field(variables, walls) else None,
        noise=NoiseFigures(landmark_m=0.0),
        static_duration_s=0.0)
