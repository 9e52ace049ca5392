"""Writers of the products of `gyro-ekf run`: estimates CSV, summary JSON, estimates bag.

Each builds its file (or bag folder) under a temporary name beside the target and renames it
into place (`output_dir.staged_file`), so an interrupted run never leaves a half-written
product; the folder they go into is `output_dir`'s. The CSV and the bag can also be written
as the rows come (`EstimatesCsv`, `EstimatesBag`): `gyro-ekf run` has a forked child write
them while it filters (io.streamed_products).
"""

from __future__ import annotations

from collections.abc import Iterator
import contextlib
import json
import logging
import math
import os
from pathlib import Path
import shutil
import tempfile
from typing import Any, TYPE_CHECKING

import numpy as np

from gyro_ekf import topics
from gyro_ekf.core.angles import quaternions_of_yaws
from gyro_ekf.core.stamps import NS_PER_S, ns_at, split_ns_array
from gyro_ekf.core.types import FloatArray
from gyro_ekf.io.errors import OutputError
from gyro_ekf.io.output_dir import staged_file
from gyro_ekf.io.products import os_reason

if TYPE_CHECKING:
    from gyro_ekf.core.trip_run import UpdateLog
    from gyro_ekf.core.types import Trip

log = logging.getLogger(__name__)

CSV_HEADER = ('t,x,y,yaw,bias,var_x,var_y,var_yaw,var_bias,cov_xy,cov_xyaw,cov_yyaw')
"""Columns of estimates.csv: s since the bag's first message, m, m, rad, rad/s, then the
variances m^2, m^2, rad^2, (rad/s)^2 and covariances m^2, m rad, m rad."""

_BAG_VERSION = 9
# Rows formatted at once. A block's temporaries (the floats as objects, the format, the
# text) take about 700 bytes a row: at 50k rows the allocator took them from the system
# and gave them back, 9k page faults and ~30 ms of system time for the 2016 log's CSV.
_CSV_BLOCK_ROWS = 4096
_BAG_BLOCK_ROWS = 1024
_INT32_MAX = 2**31 - 1


def estimates_table(stamp_s: FloatArray, state: FloatArray, covariance: FloatArray
                    ) -> FloatArray:
    """Build the rows of estimates.csv, shape (n, 12), in CSV_HEADER order.

    Args:
        stamp_s: shape (n,), s since the bag's first message.
        state: shape (n, 4): x m, y m, yaw rad, bias rad/s.
        covariance: shape (n, 4, 4).
    """
    P = np.asarray(covariance, dtype=np.float64)
    return np.column_stack([
        np.asarray(stamp_s, dtype=np.float64), np.asarray(state, dtype=np.float64),
        P[:, 0, 0], P[:, 1, 1], P[:, 2, 2], P[:, 3, 3], P[:, 0, 1], P[:, 0, 2], P[:, 1, 2]])


def write_estimates_csv(path: Path | str, stamp_s: FloatArray, state: FloatArray,
                        covariance: FloatArray) -> Path:
    """Write estimates.csv (header CSV_HEADER, SI units, one row per IMU step).

    Args:
        path: target file.
        stamp_s: shape (n,), s since the bag's first message.
        state: shape (n, 4): x m, y m, yaw rad, bias rad/s.
        covariance: shape (n, 4, 4).

    Returns:
        The path written.
    """
    csv = EstimatesCsv(path)
    try:
        csv.add(stamp_s, state, covariance)
        return csv.close()
    finally:
        csv.abort()


class EstimatesCsv:
    """estimates.csv written as its rows come (``add`` in time order, then ``close``).

    Staged beside the target and moved into place by close; ``abort`` drops it (after
    close: nothing). The same bytes as one call of write_estimates_csv.

    Raises (each method):
        OutputError: the file system refused a write (read-only, full), naming the file.
    """

    def __init__(self, path: Path | str) -> None:
        """Open the staged file and write the header."""
        self.path = Path(path)
        self._files = contextlib.ExitStack()
        staged = self._files.enter_context(staged_file(self.path))
        try:
            self._stream = self._files.enter_context(staged.open('w', encoding='ascii'))
            self._stream.write(CSV_HEADER + '\n')
        except OSError as err:
            self.abort()
            raise OutputError(f'{self.path}: cannot write: {os_reason(err)}') from None

    def add(self, stamp_s: FloatArray, state: FloatArray, covariance: FloatArray) -> None:
        """Write rows (shapes as write_estimates_csv's)."""
        count = len(stamp_s)
        # In blocks, so an hour-long trip never holds the whole (n, 12) table at once.
        row_format = ','.join(['%.9g'] * len(CSV_HEADER.split(','))) + '\n'
        try:
            for start in range(0, count, _CSV_BLOCK_ROWS):
                block = slice(start, min(start + _CSV_BLOCK_ROWS, count))
                table = estimates_table(stamp_s[block], state[block], covariance[block])
                # One format operation per block: what np.savetxt writes, without its
                # per-row Python loop.
                self._stream.write((row_format * len(table)) % tuple(table.ravel().tolist()))
        except OSError as err:
            self.abort()
            raise OutputError(f'{self.path}: cannot write: {os_reason(err)}') from None

    def close(self) -> Path:
        """Move the file into place."""
        files, self._files = self._files, contextlib.ExitStack()
        files.close()  # the stream, then staged_file's rename
        return self.path

    def abort(self) -> None:
        """Drop the staged file (idempotent)."""
        files, self._files = self._files, contextlib.ExitStack()
        # (Closing the stream on a full disk fails too: the staged file goes all the same.)
        with contextlib.suppress(Exception):
            files.__exit__(OutputError, OutputError(f'{self.path}: not written'), None)


def _json_ready(value: Any) -> Any:
    if isinstance(value, dict):
        return {str(k): _json_ready(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_json_ready(v) for v in value]
    if isinstance(value, np.ndarray):
        return _json_ready(value.tolist())
    if isinstance(value, (np.floating, float)):
        number = float(value)
        return number if math.isfinite(number) else None
    if isinstance(value, np.integer):
        return int(value)
    return value


def write_summary_json(path: Path | str, summary: dict[str, Any]) -> Path:
    """Write the summary as indented JSON; nan and inf become null (JSON has neither)."""
    path = Path(path)
    with staged_file(path) as staged:
        staged.write_text(json.dumps(_json_ready(summary), indent=2) + '\n', encoding='utf-8')
    return path


class _EstimateEncoder:
    """CDR bytes of the estimates bag's messages, many rows at a time.

    One template per topic is serialised by rosbags (frames and strings fixed, every number
    0); each row's stamp, pose, covariance, twist and bias are patched into a copy of it
    (`fast_cdr.CdrTemplate`), which yields the bytes rosbags gives for that row's message.
    """

    def __init__(self, imu_frame: str = topics.IMU_FRAME) -> None:
        from gyro_ekf.io import messages as msgs
        from gyro_ekf.io.fast_cdr import CdrTemplate

        pose = msgs.PoseWithCovariance(pose=_pose(msgs, 0.0, 0.0, 0.0),
                                       covariance=np.zeros(36))
        map_header = msgs.header(0, topics.MAP_FRAME)
        twist = msgs.TwistWithCovariance(
            twist=msgs.Twist(linear=msgs.Vector3(x=0.0, y=0.0, z=0.0),
                             angular=msgs.Vector3(x=0.0, y=0.0, z=0.0)),
            covariance=np.zeros(36))
        Vector3Stamped = msgs.TYPESTORE.types[topics.VECTOR3_STAMPED_TYPE]
        store = msgs.TYPESTORE
        self.pose = CdrTemplate(msgs.PoseWithCovarianceStamped(header=map_header, pose=pose),
                                topics.POSE_WITH_COVARIANCE_STAMPED_TYPE, store)
        self.odometry = CdrTemplate(
            msgs.Odometry(header=map_header, child_frame_id=topics.BASE_FRAME, pose=pose,
                          twist=twist), topics.ODOMETRY_TYPE, store)
        self.bias = CdrTemplate(
            Vector3Stamped(header=msgs.header(0, imu_frame),
                           vector=msgs.Vector3(x=0.0, y=0.0, z=0.0)),
            topics.VECTOR3_STAMPED_TYPE, store)

    def templates(self) -> list[tuple[str, Any]]:
        """Return (relative topic, template) in the order encode returns their bytes."""
        return [(topics.EKF_POSE, self.pose), (topics.EKF_ODOMETRY, self.odometry),
                (topics.EKF_BIAS, self.bias)]

    def encode(self, stamps_ns: Any, state: FloatArray, covariance: FloatArray,
               speed_m_s: FloatArray, yaw_rate_rad_s: FloatArray) -> list[np.ndarray]:
        """Encode m rows; return per topic one message per row, shape (m, bytes) uint8.

        Args:
            stamps_ns: shape (m,), int64 ns since the epoch, within int32 seconds.
            state: shape (m, 4); covariance: shape (m, 4, 4).
            speed_m_s, yaw_rate_rad_s: shape (m,).
        """
        sec, nanosec = split_ns_array(stamps_ns)
        quaternion_zw = quaternions_of_yaws(state[:, 2])
        # x, y, yaw of the state -> rows/columns 0, 1, 5 of the row-major 6x6.
        out = []
        for template in (self.pose, self.odometry):
            rows = template.rows(len(sec))
            template.set(rows, 'header.stamp.sec', sec)
            template.set(rows, 'header.stamp.nanosec', nanosec)
            template.set(rows, 'pose.pose.position', state[:, :2])
            template.set(rows, 'pose.pose.orientation', quaternion_zw, first=2)
            for i, row in enumerate((0, 1, 5)):
                template.set(rows, 'pose.covariance', covariance[:, i, 0:2], first=row * 6)
                template.set(rows, 'pose.covariance', covariance[:, i, 2], first=row * 6 + 5)
            if template is self.odometry:
                template.set(rows, 'twist.twist.linear', speed_m_s)
                template.set(rows, 'twist.twist.angular', yaw_rate_rad_s, first=2)
            out.append(rows)
        rows = self.bias.rows(len(sec))
        self.bias.set(rows, 'header.stamp.sec', sec)
        self.bias.set(rows, 'header.stamp.nanosec', nanosec)
        self.bias.set(rows, 'vector', state[:, 3], first=2)
        out.append(rows)
        return out


def _pose(msgs: Any, x_m: float, y_m: float, yaw_rad: float) -> Any:
    return msgs.Pose(position=msgs.Point(x=x_m, y=y_m, z=0.0),
                     orientation=msgs.yaw_quaternion(yaw_rad))


def write_estimates_bag(path: Path | str, start_time_ns: int, stamp_s: FloatArray,
                        state: FloatArray, covariance: FloatArray, speed_m_s: FloatArray,
                        yaw_rate_rad_s: FloatArray, storage: str = 'mcap', *,
                        trip: Trip | None = None, updates: UpdateLog | None = None,
                        path_length: int | None = None, visual: bool = True,
                        imu_frame: str = topics.IMU_FRAME) -> Path:
    """Write the EKF outputs as the live EKF node publishes them, one set per IMU step.

    Topics (frames per REP-105): `/ekf/pose` PoseWithCovarianceStamped in `map`;
    `/ekf/odometry` Odometry `map` -> `base_link` with the pose covariance and the held
    speed and bias-corrected yaw rate as twist; `/ekf/bias` Vector3Stamped in the IMU's frame
    (`imu_frame`: the input IMU's frame_id, `imu_link` by default; z = yaw-rate bias,
    rad/s). Pose covariances are 6x6 row-major over (x, y, z, roll, pitch, yaw); z, roll
    and pitch are not estimated and carry 0. Plus the visual topics
    of io.visual_bag (/tf, /tf_static, ekf/path, ekf/markers, landmark_markers): the
    latched ones first, then per block of rows the per-estimate topics, the block's /tf
    and its other visual messages (log times exact; MCAP readers order by log time).
    ``EstimatesBag`` writes the same bag while the rows are still coming.

    Args:
        path: the bag folder to create (must not exist).
        start_time_ns: bag stamp of t = 0, ns since the epoch.
        stamp_s: shape (n,), s since start_time_ns.
        state: shape (n, 4); covariance: shape (n, 4, 4).
        speed_m_s: held speed per row, shape (n,), m/s.
        yaw_rate_rad_s: bias-corrected yaw rate per row, shape (n,), rad/s.
        storage: 'mcap' or 'sqlite3'.
        trip: the run's inputs (LiDAR mounts, map, ground truth), or None.
        updates: the run's applied landmark updates, or None.
        path_length: most poses an ekf/path message holds (>= 1); None:
            visual_bag.PATH_LENGTH.
        visual: write the visual topics (False: only the three the live node publishes).
        imu_frame: frame of /ekf/bias and of the IMU in /tf_static (identity on base_link);
            '' means `imu_link`.

    Raises:
        OutputError: the bag folder exists or cannot be written, or path_length < 1.
    """
    bag = EstimatesBag(path, start_time_ns, stamp_s, state, covariance, speed_m_s,
                       yaw_rate_rad_s, storage, trip=trip, path_length=path_length,
                       visual=visual, imu_frame=imu_frame)
    try:
        if updates is not None:
            bag.add_updates(updates)
        return bag.close()
    finally:
        bag.abort()


class EstimatesBag:
    """``write_estimates_bag``'s bag, written as the rows become final (one writer).

    The arrays are the whole run's, filled in time order by the caller: ``advance(rows)``
    writes every block of rows that ends at or before ``rows`` once rows [0, rows) are
    final and ``add_updates`` has brought the updates stamped up to the last of them;
    ``close`` writes the rest (all rows final) and moves the bag into place; ``abort``
    drops it (after close: nothing). The same bytes as one call of write_estimates_bag.

    Raises (each method):
        OutputError: as write_estimates_bag.
    """

    def __init__(self, path: Path | str, start_time_ns: int, stamp_s: FloatArray,
                 state: FloatArray, covariance: FloatArray, speed_m_s: FloatArray,
                 yaw_rate_rad_s: FloatArray, storage: str = 'mcap', *,
                 trip: Trip | None = None, path_length: int | None = None,
                 visual: bool = True, imu_frame: str = topics.IMU_FRAME) -> None:
        """Open the bag and write its latched messages; see write_estimates_bag."""
        from rosbags.rosbag2 import StoragePlugin, Writer

        from gyro_ekf.io import visual_bag
        from gyro_ekf.io.visual_bag import VisualTopics
        from gyro_ekf.io import messages as msgs
        from gyro_ekf.io.bag_writer import LATCHED_QOS
        from gyro_ekf.io.batch_write import enable_chunk_crcs

        path = Path(path)
        if path.exists():
            raise OutputError(f'{path}: exists already')
        plugins = {'mcap': StoragePlugin.MCAP, 'sqlite3': StoragePlugin.SQLITE3}
        if storage not in plugins:
            raise OutputError(f'{path}: unknown storage {storage!r}; expected one of '
                              f'{sorted(plugins)}')
        self.path = path
        self._stamps_ns = stamps_ns = ns_at(start_time_ns, stamp_s)
        # (No copies: a caller streaming its rows fills these arrays while the bag is written.)
        self._state = state = np.asarray(state, dtype=np.float64)
        self._P = covariance = np.asarray(covariance, dtype=np.float64)
        self._speed = np.asarray(speed_m_s, dtype=np.float64)
        self._yaw_rate = np.asarray(yaw_rate_rad_s, dtype=np.float64)
        if len(stamps_ns) and (stamps_ns.min() < 0
                               or stamps_ns.max() // NS_PER_S > _INT32_MAX):
            raise OutputError(f'{path}: stamps outside builtin_interfaces/Time (int32 seconds)')
        self._encoder = _EstimateEncoder(imu_frame or topics.IMU_FRAME)
        self._shown = VisualTopics(start_time_ns, stamps_ns, state, covariance, trip, None,
                                   visual_bag.PATH_LENGTH if path_length is None
                                   else path_length, imu_frame or topics.IMU_FRAME)
        self._visual = visual
        self._written = 0  # rows written
        self._writer: Any = None
        try:
            self._aside = Path(tempfile.mkdtemp(prefix=f'.{path.name}.', suffix='.tmp',
                                                dir=path.parent))
        except OSError as err:
            raise OutputError(f'{path}: cannot write the estimates bag: '
                              f'{os_reason(err)}') from None
        with self._errors():
            self._writer = writer = Writer(self._aside / path.name, version=_BAG_VERSION,
                                           storage_plugin=plugins[storage])
            writer.open()
            enable_chunk_crcs(writer)
            self._connections = [
                writer.add_connection(topics.bag_topic(topic), template.msgtype,
                                      typestore=msgs.TYPESTORE)
                for topic, template in self._encoder.templates()]
            if visual:
                self._tf = writer.add_connection(visual_bag.TF, visual_bag.TF_TYPE,
                                                 typestore=msgs.TYPESTORE)
                self._sparse_connections = {visual_bag.TF: self._tf, **{
                    topic: writer.add_connection(topics.bag_topic(topic), msgtype,
                                                 typestore=msgs.TYPESTORE)
                    for topic, msgtype in ((visual_bag.EKF_PATH, visual_bag.PATH_TYPE),
                                           (visual_bag.EKF_MARKERS,
                                            visual_bag.MARKER_ARRAY_TYPE))}}
                for topic, msgtype, data in self._shown.latched():
                    latched = writer.add_connection(topics.bag_topic(topic), msgtype,
                                                    typestore=msgs.TYPESTORE,
                                                    offered_qos_profiles=[LATCHED_QOS])
                    writer.write(latched, int(start_time_ns), data)

    def add_updates(self, updates: UpdateLog) -> None:
        """Add the run's next applied landmark updates (in time order)."""
        self._shown.add_updates(updates)

    def advance(self, rows: int) -> None:
        """Write the blocks of rows that end at or before rows (rows [0, rows) final)."""
        with self._errors():
            # In blocks, so an hour-long trip never holds all its messages at once.
            while self._written + _BAG_BLOCK_ROWS <= min(rows, len(self._stamps_ns) - 1):
                self._write_block(self._written + _BAG_BLOCK_ROWS)

    def close(self) -> Path:
        """Write the rest (every row final) and move the bag into place."""
        with self._errors():
            while self._written < len(self._stamps_ns):
                self._write_block(min(self._written + _BAG_BLOCK_ROWS, len(self._stamps_ns)))
            writer, self._writer = self._writer, None
            writer.close()
            os.replace(self._aside / self.path.name, self.path)
        self.abort()
        return self.path

    def abort(self) -> None:
        """Drop what is written (idempotent; after close, only the staging folder)."""
        writer, self._writer = self._writer, None
        if writer is not None:
            with contextlib.suppress(Exception):
                writer.close()
        shutil.rmtree(self._aside, ignore_errors=True)

    def _write_block(self, stop: int) -> None:
        from gyro_ekf.io.batch_write import write_rows

        block = slice(self._written, stop)
        stamps_ns = self._stamps_ns
        write_rows(self._writer, self._connections, stamps_ns[block], self._encoder.encode(
            stamps_ns[block], self._state[block], self._P[block], self._speed[block],
            self._yaw_rate[block]))
        self._written = stop
        if self._visual:
            tf_stamps, tf_rows = self._shown.tf_rows(block)
            write_rows(self._writer, [self._tf], tf_stamps, [tf_rows])
            self._write_sparse(None if stop == len(stamps_ns) else int(stamps_ns[stop]))

    def _write_sparse(self, stop_ns: int | None) -> None:
        for message in self._shown.sparse_until(stop_ns):
            self._writer.write(self._sparse_connections[message.topic], message.stamp_ns,
                               message.data)

    @contextlib.contextmanager
    def _errors(self) -> Iterator[None]:
        from rosbags.rosbag2.errors import WriterError

        try:
            yield
        except WriterError as err:
            self.abort()
            raise OutputError(f'{self.path}: cannot write the estimates bag: {err}') from None
        except OSError as err:
            self.abort()
            raise OutputError(f'{self.path}: cannot write the estimates bag: '
                              f'{os_reason(err)}') from None
