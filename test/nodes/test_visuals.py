"""nodes.visuals without a node: TF rule, bounded path, scan markers, CDR of the markers."""

from __future__ import annotations

import math

import numpy as np
import pytest

from gyro_ekf.core.association import Association, AssociationOutcome, AssociationResult
from gyro_ekf.core.event_records import ObservationReport
from gyro_ekf.core.types import LandmarkMap, LidarMount
from gyro_ekf.io import messages
from gyro_ekf.nodes import visuals


@pytest.mark.parametrize('pose', [(1.0, -2.0, 0.3), (-4.0, 0.5, -3.0), (0.0, 0.0, math.pi)])
def test_inverse_undoes_compose(pose):
    other = (0.7, 2.5, -1.2)
    back = visuals.compose(visuals.inverse(pose), visuals.compose(pose, other))
    assert back == pytest.approx(other)


def test_map_to_odom_makes_map_odom_base_the_estimate():
    estimate, odometry = (3.0, 4.0, 1.0), (1.5, -0.5, 0.4)
    t = visuals.tf_transform(estimate, 'map', 'base_link', 'odom', odometry)
    assert (t.parent, t.child) == ('map', 'odom')
    chained = visuals.compose((t.x_m, t.y_m, t.yaw_rad), odometry)
    assert chained == pytest.approx(estimate)


def test_without_an_odometry_pose_tf_is_map_to_base():
    estimate = (3.0, 4.0, 1.0)
    assert visuals.tf_transform(estimate, 'map', 'base_link') == ('map', 'base_link', *estimate)
    # A frame without a pose yet (no odometry received) is not guessed.
    assert visuals.tf_transform(estimate, 'map', 'base_link', 'odom', None).child == 'base_link'


def test_path_keeps_one_pose_per_spacing_and_at_most_its_length():
    path = visuals.PathHistory(length=3, spacing_s=0.2)
    for i in range(20):  # 10 ms apart: one kept per 0.2 s
        path.add(10 ** 9 + i * 10 ** 7, float(i), 0.0, 0.0)
    assert len(path) == 1
    for i in range(1, 6):
        path.add(10 ** 9 + i * 2 * 10 ** 8, float(i), 0.0, 0.0)
    assert len(path) == 3
    message = path.message('map')
    assert [p.pose.position.x for p in message.poses] == [3.0, 4.0, 5.0]
    assert message.header.frame_id == 'map' and message.poses[0].header.frame_id == 'map'
    assert messages.from_time(message.header.stamp) == 10 ** 9 + 5 * 2 * 10 ** 8
    path.add(10 ** 9, 9.0, 0.0, 0.0)  # stamps went back: the filter restarted
    assert len(path) == 1


def test_scan_markers_pair_detections_with_their_landmarks_and_list_the_rest():
    landmarks = LandmarkMap(np.array([[2.0, 0.0], [0.0, 3.0], [9.0, 9.0]]))
    state = np.array([1.0, 0.0, 0.0, 0.0])
    points = np.array([[0.0, 3.0], [1.0, 0.0], [5.0, 5.0]])  # sensor frame = platform
    association = AssociationResult((
        Association(0, -1, AssociationOutcome.UNMATCHED, 30.0),
        Association(1, 0, AssociationOutcome.MATCHED, 0.1),
        Association(2, -1, AssociationOutcome.AMBIGUOUS, 2.0)), 9.2, np.zeros((3, 3)))
    report = ObservationReport(5.0, points, state, LidarMount(), association, np.array([0.1]))
    associated, landmark, rejected = visuals.scan_marker_points(report, landmarks)
    assert associated.tolist() == [[2.0, 0.0]]
    assert landmark.tolist() == [[2.0, 0.0]]
    assert rejected.tolist() == [[1.0, 3.0], [6.0, 5.0]]
    assert all(len(a) == 0 for a in visuals.scan_marker_points(None, landmarks))

    data = visuals.markers_bytes(7 * 10 ** 9, state, np.diag([0.04, 0.01, 0.0, 0.0]), report,
                                 landmarks, 'map')
    markers = messages.deserialize(data, 'visualization_msgs/msg/MarkerArray').markers
    by_ns = {m.ns: m for m in markers}
    assert {m.header.frame_id for m in markers} == {'map'}
    assert len(by_ns['associated'].points) == 1 and len(by_ns['rejected'].points) == 2
    assert by_ns['ellipse'].scale.x == pytest.approx(2 * 2 * 0.2)  # 2 sigma, full length


def test_landmark_markers_hold_one_cylinder_per_landmark():
    landmarks = LandmarkMap(np.array([[2.0, 0.0], [0.0, 3.0]]))
    data = visuals.landmark_markers_bytes(landmarks, 'world')
    markers = messages.deserialize(data, 'visualization_msgs/msg/MarkerArray').markers
    assert [(m.pose.position.x, m.pose.position.y) for m in markers] == [(2.0, 0.0),
                                                                         (0.0, 3.0)]
    assert {m.header.frame_id for m in markers} == {'world'}
