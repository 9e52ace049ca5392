"""`gyro-ekf calibrate` on the real logs: the course value, and refusal on moving starts."""

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


def test_calibrate_2021_log_yaw_only(shared_data, capsys):
    assert main(['calibrate', str(shared_data('2021_aas01')), '--json']) == 0
    report = json.loads(capsys.readouterr().out)
    assert report['axes_known'] == [False, False, True]
    # The 2021 log stores the same trip's yaw rate in 0.01 deg/s.
    assert report['bias_deg_s'][2] == pytest.approx(-0.9748, abs=0.01)


@pytest.mark.parametrize('log', ['2022_sim/data019b.mat', '2023_sim/DataUsr_006k.mat'])
def test_calibrate_refuses_logs_that_move_from_the_start(shared_data, capsys, log):
    assert main(['calibrate', str(shared_data(log))]) == 1
    assert 'platform moved' in capsys.readouterr().err
