"""`gyro-ekf simulate` writes a readable bag or trip file and refuses to overwrite."""

import numpy as np

from gyro_ekf.cli.main import main
from gyro_ekf.io.bag_reader import read_trip_bag
from gyro_ekf.io.trip_file import load_trip


def test_simulate_writes_a_bag_that_reads_back(tmp_path, capsys):
    out = tmp_path / 'trip'
    assert main(['simulate', '-o', str(out), '--seed', '4', '--duration-s', '12']) == 0
    trip = read_trip_bag(out)
    assert trip.imu.stamp_s[-1] == 12.0
    assert trip.ground_truth is not None and trip.true_gyro_bias_rad_s is not None
    assert main(['simulate', '-o', str(out), '--seed', '4', '--duration-s', '12']) == 1
    assert 'exists' in capsys.readouterr().err


def test_simulate_npz_is_deterministic(tmp_path):
    paths = [tmp_path / 'a.npz', tmp_path / 'b.npz']
    for path in paths:
        assert main(['simulate', '-o', str(path), '--seed', '9', '--duration-s', '10',
                     '--static-s', '0']) == 0
    first, second = (load_trip(p) for p in paths)
    np.testing.assert_array_equal(first.imu.angular_velocity_rad_s,
                                  second.imu.angular_velocity_rad_s)
    # No static start was asked for: it is moving within the first second.
    assert first.speed.speed_m_s[first.speed.stamp_s < 1.0].max() > 0.01
