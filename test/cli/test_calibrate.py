"""`gyro-ekf calibrate` on the real logs: the course value, and refusal on moving starts."""

import dataclasses
import json

import pytest

from gyro_ekf.cli.main import main


def test_calibrate_2016_log_prints_the_course_bias(shared_data, capsys):
    assert main(['calibrate', str(shared_data('2016_project1')), '--json']) == 0
    report = json.loads(capsys.readouterr().out)
    print('2016 bias deg/s:', report['bias_deg_s'], 'sigma deg/s:', report['sigma_deg_s'])
    assert report['bias_deg_s'][2] == pytest.approx(-0.9748, abs=0.001)
    assert report['n_samples'] == 1001
    assert all(report['axes_known'])


PER_AXIS = ('bias_rad_s', 'sigma_rad_s', 'bias_deg_s', 'sigma_deg_s', 'standard_error_deg_s')


def test_calibrate_2021_log_yaw_only(shared_data, capsys):
    assert main(['calibrate', str(shared_data('2021_aas01')), '--json']) == 0
    report = json.loads(capsys.readouterr().out)
    assert report['axes_known'] == [False, False, True]
    # The 2021 log stores the same trip's yaw rate in 0.01 deg/s.
    assert report['bias_deg_s'][2] == pytest.approx(-0.9748, abs=0.01)
    # x and y are not measured: null, not a bias and a noise of exactly 0 (as before).
    for key in PER_AXIS:
        assert report[key][:2] == [None, None], key
        assert report[key][2] > 0 if 'sigma' in key or 'error' in key else report[key][2] < 0


def test_calibrate_a_bag_says_null_for_the_axes_it_does_not_measure(tmp_path, capsys):
    # The same simulated trip written as a bag twice, its gyro once with x and y marked
    # not measured (as convert writes a yaw-rate-only log): only those two become null.
    from gyro_ekf.io.bag_writer import write_trip_bag
    from gyro_ekf.io.trip_file import load_trip

    assert main(['-q', 'simulate', '-o', str(tmp_path / 'trip.npz'), '--duration-s', '20',
                 '--static-s', '8', '--seed', '4']) == 0
    trip = load_trip(tmp_path / 'trip.npz')
    z_only = dataclasses.replace(trip.imu, axes_known=(False, False, True))
    reports = []
    for name, written in (('xyz', trip), ('z', dataclasses.replace(trip, imu=z_only))):
        bag = write_trip_bag(written, tmp_path / name)
        assert main(['-q', 'calibrate', str(bag), '--json']) == 0
        reports.append(json.loads(capsys.readouterr().out))
    every, z = reports
    assert every['axes_known'] == [True, True, True] and z['axes_known'] == [False, False, True]
    for key in PER_AXIS:
        assert None not in every[key], key
        assert z[key] == [None, None, every[key][2]], key


@pytest.mark.parametrize('log', ['2022_sim/data019b.mat', '2023_sim/DataUsr_006k.mat'])
def test_calibrate_refuses_logs_that_move_from_the_start(shared_data, capsys, log):
    assert main(['calibrate', str(shared_data(log))]) == 1
    assert 'platform moved' in capsys.readouterr().err
