"""Readers of the MTRN4010 course logs, one module per vintage, each returning a core Trip.

`load_course_log` looks at the variables in the given files and picks the reader:

| vintage | files (variables) | reader |
|---|---|---|
| 2016 Project 1 | IMU_dataC (`IMU`), Speed_dataC (`Vel`), Laser__2C (`dataL`) | project2016 |
| 2021 event table | Measurements_AAS01 (`A`) + MapMTRN4010 (`Map`) | aas2021 |
| 2022 simulation | data019b (`data` with `LidarCfg`) | sim2022 |
| 2023 simulation | DataUsr_006k (`data` with `LidarsCfg` and `scans2`) | sim2023 |

The map file may be given with the logs or lie beside them (any .mat file in the same folder
whose variable is `Map`). The 2021 format needs it and fails without it. The 2016 trio
converts without it too: the trip then has no landmarks (a warning says so), because its
sensor data are complete and useful on their own (calibration, dead reckoning). A caller
that uses no landmarks (`gyro-ekf calibrate`) reads either log without its map, unread and
unmentioned (`landmarks=False`).
"""

from __future__ import annotations

from collections.abc import Sequence
import dataclasses
from dataclasses import dataclass
import logging
from pathlib import Path

from gyro_ekf.core.types import Trip
from gyro_ekf.io.errors import LogFormatError
from gyro_ekf.io.matlab import _common, aas2021, project2016, sim2022, sim2023

__all__ = ['CourseLog', 'detect_course_log', 'load_course_log', 'expand_paths']

log = logging.getLogger(__name__)

PROJECT2016_VARIABLES = (project2016.IMU_VARIABLE, project2016.SPEED_VARIABLE,
                         project2016.LASER_VARIABLE)
SIM_VARIABLE = 'data'
KNOWN_VARIABLES = PROJECT2016_VARIABLES + (aas2021.LOG_VARIABLE, aas2021.MAP_VARIABLE,
                                           SIM_VARIABLE)
EXPECTED = ("expected the 2016 Project-1 trio (variables 'IMU', 'Vel', 'dataL'), the 2021 "
            "event table ('A') with its map ('Map'), or a 2022/2023 simulated log ('data')")


@dataclass(frozen=True, slots=True)
class CourseLog:
    """A detected course log: its vintage and the file holding each variable.

    Attributes:
        vintage: 'project2016', 'aas2021', 'sim2022' or 'sim2023'.
        files: variable name -> file, e.g. {'A': ..., 'Map': ...}.
    """

    vintage: str
    files: dict[str, Path]


def expand_paths(paths: Sequence[Path | str], suffix: str = '.mat') -> list[Path]:
    """Paths with every directory replaced by its files ending in `suffix` (sorted).

    Raises:
        LogFormatError: a path does not exist.
    """
    files: list[Path] = []
    for path in map(Path, paths):
        if path.is_dir():
            files += sorted(p for p in path.iterdir() if p.suffix == suffix and p.is_file())
        elif path.exists():
            files.append(path)
        else:
            raise LogFormatError(f'{path}: no such file or directory')
    return list(dict.fromkeys(files))


def _find_map_beside(log_file: Path, given: set[Path]) -> Path | None:
    for candidate in sorted(log_file.parent.glob('*.mat')):
        if candidate in given:
            continue
        try:
            names = _common.variable_names(candidate)
        except LogFormatError:
            continue
        if aas2021.MAP_VARIABLE in names:
            return candidate
    return None


def detect_course_log(paths: Sequence[Path | str], need_map: bool = True) -> CourseLog:
    """Work out which course log the files hold, from their variable names only.

    Args:
        paths: .mat files or folders of them.
        need_map: look for the map of a 2016 or 2021 log beside it, and refuse a 2021 log
            without one; False for a caller that uses no landmarks (a map among `paths`
            is still listed).

    Returns:
        The vintage and the file of each variable. For 'sim2022' and 'sim2023' the choice
        between them needs the file's fields; it is made here by loading the file.

    Raises:
        LogFormatError: no files, unknown variables, a variable in two files, an incomplete
            2016 trio, logs of two vintages mixed, or a 2021 log without a map (unless
            need_map is false).
    """
    files = expand_paths(paths)
    if not files:
        raise LogFormatError(f'no .mat files in {", ".join(map(str, paths))}; {EXPECTED}')
    roles: dict[str, Path] = {}
    for path in files:
        names = _common.variable_names(path)
        known = [name for name in names if name in KNOWN_VARIABLES]
        if not known:
            raise LogFormatError(
                f'{path.name}: variables {names} match no course log; {EXPECTED}')
        for name in known:
            if name in roles:
                raise LogFormatError(
                    f"{path.name}: variable '{name}' is also in {roles[name].name}; "
                    'give one log at a time')
            roles[name] = path
    kinds = [kind for kind, present in (
        ('2016 trio', any(v in roles for v in PROJECT2016_VARIABLES)),
        ('2021 event table', aas2021.LOG_VARIABLE in roles),
        ('simulated log', SIM_VARIABLE in roles)) if present]
    if len(kinds) > 1:
        raise LogFormatError(f'the files mix logs of different formats ({", ".join(kinds)}); '
                             'give one log at a time')
    if not kinds:
        raise LogFormatError(
            f"{roles[aas2021.MAP_VARIABLE].name}: holds only a map ('Map'); {EXPECTED}")
    given = set(files)
    if SIM_VARIABLE in roles:
        path = roles[SIM_VARIABLE]
        variables = _common.load_mat(path)
        if sim2023.is_this_format(variables):
            return CourseLog('sim2023', roles)
        if sim2022.is_this_format(variables):
            return CourseLog('sim2022', roles)
        raise LogFormatError(
            f"{path.name}: variable 'data' has neither 'data.LidarCfg' (2022 simulation) nor "
            "'data.LidarsCfg' with 'data.scans2' (2023 simulation)")
    if aas2021.LOG_VARIABLE in roles:
        if aas2021.MAP_VARIABLE not in roles and need_map:
            found = _find_map_beside(roles[aas2021.LOG_VARIABLE], given)
            if found is None:
                raise LogFormatError(
                    f"{roles[aas2021.LOG_VARIABLE].name}: the 2021 format needs its map "
                    "(MapMTRN4010.mat, variable 'Map'); none was given (--map) or found "
                    'beside the log')
            roles[aas2021.MAP_VARIABLE] = found
        return CourseLog(aas2021.FORMAT, roles)
    missing = [v for v in PROJECT2016_VARIABLES if v not in roles]
    if missing:
        raise LogFormatError(
            f"the 2016 Project-1 log needs variables 'IMU' (IMU_dataC.mat), 'Vel' "
            f"(Speed_dataC.mat) and 'dataL' (Laser__2C.mat); missing {missing} among "
            f'{[p.name for p in files]}')
    if aas2021.MAP_VARIABLE not in roles and need_map:
        found = _find_map_beside(roles[project2016.IMU_VARIABLE], given)
        if found is not None:
            roles[aas2021.MAP_VARIABLE] = found
    return CourseLog(project2016.FORMAT, roles)


def load_course_log(paths: Sequence[Path], strict_time: bool = True,
                    landmarks: bool = True) -> Trip:
    """Detect the course log in `paths` and read it into a Trip (SI, ROS conventions).

    Args:
        paths: the log's .mat files, the map (MapMTRN4010.mat) where needed, or folders of
            .mat files. For the 2016 and 2021 logs a map lying beside the log is found
            by itself.
        strict_time: refuse stamps that go back (False leaves them to the validation
            boundary, which with --skip-bad drops the older samples and counts them).
        landmarks: False for a caller that uses none (calibration): the trip then has no
            landmarks, and no map is needed, read or warned about (a simulated log's
            own landmarks are dropped too, so no vintage differs).

    Returns:
        The trip, stamps in s since the log's first stamp.

    Raises:
        LogFormatError: unknown or mixed formats, a missing map where one is needed,
            corrupt or truncated files, fields of the wrong shape or inconsistent length,
            indices out of range or stamps going back in time; the message names the file
            and field.
    """
    detected = detect_course_log(paths, need_map=landmarks)
    files = detected.files
    map_path = files.get(aas2021.MAP_VARIABLE) if landmarks else None
    if detected.vintage == 'sim2022':
        trip = sim2022.read(files[SIM_VARIABLE], strict_time=strict_time)
    elif detected.vintage == 'sim2023':
        trip = sim2023.read(files[SIM_VARIABLE], strict_time=strict_time)
    elif detected.vintage == aas2021.FORMAT:
        assert map_path is not None or not landmarks
        trip = aas2021.read(files[aas2021.LOG_VARIABLE],
                            aas2021.read_map(map_path) if map_path is not None else None,
                            strict_time)
    else:
        # Said only where landmarks are wanted (convert): a calibration never uses them.
        if map_path is None and landmarks:
            log.warning('%s: no map (MapMTRN4010.mat) given or found beside the 2016 log; '
                        'converting without landmarks', files[project2016.IMU_VARIABLE].name)
        trip = project2016.read(
            files[project2016.IMU_VARIABLE], files[project2016.SPEED_VARIABLE],
            files[project2016.LASER_VARIABLE],
            aas2021.read_map(map_path) if map_path is not None else None, strict_time)
    if map_path is not None and detected.vintage.startswith('sim'):
        log.warning('%s: a simulated log carries its own map; ignoring %s',
                    files[SIM_VARIABLE].name, map_path.name)
    if not landmarks:
        trip = dataclasses.replace(trip, landmarks=None)
    log.info('%s: %s log, %d IMU samples, %d scans', trip.name, detected.vintage,
             len(trip.imu.stamp_s), sum(len(s.stamp_s) for s in trip.scans))
    return trip
