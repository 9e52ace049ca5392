"""Offline static-window calibration: synthetic windows and the real 2016 log."""

import math

import numpy as np
import pytest
import scipy.io

from gyro_ekf.core.calibration import StaticWindowCalibrator, estimate_gyro_bias
from gyro_ekf.core.config import CalibrationConfig
from gyro_ekf.core.errors import CalibrationError

BIAS = np.array([0.003, -0.002, -0.017])
SIGMA = np.array([0.004, 0.0045, 0.005])


def _static(seed=0, rate_hz=200.0, duration_s=10.0):
    rng = np.random.default_rng(seed)
    stamps = np.arange(0.0, duration_s, 1.0 / rate_hz)
    rates = BIAS + rng.normal(size=(stamps.size, 3)) * SIGMA
    return stamps, rates


def test_static_window_gives_mean_and_sigma_per_axis():
    stamps, rates = _static()
    estimate = estimate_gyro_bias(stamps, rates)
    assert estimate.n_samples == 1001
    assert estimate.window_start_s == 0.0 and estimate.window_end_s == pytest.approx(5.0)
    np.testing.assert_allclose(estimate.bias_rad_s, BIAS, atol=4 * SIGMA.max() / math.sqrt(1000))
    np.testing.assert_allclose(estimate.sigma_rad_s, SIGMA, rtol=0.1)
    corrected = estimate.correct(rates)
    np.testing.assert_allclose(corrected[stamps <= 5.0].mean(axis=0), 0.0, atol=1e-12)


def test_window_start_and_length_are_configurable():
    stamps, rates = _static()
    rates[stamps < 4.0] += 0.5  # spinning at first, still from 4 s on
    with pytest.raises(CalibrationError, match='not static'):
        estimate_gyro_bias(stamps, rates)
    estimate = estimate_gyro_bias(stamps, rates,
                                  CalibrationConfig(window_start_s=4.0, window_length_s=5.0))
    assert estimate.window_start_s >= 4.0
    np.testing.assert_allclose(estimate.bias_rad_s, BIAS, atol=0.001)


@pytest.mark.parametrize('change, message', [
    (lambda s, r: (s[:30], r[:30]), 'needs data until'),
    (lambda s, r: (s[::40], r[::40]), 'samples, at least'),
    (lambda s, r: (np.delete(s, range(300, 400)), np.delete(r, range(300, 400), axis=0)),
     'gap of 0.505 s'),
    (lambda s, r: (s, r + np.outer(s > 2.5, [0, 0, 0.01])), 'z mean changed'),
    (lambda s, r: (s, r + np.outer(np.sin(40 * s), [0.1, 0, 0])), 'x spread'),
])
def test_bad_windows_are_refused_with_the_reason(change, message):
    stamps, rates = change(*_static())
    with pytest.raises(CalibrationError, match=message):
        estimate_gyro_bias(stamps, rates)


def test_speed_inside_the_window_refuses_it():
    stamps, rates = _static()
    speeds = np.where(stamps > 3.2, 0.2, 0.0)
    with pytest.raises(CalibrationError, match=r'moved: speed 0.2.* at 3.2'):
        estimate_gyro_bias(stamps, rates, speed_stamp_s=stamps, speed_m_s=speeds)
    estimate_gyro_bias(stamps, rates, CalibrationConfig(window_length_s=3.0),
                       speed_stamp_s=stamps, speed_m_s=speeds)


def test_yaw_only_gyro_reports_only_z():
    stamps, rates = _static()
    estimate = estimate_gyro_bias(stamps, rates[:, 2])
    assert estimate.bias_rad_s[0] == 0.0 and estimate.bias_rad_s[1] == 0.0
    assert estimate.bias_rad_s[2] == pytest.approx(BIAS[2], abs=0.001)


def test_streaming_calibrator_refuses_motion_then_accepts_a_still_window():
    stamps, rates = _static(duration_s=12.0)
    calibrator = StaticWindowCalibrator()
    refused, accepted = [], None
    for stamp, rate in zip(stamps, rates):
        calibrator.add_speed(stamp, 0.3 if stamp < 1.0 else 0.0)
        try:
            accepted = calibrator.add_imu(stamp, tuple(rate)) or accepted
        except CalibrationError as err:
            refused.append((stamp, str(err)))
    assert len(refused) == 1 and 'moved' in refused[0][1]
    assert accepted is not None and accepted.window_start_s > 5.0
    assert calibrator.refusals == 1
    np.testing.assert_allclose(accepted.bias_rad_s, BIAS, atol=0.001)


def _load_2016(shared_data):
    imu = scipy.io.loadmat(shared_data('2016_project1/IMU_dataC.mat'), squeeze_me=True,
                           struct_as_record=False)['IMU']
    speed = scipy.io.loadmat(shared_data('2016_project1/Speed_dataC.mat'), squeeze_me=True,
                             struct_as_record=False)['Vel']
    stamps = (imu.times.astype(np.int64) - int(imu.times[0])) * 1e-4
    # Rows 4-6 are the roll, pitch and yaw rates, rad/s; +row 6 is counter-clockwise yaw.
    return stamps, imu.DATAf[3:6].T.astype(np.float64), speed.speeds.astype(np.float64)


def test_real_2016_log_first_five_seconds(shared_data):
    stamps, rates, speeds = _load_2016(shared_data)
    estimate = estimate_gyro_bias(stamps, rates, speed_stamp_s=stamps, speed_m_s=speeds)
    bias_deg_s = np.rad2deg(estimate.bias_rad_s)
    print('2016 log, first 5 s: bias x y z = %.4f %.4f %.4f deg/s, sigma = %s deg/s' % (
        *bias_deg_s, np.round(np.rad2deg(estimate.sigma_rad_s), 4)))
    assert bias_deg_s[2] == pytest.approx(-0.9748, abs=0.001)
    assert np.rad2deg(estimate.sigma_rad_s[2]) == pytest.approx(0.234, abs=0.01)


def test_real_2016_log_window_with_start_of_motion_is_refused(shared_data):
    stamps, rates, speeds = _load_2016(shared_data)
    moving_from_s = stamps[np.argmax(np.abs(speeds) > 1e-3)]
    assert moving_from_s == pytest.approx(17.93, abs=0.01)
    with pytest.raises(CalibrationError, match='moved'):
        estimate_gyro_bias(stamps, rates, CalibrationConfig(window_start_s=15.0),
                           speed_stamp_s=stamps, speed_m_s=speeds)


# A turn in place: the odometry reads no speed, the gyro a steady rate with its usual
# spread, and the window's mean took the turn for bias (0.1 deg/s: 0.098 deg/s off,
# accepted). The LiDAR sees the poles turn about the platform.

def _turning(turn_deg_s: float, seed: int = 3):
    from gyro_ekf.core.simulator import SimulationConfig, simulate_trip
    return simulate_trip(SimulationConfig(duration_s=12.0, static_turn_rad_s=math.radians(
        turn_deg_s)), seed=seed)


@pytest.mark.parametrize('turn_deg_s', [0.1, -0.3, 1.0])
def test_a_platform_turning_in_place_is_refused_by_what_its_lidar_saw(turn_deg_s):
    from gyro_ekf.core.calibration import calibrate_trip, scan_turn
    trip = _turning(turn_deg_s)
    sign = '\\+' if turn_deg_s > 0 else '-'
    with pytest.raises(CalibrationError, match=f"platform not static: its LiDAR 'scan' saw "
                       f'it turn {sign}[0-9.]+ deg/s .* which the gyro\'s mean would take for '
                       'bias') as refused:
        calibrate_trip(trip)
    seen = scan_turn(trip.scans[0], 0.0, 5.0)
    assert math.degrees(seen.rate_rad_s) == pytest.approx(turn_deg_s, rel=0.15), str(refused)
    assert seen.poles >= 3 and seen.turning
    # `run` says why its summary has no offline bias (and --use-calibration seeds none).
    from gyro_ekf.analysis.offline import calibrate
    assert calibrate(trip) == (None, str(refused.value))
    # What the check stops: the gyro alone accepts the window, the turn taken for bias.
    blind = calibrate_trip(trip, use_scans=False)
    assert math.degrees(blind.bias_rad_s[2] - trip.true_gyro_bias_rad_s[2]) == pytest.approx(
        turn_deg_s, abs=0.01)


@pytest.mark.parametrize('seed', [1, 3, 7])
def test_a_still_platform_is_confirmed_by_its_lidar(seed):
    from gyro_ekf.core.calibration import calibrate_trip
    trip = _turning(0.0, seed)
    estimate = calibrate_trip(trip)
    (turn,) = estimate.scan_turns
    assert turn.topic == 'scan' and turn.scans == 51 and turn.poles >= 3
    assert abs(math.degrees(turn.rate_rad_s)) < 0.002 and not turn.turning
    assert math.degrees(estimate.bias_rad_s[2] - trip.true_gyro_bias_rad_s[2]) == pytest.approx(
        0.0, abs=0.01)


def test_pole_turn_follows_each_pole_and_needs_one_through_half_the_scans():
    from gyro_ekf.core.calibration import pole_turn
    # Two poles in the body frame, turning about the platform at -0.5 deg/s (it turns +0.5).
    rate = math.radians(0.5)
    stamps = np.arange(40) * 0.1
    scans = [np.array([[5.0 * math.cos(b - rate * t), 5.0 * math.sin(b - rate * t)]
                       for b in (0.3, -1.2)]) for t in stamps]
    turn = pole_turn(stamps.tolist(), scans)
    assert turn.poles == 2 and turn.scans == 40
    assert turn.rate_rad_s == pytest.approx(rate, rel=1e-9) and turn.turning
    # A pole seen in a third of the scans only: nothing followed, nothing said.
    assert pole_turn(stamps.tolist(), [s if k % 3 == 0 else s[:0] for k, s in
                                       enumerate(scans)]) is None


def test_real_2016_log_static_start_is_still_by_its_lidar(shared_data, tmp_path):
    from gyro_ekf.core.calibration import scan_turn
    from gyro_ekf.io.sources import load_checked_log
    trip, _ = load_checked_log([shared_data('2016_project1')], landmarks=False)
    t0 = trip.imu.stamp_s[0]
    for start, end in ((0.0, 5.0), (0.0, 17.0)):
        turn = scan_turn(trip.scans[0], t0 + start, t0 + end)
        print(f'2016 log {start}-{end} s: LiDAR turn {math.degrees(turn.rate_rad_s):+.5f} '
              f'+- {math.degrees(turn.sigma_rad_s):.5f} deg/s, {turn.poles} poles')
        assert turn.poles == 5 and not turn.turning
        assert abs(math.degrees(turn.rate_rad_s)) < 0.001


def _ring(turned_rad: float) -> np.ndarray:
    """Three poles in the LiDAR's frame, seen from a platform turned by turned_rad."""
    return np.array([[r * math.cos(b - turned_rad), r * math.sin(b - turned_rad)]
                     for b, r in ((0.4, 5.0), (-0.9, 7.0), (2.0, 9.0))])


def test_the_streaming_calibrator_waits_for_late_scans_and_refuses_a_turn():
    # Live, a LiDAR's poles come after the gyro samples of their time (detection,
    # transport): the window waits for its last scans, up to POLE_WAIT_S of gyro time.
    from gyro_ekf.core.calibration import POLE_WAIT_S
    turn = math.radians(0.3)
    calibrator = StaticWindowCalibrator(CalibrationConfig(window_length_s=1.0))
    for k in range(6):  # scans up to 0.5 s only
        calibrator.add_poles('laser', 0.1 * k, _ring(turn * 0.1 * k))
    results = [calibrator.add_imu(0.005 * i, (0.0, 0.0, 0.01 + turn)) for i in range(260)]
    assert results == [None] * 260  # the window [0, 1] s waits for its last scans
    for k in range(6, 11):
        calibrator.add_poles('laser', 0.1 * k, _ring(turn * 0.1 * k))
    with pytest.raises(CalibrationError, match="its LiDAR 'laser' saw it turn \\+0.3"):
        calibrator.add_imu(1.3, (0.0, 0.0, 0.01 + turn))
    assert calibrator.refusals == 1
    # Still from here: the next window (1.3 s on) holds no turn; scans that never come
    # are waited for no longer than POLE_WAIT_S.
    for k in range(13, 20):  # to 1.9 s: the window's last 0.4 s never come
        calibrator.add_poles('laser', 0.1 * k, _ring(turn * 1.3))
    stamps = 1.3 + 0.005 * np.arange(1, int((1.0 + POLE_WAIT_S) / 0.005) + 2)
    accepted = [calibrator.add_imu(float(t), (0.0, 0.0, 0.01)) for t in stamps]
    assert accepted[-1] is not None and accepted[:-1] == [None] * (len(stamps) - 1)
    (seen,) = accepted[-1].scan_turns
    assert seen.topic == 'laser' and seen.poles == 3 and abs(seen.rate_rad_s) < 1e-9
    assert accepted[-1].bias_rad_s[2] == pytest.approx(0.01)
