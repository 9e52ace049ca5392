"""A --params-file rcl cannot read stops every node with one line naming the file, exit 1.

Each case starts the real node executable (`python -m gyro_ekf.nodes.NODE`) in a process
of its own, on loopback discovery and ROS_DOMAIN_ID 64, and reads its stderr.
"""

from __future__ import annotations

from pathlib import Path
import subprocess
import sys

import pytest

from gyro_ekf.ros_env import child_env

REPO = Path(__file__).resolve().parents[2]
NODES = ('ekf_node', 'calibration_node', 'landmark_detector_node')


def _start(tmp_path: Path, node: str, params_file: Path) -> subprocess.CompletedProcess:
    env = child_env(64, tmp_path / 'ros_log')
    return subprocess.run([sys.executable, '-m', f'gyro_ekf.nodes.{node}', '--ros-args',
                           '--params-file', str(params_file)], env=env, cwd=REPO,
                          capture_output=True, text=True, timeout=120)


def _one_fatal_line(result: subprocess.CompletedProcess) -> str:
    assert result.returncode == 1, result.stderr
    assert 'Traceback' not in result.stderr + result.stdout, result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith('[FATAL] '), result.stderr
    return lines[0]


@pytest.mark.ros
@pytest.mark.parametrize('node', NODES)
def test_a_missing_params_file_is_one_line_naming_it(tmp_path, node):
    missing = tmp_path / 'nonexistent.yaml'
    line = _one_fatal_line(_start(tmp_path, node, missing))
    assert line == f'[FATAL] --params-file {missing}: no such file'


@pytest.mark.ros
@pytest.mark.parametrize('content,words', [
    (b'a: [\n', 'not a YAML file: expected the node content'),
    (b'\x00\xff\xfe binary', 'not a YAML file (not UTF-8 text)'),
    (b'- 1\n- 2\n', 'not a ROS 2 params file: a list'),
    (b'ekf_node:\n  publish_every_n: 2\n', "'ekf_node.publish_every_n' has a value where"),
    (b'ekf_node:\n  ros__parameters: 3\n', 'ekf_node.ros__parameters is not a mapping'),
])
def test_a_params_file_rcl_cannot_parse_is_one_line_naming_it(tmp_path, content, words):
    bad = tmp_path / 'bad.yaml'
    bad.write_bytes(content)
    line = _one_fatal_line(_start(tmp_path, 'ekf_node', bad))
    assert line.startswith(f'[FATAL] --params-file {bad}: '), line
    assert words in line, line


@pytest.mark.ros
def test_a_folder_as_params_file_is_one_line_naming_it(tmp_path):
    line = _one_fatal_line(_start(tmp_path, 'calibration_node', tmp_path))
    assert line == f'[FATAL] --params-file {tmp_path}: cannot read it: is a directory'
