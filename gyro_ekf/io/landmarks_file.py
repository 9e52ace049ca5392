"""Read a landmark map file: the EKF node's `landmarks_file` parameter.

Two layouts, picked by the file name:

- `.yaml` / `.yml`: a mapping with `landmarks: [[x, y], ...]`;
- anything else: text, one landmark per line, `x y` or `x, y`; blank lines and lines
  starting with `#` are skipped.

Coordinates are in m in the `map` frame. Every error names the file and, where it has one,
the landmark (YAML: its index) or the line (text: its number, from 1), and says what was
expected; each coordinate is checked against `core.config.InputLimits` like any other value
entering the core.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import yaml

from gyro_ekf.core.config import InputLimits
from gyro_ekf.core.types import LandmarkMap
from gyro_ekf.core.validation import coordinate_problem, LIMITS
from gyro_ekf.errors import one_line
from gyro_ekf.io.errors import LandmarksFileError

__all__ = ['read_landmarks_file', 'read_landmarks_text']

YAML_SUFFIXES = ('.yaml', '.yml')


def _number(value: Any) -> float | None:
    if isinstance(value, str):
        # PyYAML reads 1e3 (no dot, no sign in the exponent) as text; numpy took it, so do we.
        try:
            return float(value)
        except ValueError:
            return None
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return None
    return float(value)


def _yaml_rows(text: str, source: str) -> list[tuple[str, Any]]:
    try:
        document = yaml.safe_load(text)
    except yaml.YAMLError as err:
        raise LandmarksFileError(f'{source}: not valid YAML: {one_line(err)}') from None
    if not isinstance(document, dict) or 'landmarks' not in document:
        raise LandmarksFileError(f"{source}: expected a mapping with 'landmarks: [[x, y], "
                                 f"...]' (m), found {type(document).__name__}")
    rows = document['landmarks']
    if not isinstance(rows, list):
        raise LandmarksFileError(f"{source}: 'landmarks' must be a list of [x, y] pairs (m), "
                                 f'found {type(rows).__name__}')
    return [(f'landmark {index}', row) for index, row in enumerate(rows)]


def _text_rows(text: str) -> list[tuple[str, Any]]:
    rows = []
    for number, line in enumerate(text.splitlines(), start=1):
        stripped = line.strip()
        if not stripped or stripped.startswith('#'):
            continue
        fields = stripped.replace(',', ' ').split()
        rows.append((f'line {number}', fields))
    return rows


def read_landmarks_text(text: str, source: str, yaml_layout: bool,
                        limits: InputLimits = LIMITS) -> LandmarkMap:
    """Parse landmark map text (see the module docstring).

    Args:
        text: the file's text.
        source: file name for the error messages.
        yaml_layout: the YAML layout, else x y text.
        limits: the coordinate limits.

    Raises:
        LandmarksFileError: bad layout, not (x, y) pairs, non-finite or out-of-range
            coordinates, or no landmark at all.
    """
    rows = _yaml_rows(text, source) if yaml_layout else _text_rows(text)
    if not rows:
        raise LandmarksFileError(f'{source}: holds no landmarks; expected '
                                 + ("'landmarks: [[x, y], ...]'" if yaml_layout
                                    else "one 'x y' per line") + ' (m)')
    points = []
    for where, row in rows:
        pair = [_number(v) for v in row] if isinstance(row, (list, tuple)) else []
        if len(pair) != 2 or None in pair:
            raise LandmarksFileError(f'{source}: {where}: expected two numbers x y (m), got '
                                     f'{row!r}')
        problem = coordinate_problem(pair, limits)  # NaN and inf too, saying which
        if problem:
            raise LandmarksFileError(f'{source}: {where}: {problem}')
        points.append(pair)
    return LandmarkMap(np.array(points, dtype=np.float64))


def read_landmarks_file(path: Path | str, limits: InputLimits = LIMITS) -> LandmarkMap:
    """Read a landmark map file (see the module docstring).

    Raises:
        LandmarksFileError: missing or unreadable, binary (not UTF-8 text, or NUL bytes),
            or bad content; the message names the file.
    """
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as err:
        raise LandmarksFileError(f'{path}: cannot read the landmarks file: '
                                 f'{err.strerror or err}') from None
    nul = data.find(b'\0')
    if nul >= 0:  # valid UTF-8, but no text file holds one
        raise LandmarksFileError(f'{path}: binary data (NUL byte at offset {nul}): not a '
                                 'landmarks file (YAML or x y text)')
    try:
        text = data.decode('utf-8')
    except UnicodeDecodeError as err:
        raise LandmarksFileError(f'{path}: not UTF-8 text (byte at offset {err.start}): not '
                                 'a landmarks file (YAML or x y text)') from None
    return read_landmarks_text(text, str(path), path.suffix.lower() in YAML_SUFFIXES, limits)
