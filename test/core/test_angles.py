"""Yaw of a quaternion: the ZYX definition, the batch path, and a norm slightly off 1."""

from __future__ import annotations

import math

import numpy as np

from gyro_ekf.core.angles import quaternion_of_yaw, yaw_of_quaternion, yaws_of_quaternions


def _textbook_yaw(x: float, y: float, z: float, w: float) -> float:
    # The ZYX Euler yaw of a unit quaternion as usually written.
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def test_yaw_of_a_unit_quaternion_is_the_zyx_yaw_and_the_batch_path_agrees_bit_for_bit():
    rng = np.random.default_rng(3)
    q = rng.normal(size=(200, 4))
    q /= np.linalg.norm(q, axis=1)[:, None]
    one_by_one = [yaw_of_quaternion(*row) for row in q.tolist()]
    for row, yaw in zip(q.tolist(), one_by_one):
        assert abs(math.remainder(yaw - _textbook_yaw(*row), math.tau)) < 1e-12
    assert yaws_of_quaternions(*q.T).tolist() == one_by_one


def test_a_quaternion_within_the_norm_tolerance_gives_the_yaw_of_its_unit_one():
    # The validation boundary accepts a norm within 0.01 of 1; the textbook form then moved
    # the yaw by up to 6 mrad (here 5 mrad at 1 rad).
    for yaw in (-2.5, -1.0, 0.3, 1.0, 3.0):
        _, _, z, w = quaternion_of_yaw(yaw)
        for scale in (0.99, 1.005, 1.01):
            assert abs(yaw_of_quaternion(0.0, 0.0, scale * z, scale * w) - yaw) < 1e-12
    assert abs(_textbook_yaw(0.0, 0.0, 1.005 * math.sin(0.5), 1.005 * math.cos(0.5)) - 1.0) \
        > 4e-3
