"""io.landmarks_file: the EKF node's landmark map file, and every way it can be bad."""

from __future__ import annotations

import numpy as np
import pytest

from gyro_ekf.core.config import InputLimits
from gyro_ekf.errors import GyroEkfError
from gyro_ekf.io.errors import LandmarksFileError
from gyro_ekf.io.landmarks_file import read_landmarks_file

XY = [[2.0, 0.0], [0.0, 3.0], [-4.0, 1.5]]


@pytest.mark.parametrize('name, text', [
    ('map.yaml', 'landmarks: [[2.0, 0.0], [0, 3], [-4.0, 1.5]]\n'),
    ('map.yml', 'landmarks:\n  - [2.0, 0.0]\n  - [0.0, 3.0]\n  - [-4.0, 1.5]\n'),
    ('map.txt', '# x y in m\n2.0 0.0\n\n0 3\n  -4.0, 1.5\n'),
    ('map', '2 0\n0 3\n-4 1.5'),
])
def test_yaml_and_text_maps_read_the_same_landmarks(tmp_path, name, text):
    path = tmp_path / name
    path.write_text(text)
    assert np.array_equal(read_landmarks_file(path).xy_m, XY)
    assert read_landmarks_file(str(path)).xy_m.dtype == np.float64


def _refused(path, match: str) -> str:
    with pytest.raises(LandmarksFileError, match=match) as caught:
        read_landmarks_file(path)
    message = str(caught.value)
    assert message.startswith(f'{path}: '), message
    assert '\n' not in message
    return message


def test_a_missing_file_or_a_folder_is_named(tmp_path):
    _refused(tmp_path / 'nowhere.yaml', 'cannot read the landmarks file: No such file')
    _refused(tmp_path, 'cannot read the landmarks file')
    assert issubclass(LandmarksFileError, GyroEkfError)  # the node's one-line exit 1


@pytest.mark.parametrize('data, match', [
    (b'landmarks: [[1.0, 2.0]]\n\x00\x01\x02', r'binary data \(NUL byte at offset 24\)'),
    (b'\x89PNG\r\n\x1a\n' + bytes(range(200, 256)), r'not UTF-8 text \(byte at offset 0\)'),
])
def test_a_binary_file_is_refused_as_not_a_landmarks_file(tmp_path, data, match):
    path = tmp_path / 'map.yaml'
    path.write_bytes(data)
    _refused(path, match + r': not a landmarks file')


@pytest.mark.parametrize('name, text, match', [
    ('m.yaml', 'landmarks: [[1.0, 2.0]\n', 'not valid YAML'),
    ('m.yaml', '- [1.0, 2.0]\n', r"expected a mapping with 'landmarks: \[\[x, y\]"),
    ('m.yaml', 'poles: [[1.0, 2.0]]\n', r"expected a mapping with 'landmarks"),
    ('m.yaml', 'landmarks: 3\n', r"'landmarks' must be a list of \[x, y\] pairs"),
    ('m.yaml', 'landmarks: []\n', 'holds no landmarks'),
    ('m.yaml', '', 'expected a mapping'),
    ('m.yaml', 'landmarks: [[1.0, 2.0], [3.0]]\n', r'landmark 1: expected two numbers x y'),
    ('m.yaml', 'landmarks: [[1.0, 2.0], [3.0, four]]\n', 'landmark 1: expected two numbers'),
    ('m.yaml', 'landmarks: [[1.0, true]]\n', 'landmark 0: expected two numbers'),
    ('m.yaml', 'landmarks: [[1.0, 2.0, 3.0]]\n', 'landmark 0: expected two numbers'),
    ('m.yaml', 'landmarks: [[.nan, 2.0]]\n', 'landmark 0: .*not finite'),
    ('m.yaml', 'landmarks: [[1.0, 2.0], [1e300, 0.0]]\n', 'landmark 1: .*exceeds'),
    ('m.txt', '1 2\n3 4 5\n', r"line 2: expected two numbers x y \(m\), got \['3', '4', '5'\]"),
    ('m.txt', '# only a comment\n\n', "holds no landmarks; expected one 'x y' per line"),
    ('m.txt', '1 2\npole 4\n', "line 2: expected two numbers x y .*'pole'"),
    ('m.txt', '1 2\n\ninf 4\n', 'line 3: .*not finite'),
])
def test_bad_content_is_refused_naming_file_and_landmark_or_line(tmp_path, name, text, match):
    path = tmp_path / name
    path.write_text(text)
    _refused(path, match)


def test_the_coordinate_limit_is_the_one_given(tmp_path):
    path = tmp_path / 'm.yaml'
    path.write_text('landmarks: [[150.0, 0.0]]\n')
    assert read_landmarks_file(path).xy_m.tolist() == [[150.0, 0.0]]
    with pytest.raises(LandmarksFileError, match='landmark 0: .*exceeds the limit 100'):
        read_landmarks_file(path, InputLimits(max_coordinate_m=100.0))
