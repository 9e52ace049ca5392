"""estimates.csv and the estimates bag written while `gyro-ekf run` filters.

Both are built from the run's rows in time order (`results.EstimatesCsv`,
`results.EstimatesBag`), so they need not wait for the run's end: passed as drive_trip's
``on_rows``, ``StreamedProducts`` hands each block of final rows (and the updates applied
since the last) to a forked child where a core is free, which writes them while the run
goes on; ``finish`` waits for the child to close both. On the 2016 log that takes the
outputs' 0.15-0.19 s after the run down to the child's last block. Where no core is free
(or no fork) the same writer runs in this process, block by block: the same bytes either
way (tests compare them with write_estimates_csv and write_estimates_bag).

Failure: an error of the child (disk full, read-only) is raised here as it was raised
there (an OutputError naming the file), at the next block or at ``finish``; nothing is
moved into place unless ``finish`` returns, and ``abort`` (or leaving the ``with`` block
on an exception) stops and reaps the child and drops what it wrote.
"""

from __future__ import annotations

import fcntl
import os
from pathlib import Path
import pickle
import signal
import struct
from types import TracebackType
from typing import Any

import numpy as np

from gyro_ekf.core.trip_run import Estimates, UpdateLog, corrected_yaw_rate, held_speed
from gyro_ekf.core.types import ESTIMATE_SIZE, Trip
from gyro_ekf.io.errors import OutputError
from gyro_ekf.io.results import EstimatesBag, EstimatesCsv
from gyro_ekf.processes import spare_core

__all__ = ['StreamedProducts']

_FRAME = struct.Struct('<qqq')
"""A block: first row, rows, updates (rows -1: the end); then the rows' stamps, states,
covariances and wanders and the updates' stamps, landmarks and points, as float64 (the
landmarks int64)."""

_PIPE_BYTES = 1 << 20
_SEND_ROWS = 2048
"""Rows sent at once. Each write wakes the child, and a woken child can take the CPU the run
was on for a few ms: on the 2016 log, a send every 256 rows cost the run 0.13 s."""
_CSV_ROWS = 4096  # rows formatted at once (see results._CSV_BLOCK_ROWS)


class _Writer:
    """The products from the rows as they come: what the child (or this process) runs."""

    def __init__(self, csv_path: Path, bag_path: Path | None, start_time_ns: int,
                 trip: Trip, storage: str, path_length: int | None) -> None:
        self.trip = trip
        # One row per IMU sample: the stamps and held speeds are known before the rows.
        self.stamp_s = np.asarray(trip.imu.stamp_s, dtype=np.float64)
        n = len(self.stamp_s)
        self.state = np.zeros((n, ESTIMATE_SIZE))
        self.covariance = np.zeros((n, ESTIMATE_SIZE, ESTIMATE_SIZE))
        self.yaw_rate = np.zeros(n)
        self.rows = 0  # final rows
        self.csv_rows = 0  # rows in the CSV
        self.csv: EstimatesCsv | None = None
        self.bag: EstimatesBag | None = None
        try:
            self.csv = EstimatesCsv(csv_path)
            if bag_path is not None:
                self.bag = EstimatesBag(
                    bag_path, start_time_ns, self.stamp_s, self.state, self.covariance,
                    held_speed(trip.speed, self.stamp_s), self.yaw_rate, storage, trip=trip,
                    path_length=path_length)
        except BaseException:
            self.abort()
            raise

    def add(self, start: int, estimates: Estimates, updates: UpdateLog) -> None:
        stop = start + len(estimates.stamp_s)
        if start != self.rows or stop > len(self.stamp_s) or not np.array_equal(
                estimates.stamp_s, self.stamp_s[start:stop]):
            raise OutputError(f'{self.trip.name}: estimate rows {start}-{stop} out of step '
                              f'with the trip\'s IMU samples (a fault of gyro-ekf)')
        self.state[start:stop] = estimates.state
        self.covariance[start:stop] = estimates.covariance
        self.yaw_rate[start:stop] = corrected_yaw_rate(
            self.trip.imu.yaw_rate_rad_s[start:stop], estimates.state, estimates.wander_rad_s)
        self.rows = stop
        if stop - self.csv_rows >= _CSV_ROWS:
            self._csv_until(stop)
        if self.bag is not None:
            self.bag.add_updates(updates)
            self.bag.advance(stop)

    def finish(self) -> None:
        if self.rows != len(self.stamp_s):
            raise OutputError(f'{self.trip.name}: {self.rows} estimate rows of '
                              f'{len(self.stamp_s)} (a fault of gyro-ekf)')
        self._csv_until(self.rows)
        assert self.csv is not None
        self.csv.close()
        if self.bag is not None:
            self.bag.close()

    def abort(self) -> None:
        if self.csv is not None:
            self.csv.abort()
        if self.bag is not None:
            self.bag.abort()

    def _csv_until(self, stop: int) -> None:
        assert self.csv is not None
        block = slice(self.csv_rows, stop)
        self.csv.add(self.stamp_s[block], self.state[block], self.covariance[block])
        self.csv_rows = stop


class StreamedProducts:
    """estimates.csv and (optionally) the estimates bag, written from the run's rows.

    Args:
        csv_path: estimates.csv's path.
        bag_path: the estimates bag's folder, or None for none.
        start_time_ns, storage, path_length: as results.write_estimates_bag.
        trip: the run's inputs (one estimate row per IMU sample; mounts, map, truth).

    Use as a context manager and as drive_trip's ``on_rows``; call ``finish`` after the
    run.

    Raises (construction, each block, finish):
        OutputError: a product could not be written (the child's own error).
    """

    def __init__(self, csv_path: Path, bag_path: Path | None, start_time_ns: int,
                 trip: Trip, storage: str = 'mcap', path_length: int | None = None) -> None:
        """Start the writer: a forked child where a core is free, else in this process."""
        arguments = (Path(csv_path), None if bag_path is None else Path(bag_path),
                     int(start_time_ns), trip, storage, path_length)
        self._local: _Writer | None = None
        self._pid: int | None = None
        self._rows = self._errors = -1
        self._held: list[bytes] = []  # blocks not sent yet
        self._held_rows = 0
        if spare_core():
            rows_read, rows_write = os.pipe()
            errors_read, errors_write = os.pipe()
            try:
                fcntl.fcntl(rows_write, getattr(fcntl, 'F_SETPIPE_SZ', 1031), _PIPE_BYTES)
            except OSError:
                pass
            try:
                pid = os.fork()
            except OSError:
                for fd in (rows_read, rows_write, errors_read, errors_write):
                    os.close(fd)
            else:
                if pid == 0:
                    os.close(rows_write)
                    os.close(errors_read)
                    _serve(arguments, rows_read, errors_write)  # never returns
                os.close(rows_read)
                os.close(errors_write)
                self._pid, self._rows, self._errors = pid, rows_write, errors_read
                return
        self._local = _Writer(*arguments)

    def __call__(self, start: int, estimates: Estimates, updates: UpdateLog) -> None:
        """Take the next block of final rows and the updates applied since the last."""
        if self._local is not None:
            self._local.add(start, estimates, updates)
            return
        stamp_s = np.ascontiguousarray(updates.stamp_s, dtype=np.float64)
        self._held.append(b''.join((
            _FRAME.pack(start, len(estimates.stamp_s), len(stamp_s)),
            np.ascontiguousarray(estimates.stamp_s, dtype=np.float64).tobytes(),
            np.ascontiguousarray(estimates.state, dtype=np.float64).tobytes(),
            np.ascontiguousarray(estimates.covariance, dtype=np.float64).tobytes(),
            np.ascontiguousarray(estimates.wander_rad_s, dtype=np.float64).tobytes(),
            stamp_s.tobytes(),
            np.ascontiguousarray(updates.landmark, dtype=np.int64).tobytes(),
            np.ascontiguousarray(updates.point_map_m, dtype=np.float64).tobytes())))
        self._held_rows += len(estimates.stamp_s)
        if self._held_rows >= _SEND_ROWS:
            self._send_held()

    def _send_held(self) -> None:
        held, self._held, self._held_rows = self._held, [], 0
        self._send(b''.join(held))

    def finish(self) -> None:
        """Write the rest and move both products into place (all rows given)."""
        if self._local is not None:
            local, self._local = self._local, None
            try:
                local.finish()
            except BaseException:
                local.abort()
                raise
            return
        self._held.append(_FRAME.pack(0, -1, 0))
        self._send_held()
        os.close(self._rows)
        self._rows = -1
        self._reap(wait=True)

    def abort(self) -> None:
        """Stop the writer and drop what it wrote (idempotent)."""
        if self._local is not None:
            local, self._local = self._local, None
            local.abort()
        if self._rows >= 0:
            os.close(self._rows)
            self._rows = -1
        if self._pid is not None:
            # Its pipe closed before the end, the child drops its staged files and leaves.
            self._reap(wait=False)

    def _send(self, data: bytes) -> None:
        view = memoryview(data)
        try:
            while view:
                view = view[os.write(self._rows, view):]
        except BrokenPipeError:
            os.close(self._rows)
            self._rows = -1
            self._reap(wait=True)  # raises the child's error

    def _reap(self, wait: bool) -> None:
        """Collect the child's error and status; raise what went wrong there."""
        assert self._pid is not None
        with os.fdopen(self._errors, 'rb') as pipe:
            self._errors = -1
            error = pipe.read() if wait else b''
        _, status = os.waitpid(self._pid, 0)
        self._pid = None
        code = os.waitstatus_to_exitcode(status)
        if wait and code != 0:
            if error:
                raise pickle.loads(error) from None
            raise OutputError(f'cannot write the estimates: the process writing them ended '
                              f'with status {code}')

    def __enter__(self) -> StreamedProducts:
        """Return this instance (the writer runs from construction)."""
        return self

    def __exit__(self, kind: type[BaseException] | None, error: BaseException | None,
                 trace: TracebackType | None) -> None:
        """Abort unless finished (an exception, or finish never called)."""
        self.abort()


def _serve(arguments: tuple[Any, ...], rows: int, errors: int) -> None:
    """Write the products from the blocks on the pipe (the child), then leave."""
    code = 1
    writer: _Writer | None = None
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent handles Ctrl-C, then aborts
    try:
        with os.fdopen(rows, 'rb') as pipe:
            writer = _Writer(*arguments)
            while True:
                start, count, updates = _FRAME.unpack(_read(pipe, _FRAME.size))
                if count < 0:
                    writer.finish()
                    writer = None
                    code = 0
                    break
                body = _read(pipe, 8 * (count * (2 + ESTIMATE_SIZE * (1 + ESTIMATE_SIZE))
                                        + updates * 4))
                writer.add(start, *_unpack(body, count, updates))
    except BaseException as err:  # noqa: BLE001 (raised again by the parent)
        if writer is not None:
            try:
                writer.abort()
            except BaseException:  # noqa: BLE001 (the error that stopped it is the one to say)
                pass
        if not isinstance(err, _Stop):
            try:
                data = pickle.dumps(err)
            except Exception:  # noqa: BLE001 (an error that does not pickle)
                data = pickle.dumps(OutputError(f'cannot write the estimates: {err}'))
            try:
                os.write(errors, data)
            except OSError:
                pass
    finally:
        os._exit(code)


class _Stop(Exception):
    """The parent went away before the end (an abort, or it died)."""


def _read(pipe: Any, size: int) -> bytes:
    data = pipe.read(size)
    if len(data) < size:
        raise _Stop()  # the parent went away before the end: nothing is moved into place
    return data


def _unpack(body: bytes, count: int, updates: int) -> tuple[Estimates, UpdateLog]:
    values = np.frombuffer(body, dtype=np.float64)
    sizes = [count, count * ESTIMATE_SIZE, count * ESTIMATE_SIZE ** 2, count, updates,
             updates, 2 * updates]
    parts = np.split(values, np.cumsum(sizes)[:-1])
    estimates = Estimates(parts[0], parts[1].reshape(count, ESTIMATE_SIZE),
                          parts[2].reshape(count, ESTIMATE_SIZE, ESTIMATE_SIZE), parts[3])
    log = UpdateLog(stamp_s=parts[4], landmark=parts[5].view(np.int64),
                    point_map_m=parts[6].reshape(updates, 2), nis=np.zeros(updates))
    return estimates, log
