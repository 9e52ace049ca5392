"""One entry point for every input `gyro-ekf convert` accepts: course logs and trip files."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from gyro_ekf.core.types import Trip
from gyro_ekf.io import trip_file
from gyro_ekf.io.errors import LogFormatError
from gyro_ekf.io.matlab import load_course_log


def load_log(paths: Sequence[Path | str], map_path: Path | str | None = None) -> Trip:
    """Read a course log (.mat files or their folder) or a simulator trip file (.npz).

    Args:
        paths: the log's files or folder; or exactly one trip file (or a folder holding
            one trip file and no .mat files).
        map_path: the landmark map (MapMTRN4010.mat) for the 2016/2021 logs, when it is not
            among `paths` or beside them.

    Returns:
        The trip.

    Raises:
        LogFormatError: anything load_course_log or load_trip refuses, or a trip file mixed
            with other inputs.
    """
    inputs = [Path(p) for p in paths]
    if not inputs:
        raise LogFormatError('no input given; expected course log .mat files or a trip .npz')
    expanded: list[Path] = []
    for path in inputs:
        if path.is_dir() and not any(path.glob('*.mat')):
            expanded += sorted(path.glob('*' + trip_file.SUFFIX))
        else:
            expanded.append(path)
    trips = [p for p in expanded if p.suffix == trip_file.SUFFIX]
    if trips:
        if len(expanded) != 1 or map_path is not None:
            raise LogFormatError(
                f'{trips[0].name}: a trip file carries everything itself; give it alone')
        return trip_file.load_trip(trips[0])
    return load_course_log(inputs + ([Path(map_path)] if map_path is not None else []))
