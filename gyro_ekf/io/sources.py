"""One entry point for every input `gyro-ekf convert` accepts: course logs and trip files.

Every trip read here passes the validation boundary (`core.validation.validate_trip`)
before anyone uses it: a bad value is an InvalidInputError naming the file, field and
index, or with skip_bad a dropped and counted sample.
"""

from __future__ import annotations

from collections.abc import Sequence
import dataclasses
from pathlib import Path

from gyro_ekf.core.config import InputLimits
from gyro_ekf.core.errors import InvalidInputError
from gyro_ekf.core.types import Trip
from gyro_ekf.core.validation import InputReport, validate_trip
from gyro_ekf.io import trip_file
from gyro_ekf.io.errors import LogFormatError
from gyro_ekf.io.matlab import detect_course_log, expand_paths, load_course_log
from gyro_ekf.io.matlab._common import variable_names
from gyro_ekf.io.matlab.aas2021 import MAP_VARIABLE
from gyro_ekf.io.matlab.project2016 import IMU_VARIABLE, LASER_VARIABLE, SPEED_VARIABLE


def load_log(paths: Sequence[Path | str], map_path: Path | str | None = None) -> Trip:
    """Read and check a course log or trip file; see load_checked_log (bad input refused)."""
    return load_checked_log(paths, map_path)[0]


def _with_trip_files(inputs: list[Path]) -> list[Path]:
    """Replace each input folder holding no .mat file by the trip files in it."""
    expanded: list[Path] = []
    for path in inputs:
        if path.is_dir() and not any(path.glob('*.mat')):
            expanded += sorted(path.glob('*' + trip_file.SUFFIX))
        else:
            expanded.append(path)
    return expanded


def stream_files(paths: Sequence[Path | str]) -> dict[str, Path]:
    """Name the file each sensor stream of a course log or trip file is read from.

    For messages about a stream as a whole (a refused calibration window), which no
    field and index of validate_trip point to: the 2016 log spreads over three files.

    Args:
        paths: as load_checked_log takes them, once it has read them.

    Returns:
        {'imu': the file holding the gyro, 'speed': the file holding the speed, 'lidar':
        the file holding the scans}.
    """
    inputs = [Path(p) for p in paths]
    trips = [p for p in _with_trip_files(inputs) if p.suffix == trip_file.SUFFIX]
    if trips:
        return {'imu': trips[0], 'speed': trips[0], 'lidar': trips[0]}
    files = detect_course_log(inputs, need_map=False).files
    # The 2021 event table and the simulated logs hold every stream in their one file.
    data = next(p for variable, p in files.items() if variable != MAP_VARIABLE)
    return {'imu': files.get(IMU_VARIABLE, data), 'speed': files.get(SPEED_VARIABLE, data),
            'lidar': files.get(LASER_VARIABLE, data)}


def load_checked_log(paths: Sequence[Path | str], map_path: Path | str | None = None,
                     skip_bad: bool = False, limits: InputLimits | None = None,
                     landmarks: bool = True) -> tuple[Trip, InputReport]:
    """Read a course log (.mat files or their folder) or a simulator trip file (.npz).

    Args:
        paths: the log's files or folder; or exactly one trip file (or a folder holding
            one trip file and no .mat files).
        map_path: the landmark map (MapMTRN4010.mat) for the 2016/2021 logs, when it is not
            among `paths` or beside them.
        skip_bad: drop bad samples (and stamps that go back) and count them instead of
            refusing the first.
        limits: plausible input ranges; InputLimits() when None.
        landmarks: False for a caller that uses none (calibration): the trip comes without
            them, and a course log needs no map (see load_course_log).

    Returns:
        The checked trip and what the check dropped.

    Raises:
        LogFormatError: anything load_course_log or load_trip refuses, or a trip file mixed
            with other inputs.
        InvalidInputError: a bad value (without skip_bad), or one with nothing to skip (map,
            mount, initial pose, noise figures, a stream that jumps ahead and stays there).
    """
    inputs = [Path(p) for p in paths]
    if not inputs:
        raise LogFormatError('no input given; expected course log .mat files or a trip .npz')
    expanded = _with_trip_files(inputs)
    trips = [p for p in expanded if p.suffix == trip_file.SUFFIX]
    if trips:
        if len(expanded) != 1 or map_path is not None:
            raise LogFormatError(
                f'{trips[0].name}: a trip file carries everything itself; give it alone')
        trip = trip_file.load_trip(trips[0])
        if not landmarks:
            trip = dataclasses.replace(trip, landmarks=None)
        return validate_trip(trip, trips[0].name, limits or InputLimits(), skip_bad=skip_bad)
    if map_path is not None:
        # A map named on its own must be one: among the log's files a wrong one only
        # left the log without landmarks and a warning that no map was given.
        names = variable_names(Path(map_path))
        if MAP_VARIABLE not in names:
            raise LogFormatError(f'{Path(map_path).name}: not a landmark map: no variable '
                                 f"'{MAP_VARIABLE}' (it has {names}); expected "
                                 'MapMTRN4010.mat')
    given = inputs + ([Path(map_path)] if map_path is not None else [])
    trip = load_course_log(given, strict_time=not skip_bad, landmarks=landmarks)
    source = ', '.join(p.name for p in expand_paths(inputs))
    try:
        return validate_trip(trip, source, limits or InputLimits(), skip_bad=skip_bad)
    except InvalidInputError as err:
        # Name the one file the bad value came from (the 2016 log spreads over three).
        files = detect_course_log(given, need_map=landmarks).files
        variable = {'imu': 'IMU', 'speed': 'Vel', 'lidar': 'dataL',
                    'landmarks': 'Map'}.get(err.field.split('.')[0])
        if variable not in files or len(set(files.values())) == 1:
            raise
        raise InvalidInputError(files[variable].name, err.field, err.index,
                                err.reason) from None
