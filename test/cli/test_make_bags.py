"""The bundled bags rebuild bit for bit, stay small, and behave as their README says."""

import filecmp
import math
from pathlib import Path

import pytest

from gyro_ekf.cli.calibrate import calibrate_trip
from gyro_ekf.cli.make_bags import BUNDLED_BAGS, build_bundled_bags
from gyro_ekf.core.config import CalibrationConfig
from gyro_ekf.core.errors import CalibrationError
from gyro_ekf.io.bag_reader import read_trip_bag

BAGS = Path(__file__).resolve().parents[2] / 'bags'


def _files(root):
    return sorted(p.relative_to(root) for p in root.rglob('*') if p.is_file()
                  and p.name != 'README.md')


def test_make_bags_rebuilds_the_committed_bags_bit_for_bit(tmp_path):
    build_bundled_bags(tmp_path)
    assert _files(tmp_path) == _files(BAGS)
    for relative in _files(BAGS):
        assert filecmp.cmp(tmp_path / relative, BAGS / relative, shallow=False), relative


def test_bundled_bags_are_small_and_described():
    total = sum((BAGS / f).stat().st_size for f in _files(BAGS))
    assert total < 5e6, f'bundled bags take {total / 1e6:.2f} MB'
    readme = (BAGS / 'README.md').read_text()
    for bag in BUNDLED_BAGS:
        assert f'`{bag.name}`' in readme


def test_static_start_bag_calibrates_to_its_injected_bias():
    trip = read_trip_bag(BAGS / 'sim_static_start')
    estimate = calibrate_trip(trip, CalibrationConfig())
    assert trip.true_gyro_bias_rad_s is not None and trip.ground_truth is not None
    standard_error = estimate.bias_standard_error_rad_s
    for axis in range(3):
        assert abs(estimate.bias_rad_s[axis] - trip.true_gyro_bias_rad_s[axis]) < (
            4 * standard_error[axis])
    assert math.degrees(trip.true_gyro_bias_rad_s[2]) == pytest.approx(-0.9)


def test_moving_start_bag_is_refused_by_calibration():
    trip = read_trip_bag(BAGS / 'sim_moving_start')
    with pytest.raises(CalibrationError, match='moved'):
        calibrate_trip(trip, CalibrationConfig())
