"""Reader of the 2022 simulated log (data019b.mat, variable `data`).

- `data.scans` (321, M): plain range in cm, 321 beams from -80 to +80 deg, 0 = forward,
  counter-clockwise; >= 16000 cm is no return (+inf). No intensities.
- `data.LidarCfg` Lx, Ly in m and Alpha in DEGREES (its `info` says so) -> LidarMount.
- `data.etc.ns` = [speed sigma m/s, gyro sigma rad/s, (undocumented, ignored),
  injected gyro bias rad/s]: the stated noise and the true bias [0, 0, ns(4)]. The map is
  the simulator's own, so it is stated exact (landmark_m = 0).
- Ground truth `data.verify.poseL` at the LiDAR events; initial pose `data.pose0`; map
  `data.Landmarks`; walls `data.Walls`.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from gyro_ekf.core.types import LandmarkMap, LidarMount, NoiseFigures, ScanSeries, Trip
from gyro_ekf.io.errors import LogFormatError
from gyro_ekf.io.matlab import _common as mat
from gyro_ekf.io.matlab import _sim

FORMAT = 'sim2022'
BEAMS = 321
ANGLE_MIN_RAD = math.radians(-80.0)
ANGLE_INCREMENT_RAD = math.radians(0.5)
NO_RETURN_CM = 16000
RANGE_MIN_M = 0.0
RANGE_MAX_M = NO_RETURN_CM / 100.0


def is_this_format(variables: dict) -> bool:
    """Whether a `data` log is the 2022 vintage (one LiDAR, `LidarCfg`)."""
    return mat.has_field(variables, 'data.LidarCfg') and not mat.has_field(
        variables, 'data.scans2')


def read(path: Path, variables: dict | None = None, strict_time: bool = True) -> Trip:
    """Read data019b.mat-style logs into a Trip.

    Args:
        path: the .mat file.
        variables: its variables if already loaded.

    Raises:
        LogFormatError: a field is missing or inconsistent.
    """
    variables = mat.load_mat(path) if variables is None else variables
    events = _sim.read_events(path, variables, 'data.scans', strict_time)
    words = mat.array(variables, 'data.scans', path, (BEAMS, None), 'u')
    rows = words[:, events.scan_columns].T
    ranges = mat.decode_ranges(rows, rows >= NO_RETURN_CM)
    mount = LidarMount(
        mat.scalar(variables, 'data.LidarCfg.Lx', path),
        mat.scalar(variables, 'data.LidarCfg.Ly', path),
        math.radians(mat.scalar(variables, 'data.LidarCfg.Alpha', path)))
    ns = [mat.decimal(v) for v in mat.array(variables, 'data.etc.ns', path, (4,), 'f')]
    if not np.all(np.isfinite(ns)) or ns[0] < 0 or ns[1] < 0:
        raise LogFormatError(
            f"{path.name}: field 'data.etc.ns' = {ns}, expected "
            '[speed sigma >= 0, gyro sigma >= 0, _, bias]')
    scan = ScanSeries(
        stamp_s=events.scan_stamp_s, ranges_m=ranges, intensities=None,
        angle_min_rad=ANGLE_MIN_RAD, angle_increment_rad=ANGLE_INCREMENT_RAD,
        range_min_m=RANGE_MIN_M, range_max_m=RANGE_MAX_M, mount=mount)
    return Trip(
        name=path.stem,
        imu=events.imu,
        speed=events.speed,
        scans=(scan,),
        landmarks=LandmarkMap(_sim.points(path, variables, 'data.Landmarks')),
        initial_pose=_sim.pose(path, variables, 'data.pose0'),
        ground_truth=events.ground_truth,
        true_gyro_bias_rad_s=np.array([0.0, 0.0, ns[3]]),
        noise=NoiseFigures(gyro_rad_s=ns[1], speed_m_s=ns[0], landmark_m=0.0),
        walls=_sim.points(path, variables, 'data.Walls') if mat.has_field(
            variables, 'data.Walls') else None,
        static_duration_s=0.0)
