"""The visual topics of `gyro-ekf run`'s estimates bag, read back with mcap_ros2 and rosbags.

/tf, /tf_static, ekf/path, ekf/markers and landmark_markers of a run on the bundled
bags/sim_static_start, against the run's own estimates.csv, the input bag's map and ground
truth, and its params sidecar.
"""

from __future__ import annotations

from collections import defaultdict
import json
import math
from pathlib import Path
import shutil
import warnings

import numpy as np
import pytest
from rosbags.interfaces import QosDurability
from rosbags.rosbag2 import Reader
import yaml

from gyro_ekf.io import output_dir, results, visual_bag
from gyro_ekf.io.errors import OutputError
from gyro_ekf.cli.main import main
from gyro_ekf.io import messages as msgs

BAGS = Path(__file__).resolve().parents[2] / 'bags'
SOURCE = BAGS / 'sim_static_start'
PATH_LENGTH = 40
VISUAL = {'/tf', '/tf_static', '/ekf/path', '/ekf/markers', '/landmark_markers'}


def _run(bag: Path, out: Path, *extra: str) -> int:
    return main(['-q', 'run', str(bag), '-o', str(out), '--no-progress', '--no-plots',
                 *extra])


def _messages(bag: Path) -> dict[str, list[tuple[int, bytes, object]]]:
    """Topic -> [(log time ns, CDR bytes, rosbags message)] of the visual topics."""
    found = defaultdict(list)
    with Reader(bag) as reader:
        for connection, stamp, data in reader.messages():
            if connection.topic in VISUAL:
                found[connection.topic].append(
                    (stamp, bytes(data), msgs.deserialize(data, connection.msgtype)))
    return found


def _source(topic: str) -> list[object]:
    with Reader(SOURCE) as reader:
        chosen = [c for c in reader.connections if c.topic == topic]
        return [msgs.deserialize(d, c.msgtype) for c, _, d in reader.messages(chosen)]


@pytest.fixture(scope='module')
def run(tmp_path_factory):
    out = tmp_path_factory.mktemp('visual') / 'out'
    assert _run(SOURCE, out, '--path-length', str(PATH_LENGTH)) == 0
    rows = np.loadtxt(out / 'estimates.csv', delimiter=',', skiprows=1)
    start_ns = yaml.safe_load((BAGS / 'sim_static_start.params.yaml').read_text())[
        '/**']['ros__parameters']['trip']['log_time_zero_ns']
    bag = out / output_dir.ESTIMATES_BAG
    return bag, rows, _messages(bag), start_ns


def _row_at(rows, start_ns: int, stamp_ns: int) -> np.ndarray:
    index = int(np.argmin(np.abs(start_ns + rows[:, 0] * 1e9 - stamp_ns)))
    assert abs(start_ns + rows[index, 0] * 1e9 - stamp_ns) < 1e3   # the same estimate
    return rows[index]


def test_every_visual_message_decodes_with_mcap_ros2_as_rosbags_does(run):
    with warnings.catch_warnings():   # mcap_ros2.reader imports the deprecated mcap_ros1
        warnings.simplefilter('ignore', DeprecationWarning)
        from mcap_ros2.reader import read_ros2_messages
    bag, _, found, _ = run
    decoded = defaultdict(list)
    for message in read_ros2_messages(str(next(bag.glob('*.mcap')))):
        decoded[message.channel.topic].append(message)
    assert set(decoded) >= VISUAL
    for topic in VISUAL:
        assert len(decoded[topic]) == len(found[topic]) > 0, topic
    last_path = max(decoded['/ekf/path'], key=lambda m: m.log_time_ns).ros_msg
    assert last_path.poses[-1].pose.position.x == found['/ekf/path'][-1][2].poses[-1].pose \
        .position.x
    # The templates give the bytes rosbags gives for the decoded message.
    for topic in VISUAL:
        for _, data, message in found[topic][::7]:
            assert msgs.serialize(message) == data, topic


def test_tf_holds_the_estimate_and_the_ground_truth(run):
    _, rows, found, start_ns = run
    by_child = defaultdict(list)
    for stamp, _, message in found['/tf']:
        for transform in message.transforms:
            assert msgs.from_time(transform.header.stamp) == stamp
            by_child[(transform.header.frame_id, transform.child_frame_id)].append(transform)
    assert set(by_child) == {('map', 'base_link'), ('map', 'base_link_truth')}
    estimated = by_child[('map', 'base_link')]
    assert len(estimated) < len(rows) / 3                      # decimated from 200 Hz
    for transform in estimated[::50] + estimated[-1:]:
        row = _row_at(rows, start_ns, msgs.from_time(transform.header.stamp))
        t = transform.transform
        assert (t.translation.x, t.translation.y) == pytest.approx(row[1:3], abs=1e-6)
        assert msgs.quaternion_yaw(t.rotation) == pytest.approx(row[3], abs=1e-6)
    truth = _source('/ground_truth')
    assert len(by_child[('map', 'base_link_truth')]) == len(truth)
    for transform, odometry in list(zip(by_child[('map', 'base_link_truth')], truth))[::100]:
        assert transform.header.stamp == odometry.header.stamp
        assert msgs.pose_of(odometry.pose.pose) == pytest.approx((
            transform.transform.translation.x, transform.transform.translation.y,
            msgs.quaternion_yaw(transform.transform.rotation)), abs=1e-12)


def test_path_is_bounded_and_ends_at_the_last_estimate(run):
    _, rows, found, start_ns = run
    paths = [message for _, _, message in found['/ekf/path']]
    assert all(p.header.frame_id == 'map' for p in paths)
    assert max(len(p.poses) for p in paths) == PATH_LENGTH
    assert len(paths) == pytest.approx(rows[-1, 0] / visual_bag.PATH_PERIOD_S, abs=2)
    last = paths[-1]
    assert msgs.from_time(last.header.stamp) == pytest.approx(start_ns + rows[-1, 0] * 1e9,
                                                              abs=1e3)
    assert msgs.pose_of(last.poses[-1].pose) == pytest.approx(rows[-1, 1:4], abs=1e-6)
    stamps = [msgs.from_time(p.header.stamp) for p in last.poses]
    assert stamps == sorted(stamps)
    for pose in last.poses[::9]:
        row = _row_at(rows, start_ns, msgs.from_time(pose.header.stamp))
        assert msgs.pose_of(pose.pose) == pytest.approx(row[1:4], abs=1e-6)


def test_markers_show_ellipse_heading_and_associations(run):
    _, rows, found, start_ns = run
    landmarks = np.array([[p.position.x, p.position.y]
                          for p in _source('/landmark_map')[0].poses])
    with_associations = 0
    for stamp, _, message in found['/ekf/markers'][::5]:
        named = {m.ns: m for m in message.markers}
        assert set(named) == {'ellipse', 'heading', 'associated', 'association', 'rejected'}
        assert all(m.header.frame_id == 'map' and msgs.from_time(m.header.stamp) == stamp
                   for m in message.markers)
        row = _row_at(rows, start_ns, stamp)
        heading = msgs.pose_of(named['heading'].pose)
        assert heading == pytest.approx(row[1:4], abs=1e-6)
        # 2-sigma ellipse: the full axes are 4 sigma along the covariance's eigenvectors.
        covariance = np.array([[row[5], row[9]], [row[9], row[6]]])
        sigmas = np.sqrt(np.linalg.eigvalsh(covariance))
        scale = named['ellipse'].scale
        assert (scale.y, scale.x) == pytest.approx(4 * sigmas, rel=1e-4, abs=1e-9)
        detected = named['associated'].points
        lines = named['association'].points
        assert len(lines) == 2 * len(detected)
        for k, point in enumerate(detected):
            assert (lines[2 * k].x, lines[2 * k].y) == (point.x, point.y)
            end = np.array([lines[2 * k + 1].x, lines[2 * k + 1].y])
            assert np.min(np.linalg.norm(landmarks - end, axis=1)) < 1e-6   # a landmark
            assert np.linalg.norm(end - (point.x, point.y)) < 1.0
        with_associations += bool(detected)
        assert named['rejected'].points == []       # the offline run keeps no rejections
    assert with_associations > len(found['/ekf/markers']) / 10


def test_latched_map_and_mounts(run):
    bag, _, found, start_ns = run
    with Reader(bag) as reader:
        for connection in reader.connections:
            durability = connection.ext.offered_qos_profiles[0].durability \
                if connection.ext.offered_qos_profiles else None
            latched = connection.topic in ('/tf_static', '/landmark_markers')
            assert (durability == QosDurability.TRANSIENT_LOCAL) == latched, connection.topic
    (stamp, _, markers), = found['/landmark_markers']
    assert stamp == start_ns
    landmarks = _source('/landmark_map')[0].poses
    assert [m.id for m in markers.markers] == list(range(len(landmarks)))
    for marker, pose in zip(markers.markers, landmarks):
        assert marker.type == msgs.MARKER_CYLINDER and marker.header.frame_id == 'map'
        assert (marker.pose.position.x, marker.pose.position.y) == (pose.position.x,
                                                                    pose.position.y)
    (_, _, static), = found['/tf_static']
    mounts = {t.child_frame_id: t for t in static.transforms}
    assert set(mounts) == {'imu_link', 'laser'}
    assert all(t.header.frame_id == 'base_link' for t in static.transforms)
    imu = mounts['imu_link'].transform
    assert (imu.translation.x, imu.translation.y, imu.rotation.w) == (0.0, 0.0, 1.0)


def test_static_transforms_follow_the_sidecar_mount(tmp_path):
    bag = tmp_path / 'moved'
    shutil.copytree(SOURCE, bag)
    params = yaml.safe_load((BAGS / 'sim_static_start.params.yaml').read_text())
    lidar = params['/**']['ros__parameters']['lidar']
    lidar['scan'].update(x_m=0.31, y_m=-0.12, yaw_rad=0.25)
    (tmp_path / 'moved.params.yaml').write_text(yaml.safe_dump(params))
    assert _run(bag, tmp_path / 'out') == 0
    (_, _, static), = _messages(tmp_path / 'out' / output_dir.ESTIMATES_BAG)['/tf_static']
    # The child is the frame_id of the scans, so TF places them.
    mount, = [t for t in static.transforms if t.child_frame_id == 'laser']
    assert mount.header.frame_id == 'base_link'
    assert (mount.transform.translation.x, mount.transform.translation.y,
            mount.transform.translation.z) == (0.31, -0.12, 0.0)
    assert msgs.quaternion_yaw(mount.transform.rotation) == pytest.approx(0.25, abs=1e-15)


def test_path_length_zero_is_refused(tmp_path, capsys):
    with pytest.raises(SystemExit) as exit_info:
        _run(SOURCE, tmp_path / 'out', '--path-length', '0')
    assert exit_info.value.code == 2
    assert "--path-length: '0': must be a whole number of poses >= 1" in capsys.readouterr().err
    assert not (tmp_path / 'out').exists()
    stamps = np.arange(3) * 0.005
    with pytest.raises(OutputError, match='path length 0: must be a whole number of poses'):
        results.write_estimates_bag(tmp_path / 'estimates', 1_700_000_000_000_000_000, stamps,
                                    np.zeros((3, 4)), np.tile(np.eye(4), (3, 1, 1)),
                                    np.zeros(3), np.zeros(3), path_length=0)
    assert not (tmp_path / 'estimates').exists()
    assert not list(tmp_path.iterdir())


def test_marker_builder_ellipse_axes():
    # An ellipse along 30 deg with sigmas 0.2 and 0.05 m.
    angle = math.radians(30.0)
    rotation = np.array([[math.cos(angle), -math.sin(angle)],
                         [math.sin(angle), math.cos(angle)]])
    covariance = rotation @ np.diag([0.2**2, 0.05**2]) @ rotation.T
    major, minor, direction = msgs.covariance_ellipse(covariance)
    assert (major, minor) == pytest.approx((0.8, 0.2))
    assert math.remainder(direction - angle, math.pi) == pytest.approx(0.0, abs=1e-12)


def test_bias_is_in_the_imu_frame(run, tmp_path):
    # gyro-ekf run: imu_link, the frame of every bag convert, simulate and make-bags write.
    bag, _, found, _ = run
    imu_frame = _source('/imu')[0].header.frame_id
    with Reader(bag) as reader:
        chosen = [c for c in reader.connections if c.topic == '/ekf/bias']
        frames = {msgs.deserialize(d, c.msgtype).header.frame_id
                  for c, _, d in reader.messages(chosen)}
    assert frames == {imu_frame}
    (_, _, static), = found['/tf_static']
    assert imu_frame in {t.child_frame_id for t in static.transforms}
    # Another IMU frame: ekf/bias and the identity mount follow it.
    stamps = np.arange(3) * 0.005
    written = results.write_estimates_bag(
        tmp_path / 'estimates', 1_700_000_000_000_000_000, stamps, np.zeros((3, 4)),
        np.tile(np.eye(4), (3, 1, 1)), np.zeros(3), np.zeros(3), imu_frame='gyro_board')
    with Reader(written) as reader:
        seen = {(c.topic, f) for c, _, d in reader.messages() if c.topic != '/ekf/markers'
                for f in _frames(msgs.deserialize(d, c.msgtype))}
    assert ('/ekf/bias', 'gyro_board') in seen and ('/tf_static', 'gyro_board') in seen
    assert not any('imu_link' in f for _, f in seen)


def _frames(message) -> list[str]:
    if hasattr(message, 'transforms'):
        return [t.child_frame_id for t in message.transforms]
    return [message.header.frame_id]


def test_foxglove_layout_shows_only_topics_the_bag_has(run):
    bag, _, _, _ = run
    layout = json.loads((BAGS.parent / 'config' / 'foxglove_layout.json').read_text())
    with Reader(bag) as reader:
        present = {c.topic: c.msgcount for c in reader.connections}
    panels = layout['configById']
    shown = {topic for panel in panels.values() for topic in panel.get('topics', {})}
    plotted = {path['value'].split('.')[0] for panel in panels.values()
               for path in panel.get('paths', [])}
    assert shown | plotted and all(present.get(t, 0) > 0 for t in shown | plotted), \
        sorted((shown | plotted) - set(present))

    def leaves(node):
        return [node] if isinstance(node, str) else leaves(node['first']) + leaves(
            node['second'])
    assert sorted(leaves(layout['layout'])) == sorted(panels)
    # Rounding can leave a covariance slightly indefinite: a flat ellipse, never NaN.
    major, minor, _ = msgs.covariance_ellipse(np.array([[1e-6, 0.0], [0.0, -1e-18]]))
    assert (major, minor) == (pytest.approx(4e-3), 0.0)
