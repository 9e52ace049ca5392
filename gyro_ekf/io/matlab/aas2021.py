"""Reader of the 2021 event-table log (Measurements_AAS01.mat) and its map (MapMTRN4010.mat).

Each column of `A.Z` is one event at `A.t`: row 1 speed in mm/s, row 2 yaw rate in 0.01 deg/s
(same sign as the 2016 `+DATAf(6,:)`), row 3 the 1-based index of a scan in `A.scans`, or a
value <= 0 for no scan (the README says 0; the AAS01 file in fact holds -1). Events without a
scan are speed+gyro samples and give one /imu and one /odom each; scan events repeat the
previous speed and rate and give only the scan. The gyro has the yaw axis
only (x and y are unknown) and there is no accelerometer. Scans decode as in 2016.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from gyro_ekf.core.types import ImuSeries, LandmarkMap, ScanSeries, SpeedSeries, Trip
from gyro_ekf.io.errors import LogFormatError
from gyro_ekf.io.matlab import _common as mat
from gyro_ekf.io.matlab import project2016

FORMAT = 'aas2021'
LOG_VARIABLE = 'A'
MAP_VARIABLE = 'Map'
SPEED_UNIT_M_S = 1e-3
"""One count of `A.Z` row 1, m/s."""
RATE_UNIT_RAD_S = 0.01 * math.pi / 180.0
"""One count of `A.Z` row 2, rad/s."""


def read_map(path: Path) -> LandmarkMap:
    """Read MapMTRN4010.mat (`Map.x`, `Map.y`, m; `Map.n`, their count, where present).

    Raises:
        LogFormatError: missing fields, lengths that disagree, or a count `Map.n` that is
            not theirs (a map cut short or padded: some of its poles were lost).
    """
    variables = mat.load_mat(path)
    x = mat.array(variables, 'Map.x', path, (None,), 'iuf')
    y = mat.array(variables, 'Map.y', path, (None,), 'iuf')
    mat.check_length(path, 'Map.y', y.size, 'Map.x', x.size)
    if mat.has_field(variables, 'Map.n'):
        count = mat.scalar(variables, 'Map.n', path)
        if count != x.size:
            raise LogFormatError(f"{path.name}: field 'Map.n' says {count:g} poles but "
                                 f"'Map.x' and 'Map.y' hold {x.size}: the map was cut short "
                                 'or padded; fix it before it is used')
    return LandmarkMap(xy_m=np.column_stack([x, y]).astype(np.float64))


def read(path: Path, landmarks: LandmarkMap | None, strict_time: bool = True) -> Trip:
    """Read the event table into a Trip.

    Args:
        path: the file holding `A`.
        landmarks: the map, which this format needs for anything but calibration; None
            only for a caller that uses no landmarks.

    Returns:
        The trip, stamps in s since the first event.

    Raises:
        LogFormatError: a field is missing, has the wrong shape, an index is out of range
            or the stamps go back in time.
    """
    variables = mat.load_mat(path)
    times = mat.array(variables, 'A.t', path, (None,), 'iu')
    events = mat.array(variables, 'A.Z', path, (3, None), 'iuf')
    mat.check_length(path, 'A.Z', events.shape[1], 'A.t', times.size)
    words = mat.array(variables, 'A.scans', path, (project2016.SICK_BEAMS, None), 'u')
    mat.check_stamps(path, 'A.t', times, strict_time)
    if times.size == 0:
        raise LogFormatError(f"{path.name}: field 'A.t' holds no events")

    zero = int(times[0])
    is_scan = mat.check_whole(path, 'A.Z(3,:)', events[2]) > 0
    scan_columns = mat.check_indices(path, 'A.Z(3,:)', events[2][is_scan], 'A.scans',
                                     words.shape[1])
    ranges, intensities = project2016.decode_sick_scans(path, 'A.scans',
                                                        words[:, scan_columns])
    sample_s = mat.stamps_s(times[~is_scan], zero)
    speed_m_s = events[0][~is_scan].astype(np.float64) * SPEED_UNIT_M_S
    yaw_rate = events[1][~is_scan].astype(np.float64) * RATE_UNIT_RAD_S
    rates = np.zeros((yaw_rate.size, 3))
    rates[:, 2] = yaw_rate
    scan = ScanSeries(
        stamp_s=mat.stamps_s(times[is_scan], zero), ranges_m=ranges, intensities=intensities,
        angle_min_rad=-math.pi / 2.0, angle_increment_rad=project2016.SICK_INCREMENT_RAD,
        range_min_m=project2016.SICK_RANGE_MIN_M, range_max_m=project2016.SICK_RANGE_MAX_M,
        mount=project2016.LIDAR_MOUNT)
    return Trip(
        name=path.stem,
        imu=ImuSeries(stamp_s=sample_s, angular_velocity_rad_s=rates,
                      axes_known=(False, False, True)),
        speed=SpeedSeries(stamp_s=sample_s, speed_m_s=speed_m_s),
        scans=(scan,),
        landmarks=landmarks,
        initial_pose=np.array(mat.COURSE_INITIAL_POSE),
        static_duration_s=project2016.static_duration_s(sample_s, speed_m_s))
