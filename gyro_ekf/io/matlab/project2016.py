"""Reader of the 2016 Project-1 trio: IMU_dataC.mat, Speed_dataC.mat and Laser__2C.mat.

Conversions (see ../shared/data/mtrn4010/README.md):

- gyro: `IMU.DATAf` rows 4-6 are the roll, pitch and yaw rates in rad/s and become the x, y, z
  angular velocity; the yaw rate is `+DATAf(6,:)` (counter-clockwise positive).
- accelerometer: rows 1-3, in g, become m/s^2 (times 9.80665) without any change of sign. At
  rest the log's z row reads about -1 g, i.e. the logger reports gravity rather than specific
  force; the values are passed through as logged.
- speed: `Vel.speeds`, m/s.
- LiDAR: `dataL.Scans` words, bits 0-12 range in cm, bits 13-15 intensity 0..7; ranges
  >= 8000 cm mean no return (+inf). Beam bearings 0..180 deg with 0 = right become -90..+90
  deg with 0 = forward (counter-clockwise in both).
- The map is not part of this format: pass the 2021 MapMTRN4010.mat with it (see
  `gyro_ekf.io.matlab.load_course_log`). Initial pose (0, 0, pi/2) by course convention.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from gyro_ekf.core.types import ImuSeries, LandmarkMap, LidarMount, ScanSeries, SpeedSeries, Trip
from gyro_ekf.io.errors import LogFormatError
from gyro_ekf.io.matlab import _common as mat

FORMAT = 'project2016'
IMU_VARIABLE = 'IMU'
SPEED_VARIABLE = 'Vel'
LASER_VARIABLE = 'dataL'

SICK_BEAMS = 361
SICK_INCREMENT_RAD = math.radians(0.5)
SICK_RANGE_BITS = 0x1FFF
SICK_INTENSITY_SHIFT = 13
SICK_NO_RETURN_CM = 8000
SICK_RANGE_MIN_M = 0.0
SICK_RANGE_MAX_M = SICK_NO_RETURN_CM / 100.0
LIDAR_MOUNT = LidarMount(0.46, 0.0, 0.0)


def decode_sick_scans(path: Path, dotted: str, words: np.ndarray
                      ) -> tuple[np.ndarray, np.ndarray]:
    """Split SICK LMS291 words (beams, m) into ranges and intensities, one row per scan.

    Args:
        path: the file, for messages.
        dotted: the field name, for messages.
        words: shape (361, m), uint16.

    Returns:
        ranges_m shape (m, 361) float32 with +inf for no return, and intensities shape
        (m, 361) float32 (0..7).

    Raises:
        LogFormatError: the words are not unsigned 16-bit.
    """
    if words.dtype != np.uint16:
        raise LogFormatError(
            f"{path.name}: field '{dotted}' has type {words.dtype}, expected uint16 words")
    rows = words.T
    range_cm = rows & SICK_RANGE_BITS
    ranges = mat.decode_ranges(range_cm, range_cm >= SICK_NO_RETURN_CM)
    intensities = (rows >> SICK_INTENSITY_SHIFT).astype(np.float32)
    return ranges, intensities


def sick_angles(path: Path, variables: dict, dotted: str) -> tuple[float, float]:
    """Bearing of beam 0 and increment in ROS convention, from `angles` when the log has it.

    Returns:
        angle_min_rad (0 = forward, counter-clockwise) and angle_increment_rad.

    Raises:
        LogFormatError: the angles are not evenly spaced.
    """
    if not mat.has_field(variables, dotted):
        return -math.pi / 2.0, SICK_INCREMENT_RAD
    angles = mat.array(variables, dotted, path, (SICK_BEAMS,), 'f').astype(np.float64)
    steps = np.diff(angles)
    if np.abs(steps - SICK_INCREMENT_RAD).max() > 1e-6:
        raise LogFormatError(
            f"{path.name}: field '{dotted}' is not evenly spaced at 0.5 deg")
    return float(angles[0]) - math.pi / 2.0, SICK_INCREMENT_RAD


def read(imu_path: Path, speed_path: Path, laser_path: Path,
         landmarks: LandmarkMap | None, strict_time: bool = True) -> Trip:
    """Read the 2016 trio into a Trip.

    Args:
        imu_path: the file holding `IMU`.
        speed_path: the file holding `Vel`.
        laser_path: the file holding `dataL`.
        landmarks: the map (MapMTRN4010.mat), or None to convert without one.

    Returns:
        The trip, stamps in s since the earliest stamp of the three files.

    Raises:
        LogFormatError: a field is missing, has the wrong shape or goes back in time.
    """
    imu_vars = mat.load_mat(imu_path)
    imu_times = mat.array(imu_vars, 'IMU.times', imu_path, (None,), 'iu')
    data = mat.array(imu_vars, 'IMU.DATAf', imu_path, (9, None), 'f')
    mat.check_length(imu_path, 'IMU.DATAf', data.shape[1], 'IMU.times', imu_times.size)
    mat.check_stamps(imu_path, 'IMU.times', imu_times, strict_time)

    speed_vars = mat.load_mat(speed_path)
    speed_times = mat.array(speed_vars, 'Vel.times', speed_path, (None,), 'iu')
    speeds = mat.array(speed_vars, 'Vel.speeds', speed_path, (None,), 'f')
    mat.check_length(speed_path, 'Vel.speeds', speeds.size, 'Vel.times', speed_times.size)
    mat.check_stamps(speed_path, 'Vel.times', speed_times, strict_time)

    laser_vars = mat.load_mat(laser_path)
    laser_times = mat.array(laser_vars, 'dataL.times', laser_path, (None,), 'iu')
    words = mat.array(laser_vars, 'dataL.Scans', laser_path, (SICK_BEAMS, None), 'u')
    mat.check_length(laser_path, 'dataL.Scans', words.shape[1], 'dataL.times',
                     laser_times.size)
    mat.check_stamps(laser_path, 'dataL.times', laser_times, strict_time)
    angle_min, increment = sick_angles(laser_path, laser_vars, 'dataL.angles')
    ranges, intensities = decode_sick_scans(laser_path, 'dataL.Scans', words)

    firsts = [int(t[0]) for t in (imu_times, speed_times, laser_times) if t.size]
    if not firsts:
        raise LogFormatError(f'{imu_path.name}: the log holds no samples')
    zero = min(firsts)
    rates = data[3:6].T.astype(np.float64)
    speed_s = mat.stamps_s(speed_times, zero)
    speed_m_s = speeds.astype(np.float64)
    scan = ScanSeries(
        stamp_s=mat.stamps_s(laser_times, zero), ranges_m=ranges, intensities=intensities,
        angle_min_rad=angle_min, angle_increment_rad=increment,
        range_min_m=SICK_RANGE_MIN_M, range_max_m=SICK_RANGE_MAX_M, mount=LIDAR_MOUNT)
    return Trip(
        name=imu_path.stem,
        imu=ImuSeries(
            stamp_s=mat.stamps_s(imu_times, zero), angular_velocity_rad_s=rates,
            axes_known=(True, True, True),
            linear_acceleration_m_s2=data[0:3].T.astype(np.float64) * mat.GRAVITY_M_S2),
        speed=SpeedSeries(stamp_s=speed_s, speed_m_s=speed_m_s),
        scans=(scan,),
        landmarks=landmarks,
        initial_pose=np.array(mat.COURSE_INITIAL_POSE),
        static_duration_s=static_duration_s(speed_s, speed_m_s))


def static_duration_s(stamp_s: np.ndarray, speed_m_s: np.ndarray) -> float:
    """Time until the first non-zero speed sample, s (the whole trip if it never moves).

    Args:
        stamp_s: shape (n,), s since the log's time zero.
        speed_m_s: shape (n,), m/s.
    """
    moving = np.flatnonzero(speed_m_s != 0.0)
    if moving.size:
        return float(stamp_s[moving[0]])
    return float(stamp_s[-1]) if stamp_s.size else 0.0
