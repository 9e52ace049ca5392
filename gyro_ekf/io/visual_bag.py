"""The visual topics of the estimates bag: /tf, /tf_static, ekf/path, ekf/markers, landmarks.

What the estimates bag holds so that Foxglove or RViz shows the run without setup:

- `/tf` tf2_msgs/TFMessage: `map -> base_link` from the estimate every TF_PERIOD_S (25 Hz;
  viewers interpolate TF, and every IMU step would add a quarter to the bag's messages,
  and to the time of writing them, for nothing a viewer shows), and
  `map -> base_link_truth` at each ground-truth sample where the trip has one.
- `/tf_static` (transient local): `base_link -> <IMU frame>` identity (the frame of
  ekf/bias: the input IMU's frame_id, `imu_link` by default) and `base_link -> <frame>`
  of each LiDAR's mount.
- `ekf/path` nav_msgs/Path in `map`: a pose every PATH_SPACING_S, published every
  PATH_PERIOD_S, the last `path_length` poses (PATH_LENGTH by default); the last message ends
  at the last estimate.
- `ekf/markers` visualization_msgs/MarkerArray every MARKERS_PERIOD_S (and at the last
  estimate): the 2-sigma position ellipse, the heading, and the detections of the last scan
  in that period that updated the filter, each with a line to its landmark. The offline run
  keeps only the applied updates (core.trip_run.UpdateLog), so the 'rejected' marker is
  always empty here.
- `landmark_markers` (transient local): one cylinder per landmark of the map.

Every message is encoded like the other per-estimate topics: one rosbags-serialised template
per layout (per pose count for ekf/path, per association count for ekf/markers) whose
numbers are patched per row, giving the bytes rosbags gives for each message.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from gyro_ekf import topics
from gyro_ekf.io.errors import OutputError
from gyro_ekf.core.angles import quaternions_of_yaws
from gyro_ekf.core.stamps import NS_PER_S, ns_at, seconds_since, split_ns, split_ns_array
from gyro_ekf.core.types import FloatArray, Trip
from gyro_ekf.io import messages as msgs

TF = topics.TF
TF_STATIC = topics.TF_STATIC
EKF_PATH = topics.EKF_PATH
EKF_MARKERS = topics.EKF_MARKERS
LANDMARK_MARKERS = topics.LANDMARK_MARKERS
TF_TYPE = 'tf2_msgs/msg/TFMessage'
PATH_TYPE = 'nav_msgs/msg/Path'
MARKER_ARRAY_TYPE = 'visualization_msgs/msg/MarkerArray'
TRUTH_FRAME = 'base_link_truth'

PATH_LENGTH = 600
"""Default most poses an ekf/path message holds (600 at PATH_SPACING_S: the last 2 min)."""
PATH_SPACING_S = 0.2
PATH_PERIOD_S = 1.0
MARKERS_PERIOD_S = 0.5
TF_PERIOD_S = 0.04

_POSE_BYTES = 56
"""A geometry_msgs/Pose (or Transform): 7 float64, always 8-aligned, at a message's end."""


def check_path_length(path_length: int) -> int:
    """Return path_length if it is a usable ekf/path length (>= 1), else raise OutputError."""
    if isinstance(path_length, bool) or not isinstance(path_length, (int, np.integer)) \
            or path_length < 1:
        raise OutputError(f'path length {path_length!r}: must be a whole number of poses >= 1')
    return int(path_length)


def _pose_columns(poses: FloatArray) -> FloatArray:
    """x, y, 0, then the yaw quaternion (0, 0, sin, cos), shape (n, 7); math's sin/cos."""
    poses = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
    out = np.zeros((len(poses), 7))
    out[:, :2] = poses[:, :2]
    out[:, 5:7] = quaternions_of_yaws(poses[:, 2])
    return out


class _TfTemplate:
    """CDR bytes of a one-transform TFMessage parent -> child, patched per row.

    Layout (rosbags' little-endian CDR): 4 bytes encapsulation, the transforms count, the
    header stamp (sec, nanosec) at bytes 8-15, strings, then the Transform's 7 float64 last.
    """

    def __init__(self, parent: str, child: str) -> None:
        self.data = np.frombuffer(msgs.serialize(msgs.tf_message(
            [msgs.transform_stamped(0, parent, child, 0.0, 0.0, 0.0)])), dtype=np.uint8)

    def rows(self, stamps_ns: NDArray[np.int64], poses: FloatArray) -> NDArray[np.uint8]:
        """One message per row, shape (n, size): stamps ns, poses (n, 3) x m, y m, yaw rad."""
        sec, nanosec = split_ns_array(stamps_ns)
        rows = np.tile(self.data, (len(sec), 1))
        rows[:, 8:12].view('<i4')[:, 0] = sec
        rows[:, 12:16].view('<u4')[:, 0] = nanosec
        rows[:, -_POSE_BYTES:].view('<f8')[:] = _pose_columns(poses)
        return rows


class _PathTemplate:
    """CDR bytes of a nav_msgs/Path of k planar poses in one frame.

    A PoseStamped element ends with its Pose (8-aligned, last 56 bytes) and starts with its
    stamp; elements after the first all have the same size (the first may carry alignment
    padding). Derived from rosbags' serialisation of paths of 0-3 poses and checked.
    """

    def __init__(self, frame_id: str) -> None:
        def cdr(k: int) -> bytes:
            return msgs.serialize(msgs.path_message(0, [0] * k, np.zeros((k, 3)), frame_id))

        empty, one, two, three = (cdr(k) for k in range(4))
        self.head = np.frombuffer(empty, dtype=np.uint8)
        self.first = np.frombuffer(one[len(empty):], dtype=np.uint8)
        self.rest = np.frombuffer(two[len(one):], dtype=np.uint8)
        # (The head differs in its count only.)
        if three[len(empty):] != two[len(empty):] + self.rest.tobytes() or len(self.rest) % 8:
            raise OutputError(f'{PATH_TYPE}: unexpected CDR layout of rosbags')

    def elements(self, stamps_ns: NDArray[np.int64], poses: FloatArray
                 ) -> tuple[NDArray[np.uint8], NDArray[np.uint8]]:
        """Every pose as a first element and as a later one, shapes (n, first), (n, rest).

        Encoded once per run: each path message then only joins the rows it holds.
        """
        sec, nanosec = split_ns_array(stamps_ns)
        columns = _pose_columns(poses)
        out = []
        for template in (self.first, self.rest):
            rows = np.tile(template, (len(sec), 1))
            rows[:, 0:4].view('<i4')[:, 0] = sec
            rows[:, 4:8].view('<u4')[:, 0] = nanosec
            rows[:, -_POSE_BYTES:].view('<f8')[:] = columns
            out.append(rows)
        return out[0], out[1]

    def encode(self, stamp_ns: int, first: NDArray[np.uint8], rest: NDArray[np.uint8]
               ) -> bytes:
        """Join one Path: its stamp, its first pose, the rest (rows of `elements`)."""
        head = self.head.copy()
        sec, nanosec = split_ns(stamp_ns)
        head[4:8].view('<i4')[0], head[8:12].view('<u4')[0] = sec, nanosec
        head[-4:].view('<u4')[0] = 1 + len(rest)
        return head.tobytes() + first.tobytes() + rest.tobytes()


class _MarkersTemplate:
    """CDR bytes of msgs.ekf_markers_message with k associations, patched many rows at once.

    The layout is fixed once k is: rosbags serialises one probe message per k with
    distinct probe numbers, and every place a probe's bytes occur is overwritten by that
    row's value (x and y stand in both the ellipse and the arrow, a detection in both its
    sphere and its line). The result is the bytes of the builder's own message.
    """

    _STAMP = 1_234_567_891 * NS_PER_S + 987_654_321
    _X, _Y, _YAW = 1111.0625, 2222.1875, 0.3125
    _COVARIANCE = np.array([[0.5, 0.125], [0.125, 0.25]])

    def __init__(self) -> None:
        self._cache: dict[int, tuple[NDArray[np.uint8], dict[str, list[int]]]] = {}

    def _layout(self, k: int) -> tuple[NDArray[np.uint8], dict[str, list[int]]]:
        if k in self._cache:
            return self._cache[k]
        detected = np.column_stack([3000.0625 + np.arange(k), 4000.0625 + np.arange(k)])
        landmark = np.column_stack([5000.0625 + np.arange(k), 6000.0625 + np.arange(k)])
        data = msgs.serialize(msgs.ekf_markers_message(
            self._STAMP, np.array([self._X, self._Y, self._YAW]), self._COVARIANCE,
            detected, landmark))
        values, _ = self._values(np.array([self._STAMP]), np.array([[self._X, self._Y,
                                                                     self._YAW]]),
                                 self._COVARIANCE[None])
        offsets: dict[str, list[int]] = {}
        for name, column in values.items():
            offsets[name] = _find_all(data, column[0].tobytes())
        for i in range(k):
            for name, value in (('dx', detected[i, 0]), ('dy', detected[i, 1]),
                                ('lx', landmark[i, 0]), ('ly', landmark[i, 1])):
                offsets[f'{name}{i}'] = _find_all(data, np.float64(value).tobytes())
        expected = {'sec': 5, 'nanosec': 5, 'x': 2, 'y': 2}
        if any(len(found) != expected.get(name, 2 if name[:2] in ('dx', 'dy') else 1)
               for name, found in offsets.items()):
            raise OutputError(f'{MARKER_ARRAY_TYPE}: unexpected CDR layout of rosbags')
        self._cache[k] = (np.frombuffer(data, dtype=np.uint8), offsets)
        return self._cache[k]

    @staticmethod
    def _values(stamps_ns: NDArray[np.int64], poses: FloatArray, covariance_xy: FloatArray
                ) -> tuple[dict[str, NDArray[Any]], None]:
        """Per row the numbers the builder writes, each an array of its wire dtype."""
        sec, nanosec = split_ns_array(stamps_ns)
        major, minor, direction = msgs.covariance_ellipses(covariance_xy)
        heading = _pose_columns(poses)
        turned = _pose_columns(np.column_stack([poses[:, :2], direction]))
        return {'sec': sec.astype('<i4'), 'nanosec': nanosec.astype('<u4'),
                'x': heading[:, 0], 'y': heading[:, 1],
                'qz': heading[:, 5], 'qw': heading[:, 6],
                'ez': turned[:, 5], 'ew': turned[:, 6],
                'major': major, 'minor': minor}, None

    def encode(self, stamps_ns: NDArray[np.int64], poses: FloatArray,
               covariance_xy: FloatArray, detected: FloatArray, landmark: FloatArray
               ) -> NDArray[np.uint8]:
        """Rows with k associations each: detected, landmark shape (n, k, 2); -> (n, size)."""
        k = detected.shape[1]
        template, offsets = self._layout(k)
        rows = np.tile(template, (len(stamps_ns), 1))
        values, _ = self._values(stamps_ns, poses, covariance_xy)
        for i in range(k):
            values.update({f'dx{i}': detected[:, i, 0], f'dy{i}': detected[:, i, 1],
                           f'lx{i}': landmark[:, i, 0], f'ly{i}': landmark[:, i, 1]})
        for name, column in values.items():
            column = np.asarray(column)
            width = column.dtype.itemsize
            for offset in offsets[name]:
                rows[:, offset:offset + width].view(column.dtype)[:, 0] = column
        return rows


def _find_all(data: bytes, pattern: bytes) -> list[int]:
    found, start = [], data.find(pattern)
    while start >= 0:
        found.append(start)
        start = data.find(pattern, start + 1)
    return found


def _first_of_each_period(stamp_s: FloatArray, period_s: float) -> NDArray[np.int64]:
    """Rows that open a new period of the stamps, and the last row; sorted."""
    stamp_s = np.asarray(stamp_s, dtype=np.float64)
    if not len(stamp_s):
        return np.zeros(0, dtype=np.int64)
    bins = np.floor(stamp_s / period_s)
    opening = np.flatnonzero(np.concatenate([[True], bins[1:] != bins[:-1]]))
    return np.union1d(opening, [len(stamp_s) - 1]).astype(np.int64)


@dataclass(frozen=True)
class SparseMessage:
    """One message of a visual topic other than the dense /tf (see VisualTopics.sparse)."""

    stamp_ns: int
    topic: str
    data: bytes


class VisualTopics:
    """Builds the visual topics of an estimates bag from a run's rows and its trip.

    The rows may still be filling while the bag is written (io.streamed_products):
    ``sparse_until(stop_ns)`` reads only the rows stamped before stop_ns and the updates
    ``add_updates`` has brought so far, so both must be final up to there; the stamps are
    known from the start.

    Constructor args:
        start_time_ns: bag stamp of t = 0.
        stamps_ns: estimate stamps, shape (n,), ns since the epoch.
        state: shape (n, 4); covariance: shape (n, 4, 4).
        trip: the run's inputs (LiDAR mounts, map, ground truth), or None.
        updates: the run's core.trip_run.UpdateLog (the first of them), or None.
        path_length: most poses in an ekf/path message (>= 1).
        imu_frame: the IMU's frame (identity on base_link in /tf_static).

    Raises:
        OutputError: path_length is not >= 1.
    """

    def __init__(self, start_time_ns: int, stamps_ns: NDArray[np.int64], state: FloatArray,
                 covariance: FloatArray, trip: Trip | None = None, updates: Any = None,
                 path_length: int = PATH_LENGTH, imu_frame: str = topics.IMU_FRAME) -> None:
        """Keep the rows; see the class for the arguments."""
        self.path_length = check_path_length(path_length)
        self.start_time_ns = int(start_time_ns)
        self.stamps_ns = stamps_ns
        self.state = state
        self.covariance = covariance
        self.trip = trip
        self.imu_frame = imu_frame
        self.tf = _TfTemplate(topics.MAP_FRAME, topics.BASE_FRAME)
        relative = self._relative_s()
        self._tf_rows = _first_of_each_period(relative, TF_PERIOD_S)
        # ekf/path: the rows published, the rows kept in paths, each kept row's elements
        # once encoded (filled as the rows come), the next published row to write.
        self._path_rows = _first_of_each_period(relative, PATH_PERIOD_S)
        self._path_kept = np.union1d(_first_of_each_period(relative, PATH_SPACING_S),
                                     self._path_rows)
        self._path_template = _PathTemplate(topics.MAP_FRAME)
        self._path_first = np.empty((len(self._path_kept), len(self._path_template.first)),
                                    dtype=np.uint8)
        self._path_rest = np.empty((len(self._path_kept), len(self._path_template.rest)),
                                   dtype=np.uint8)
        self._path_encoded = 0
        self._path_next = 0
        # ekf/markers: their rows and the next to write; the updates as they come.
        self._marker_rows = _first_of_each_period(relative, MARKERS_PERIOD_S)
        self._marker_next = 0
        self._markers_template = _MarkersTemplate()
        # The updates so far: stamps ns, detections in the map, their landmarks (m).
        self._update_ns = np.zeros(0, dtype=np.int64)
        self._update_point = np.zeros((0, 2))
        self._update_landmark = np.zeros((0, 2))
        self._update_count = 0
        if updates is not None:
            self.add_updates(updates)
        # Ground truth: all known from the start.
        truth = None if trip is None else trip.ground_truth
        self._truth_ns = (np.zeros(0, dtype=np.int64) if truth is None
                          else self._to_ns(truth.stamp_s))
        self._truth_next = 0

    def latched(self) -> list[tuple[str, str, bytes]]:
        """(topic, type, CDR) of the transient-local messages, stamped start_time_ns."""
        stamp = self.start_time_ns
        mounts = [msgs.transform_stamped(stamp, topics.BASE_FRAME, self.imu_frame,
                                         0.0, 0.0, 0.0)]
        landmarks = None
        if self.trip is not None:
            mounts += [msgs.transform_stamped(stamp, topics.BASE_FRAME, scan.frame_id,
                                              scan.mount.x_m, scan.mount.y_m,
                                              scan.mount.yaw_rad)
                       for scan in self.trip.scans]
            landmarks = self.trip.landmarks
        out = [(TF_STATIC, TF_TYPE, msgs.serialize(msgs.tf_message(mounts)))]
        if landmarks is not None:
            out.append((LANDMARK_MARKERS, MARKER_ARRAY_TYPE,
                        msgs.serialize(msgs.landmark_markers_message(stamp, landmarks))))
        return out

    def tf_rows(self, block: slice) -> tuple[NDArray[np.int64], NDArray[np.uint8]]:
        """/tf map -> base_link of the estimate rows of block that TF_PERIOD_S keeps.

        Returns:
            Their stamps, shape (m,) ns, and messages, shape (m, size).
        """
        chosen = self._tf_rows[(self._tf_rows >= block.start) & (self._tf_rows < block.stop)]
        return self.stamps_ns[chosen], self.tf.rows(self.stamps_ns[chosen],
                                                    self.state[chosen, :3])

    def add_updates(self, updates: Any) -> None:
        """Add the run's next applied updates (a core.trip_run.UpdateLog, in time order)."""
        count = len(updates.stamp_s)
        if not count or self.trip is None or self.trip.landmarks is None:
            return  # no markers of detections without a map
        have = self._update_count
        if have + count > len(self._update_ns):
            # Grown by doubling: a long run adds a few updates at a time.
            size = max(2 * len(self._update_ns), have + count, 1024)
            self._update_ns = np.resize(self._update_ns, size)
            self._update_point = np.resize(self._update_point, (size, 2))
            self._update_landmark = np.resize(self._update_landmark, (size, 2))
        self._update_ns[have:have + count] = self._to_ns(updates.stamp_s)
        self._update_point[have:have + count] = np.asarray(updates.point_map_m).reshape(-1, 2)
        self._update_landmark[have:have + count] = np.asarray(
            self.trip.landmarks.xy_m)[updates.landmark]
        self._update_count = have + count

    def sparse_until(self, stop_ns: int | None) -> list[SparseMessage]:
        """Return the other messages (truth /tf, ekf/path, ekf/markers) stamped before stop_ns.

        In time order, each message once over successive calls; None: all that are left.
        The rows stamped before stop_ns must be final and the updates up to the last of
        them added.
        """
        rows = (len(self.stamps_ns) if stop_ns is None
                else int(np.searchsorted(self.stamps_ns, stop_ns, side='left')))
        path = _before(self._path_rows, self._path_next, rows)
        markers = _before(self._marker_rows, self._marker_next, rows)
        self._path_next, self._marker_next = path.stop, markers.stop
        messages = [*self._truth_until(stop_ns), *self._path(path), *self._markers(markers)]
        # Stable: at one stamp, truth before path before markers, as a merge of the three.
        messages.sort(key=lambda m: m.stamp_ns)
        return messages

    def _relative_s(self) -> FloatArray:
        return seconds_since(self.stamps_ns, self.start_time_ns)

    def _to_ns(self, stamp_s: FloatArray) -> NDArray[np.int64]:
        return ns_at(self.start_time_ns, stamp_s)

    def _truth_until(self, stop_ns: int | None) -> list[SparseMessage]:
        begin = self._truth_next
        end = (len(self._truth_ns) if stop_ns is None
               else int(np.searchsorted(self._truth_ns, stop_ns, side='left')))
        self._truth_next = max(begin, end)
        if end <= begin:
            return []
        assert self.trip is not None and self.trip.ground_truth is not None
        template = _TfTemplate(topics.MAP_FRAME, TRUTH_FRAME)
        out = []
        for start in range(begin, end, 4096):
            part = slice(start, min(start + 4096, end))
            stamps = self._truth_ns[part]
            rows = template.rows(stamps, self.trip.ground_truth.pose[part])
            out += [SparseMessage(stamp, TF, row.tobytes())
                    for stamp, row in zip(stamps.tolist(), rows)]
        return out

    def _path(self, new: range) -> list[SparseMessage]:
        """ekf/path at the published rows of index range new."""
        if not new:
            return []
        # Encode the kept rows the new messages reach (each once).
        reach = int(np.searchsorted(self._path_kept, self._path_rows[new.stop - 1],
                                    side='right'))
        if reach > self._path_encoded:
            kept = self._path_kept[self._path_encoded:reach]
            self._path_first[self._path_encoded:reach], \
                self._path_rest[self._path_encoded:reach] = self._path_template.elements(
                    self.stamps_ns[kept], self.state[kept, :3])
            self._path_encoded = reach
        out = []
        for row in self._path_rows[new.start:new.stop].tolist():
            last = int(np.searchsorted(self._path_kept, row, side='right'))
            first = max(0, last - self.path_length)
            stamp = int(self.stamps_ns[row])
            out.append(SparseMessage(stamp, EKF_PATH, self._path_template.encode(
                stamp, self._path_first[first], self._path_rest[first + 1:last])))
        return out

    def _markers(self, new: range) -> list[SparseMessage]:
        """ekf/markers at the marker rows of index range new."""
        if not new:
            return []
        first = new.start
        count = self._update_count
        update_ns = self._update_ns[:count]
        point_map, landmark_xy = self._update_point[:count], self._update_landmark[:count]
        marker_rows = self._marker_rows[new.start:new.stop]
        stamps = self.stamps_ns[marker_rows]
        # The updates of the last scan in (previous marker, this marker] that had any.
        end = np.searchsorted(update_ns, stamps, side='right')
        last_ns = (update_ns[np.maximum(end - 1, 0)] if len(update_ns)
                   else np.zeros(len(stamps), dtype=np.int64))
        previous = np.concatenate([[np.iinfo(np.int64).min if first == 0 else
                                    self.stamps_ns[self._marker_rows[first - 1]]],
                                   stamps[:-1]])
        fresh = (end > 0) & (last_ns > previous)
        begin = np.where(fresh, np.searchsorted(update_ns, last_ns, side='left'), end)
        end = np.where(fresh, end, begin)
        counts = end - begin
        out = []
        for start in range(0, len(marker_rows), 256):
            part = slice(start, start + 256)
            encoded: dict[int, Iterator[NDArray[np.uint8]]] = {}
            for k in np.unique(counts[part]).tolist():
                chosen = np.flatnonzero(counts[part] == k) + start
                picks = begin[chosen, None] + np.arange(k)
                encoded[k] = iter(self._markers_template.encode(
                    stamps[chosen], self.state[marker_rows[chosen], :3],
                    self.covariance[marker_rows[chosen], :2, :2],
                    point_map[picks] if k else np.zeros((len(chosen), 0, 2)),
                    landmark_xy[picks] if k else np.zeros((len(chosen), 0, 2))))
            out += [SparseMessage(int(stamps[i]), EKF_MARKERS,
                                  next(encoded[int(counts[i])]).tobytes())
                    for i in range(start, min(start + 256, len(marker_rows)))]
        return out


def _before(periodic_rows: NDArray[np.int64], done: int, rows: int) -> range:
    """Return the indices of periodic_rows from done on that lie before row `rows`."""
    return range(done, max(done, int(np.searchsorted(periodic_rows, rows, side='left'))))
