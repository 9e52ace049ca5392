"""estimates.csv and the estimates bag written while `gyro-ekf run` filters.

Both are built from the run's rows in time order (`results.EstimatesCsv`,
`results.EstimatesBag`), so they need not wait for the run's end. ``StreamedProducts``
holds the run's estimate arrays (drive_trip's ``into``) in memory it shares with a forked
child where a core is free; as drive_trip's ``on_rows`` it tells the child how many rows
are final (and hands it the updates applied since), and the child writes them while the
run goes on; ``finish`` waits for it to close both. On the 2016 log that takes the outputs'
0.15-0.19 s after the run down to the child's last block, and no row is copied. Where no
core is free (or no fork) the same writer runs in this process, block by block: the same
bytes either way (tests compare them with write_estimates_csv and write_estimates_bag).

Failure: an error of the child (disk full, read-only) is raised here as it was raised
there (an OutputError naming the file), at the next block or at ``finish``; nothing is
moved into place unless ``finish`` returns, and ``abort`` (or leaving the ``with`` block
on an exception) stops and reaps the child and drops what it wrote.
"""

from __future__ import annotations

import mmap
import os
from pathlib import Path
import pickle
import signal
import struct
from types import TracebackType
from typing import Any

import numpy as np

from gyro_ekf.core.trip_run import (Estimates, UpdateLog, corrected_yaw_rate,
                                    estimate_arrays, held_speed)
from gyro_ekf.core.types import ESTIMATE_SIZE, Trip
from gyro_ekf.io.errors import OutputError
from gyro_ekf.io.results import EstimatesBag, EstimatesCsv
from gyro_ekf.processes import spare_core, write_all

__all__ = ['StreamedProducts']

_FRAME = struct.Struct('<qqq')
"""A block: first row, end row (-1: the end of the run), updates; then the updates'
stamps, landmarks and points (float64; the landmarks int64). The rows themselves are in
the shared arrays."""

_SEND_ROWS = 2048
"""Rows announced at once. Each write wakes the child, and a woken child can take the CPU
the run was on for a few ms: on the 2016 log, a write every 256 rows cost the run 0.13 s."""

_CSV_ROWS = 4096  # rows formatted at once (see results._CSV_BLOCK_ROWS)
_ROW_FLOATS = 2 + ESTIMATE_SIZE * (1 + ESTIMATE_SIZE)  # stamp, state, covariance, wander


class _Writer:
    """The products from the rows as they become final: what the child (or this process) runs.

    ``estimates``: the run's arrays, read up to the rows announced.
    """

    def __init__(self, csv_path: Path, bag_path: Path | None, start_time_ns: int,
                 trip: Trip, storage: str, path_length: int | None,
                 estimates: Estimates) -> None:
        self.trip = trip
        self.estimates = estimates
        # One row per IMU sample: the stamps and held speeds are known before the rows.
        self.stamp_s = np.asarray(trip.imu.stamp_s, dtype=np.float64)
        self.yaw_rate = np.zeros(len(self.stamp_s))
        self.rows = 0  # final rows
        self.csv_rows = 0  # rows in the CSV
        self.csv: EstimatesCsv | None = None
        self.bag: EstimatesBag | None = None
        try:
            self.csv = EstimatesCsv(csv_path)
            if bag_path is not None:
                self.bag = EstimatesBag(
                    bag_path, start_time_ns, self.stamp_s, estimates.state,
                    estimates.covariance, held_speed(trip.speed, self.stamp_s),
                    self.yaw_rate, storage, trip=trip, path_length=path_length)
        except BaseException:
            self.abort()
            raise

    def add(self, start: int, stop: int, updates: UpdateLog) -> None:
        rows = slice(start, stop)
        if start != self.rows or stop > len(self.stamp_s) or not np.array_equal(
                self.estimates.stamp_s[rows], self.stamp_s[rows]):
            raise OutputError(f'{self.trip.name}: estimate rows {start}-{stop} out of step '
                              f'with the trip\'s IMU samples (a fault of gyro-ekf)')
        self.yaw_rate[rows] = corrected_yaw_rate(
            self.trip.imu.yaw_rate_rad_s[rows], self.estimates.state[rows],
            self.estimates.wander_rad_s[rows])
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
        rows = slice(self.csv_rows, stop)
        self.csv.add(self.stamp_s[rows], self.estimates.state[rows],
                     self.estimates.covariance[rows])
        self.csv_rows = stop


class StreamedProducts:
    """estimates.csv and (optionally) the estimates bag, written from the run's rows.

    Args:
        csv_path: estimates.csv's path.
        bag_path: the estimates bag's folder, or None for none.
        start_time_ns, storage, path_length: as results.write_estimates_bag.
        trip: the run's inputs (one estimate row per IMU sample; mounts, map, truth).

    Use as a context manager; pass ``estimates`` as drive_trip's (run_trip's) ``into`` and
    the instance as its ``on_rows``; call ``finish`` after the run.

    Raises (construction, each block, finish):
        OutputError: a product could not be written (the child's own error), or the rows
            are not in ``estimates``.
    """

    def __init__(self, csv_path: Path, bag_path: Path | None, start_time_ns: int,
                 trip: Trip, storage: str = 'mcap', path_length: int | None = None) -> None:
        """Start the writer: a forked child where a core is free, else in this process."""
        n = len(trip.imu.stamp_s)
        self._local: _Writer | None = None
        self._pid: int | None = None
        self._rows = self._errors = -1
        self._held: list[bytes] = []  # blocks not announced yet
        self._held_rows = 0
        child = spare_core()
        # The run's rows, in memory the child sees as the run writes them.
        self.estimates = estimate_arrays(n, mmap.mmap(-1, max(8 * _ROW_FLOATS * n, 1))
                                         if child else None)
        arguments = (Path(csv_path), None if bag_path is None else Path(bag_path),
                     int(start_time_ns), trip, storage, path_length, self.estimates)
        if child:
            rows_read, rows_write = os.pipe()
            errors_read, errors_write = os.pipe()
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
        """Take the next block of final rows (in ``estimates``) and the updates since."""
        if not np.may_share_memory(estimates.state, self.estimates.state):
            raise OutputError('streamed products: the run\'s rows are not in its arrays '
                              '(run_trip(into=products.estimates))')
        stop = start + len(estimates.stamp_s)
        if self._local is not None:
            self._local.add(start, stop, updates)
            return
        stamp_s = np.ascontiguousarray(updates.stamp_s, dtype=np.float64)
        self._held.append(b''.join((
            _FRAME.pack(start, stop, len(stamp_s)), stamp_s.tobytes(),
            np.ascontiguousarray(updates.landmark, dtype=np.int64).tobytes(),
            np.ascontiguousarray(updates.point_map_m, dtype=np.float64).tobytes())))
        self._held_rows += stop - start
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
        try:
            write_all(self._rows, data)
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
                start, stop, updates = _FRAME.unpack(_read(pipe, _FRAME.size))
                if stop < 0:
                    writer.finish()
                    writer = None
                    code = 0
                    break
                writer.add(start, stop, _updates(_read(pipe, 8 * 4 * updates), updates))
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
                write_all(errors, data)
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


def _updates(body: bytes, count: int) -> UpdateLog:
    stamp_s, landmark, point_map = np.split(np.frombuffer(body, dtype=np.float64),
                                            [count, 2 * count])
    return UpdateLog(stamp_s=stamp_s, landmark=landmark.view(np.int64),
                     point_map_m=point_map.reshape(count, 2), nis=np.zeros(count))
