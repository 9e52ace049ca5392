"""Pole detection ahead of the run, in a forked child where a core is free (`gyro-ekf run`).

Detection does not depend on the filter (core.trip_run.ScanDetector), so while the run
filters one block of scans a child can already find the poles of the next ones: on the
2016 log that takes 0.09 s of the run's 1.1 s off the critical path. The child runs the
same ``ScanDetector.block`` in ``ScanDetector.order`` and hands each block over a pipe as
raw float64 (the same numbers, to the bit); the run takes them as it reaches them.

The child is only a shortcut: when it cannot be started (no fork, one usable core), dies
or falls out of step, every block from then on is found in the run's own process, so a
failure of the child never changes a result or fails a run. A detection error is raised
by the run's own call of ``ScanDetector.block``, as without the child.
"""

from __future__ import annotations

import fcntl
import logging
import os
import signal
import struct
from types import TracebackType
from typing import BinaryIO

import numpy as np

from gyro_ekf.core.trip_run import ScanDetector
from gyro_ekf.core.types import FloatArray
from gyro_ekf.processes import spare_core, write_all

__all__ = ['DetectionsAhead', 'MIN_BLOCKS']

log = logging.getLogger(__name__)

MIN_BLOCKS = 4
"""Fewer blocks than this are found in the run's own process: a fork costs some 10 ms."""

_HEADER = struct.Struct('<iiii')
"""Each block: series, first scan, scans, poles; then the scans' pole counts (int32) and
the poles' sensor-frame centres (float64, x y per pole)."""

_PIPE_BYTES = 1 << 20
"""Pipe capacity asked for (Linux), so the child can run several blocks ahead."""


class DetectionsAhead:
    """``ScanDetector.block`` answered by a child that detects ahead (see the module).

    Use as a context manager (the child is reaped on exit, whatever happened) and pass
    the instance as drive_trip's ``detections``.
    """

    def __init__(self, detector: ScanDetector) -> None:
        """Start the child where a core is free and the trip has blocks enough."""
        self._detector = detector
        self._pid: int | None = None
        self._pipe: BinaryIO | None = None
        order = detector.order()
        if len(order) < MIN_BLOCKS or not spare_core():
            return
        read_end, write_end = os.pipe()
        try:
            fcntl.fcntl(write_end, getattr(fcntl, 'F_SETPIPE_SZ', 1031), _PIPE_BYTES)
        except OSError:
            pass  # the default capacity: the child keeps fewer blocks ahead
        try:
            pid = os.fork()
        except OSError:
            os.close(read_end)
            os.close(write_end)
            return
        if pid == 0:
            os.close(read_end)
            _detect(detector, order, write_end)  # never returns
        os.close(write_end)
        self._pid = pid
        self._pipe = os.fdopen(read_end, 'rb')

    @property
    def ahead(self) -> bool:
        """Whether blocks still come from the child."""
        return self._pipe is not None

    def __call__(self, series: int, begin: int) -> list[FloatArray]:
        """Pole centres of each scan of the block (series, begin), as ScanDetector.block."""
        if self._pipe is not None:
            found = self._receive(series, begin)
            if found is not None:
                return found
            self.close()
        return self._detector.block(series, begin)

    def _receive(self, series: int, begin: int) -> list[FloatArray] | None:
        assert self._pipe is not None
        header = self._pipe.read(_HEADER.size)
        if len(header) < _HEADER.size:
            log.debug('pole detection ahead stopped (block %d of LiDAR %d)', begin, series)
            return None
        their_series, their_begin, scans, poles = _HEADER.unpack(header)
        body = bytearray(4 * scans + 16 * poles)  # writable, as the arrays found here are
        if self._pipe.readinto(body) < len(body) or (their_series, their_begin) != (
                series, begin):
            log.debug('pole detection ahead out of step at block %d of LiDAR %d',
                      begin, series)
            return None
        counts = np.frombuffer(body, dtype=np.int32, count=scans)
        points = np.frombuffer(body, dtype=np.float64, offset=4 * scans).reshape(-1, 2)
        return np.split(points, np.cumsum(counts[:-1]))

    def close(self) -> None:
        """Stop and reap the child (idempotent)."""
        if self._pipe is not None:
            self._pipe.close()
            self._pipe = None
        if self._pid is not None:
            try:
                os.kill(self._pid, signal.SIGKILL)  # done or not, it is not needed now
            except ProcessLookupError:
                pass
            os.waitpid(self._pid, 0)
            self._pid = None

    def __enter__(self) -> DetectionsAhead:
        """Return this instance (the child runs from construction)."""
        return self

    def __exit__(self, kind: type[BaseException] | None, error: BaseException | None,
                 trace: TracebackType | None) -> None:
        """Stop and reap the child."""
        self.close()


def _detect(detector: ScanDetector, order: list[tuple[int, int]], pipe: int) -> None:
    """Send every block down the pipe in order (the child), then leave without cleanup."""
    code = 1
    try:
        for series, begin in order:
            found = detector.block(series, begin)
            counts = np.array([len(points) for points in found], dtype=np.int32)
            points = (np.concatenate(found) if found else np.zeros((0, 2))).astype(
                np.float64, copy=False)
            write_all(pipe, b''.join((
                _HEADER.pack(series, begin, len(found), int(counts.sum())),
                counts.tobytes(), np.ascontiguousarray(points).tobytes())))
        code = 0
    except BaseException:  # noqa: BLE001 (the run finds the rest itself, and raises there)
        pass
    finally:
        os._exit(code)
