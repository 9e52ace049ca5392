"""What ekf_node shows RViz and Foxglove: ekf/path, ekf/markers, landmark_markers, TF.

The messages are the ones `gyro-ekf run` writes into its estimates bag (io.messages builds
both), serialized by the project's typestore and published as CDR bytes, so the live view
and the bag look the same. Path and markers go out on timers of the node clock (ROS time
with use_sim_time), not per IMU sample: a viewer draws a few frames a second, and building
a 600-pose path per sample would cost more than the filter.

TF follows robot_localization: with an `odom_frame` whose odometry carries a pose, the node
broadcasts `world_frame -> odom_frame` (so that world -> odom -> base_link is the
estimate); without one, `world_frame -> base_frame` directly. The transforms are computed
by `tf_transform` (pure, tested without TF); broadcasting needs tf2_msgs, which a real
Jazzy install has and the PyPI packages do not.
"""

from __future__ import annotations

import math
from collections import deque
from typing import Any, NamedTuple

import numpy as np

from gyro_ekf.core.association import AssociationOutcome
from gyro_ekf.core.event_records import ObservationReport
from gyro_ekf.core.stamps import NS_PER_S
from gyro_ekf.core.types import FloatArray, LandmarkMap
from gyro_ekf.io import messages


class PlanarTransform(NamedTuple):
    """A transform to broadcast: child's pose in parent (m, m, rad)."""

    parent: str
    child: str
    x_m: float
    y_m: float
    yaw_rad: float


def compose(a: tuple[float, float, float], b: tuple[float, float, float]
            ) -> tuple[float, float, float]:
    """Planar pose b given in frame a, expressed in a's parent (a * b)."""
    c, s = math.cos(a[2]), math.sin(a[2])
    return (a[0] + c * b[0] - s * b[1], a[1] + s * b[0] + c * b[1],
            math.remainder(a[2] + b[2], math.tau))


def inverse(a: tuple[float, float, float]) -> tuple[float, float, float]:
    """Return the planar pose of a's parent in a's frame (a^-1)."""
    c, s = math.cos(a[2]), math.sin(a[2])
    return (-c * a[0] - s * a[1], s * a[0] - c * a[1], math.remainder(-a[2], math.tau))


def tf_transform(world_base: tuple[float, float, float], world_frame: str, base_frame: str,
                 odom_frame: str = '', odom_base: tuple[float, float, float] | None = None
                 ) -> PlanarTransform:
    """Choose the transform ekf_node broadcasts for one estimate (robot_localization's rule).

    Args:
        world_base: the estimate, base_frame's pose in world_frame (x m, y m, yaw rad).
        odom_frame: the odometry's frame; '' when the odometry carries no pose.
        odom_base: base_frame's pose in odom_frame from the latest odometry, if any.

    Returns:
        world -> odom (world_base * odom_base^-1: the correction odometry needs) when an
        odometry pose is known, else world -> base.
    """
    if odom_frame and odom_base is not None:
        return PlanarTransform(world_frame, odom_frame,
                               *compose(world_base, inverse(odom_base)))
    return PlanarTransform(world_frame, base_frame, *world_base)


class PathHistory:
    """The last `length` poses, one every `spacing_s` of stamp time, for ekf/path."""

    def __init__(self, length: int, spacing_s: float):
        """Keep at most length poses (the path's bound), spaced spacing_s apart."""
        self._poses: deque[tuple[int, float, float, float]] = deque(maxlen=length)
        self._spacing_ns = int(spacing_s * NS_PER_S)

    def add(self, stamp_ns: int, x_m: float, y_m: float, yaw_rad: float) -> None:
        """Offer an estimate; it is kept when spacing_s has passed since the last kept one."""
        if self._poses and stamp_ns - self._poses[-1][0] < self._spacing_ns:
            if stamp_ns < self._poses[-1][0]:  # the filter restarted: a new path
                self._poses.clear()
            else:
                return
        self._poses.append((stamp_ns, x_m, y_m, yaw_rad))

    def clear(self) -> None:
        """Forget the path (a filter reset)."""
        self._poses.clear()

    def __len__(self) -> int:
        return len(self._poses)

    def message(self, frame_id: str) -> Any:
        """nav_msgs/Path (typestore message) of the kept poses, stamped with the newest."""
        rows = np.array([pose[1:] for pose in self._poses], dtype=np.float64).reshape(-1, 3)
        stamps = [pose[0] for pose in self._poses]
        return messages.path_message(stamps[-1] if stamps else 0, stamps, rows, frame_id)


def scan_marker_points(report: ObservationReport | None, landmarks: LandmarkMap | None
                       ) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Associated detections, their landmarks and the other detections of a scan, in the map.

    Returns:
        shape (k, 2), (k, 2), (r, 2), m: empty when there is no report or no association.
    """
    none = np.zeros((0, 2))
    if report is None or report.association is None or landmarks is None:
        return none, none, none
    points = report.points_map_m
    matched = [(a.detection_index, a.landmark_index) for a in report.association.associations
               if a.outcome is AssociationOutcome.MATCHED]
    detections = [i for i, _ in matched]
    rejected = np.ones(len(points), dtype=bool)
    rejected[detections] = False
    return (points[detections].reshape(-1, 2),
            np.asarray(landmarks.xy_m)[[j for _, j in matched]].reshape(-1, 2),
            points[rejected].reshape(-1, 2))


def markers_bytes(stamp_ns: int, state: FloatArray, covariance: FloatArray,
                  report: ObservationReport | None, landmarks: LandmarkMap | None,
                  frame_id: str) -> bytes:
    """CDR of ekf/markers for one estimate and the last scan (see io.messages)."""
    associated, landmark, rejected = scan_marker_points(report, landmarks)
    return messages.serialize(messages.ekf_markers_message(
        stamp_ns, state, covariance, associated, landmark, rejected, frame_id))


def landmark_markers_bytes(landmarks: LandmarkMap, frame_id: str, stamp_ns: int = 0) -> bytes:
    """CDR of landmark_markers: one cylinder per landmark of the map."""
    return messages.serialize(messages.landmark_markers_message(stamp_ns, landmarks, frame_id))
