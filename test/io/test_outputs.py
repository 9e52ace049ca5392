"""estimates.csv, summary.json and the estimates bag."""

from __future__ import annotations

import json
import math
import os

import numpy as np
import pytest
from rosbags.rosbag2 import Reader

from gyro_ekf import topics
from gyro_ekf.io import output_dir, results
from gyro_ekf.io.errors import OutputError
from gyro_ekf.io import messages as msgs


def _history(n=5):
    stamps = np.arange(n) * 0.005
    state = np.column_stack([np.arange(n), 2 * np.arange(n), np.full(n, 0.5),
                             np.full(n, -0.017)]).astype(float)
    P = np.array([[1, 5, 6, 0], [5, 2, 7, 0], [6, 7, 3, 0], [0, 0, 0, 4]], dtype=float)
    return stamps, state, np.tile(P, (n, 1, 1))


def test_csv_header_columns_and_units(tmp_path):
    stamps, state, P = _history()
    path = results.write_estimates_csv(tmp_path / 'estimates.csv', stamps, state, P)
    lines = path.read_text().splitlines()
    assert lines[0] == 't,x,y,yaw,bias,var_x,var_y,var_yaw,var_bias,cov_xy,cov_xyaw,cov_yyaw'
    rows = np.loadtxt(path, delimiter=',', skiprows=1)
    assert rows.shape == (5, 12)
    assert rows[1].tolist() == pytest.approx([0.005, 1, 2, 0.5, -0.017, 1, 2, 3, 4, 5, 6, 7])
    assert not list(tmp_path.glob('.*.tmp'))


def test_csv_rows_do_not_depend_on_the_blocks_they_are_formatted_in(tmp_path, monkeypatch):
    stamps, state, P = _history(30)
    P = P * np.linspace(1.0, 2.0, 30)[:, None, None]  # rows that differ
    whole = results.write_estimates_csv(tmp_path / 'whole.csv', stamps, state, P)
    monkeypatch.setattr(results, '_CSV_BLOCK_ROWS', 7)  # no divisor of 30
    blocked = results.write_estimates_csv(tmp_path / 'blocked.csv', stamps, state, P)
    assert blocked.read_bytes() == whole.read_bytes()
    assert len(whole.read_text().splitlines()) == 31


def test_output_folder_is_not_overwritten_without_force(tmp_path):
    out = tmp_path / 'out'
    assert output_dir.prepare_output_dir(out) == out
    assert not out.exists()                       # nothing is created before the outputs
    out.mkdir()
    output_dir.prepare_output_dir(out)              # empty: fine
    (out / 'summary.json').write_text('{}')
    with pytest.raises(OutputError, match='not empty; use --force'):
        output_dir.prepare_output_dir(out)
    assert output_dir.prepare_output_dir(out, force=True) == out
    (tmp_path / 'file').write_text('')
    with pytest.raises(OutputError, match='not a folder'):
        output_dir.prepare_output_dir(tmp_path / 'file')


def test_an_output_folder_on_a_file_system_of_its_own_is_staged_inside_it(tmp_path,
                                                                          monkeypatch):
    # A container's volume as -o: a rename from a staging folder beside it crossed file
    # systems ("invalid cross-device link"). Such a folder stages inside itself.
    out = tmp_path / 'volume'
    out.mkdir()
    real_stat = output_dir.Path.stat

    def stat(path, *args, **kwargs):
        result = real_stat(path, *args, **kwargs)
        if path != out.absolute():
            return result
        fields = list(result[:10])
        fields[2] += 1  # st_dev: another file system than its parent's
        return os.stat_result(fields)
    monkeypatch.setattr(output_dir.Path, 'stat', stat)
    assert output_dir._stage_in(out.absolute()) == out.absolute()
    for force, text in ((False, 'first'), (True, 'second')):
        with output_dir.staged_output_dir(out, force=force) as staging:
            assert staging.parent == out.absolute()
            (staging / 'summary.json').write_text(text)
        assert sorted(p.name for p in out.iterdir()) == ['summary.json']
        assert (out / 'summary.json').read_text() == text
    assert sorted(p.name for p in tmp_path.iterdir()) == ['volume']


def test_a_failed_write_leaves_no_folder_it_made(tmp_path):
    # Staging starts before `gyro-ekf run` filters (its products are written meanwhile): a
    # run that fails removes the folders made for -o, and only those.
    (tmp_path / 'kept').mkdir()
    for out in (tmp_path / 'new' / 'deeper' / 'out', tmp_path / 'kept' / 'out'):
        with pytest.raises(RuntimeError, match='the run failed'):
            with output_dir.staged_output_dir(out) as staging:
                (staging / 'summary.json').write_text('{}')
                raise RuntimeError('the run failed')
    assert sorted(p.name for p in tmp_path.iterdir()) == ['kept']
    assert list((tmp_path / 'kept').iterdir()) == []
    with output_dir.staged_output_dir(tmp_path / 'new' / 'out') as staging:
        (staging / 'summary.json').write_text('{}')
    assert [p.name for p in (tmp_path / 'new' / 'out').iterdir()] == ['summary.json']


def test_summary_json_turns_nan_into_null(tmp_path):
    path = results.write_summary_json(tmp_path / 's.json', {
        'a': math.nan, 'b': np.float64(1.5), 'c': np.array([1, 2]), 'd': {'e': np.int64(3)}})
    assert json.loads(path.read_text()) == {'a': None, 'b': 1.5, 'c': [1, 2], 'd': {'e': 3}}


def test_estimates_bag_has_the_live_node_topics(tmp_path):
    stamps, state, P = _history()
    bag = results.write_estimates_bag(tmp_path / 'estimates', 1_700_000_000_000_000_000, stamps,
                                      state, P, np.full(5, 0.3), np.full(5, 0.1))
    with Reader(bag) as reader:
        kinds = {c.topic: c.msgtype for c in reader.connections}
        # Besides these, the visual topics (test_estimates_bag_visual.py).
        assert kinds.items() >= {'/ekf/pose': topics.POSE_WITH_COVARIANCE_STAMPED_TYPE,
                                 '/ekf/odometry': topics.ODOMETRY_TYPE,
                                 '/ekf/bias': topics.VECTOR3_STAMPED_TYPE}.items()
        assert [c.msgcount for c in reader.connections if c.topic.startswith('/ekf/')
                and c.topic not in ('/ekf/path', '/ekf/markers')] == [5, 5, 5]
        messages = {}
        for connection, stamp, data in reader.messages():
            messages.setdefault(connection.topic, []).append(
                (stamp, msgs.deserialize(data, connection.msgtype)))
    stamp, pose = messages['/ekf/pose'][1]
    assert stamp == 1_700_000_000_005_000_000
    assert pose.header.frame_id == 'map'
    assert pose.pose.pose.position.x == 1.0
    assert msgs.quaternion_yaw(pose.pose.pose.orientation) == pytest.approx(0.5)
    cov = pose.pose.covariance.reshape(6, 6)
    assert cov[0, 0] == 1 and cov[0, 1] == 5 and cov[0, 5] == 6 and cov[5, 5] == 3
    odom = messages['/ekf/odometry'][1][1]
    assert odom.child_frame_id == 'base_link'
    assert odom.twist.twist.linear.x == pytest.approx(0.3)
    assert odom.twist.twist.angular.z == pytest.approx(0.1)
    assert messages['/ekf/bias'][1][1].vector.z == pytest.approx(-0.017)
    with pytest.raises(OutputError, match='exists already'):
        results.write_estimates_bag(bag, 1, stamps, state, P, np.zeros(5), np.zeros(5))
