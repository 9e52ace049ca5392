"""Writers of the products of `gyro-ekf run`: estimates CSV, summary JSON, estimates bag.

Each builds its file (or bag folder) under a temporary name beside the target and renames it
into place (`output_dir.staged_file`), so an interrupted run never leaves a half-written
product; the folder they go into is `output_dir`'s. `start_estimates_csv` writes the CSV in
a forked child where a core is free, beside the caller's own work (the bag).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
import json
import logging
import math
import os
from pathlib import Path
import pickle
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
from gyro_ekf.processes import spare_core as _spare_core

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
    path = Path(path)
    count = len(stamp_s)
    with staged_file(path) as staged, staged.open('w', encoding='ascii') as stream:
        stream.write(CSV_HEADER + '\n')
        # In blocks, so an hour-long trip never holds the whole (n, 12) table at once.
        row_format = ','.join(['%.9g'] * len(CSV_HEADER.split(','))) + '\n'
        for start in range(0, count, _CSV_BLOCK_ROWS):
            block = slice(start, min(start + _CSV_BLOCK_ROWS, count))
            table = estimates_table(stamp_s[block], state[block], covariance[block])
            # One format operation per block: what np.savetxt writes, without its
            # per-row Python loop.
            stream.write((row_format * len(table)) % tuple(table.ravel().tolist()))
    return path


def start_estimates_csv(path: Path | str, stamp_s: FloatArray, state: FloatArray,
                        covariance: FloatArray) -> Callable[[], Path]:
    """Start ``write_estimates_csv`` beside the caller's own work; return what waits for it.

    Formatting the rows is pure Python (a tenth of a second for the 2016 log's 44.6k rows)
    and holds the interpreter, so a thread would gain nothing: where a second core is free
    to use, a forked child writes the file while the caller goes on (`gyro-ekf run` writes
    the estimates bag meanwhile), and the same bytes result. Elsewhere (no fork, one core)
    the file is written here and now. Call the returned function before using the file,
    and also when the caller's own work failed: it reaps the child.

    Raises (from the returned function, else at once):
        OutputError, OSError: the file could not be written; the child's own exception,
            as ``write_estimates_csv`` raises it here (naming the file).
    """
    path = Path(path)
    pid = None
    if _spare_core():
        read_end, write_end = os.pipe()
        try:
            pid = os.fork()
        except OSError:  # no process to spare after all: written here
            os.close(read_end)
            os.close(write_end)
    if pid is None:
        write_estimates_csv(path, stamp_s, state, covariance)
        return lambda: path
    if pid == 0:  # the child: write, hand back what went wrong, leave without cleanup
        code = 1
        try:
            os.close(read_end)
            with os.fdopen(write_end, 'wb') as pipe:
                try:
                    write_estimates_csv(path, stamp_s, state, covariance)
                    code = 0
                except BaseException as err:  # noqa: BLE001 (raised again by the parent)
                    try:
                        pipe.write(pickle.dumps(err))
                    except Exception:  # noqa: BLE001 (an error that does not pickle)
                        pipe.write(pickle.dumps(OutputError(f'{path}: cannot write: {err}')))
        finally:
            os._exit(code)
    os.close(write_end)

    def wait() -> Path:
        with os.fdopen(read_end, 'rb') as pipe:
            error = pipe.read()
        _, status = os.waitpid(pid, 0)
        code = os.waitstatus_to_exitcode(status)
        if code != 0:
            if error:
                # The child's own exception (an OSError with its errno, an OutputError): as
                # if the file had been written here.
                raise pickle.loads(error) from None
            raise OutputError(f'{path}: cannot write: the process writing it ended with '
                              f'status {code}')
        return path
    return wait


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


class _Lookahead:
    """Hands out the messages of a time-ordered iterator a stamp range at a time."""

    def __init__(self, messages: Iterator[Any]) -> None:
        self._messages = messages
        self._next = next(messages, None)

    def until(self, stop_ns: int | None) -> Iterator[Any]:
        """Yield the messages stamped before stop_ns (all that are left when None)."""
        while self._next is not None and (stop_ns is None or self._next.stamp_ns < stop_ns):
            yield self._next
            self._next = next(self._messages, None)


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
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.rosbag2.errors import WriterError

    from gyro_ekf.io import visual_bag
    from gyro_ekf.io.visual_bag import VisualTopics
    from gyro_ekf.io import messages as msgs
    from gyro_ekf.io.bag_writer import LATCHED_QOS
    from gyro_ekf.io.batch_write import enable_chunk_crcs, write_rows

    path = Path(path)
    if path.exists():
        raise OutputError(f'{path}: exists already')
    plugins = {'mcap': StoragePlugin.MCAP, 'sqlite3': StoragePlugin.SQLITE3}
    if storage not in plugins:
        raise OutputError(f'{path}: unknown storage {storage!r}; expected one of '
                          f'{sorted(plugins)}')
    stamps_ns = ns_at(start_time_ns, stamp_s)
    state = np.asarray(state, dtype=np.float64)
    P = np.asarray(covariance, dtype=np.float64)
    speed_m_s = np.asarray(speed_m_s, dtype=np.float64)
    yaw_rate_rad_s = np.asarray(yaw_rate_rad_s, dtype=np.float64)
    if len(stamps_ns) and (stamps_ns.min() < 0 or stamps_ns.max() // NS_PER_S > _INT32_MAX):
        raise OutputError(f'{path}: stamps outside builtin_interfaces/Time (int32 seconds)')
    imu_frame = imu_frame or topics.IMU_FRAME
    encoder = _EstimateEncoder(imu_frame)
    shown = VisualTopics(start_time_ns, stamps_ns, state, P, trip, updates,
                         visual_bag.PATH_LENGTH if path_length is None else path_length,
                         imu_frame)
    try:
        aside = Path(tempfile.mkdtemp(prefix=f'.{path.name}.', suffix='.tmp', dir=path.parent))
    except OSError as err:
        raise OutputError(f'{path}: cannot write the estimates bag: {os_reason(err)}') from None
    staged = aside / path.name
    try:
        with Writer(staged, version=_BAG_VERSION, storage_plugin=plugins[storage]) as writer:
            enable_chunk_crcs(writer)
            connections = [writer.add_connection(topics.bag_topic(topic), template.msgtype,
                                                 typestore=msgs.TYPESTORE)
                           for topic, template in encoder.templates()]
            if visual:
                tf = writer.add_connection(visual_bag.TF, visual_bag.TF_TYPE,
                                           typestore=msgs.TYPESTORE)
                sparse_connections = {visual_bag.TF: tf, **{
                    topic: writer.add_connection(topics.bag_topic(topic), msgtype,
                                                 typestore=msgs.TYPESTORE)
                    for topic, msgtype in ((visual_bag.EKF_PATH, visual_bag.PATH_TYPE),
                                           (visual_bag.EKF_MARKERS,
                                            visual_bag.MARKER_ARRAY_TYPE))}}
                for topic, msgtype, data in shown.latched():
                    latched = writer.add_connection(topics.bag_topic(topic), msgtype,
                                                    typestore=msgs.TYPESTORE,
                                                    offered_qos_profiles=[LATCHED_QOS])
                    writer.write(latched, int(start_time_ns), data)
                sparse = _Lookahead(shown.sparse())
            # In blocks, so an hour-long trip never holds all its messages at once.
            for start in range(0, len(stamps_ns), _BAG_BLOCK_ROWS):
                block = slice(start, min(start + _BAG_BLOCK_ROWS, len(stamps_ns)))
                write_rows(writer, connections, stamps_ns[block], encoder.encode(
                    stamps_ns[block], state[block], P[block], speed_m_s[block],
                    yaw_rate_rad_s[block]))
                if not visual:
                    continue
                tf_stamps, tf_rows = shown.tf_rows(block)
                write_rows(writer, [tf], tf_stamps, [tf_rows])
                last = block.stop == len(stamps_ns)
                for message in sparse.until(None if last else int(stamps_ns[block.stop])):
                    writer.write(sparse_connections[message.topic], message.stamp_ns,
                                 message.data)
        os.replace(staged, path)
    except WriterError as err:
        raise OutputError(f'{path}: cannot write the estimates bag: {err}') from None
    except OSError as err:
        raise OutputError(f'{path}: cannot write the estimates bag: {os_reason(err)}') from None
    finally:
        shutil.rmtree(aside, ignore_errors=True)
    return path
