"""Helpers shared by the MATLAB course-log readers: loading, field access, checks, decoding.

Stamps in every course log are uint32 counts of 0.1 ms. Readers subtract the log's first
count in int64 (exact) and only then divide by 10 000, so a stamp in seconds is the correctly
rounded value of an exact count; the bag writer multiplies back to integer nanoseconds.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
import scipy.io

from gyro_ekf.io.errors import LogFormatError

COUNTS_PER_S = 10_000
"""Stamp resolution of every course log: one count is 0.1 ms."""

GRAVITY_M_S2 = 9.80665
"""Standard gravity, m/s^2, to turn accelerations in g into SI."""

COURSE_INITIAL_POSE = (0.0, 0.0, math.pi / 2.0)
"""Initial pose of the real 2016/2021 trip by course convention: x m, y m, heading rad."""


def load_mat(path: Path) -> dict[str, Any]:
    """Read a MATLAB v5 file as scipy does with squeeze_me and struct objects.

    Args:
        path: the .mat file.

    Returns:
        The variables of the file, without scipy's '__header__'-style entries.

    Raises:
        LogFormatError: the file is missing, truncated or not a MATLAB v5 file.
    """
    try:
        raw = scipy.io.loadmat(str(path), squeeze_me=True, struct_as_record=False)
    except FileNotFoundError:
        raise LogFormatError(f'{path}: no such file') from None
    except Exception as err:  # scipy raises ValueError, TypeError, OSError, zlib.error, ...
        raise LogFormatError(
            f'{path.name}: not a readable MATLAB v5 file (corrupt or truncated?): {err}'
        ) from err
    return {key: value for key, value in raw.items() if not key.startswith('__')}


def variable_names(path: Path) -> list[str]:
    """Names of the top-level variables of a .mat file, without reading their data.

    Raises:
        LogFormatError: the file is missing, truncated or not a MATLAB v5 file.
    """
    try:
        return [name for name, _, _ in scipy.io.whosmat(str(path))]
    except FileNotFoundError:
        raise LogFormatError(f'{path}: no such file') from None
    except Exception as err:
        raise LogFormatError(
            f'{path.name}: not a readable MATLAB v5 file (corrupt or truncated?): {err}'
        ) from err


def field(variables: dict[str, Any], dotted: str, path: Path) -> Any:
    """Get the value of a (nested) field such as 'data.verify.poseL'.

    Raises:
        LogFormatError: a part of the name is missing; the message names file and field.
    """
    parts = dotted.split('.')
    if parts[0] not in variables:
        raise LogFormatError(f"{path.name}: variable '{parts[0]}' is missing")
    value = variables[parts[0]]
    for depth, part in enumerate(parts[1:], start=2):
        if not hasattr(value, '_fieldnames') or part not in value._fieldnames:
            raise LogFormatError(
                f"{path.name}: field '{'.'.join(parts[:depth])}' is missing")
        value = getattr(value, part)
    return value


def has_field(variables: dict[str, Any], dotted: str) -> bool:
    """Whether a (nested) field such as 'data.LidarsCfg' exists."""
    parts = dotted.split('.')
    value = variables.get(parts[0])
    if value is None:
        return False
    for part in parts[1:]:
        if not hasattr(value, '_fieldnames') or part not in value._fieldnames:
            return False
        value = getattr(value, part)
    return True


def array(variables: dict[str, Any], dotted: str, path: Path, shape: Sequence[int | None],
          kind: str = 'iuf') -> NDArray[Any]:
    """Get a numeric array field with a checked shape.

    Args:
        variables: the file's variables (from load_mat).
        dotted: field name, e.g. 'data.vw'.
        path: the file, for messages.
        shape: expected shape; None is any length (the messages call it n, m, ...).
        kind: accepted numpy dtype kinds ('i' signed, 'u' unsigned, 'f' float).

    Returns:
        The array as stored (no copy, no conversion).

    Raises:
        LogFormatError: missing field, wrong type or shape, naming file and field.
    """
    value = np.asarray(field(variables, dotted, path))
    expected = '(' + ', '.join('n' if s is None else str(s) for s in shape) + \
        (',)' if len(shape) == 1 else ')')
    if value.dtype.kind not in kind:
        raise LogFormatError(
            f"{path.name}: field '{dotted}' has type {value.dtype}, expected numbers")
    if value.ndim != len(shape) or any(
            want is not None and got != want for got, want in zip(value.shape, shape)):
        raise LogFormatError(
            f"{path.name}: field '{dotted}' has shape {value.shape}, expected {expected}")
    return value


def scalar(variables: dict[str, Any], dotted: str, path: Path) -> float:
    """Get a numeric scalar field as float.

    Raises:
        LogFormatError: missing or not a single number.
    """
    value = np.asarray(field(variables, dotted, path))
    if value.size != 1 or value.dtype.kind not in 'iuf':
        raise LogFormatError(
            f"{path.name}: field '{dotted}' is {value.dtype} of shape {value.shape}, "
            'expected one number')
    return float(value.reshape(()))


def decimal(value: float | np.floating) -> float:
    """Turn a float32 field value into the float64 of its shortest decimal form.

    MATLAB logs store figures such as 0.08 m/s in single precision; this gives back 0.08
    (what the author typed), not 0.0799999982 (its float32 rounding).
    """
    if isinstance(value, np.float32):
        return float(str(value))
    return float(value)


def check_length(path: Path, dotted: str, length: int, other: str, expected: int) -> None:
    """Require two fields to agree in length.

    Raises:
        LogFormatError: e.g. "Speed_dataC.mat: field 'Vel.speeds' has 10 samples but
            'Vel.times' has 12".
    """
    if length != expected:
        raise LogFormatError(
            f"{path.name}: field '{dotted}' has {length} samples but '{other}' has {expected}")


def check_stamps(path: Path, dotted: str, counts: NDArray[Any], strict: bool = True) -> None:
    """Require stamps (counts of 0.1 ms) to be non-decreasing.

    With `strict` False nothing is checked here: `gyro-ekf convert --skip-bad` leaves time
    that goes back to the validation boundary, which drops the older samples and counts them.

    Raises:
        LogFormatError: names the field, the index and both values.
    """
    if not strict:
        return
    steps = np.diff(counts.astype(np.int64))
    if steps.size and steps.min() < 0:
        i = int(np.argmax(steps < 0))
        before, spike, after = (int(c) for c in counts[i - 1:i + 2]) if i > 0 else (0, 0, -1)
        if before <= after and 10 * (after - before) < spike - before:
            # One stamp far ahead of two close neighbours (a flipped bit): name that one.
            raise LogFormatError(
                f"{path.name}: field '{dotted}' jumps ahead at index {i} "
                f'({int(counts[i - 1])} -> {int(counts[i])} counts of 0.1 ms, '
                f'+{steps[i - 1] / COUNTS_PER_S:.4f} s) and back after it; expected '
                'non-decreasing stamps')
        raise LogFormatError(
            f"{path.name}: field '{dotted}' goes back in time at index {i + 1} "
            f'({int(counts[i])} -> {int(counts[i + 1])} counts of 0.1 ms, '
            f'{steps[i] / COUNTS_PER_S:.4f} s); expected non-decreasing stamps')


def stamps_s(counts: NDArray[Any], zero: int) -> NDArray[np.float64]:
    """Turn counts of 0.1 ms into float seconds since the count `zero`, exactly rounded.

    Args:
        counts: shape (n,), integer counts of 0.1 ms.
        zero: the log's first count.

    Returns:
        Shape (n,), s.
    """
    return (counts.astype(np.int64) - np.int64(zero)) / float(COUNTS_PER_S)


def check_whole(path: Path, dotted: str, values: NDArray[Any]) -> NDArray[np.float64]:
    """Refuse event indices or kinds that are not whole numbers; return them as float64.

    A float field can hold NaN, inf or 2.5, which integer conversion turns into an error
    or, worse, into another index.

    Raises:
        LogFormatError: names the field, the value and the event.
    """
    numbers = np.asarray(values, dtype=np.float64)
    with np.errstate(invalid='ignore'):
        whole = np.isfinite(numbers) & (numbers == np.round(numbers))
    if not whole.all():
        i = int(np.argmin(whole))
        raise LogFormatError(f"{path.name}: field '{dotted}' holds {numbers[i]} at event "
                             f'{i + 1}, not an index')
    return numbers


def check_indices(path: Path, dotted: str, indices: NDArray[Any], target: str,
                  size: int) -> NDArray[np.int64]:
    """Validate 1-based MATLAB indices into a field with `size` columns.

    Returns:
        The indices, 0-based, int64.

    Raises:
        LogFormatError: an index is not a whole number (NaN, inf, 2.5) or is out of range.
    """
    numbers = check_whole(path, dotted, indices)
    bad = (numbers < 1) | (numbers > size)
    if bad.any():
        i = int(np.argmax(bad))
        raise LogFormatError(
            f"{path.name}: field '{dotted}' holds index {int(indices[i])} at event {i + 1}, "
            f"but '{target}' has {size} columns")
    return indices.astype(np.int64) - 1


def decode_ranges(range_cm: NDArray[Any], no_return: NDArray[np.bool_]) -> NDArray[np.float32]:
    """Ranges in cm to float32 m with +inf where there is no return (REP-117).

    Args:
        range_cm: shape (m, beams), integer cm.
        no_return: shape (m, beams), True where the sensor saw nothing.

    Returns:
        Shape (m, beams), float32, m.
    """
    ranges = range_cm.astype(np.float32) / np.float32(100.0)
    ranges[no_return] = np.inf
    return ranges
