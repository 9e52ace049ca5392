"""Decode and encode many CDR messages of one fixed-layout type at once with numpy.

rosbags deserialises one message at a time in Python, which costs a few microseconds per
message; the sensor topics of a bag hold hundreds of thousands of them. Imu, Odometry and
LaserScan have a layout that is fixed once the lengths of their strings and sequences are
known, and those are almost always the same for every message of a topic. So the messages
of a batch are laid side by side as rows of a uint8 matrix, grouped by their layout, and
each requested field is read as a column slice viewed as its little-endian dtype: the same
bytes rosbags reads, so the values are bit-identical.

CDR (XCDR1, as rosbag2 stores it): a 4-byte encapsulation header (`00 01` = little endian),
then the body; every primitive is aligned to its size counted from the body's start; a
string is a uint32 length (including the NUL) and its bytes; a sequence is a uint32 count
and its elements. Messages that are not little-endian CDR are decoded with rosbags and
re-serialised little endian first; malformed messages are handed to rosbags, whose error
is reported.

Encoding goes the other way (`CdrTemplate`): rosbags serialises one template message, whose
strings and sequence lengths fix the layout; its bytes are repeated once per row and the
numeric fields are overwritten column by column, giving the bytes rosbags would give for
each row's message.
"""

from __future__ import annotations

from collections.abc import Collection, Sequence
from dataclasses import dataclass
import struct
from typing import Any

import numpy as np
from numpy.typing import NDArray
from rosbags.serde import SerdeError

from gyro_ekf import topics

__all__ = ['CdrDecodeError', 'CdrTemplate', 'Columns', 'DECODE_FAILURES', 'Field', 'LAYOUTS',
           'decode_columns']

_HEADER_BYTES = 4
_LITTLE_ENDIAN = b'\x00\x01'
_MAX_TRAILING_BYTES = 3
"""Padding rosbags accepts after the last field (rmw implementations pad to 4 bytes)."""

DECODE_FAILURES: tuple[type[Exception], ...] = (
    SerdeError, ValueError, LookupError, struct.error, OverflowError, MemoryError, TypeError,
    AttributeError, AssertionError)
"""What rosbags' deserialisation raises on malformed bytes (each read is bounded by them,
so a MemoryError means a length it tried to trust)."""

_PRIMITIVES = {'f8': np.dtype('<f8'), 'f4': np.dtype('<f4'), 'i4': np.dtype('<i4'),
               'u4': np.dtype('<u4')}


class CdrDecodeError(ValueError):
    """A message of a batch cannot be decoded.

    Attributes:
        index: position of the message in the batch, or None when the whole call is wrong.
        reason: what is wrong with it.
    """

    def __init__(self, reason: str, index: int | None = None) -> None:
        """Say why, and which message of the batch (if one is to blame)."""
        super().__init__(reason if index is None else f'message {index} of the batch: {reason}')
        self.index = index
        self.reason = reason


@dataclass(frozen=True, slots=True)
class Field:
    """One entry of a message layout, in serialisation order.

    Attributes:
        name: dotted path of the field ('angular_velocity', 'header.stamp.sec').
        kind: 'f8', 'f4', 'i4' or 'u4' (count consecutive primitives), 'string', or
            'seq_f4' (a sequence of float32).
        count: number of primitives for the fixed kinds.
    """

    name: str
    kind: str
    count: int = 1


_HEADER = (Field('header.stamp.sec', 'i4'), Field('header.stamp.nanosec', 'u4'),
           Field('header.frame_id', 'string'))
_POSE_WITH_COVARIANCE = (Field('pose.pose.position', 'f8', 3),
                         Field('pose.pose.orientation', 'f8', 4),
                         Field('pose.covariance', 'f8', 36))
_TWIST_WITH_COVARIANCE = (Field('twist.twist.linear', 'f8', 3),
                          Field('twist.twist.angular', 'f8', 3),
                          Field('twist.covariance', 'f8', 36))

LAYOUTS: dict[str, tuple[Field, ...]] = {
    topics.IMU_TYPE: (*_HEADER, Field('orientation', 'f8', 4),
                      Field('orientation_covariance', 'f8', 9),
                      Field('angular_velocity', 'f8', 3),
                      Field('angular_velocity_covariance', 'f8', 9),
                      Field('linear_acceleration', 'f8', 3),
                      Field('linear_acceleration_covariance', 'f8', 9)),
    topics.ODOMETRY_TYPE: (*_HEADER, Field('child_frame_id', 'string'),
                           *_POSE_WITH_COVARIANCE, *_TWIST_WITH_COVARIANCE),
    topics.POSE_WITH_COVARIANCE_STAMPED_TYPE: (*_HEADER, *_POSE_WITH_COVARIANCE),
    topics.VECTOR3_STAMPED_TYPE: (*_HEADER, Field('vector', 'f8', 3)),
    topics.LASER_SCAN_TYPE: (*_HEADER, Field('angle_min', 'f4'), Field('angle_max', 'f4'),
                             Field('angle_increment', 'f4'), Field('time_increment', 'f4'),
                             Field('scan_time', 'f4'), Field('range_min', 'f4'),
                             Field('range_max', 'f4'), Field('ranges', 'seq_f4'),
                             Field('intensities', 'seq_f4')),
}
"""Layouts of the message types with a fast path (Jazzy definitions)."""


@dataclass(frozen=True, slots=True)
class Columns:
    """Requested fields of a batch of n messages, rows in batch order.

    Attributes:
        values: field name -> array. Fixed fields: shape (n,) for one primitive, else
            (n, count). Sequences: shape (n, k) when every message has k elements; a
            sequence whose length varies is left out (see counts).
        counts: sequence field name -> element count per message, shape (n,).
    """

    values: dict[str, NDArray[Any]]
    counts: dict[str, NDArray[np.int64]]


def _align(offset: NDArray[np.int64], size: int) -> NDArray[np.int64]:
    return (offset + (size - 1)) // size * size


def _read_u32(block: NDArray[np.uint8], column: NDArray[np.int64]) -> NDArray[np.int64]:
    """Read a little-endian uint32 per row at per-row byte columns (all in bounds).

    Rows shorter than 4 bytes are all malformed (the caller marks them); they read 0.
    """
    if block.shape[1] < 4:
        return np.zeros(block.shape[0], dtype=np.int64)
    picked = block[np.arange(block.shape[0])[:, None], column[:, None] + np.arange(4)]
    return np.ascontiguousarray(picked).view('<u4')[:, 0].astype(np.int64)


def _walk(block: NDArray[np.uint8], layout: Sequence[Field]
          ) -> tuple[dict[str, NDArray[np.int64]], NDArray[np.int64], NDArray[np.bool_]]:
    """Find every field's byte column per row of a block of equal-length messages.

    Returns:
        Column of each field (for a string or sequence: of its length word), the lengths
        of the strings and sequences as an (m, v) key, and which rows are malformed.
    """
    m, length = block.shape
    offset = np.zeros(m, dtype=np.int64)
    bad = np.zeros(m, dtype=np.bool_)
    columns: dict[str, NDArray[np.int64]] = {}
    keys = []
    for field in layout:
        if field.kind in _PRIMITIVES:
            size = _PRIMITIVES[field.kind].itemsize
            offset = _align(offset, size)
            columns[field.name] = offset + _HEADER_BYTES
            offset = offset + size * field.count
            continue
        offset = _align(offset, 4)
        column = offset + _HEADER_BYTES
        bad |= column + 4 > length
        columns[field.name] = column
        count = _read_u32(block, np.where(bad, 0, column))
        count[bad] = 0
        keys.append(count)
        offset = offset + 4 + (count if field.kind == 'string' else 4 * count)
        bad |= offset + _HEADER_BYTES > length
    spare = length - _HEADER_BYTES - offset
    bad |= (spare < 0) | (spare > _MAX_TRAILING_BYTES)
    key = np.stack(keys, axis=1) if keys else np.zeros((m, 0), dtype=np.int64)
    return columns, key, bad


def _canonical(data: bytes | memoryview, msgtype: str, typestore: Any) -> bytes:
    """Little-endian CDR of a message via rosbags (raises SerdeError if it is malformed)."""
    message = typestore.deserialize_cdr(data, msgtype)
    return bytes(typestore.serialize_cdr(message, msgtype, little_endian=True))


def decode_columns(datas: Sequence[bytes | memoryview], msgtype: str,
                   fields: Collection[str], typestore: Any) -> Columns:
    """Decode the named fields of a batch of CDR messages of one type.

    Args:
        datas: the raw messages (with their 4-byte encapsulation header), n of them.
        msgtype: one of LAYOUTS, e.g. 'sensor_msgs/msg/Imu'.
        fields: names of primitive or sequence fields of the layout to return.
        typestore: rosbags typestore of the type (for messages off the fast path).

    Returns:
        The values and sequence counts, rows in the order of datas.

    Raises:
        CdrDecodeError: a message does not decode (the text gives its index in the batch),
            or the type or a field has no fast path.
    """
    if msgtype not in LAYOUTS:
        raise CdrDecodeError(f'no fast CDR layout for {msgtype}')
    layout = LAYOUTS[msgtype]
    unknown = sorted(set(fields) - {f.name for f in layout if f.kind != 'string'})
    if unknown:
        raise CdrDecodeError(f'{msgtype} has no numeric field {unknown[0]!r}')
    datas = list(datas)
    for i, data in enumerate(datas):
        if bytes(data[:2]) != _LITTLE_ENDIAN:
            datas[i] = _rosbags_bytes(data, msgtype, typestore, i)
    batch = _Batch(datas, layout, list(fields))
    malformed = batch.decode()
    if malformed:
        # What the walk rejects goes through rosbags, which raises or returns the canonical
        # little-endian form; the second pass must then accept it.
        for i in malformed:
            datas[i] = _rosbags_bytes(datas[i], msgtype, typestore, i)
        batch = _Batch(datas, layout, list(fields))
        malformed = batch.decode()
        if malformed:
            raise CdrDecodeError('layout not understood', malformed[0])
    return batch.columns()


class _Batch:
    """Decoding state of one call of decode_columns."""

    def __init__(self, datas: list[bytes | memoryview], layout: Sequence[Field],
                 fields: list[str]) -> None:
        self.datas = datas
        self.fields = fields
        self.layout = layout
        self.by_name = {f.name: f for f in layout}
        self.n = len(datas)
        self.values: dict[str, NDArray[Any]] = {}
        self.counts = {name: np.zeros(self.n, dtype=np.int64) for name in fields
                       if self.by_name[name].kind == 'seq_f4'}
        self.seq_width: dict[str, int | None] = {}

    def decode(self) -> list[int]:
        """Fill values and counts; return the indices of malformed messages (then stop)."""
        n = self.n
        lengths = np.fromiter(map(len, self.datas), dtype=np.int64, count=n)
        unique_lengths = np.unique(lengths)
        for length in unique_lengths.tolist():
            if len(unique_lengths) == 1:
                rows = None
                joined = b''.join(self.datas)
                m = n
            else:
                rows = np.flatnonzero(lengths == length)
                joined = b''.join([self.datas[i] for i in rows.tolist()])
                m = len(rows)
            block = np.frombuffer(joined, dtype=np.uint8).reshape(m, length)
            columns, key, bad = _walk(block, self.layout)
            if bad.any():
                picked = np.flatnonzero(bad)
                return (picked if rows is None else rows[picked]).tolist()
            if key.shape[1] and not (key == key[0]).all():
                _, group_of = np.unique(key, axis=0, return_inverse=True)
                group_of = group_of.ravel()
                groups: list[NDArray[np.int64] | None] = [
                    np.flatnonzero(group_of == g) for g in range(int(group_of.max()) + 1)]
            else:
                groups = [None]
            for group in groups:
                if group is None:
                    sub, first, target = block, 0, rows
                else:
                    sub, first = block[group], int(group[0])
                    target = group if rows is None else rows[group]
                self._extract(sub, {k: int(v[first]) for k, v in columns.items()},
                              block[first], slice(None) if target is None else target)
        return []

    def _extract(self, sub: NDArray[np.uint8], columns: dict[str, int],
                 first_row: NDArray[np.uint8], target: Any) -> None:
        """Copy the requested fields of rows sharing one layout into the outputs."""
        for name in self.fields:
            field = self.by_name[name]
            column = columns[name]
            if field.kind == 'seq_f4':
                width = int(first_row[column:column + 4].view('<u4')[0])
                self.counts[name][target] = width
                if self.seq_width.setdefault(name, width) != width:
                    self.seq_width[name] = None
                if self.seq_width[name] is None:
                    self.values.pop(name, None)
                    continue
                dtype, count, column = _PRIMITIVES['f4'], width, column + 4
            else:
                dtype, count = _PRIMITIVES[field.kind], field.count
            part = sub[:, column:column + dtype.itemsize * count].view(dtype)
            if name not in self.values:
                self.values[name] = np.empty((self.n, count), dtype=dtype)
            self.values[name][target] = part

    def columns(self) -> Columns:
        """Return the decoded fields, single primitives as shape (n,)."""
        values = {}
        for name in self.fields:
            field = self.by_name[name]
            if field.kind == 'seq_f4':
                if self.n == 0:
                    values[name] = np.empty((0, 0), dtype=_PRIMITIVES['f4'])
                elif name in self.values:
                    values[name] = self.values[name]
                continue
            array = self.values.get(name)
            if array is None:
                array = np.empty((0, field.count), dtype=_PRIMITIVES[field.kind])
            values[name] = array[:, 0] if field.count == 1 else array
        return Columns(values, self.counts)


def _rosbags_bytes(data: bytes | memoryview, msgtype: str, typestore: Any, index: int
                   ) -> bytes:
    try:
        return _canonical(data, msgtype, typestore)
    except DECODE_FAILURES as err:
        raise CdrDecodeError(str(err) or type(err).__name__, index) from None


class CdrTemplate:
    """Little-endian CDR bytes of one message, repeated per row with patched numbers.

    Attributes:
        msgtype: the message type, one of LAYOUTS.
        data: the template's CDR bytes (rosbags' serialisation).
    """

    def __init__(self, message: Any, msgtype: str, typestore: Any) -> None:
        """Serialise the template with rosbags and locate its fields.

        Raises:
            CdrDecodeError: the type has no layout.
        """
        if msgtype not in LAYOUTS:
            raise CdrDecodeError(f'no fast CDR layout for {msgtype}')
        self.msgtype = msgtype
        self.data = bytes(typestore.serialize_cdr(message, msgtype, little_endian=True))
        self._fields = {f.name: f for f in LAYOUTS[msgtype]}
        row = np.frombuffer(self.data, dtype=np.uint8).reshape(1, -1)
        columns, _, bad = _walk(row, LAYOUTS[msgtype])
        assert not bad.any(), 'rosbags serialised a message the layout does not describe'
        self._columns = {name: int(column[0]) for name, column in columns.items()}

    @property
    def size(self) -> int:
        """Bytes per message."""
        return len(self.data)

    def rows(self, n: int) -> NDArray[np.uint8]:
        """Return n copies of the template, shape (n, size), to patch and write."""
        return np.tile(np.frombuffer(self.data, dtype=np.uint8), (n, 1))

    def set(self, rows: NDArray[np.uint8], name: str, values: Any, first: int = 0) -> None:
        """Overwrite a primitive field (or elements first.. of an array field) in every row.

        Args:
            rows: from `rows`, shape (n, size).
            name: field of the layout, e.g. 'pose.pose.orientation'.
            values: shape (n,) or (n, k) (or broadcastable), converted to the field's dtype.
            first: index of the first element of the field to overwrite.

        Raises:
            CdrDecodeError: not a primitive field, or the elements run past its end.
        """
        field = self._fields.get(name)
        if field is None or field.kind not in _PRIMITIVES:
            raise CdrDecodeError(f'{self.msgtype} has no primitive field {name!r}')
        dtype = _PRIMITIVES[field.kind]
        values = np.asarray(values)
        count = 1 if values.ndim < 2 else values.shape[1]
        if first < 0 or first + count > field.count:
            raise CdrDecodeError(f'{self.msgtype}.{name} has {field.count} elements, not '
                                 f'{first + count}')
        start = self._columns[name] + first * dtype.itemsize
        target = rows[:, start:start + count * dtype.itemsize].view(dtype)
        target[...] = values.reshape(-1, count) if values.ndim else values
