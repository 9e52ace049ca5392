"""The offline batch run: every event of a trip through one EventDriver, history as arrays.

`drive_trip` is what `gyro-ekf run` (analysis.offline) runs: the trip's events in driver
order (`iter_trip_events`, computed once on compact arrays), LiDAR detection a block of
scans at a time (`ScanDetector`: it does not depend on the filter, so `gyro-ekf run` has a
child find the blocks ahead, analysis.detect_ahead), and the estimates kept as the filter's
packed rows, copied into arrays a block at a time, so a long trip holds no Python object
per sample.
"""

from __future__ import annotations

from array import array
from collections.abc import Callable, Iterator
from dataclasses import dataclass
import math
from typing import Any

import numpy as np
from numpy.typing import NDArray

from gyro_ekf.core.body_frame import Shift, shift_estimates
from gyro_ekf.core.config import DetectorConfig
from gyro_ekf.core.detection import detect_poles_in_scans
from gyro_ekf.core.ekf import PACKED_ROW_SIZE, unpack_rows
from gyro_ekf.core.event_records import DriverStats, EventKind
from gyro_ekf.core.events import EventDriver
from gyro_ekf.core.health import HealthMonitor
from gyro_ekf.core.mount_online import OnlineMounts
from gyro_ekf.core.odometry_online import OdometryTracker
from gyro_ekf.core.models import points_less_range, points_upright, sensor_points_to_map
from gyro_ekf.core.types import (BIAS, ESTIMATE_SIZE, WANDER, FloatArray, ScanSeries,
                                 SpeedSeries, Trip)

__all__ = ['DETECTION_RETURNS', 'Estimates', 'ROW_BLOCK', 'ScanDetector', 'TripRun', 'UpdateLog',
           'corrected_yaw_rate', 'drive_trip', 'estimate_arrays', 'held_speed',
           'iter_trip_events']

DETECTION_RETURNS = 50_000
"""Beams per detection batch of drive_trip: the whole scans that hold this many (at least one).

Batches amortise numpy's per-call cost; this size keeps each float64 temporary of the
detector near 400 kB. At 1.5 MB (512 scans of the 2016 log's 361 beams) the allocator gave
them back to the system after every batch and took them again, one page fault per 4 kB:
23k faults and about 40 ms of system time in that log's run (now some 3k)."""


ROW_BLOCK = 256
"""Estimates drive_trip holds as plain floats before copying them into its arrays.

Few enough that their floats are still in the CPU's cache when copied: the 2016 log's
44.6k rows took 25 ms to copy in blocks of 4096 rows, 10 ms in blocks of 256."""


def iter_trip_events(trip: Trip, block: int = 65_536
                     ) -> Iterator[tuple[float, EventKind, int, int]]:
    """All events of a trip in driver order: (stamp_s, kind, series index, sample index).

    The series index picks the ScanSeries for observations (0 otherwise). The order is
    computed once on compact arrays and handed out in blocks, so a long trip never holds
    a Python object per event.
    """
    stamps = [trip.speed.stamp_s, trip.imu.stamp_s] + [s.stamp_s for s in trip.scans]
    kinds = [EventKind.SPEED, EventKind.IMU] + [EventKind.OBSERVATION] * len(trip.scans)
    series = [0, 0] + list(range(len(trip.scans)))
    all_stamps = np.concatenate(stamps)
    all_kinds = np.concatenate([np.full(len(s), int(k), dtype=np.int8)
                                for s, k in zip(stamps, kinds)])
    all_series = np.concatenate([np.full(len(s), i, dtype=np.int16)
                                 for s, i in zip(stamps, series)])
    all_index = np.concatenate([np.arange(len(s), dtype=np.int32) for s in stamps])
    order = np.lexsort((all_index, all_series, all_kinds, all_stamps))
    kinds_by_value = [EventKind(k) for k in range(len(EventKind))]
    for begin in range(0, order.size, block):
        part = order[begin:begin + block]
        # tolist() per block: element-wise numpy scalar access would dominate the loop.
        yield from zip(all_stamps[part].tolist(),
                       [kinds_by_value[k] for k in all_kinds[part].tolist()],
                       all_series[part].tolist(), all_index[part].tolist())


def estimate_arrays(n: int, buffer: Any = None) -> Estimates:
    """Arrays for n estimate rows (not yet filled), in buffer when given (>= 22 n float64).

    Raises:
        ValueError: buffer is too small.
    """
    shapes = [(n,), (n, ESTIMATE_SIZE), (n, ESTIMATE_SIZE, ESTIMATE_SIZE), (n,)]
    if buffer is None:
        return Estimates(*(np.empty(shape) for shape in shapes))
    arrays, offset = [], 0
    for shape in shapes:
        count = math.prod(shape)
        arrays.append(np.frombuffer(buffer, dtype=np.float64, count=count,
                                    offset=offset).reshape(shape))
        offset += 8 * count
    return Estimates(*arrays)


def held_speed(speed: SpeedSeries, stamp_s: FloatArray) -> FloatArray:
    """Odometry speed held at each stamp (its last sample at or before), m/s; 0 before any."""
    stamp_s = np.asarray(stamp_s, dtype=np.float64)
    if not len(speed.stamp_s):
        return np.zeros(len(stamp_s))
    held = np.searchsorted(speed.stamp_s, stamp_s, side='right') - 1
    out = np.asarray(speed.speed_m_s[np.maximum(held, 0)], dtype=np.float64)
    out[held < 0] = 0.0
    return out


def corrected_yaw_rate(measured_rad_s: FloatArray, state: FloatArray,
                       wander_rad_s: FloatArray) -> FloatArray:
    """Return the rate the heading moved by: measured less the bias and the wander, rad/s.

    Args:
        measured_rad_s: the gyro's yaw rate at each estimate row, shape (n,).
        state: the rows' states, shape (n, 4); wander_rad_s: their wander, shape (n,).
    """
    return np.asarray(measured_rad_s - state[:, BIAS] - wander_rad_s, dtype=np.float64)


class ScanDetector:
    """Pole detection of a trip's scans, a block of scans at a time, as drive_trip needs it.

    Detection does not depend on the filter, so a whole block is found in one call (numpy's
    per-call cost amortised, see DETECTION_RETURNS). Blocks are fixed: block k of a LiDAR
    holds its scans [k b, (k + 1) b), b = ``block_sizes[series]``, and drive_trip asks for
    each when it reaches its first scan; ``order`` lists them in that order, which lets
    another process find them ahead of the run (analysis.detect_ahead).
    """

    def __init__(self, trip: Trip, config: DetectorConfig) -> None:
        """Keep the trip's scans and the detector's configuration."""
        self.scans = trip.scans
        self.config = config
        self.block_sizes = [max(1, DETECTION_RETURNS // max(len(scan.angles_rad), 1))
                            for scan in trip.scans]

    def block(self, series: int, begin: int) -> list[FloatArray]:
        """Pole centres (sensor frame, shape (k, 2), m) of each scan of the block at begin."""
        scan: ScanSeries = self.scans[series]
        stop = min(begin + self.block_sizes[series], len(scan.stamp_s))
        found = detect_poles_in_scans(
            scan.ranges_m[begin:stop], scan.angles_rad,
            None if scan.intensities is None else scan.intensities[begin:stop], self.config)
        points = [poles.points_sensor_m for poles in found]
        if scan.upside_down:
            # Mounted upside down (the params file's upside_down), as the node takes it.
            points = [points_upright(p) for p in points]
        if scan.range_offset_m:
            # A LiDAR that reads long (the params file's range_offset_m), as the node does.
            points = [points_less_range(p, scan.range_offset_m) for p in points]
        return points

    def order(self) -> list[tuple[int, int]]:
        """(series, first scan) of every block, in the order drive_trip first needs them.

        The order of their first scans' events in iter_trip_events: by stamp, then series.
        """
        firsts = [(series, np.arange(0, len(scan.stamp_s), self.block_sizes[series]))
                  for series, scan in enumerate(self.scans)]
        if not firsts:
            return []
        stamps = np.concatenate([self.scans[series].stamp_s[index] for series, index in firsts])
        series = np.concatenate([np.full(len(index), series) for series, index in firsts])
        index = np.concatenate([index for _, index in firsts])
        order = np.lexsort((index, series, stamps))
        return list(zip(series[order].tolist(), index[order].tolist()))


@dataclass(frozen=True, slots=True)
class Estimates:
    """History of a run: one row per IMU sample.

    Attributes:
        stamp_s: shape (n,), s.
        state: shape (n, 4): x m, y m, yaw rad, bias rad/s.
        covariance: shape (n, 4, 4).
        wander_rad_s: the filter's fifth state, the gyro's wander (core/gyro_wander.py), at
            each row, shape (n,), rad/s: 0 unless a wander was found. The yaw-rate error the
            filter takes out is the bias plus it.
    """

    stamp_s: FloatArray
    state: FloatArray
    covariance: FloatArray
    wander_rad_s: FloatArray


@dataclass(frozen=True, slots=True)
class UpdateLog:
    """Every landmark update applied during a run, in time order.

    Attributes:
        stamp_s: scan stamp of each update, shape (m,), s.
        landmark: index of the landmark in the map, shape (m,).
        point_map_m: the detection placed in the map at the prior pose, shape (m, 2), m.
        nis: normalised innovation squared of each update, shape (m,).
    """

    stamp_s: FloatArray
    landmark: NDArray[np.int64]
    point_map_m: FloatArray
    nis: FloatArray


@dataclass(frozen=True, slots=True)
class TripRun:
    """Result of driving the filter through a whole trip.

    Attributes:
        estimates: one row per IMU sample.
        updates: the applied landmark updates (compact: a long trip keeps no per-scan
            objects).
        stats: final counts.
        health: the per-LiDAR health figures, exclusions and readmissions.
        mounts: the online mount estimates of every LiDAR but the first.
        odometry: the online odometry speed-scale estimate (core/odometry_online.py).
        noise: each LiDAR's measured noise at the end (EventDriver.noise_report).
        held_start: the start pose held until the platform moved (EventDriver
            .held_start_report, core/held_start.py).
        gyro_scale: the gyro's scale measured against the LiDARs' heading
            (GyroScaleWatch.report, core/gyro_scale.py).
        input_loss: per input ('gyro', 'odometry'), the samples received and those its
            stamps imply were lost (InputLoss.report, core/input_loss.py).
        time_offsets: each LiDAR's stamps against the gyro's (EventDriver
            .time_offset_report, core/time_offset.py).
        input_spikes: per input ('gyro', 'odometry'), the lone samples far from both
            neighbours that were left out (SpikeGate.report, core/input_spikes.py).
        stamp_jitter: each LiDAR's stamps' scatter about when its scans were taken
            (EventDriver.stamp_jitter_report, core/stamp_jitter.py).
        map_poles: the mapped poles found to stand elsewhere (EventDriver
            .map_poles_report, core/map_poles.py).
        turn_signs: per LiDAR, whether its scans turn the way the gyro does (EventDriver
            .turn_sign_report, core/turn_sign.py).
        gyro_frozen: the gyro's runs of one repeated value, their repeats left out
            (FrozenWatch.report, core/input_frozen.py).
        scan_loss: per LiDAR (its name), the scans received and those its stamps imply
            were lost (InputLoss.report).
        rest_turns: the stops whose poles turned while zero-rate updates held them still
            (EventDriver.rest_turn_report, core/rest_turn.py).
    """

    estimates: Estimates
    updates: UpdateLog
    stats: DriverStats
    health: HealthMonitor | None = None
    mounts: OnlineMounts | None = None
    odometry: OdometryTracker | None = None
    noise: list[dict] | None = None
    held_start: dict | None = None
    gyro_scale: dict | None = None
    input_loss: dict | None = None
    time_offsets: list[dict] | None = None
    input_spikes: dict | None = None
    stamp_jitter: list[dict] | None = None
    map_poles: list[dict] | None = None
    turn_signs: list[dict] | None = None
    gyro_frozen: dict | None = None
    scan_loss: dict | None = None
    rest_turns: list[dict] | None = None


def _variances(values: FloatArray | None, n: int) -> list[float | None]:
    if values is None:
        return [None] * n
    return [None if math.isnan(v) else v for v in np.asarray(values, dtype=np.float64).tolist()]


def drive_trip(trip: Trip, driver: EventDriver,
               progress: Callable[[int], None] | None = None,
               detections: Callable[[int, int], list[FloatArray]] | None = None,
               on_rows: Callable[[int, Estimates, UpdateLog], None] | None = None,
               into: Estimates | None = None) -> TripRun:
    """Run every event of a trip through a driver and collect the history.

    Args:
        trip: the inputs; trip.landmarks is used when the driver has no map.
        driver: a fresh driver (its pose is the filter's start); the mounts of every LiDAR
            but the first are estimated online (EventDriver.track_mounts).
        progress: called with the number of events processed since the last call.
        detections: (series, first scan) -> the pole centres of each scan of that block,
            as ``ScanDetector(trip, driver.detector_config).block`` gives them (the
            default), asked for in ``ScanDetector.order``.
        on_rows: called as rows become final, in time order: (first row, those rows'
            estimates (views of the run's arrays, valid during the call), the updates
            applied since the last call). By then every update stamped up to the last of
            those rows is in (a scan sorts before an IMU sample of its stamp). Lets a
            caller write the products while the run goes on (io.streamed_products).
        into: the arrays to fill with the estimates (``estimate_arrays``; e.g. memory a
            writer process shares), else new ones.
    """
    if detections is None:
        detections = ScanDetector(trip, driver.detector_config).block
    if driver.landmarks is None:
        driver.landmarks = trip.landmarks
    # A LiDAR stated at the first one's mount shares its key (health, rest counts): untracked.
    driver.track_mounts((scan.mount, scan.topic) for scan in trip.scans[1:]
                        if scan.mount != trip.scans[0].mount)
    driver.mount_yaw_sigmas.update((scan.mount, scan.yaw_sigma_rad) for scan in trip.scans
                                   if scan.yaw_sigma_rad)
    n = len(trip.imu.stamp_s)
    arrays = estimate_arrays(n) if into is None else into
    if len(arrays.stamp_s) != n:
        raise ValueError(f'into: {len(arrays.stamp_s)} rows for {n} IMU samples')
    stamps, states = arrays.stamp_s, arrays.state
    covariances, wanders = arrays.covariance, arrays.wander_rad_s
    # array('d') keeps 8 bytes per value while a long trip accumulates updates.
    update_stamp, update_landmark = array('d'), array('q')
    update_x, update_y, update_nis = array('d'), array('d'), array('d')
    # Plain floats, converted once: a numpy scalar read per event costs more than the read.
    yaw_rates = trip.imu.yaw_rate_rad_s.tolist()
    speeds = trip.speed.speed_m_s.tolist()
    # Each message's own variance where the trip has one (NaN: not given), else None: the
    # configured noise. Lists of floats and None, read once per event.
    rate_variances = _variances(trip.imu.yaw_rate_variance, len(yaw_rates))
    speed_variances = _variances(trip.speed.speed_variance, len(speeds))
    detected: dict[int, tuple[int, list[FloatArray]]] = {}
    row = 0
    processed = 0
    # Rows are kept as plain floats and copied into the arrays a block at a time: two
    # small arrays per IMU step would cost more than the filter step itself. One flat list
    # of them end to end: np.array reads it faster than a list of rows.
    pending: list[float] = []
    pending_stamps: list[float] = []  # their stamps, likewise
    packed_row = driver.ekf.packed_row
    sent_updates = 0  # updates handed to on_rows
    # The two LiDARs' mixture (core/body_frame.py) as it changes at scans: (first row, its
    # shift), the last one holding on; estimate() reports the same.
    shifts: list[tuple[int, Shift | None]] = [(0, None)]

    def flush(last: bool = False) -> None:
        nonlocal sent_updates
        start = row - len(pending) // PACKED_ROW_SIZE
        if pending:
            stamps[start:row] = pending_stamps
            pending_stamps.clear()
            rows, full = unpack_rows(pending)
            states[start:row] = rows[:, :ESTIMATE_SIZE]
            wanders[start:row] = rows[:, WANDER]
            covariances[start:row] = full[:, :ESTIMATE_SIZE, :ESTIMATE_SIZE]
            pending.clear()
            for k, (first, shift) in enumerate(shifts):
                end = shifts[k + 1][0] if k + 1 < len(shifts) else row
                if shift is not None and end > start and first < row:
                    rows_of = slice(max(first, start), end)
                    shift_estimates(states[rows_of], covariances[rows_of], shift)
            del shifts[:-1]
        if on_rows is not None and (start < row or last):
            on_rows(start, Estimates(stamps[start:row], states[start:row],
                                     covariances[start:row], wanders[start:row]),
                    updates_since(sent_updates))
            sent_updates = len(update_stamp)

    def updates_since(first: int) -> UpdateLog:
        return UpdateLog(stamp_s=np.array(update_stamp[first:], dtype=np.float64),
                         landmark=np.array(update_landmark[first:], dtype=np.int64),
                         point_map_m=np.column_stack([update_x[first:], update_y[first:]])
                         if len(update_x) > first else np.zeros((0, 2)),
                         nis=np.array(update_nis[first:], dtype=np.float64))

    # Enum members looked up once: EventKind.IMU costs a class attribute lookup per event.
    imu, speed = EventKind.IMU, EventKind.SPEED
    # Bound once, likewise: two attribute look-ups per sample add up over 89 000 samples.
    step_imu, on_speed = driver.step_imu, driver.on_speed
    keep_row, keep_stamp = pending.extend, pending_stamps.append
    for stamp_s, kind, series, index in iter_trip_events(trip):
        if kind is imu:
            step_imu(stamp_s, yaw_rates[index], rate_variances[index])
            keep_stamp(stamp_s)
            keep_row(packed_row())
            row += 1
            if row % ROW_BLOCK == 0:
                flush()
        elif kind is speed:
            on_speed(stamp_s, speeds[index], speed_variances[index])
        else:
            scan: ScanSeries = trip.scans[series]
            begin, found = detected.get(series, (0, []))
            if not begin <= index < begin + len(found):
                # Detection does not depend on the filter: a block of scans at once.
                begin, found = index, detections(series, index)
                detected[series] = (begin, found)
            report = driver.on_detections(stamp_s, found[index - begin], scan.mount,
                                          scan.topic)
            if driver.frame_shift != shifts[-1][1]:
                shifts.append((row, driver.frame_shift))
            if report.nis.size:
                # Plain floats and the associations themselves: an index array of the
                # pairs and a row of the points per update cost more than the maths.
                matched = report.association.matched()
                update_stamp.extend([stamp_s] * len(matched))
                points = report.points_sensor_m.tolist()
                for match, (px, py) in zip(matched, sensor_points_to_map(
                        report.prior_state.tolist(),
                        [points[match.detection_index] for match in matched], report.mount)):
                    update_landmark.append(match.landmark_index)
                    update_x.append(px)
                    update_y.append(py)
                update_nis.extend(report.nis.tolist())
        processed += 1
        if progress is not None and processed % 10_000 == 0:
            progress(10_000)
    flush(last=True)  # (the updates after the last IMU sample too)
    if progress is not None:
        progress(processed % 10_000)
    updates = UpdateLog(
        stamp_s=np.frombuffer(update_stamp, dtype=np.float64),
        landmark=np.frombuffer(update_landmark, dtype=np.int64),
        point_map_m=np.column_stack([np.frombuffer(update_x, dtype=np.float64),
                                     np.frombuffer(update_y, dtype=np.float64)]),
        nis=np.frombuffer(update_nis, dtype=np.float64))
    return TripRun(Estimates(stamps, states, covariances, wanders), updates, driver.stats,
                   driver.health, driver.mounts, driver.odometry, driver.noise_report(),
                   driver.held_start_report(), driver.gyro_scale.report(),
                   {name: loss.report() for name, loss in driver.input_loss.items()},
                   driver.time_offset_report(),
                   {name: gate.report() for name, gate in driver.input_spikes.items()},
                   driver.stamp_jitter_report(), driver.map_poles_report(),
                   driver.turn_sign_report(), driver.gyro_frozen.report(),
                   {name: loss.report() for name, loss in driver.scan_loss.items()},
                   driver.rest_turn_report())
