"""Zero-rate updates: standing still, each gyro sample measures the bias (core/events.py)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from stop_trips import trip_with_stops

from gyro_ekf.core.config import EkfConfig, with_stated_noise
from gyro_ekf.core.ekf import GyroBiasEkf
from gyro_ekf.core.events import EventDriver
from gyro_ekf.core.gyro_wander import block_mean_share
from gyro_ekf.core.trip_run import drive_trip

OFF = {'zero_rate_max_spread_rad_s': 0.0}
STATIC_START_2016_S = 17.92
"""The 2016 trip's static start (shared data README: speed exactly 0 until then)."""
STOPS_AT_S, STOP_S = (15.0, 30.0, 45.0), 5.0


def _drive(trip, **changes):
    config = with_stated_noise(dataclasses.replace(EkfConfig(), **changes), trip.noise)
    return drive_trip(trip, EventDriver(config, pose=trip.initial_pose))


def _at(estimates, stamp_s):
    """Row of the last estimate at or before stamp_s."""
    return int(np.searchsorted(estimates.stamp_s, stamp_s, side='right')) - 1


def test_a_zero_rate_update_is_the_kalman_update_of_h_equal_b_plus_c():
    # The gyro at rest reads the bias and the wander: h = b + c, H = [0, 0, 0, 1, 1].
    rng = np.random.default_rng(4)
    A = rng.standard_normal((5, 5))
    ekf = GyroBiasEkf(EkfConfig(), pose=np.array([1.0, 2.0, 0.3]), bias_rad_s=0.01,
                      covariance=A @ A.T + 0.1 * np.eye(5))
    x, P = ekf.x, ekf.P
    z, r = 0.02, 1e-4
    H = np.array([[0.0, 0.0, 0.0, 1.0, 1.0]])
    S = (H @ P @ H.T).item() + r
    K = P @ H.T / S
    nis = ekf.update_zero_rate(z, r)
    I_KH = np.eye(5) - K @ H
    assert np.allclose(ekf.x, x + (K * (z - x[3] - x[4])).ravel(), atol=1e-15)
    assert np.allclose(ekf.P, I_KH @ P @ I_KH.T + r * K @ K.T, atol=1e-12)
    assert nis == pytest.approx((z - x[3] - x[4]) ** 2 / S)


def test_holding_the_position_moves_only_the_heading():
    config = EkfConfig()
    ekf = GyroBiasEkf(config, pose=np.array([1.0, 2.0, 0.3]), bias_rad_s=0.01)
    P = ekf.P
    ekf.predict(0.5, 0.03, 0.1, hold_position=True)
    assert ekf.x[:2].tolist() == [1.0, 2.0]
    assert ekf.x[2] == pytest.approx(0.3 + 0.1 * (0.03 - 0.01))
    # No speed noise; only the position random walk.
    walk = 0.1 * config.position_random_walk_m_sqrt_s ** 2
    assert np.allclose(ekf.P[:2, :2], P[:2, :2] + walk * np.eye(2), rtol=0, atol=1e-18)


def test_holding_still_at_an_exact_pose_moves_only_the_bias():
    ekf = GyroBiasEkf(EkfConfig(bias_random_walk_rad_s2=1e-4), pose=np.array([1.0, 2.0, 0.3]),
                      bias_rad_s=0.01)
    ekf.bias_rate_found = 2e-3
    x, P = ekf.x, ekf.P
    ekf.hold_still(0.1)
    # As predict with speed 0, the heading not integrated and no noise but the bias's.
    assert ekf.x[:3].tolist() == x[:3].tolist()
    assert ekf.x[3] == pytest.approx(0.01 + 0.1 * 2e-3)
    grown = P.copy()
    grown[3, 3] += 0.1 ** 2 * 1e-4 ** 2
    assert np.array_equal(ekf.P[:3], grown[:3]) and ekf.P[3, 3] == pytest.approx(grown[3, 3])


@pytest.fixture(scope='module')
def stops():
    """A 60 s simulated trip with three 5 s stops, run with and without zero-rate updates.

    With the defaults, and with no wander assumed (the gyro's white noise alone).
    """
    trip, spans = trip_with_stops(seed=3, stops_at_s=STOPS_AT_S, stop_s=STOP_S)
    white = {'gyro_wander_prior_rad_s': 0.0}
    return (trip, spans, _drive(trip), _drive(trip, **OFF), _drive(trip, **white),
            _drive(trip, **OFF, **white))


def _information_per_stop(run, spans):
    """Bias information gained over each stop, 1/sigma_end^2 - 1/sigma_start^2, (s/rad)^2."""
    estimates = run.estimates
    gained = []
    for start_s, end_s in spans:
        first, last = _at(estimates, start_s), _at(estimates, end_s)
        var = estimates.covariance[[first, last], 3, 3]
        gained.append(1.0 / var[1] - 1.0 / var[0])
    return np.array(gained)


def test_the_bias_sigma_shrinks_at_every_stop_by_what_the_gyro_samples_tell(stops):
    trip, spans, run, off, white, white_off = stops
    # Standing still, each of the stop's gyro samples measures the bias with the gyro's
    # white noise: n samples add about n / sigma^2 of information (less the first
    # zero_rate_min_still_s, which only shows the platform is still).
    sigma = trip.noise.gyro_rad_s
    rate = 1.0 / np.median(np.diff(trip.imu.stamp_s))
    still_s = STOP_S - EkfConfig().zero_rate_min_still_s
    offered = still_s * rate / sigma ** 2
    gained = _information_per_stop(white, spans)
    landmarks_only = _information_per_stop(white_off, spans)
    print('information gained per stop / offered:', np.round(gained / offered, 2),
          'without zero-rate updates:', np.round(landmarks_only / offered, 2))
    # Landmark looks at rest teach the bias too (through the heading); the zero-rate
    # updates add at least half of what the gyro samples offer on top, at every stop.
    assert np.all(gained - landmarks_only >= 0.5 * offered)
    # With the prior wander assumed the samples measure b + c: they tell the bias only up
    # to the wander's mean over the stop (variance s^2 g). The stops gain 0.46-0.65 of that
    # (the white noise's above: 0.95-1.02 of theirs), still a good share at every stop.
    prior = EkfConfig().gyro_wander_prior_rad_s
    offered = 1.0 / (1.0 / offered + prior ** 2 * block_mean_share(
        still_s, EkfConfig().gyro_wander_tau_s))
    gained = _information_per_stop(run, spans) - _information_per_stop(off, spans)
    print('with the prior wander, gained / offered:', np.round(gained / offered, 2))
    assert np.all(gained >= 0.4 * offered)
    assert run.stats.stops == len(spans)
    true_bias = trip.true_gyro_bias_rad_s[2]
    estimates = run.estimates
    for start_s, end_s in spans:
        row = _at(estimates, end_s)
        start_var = estimates.covariance[_at(estimates, start_s), 3, 3]
        assert estimates.covariance[row, 3, 3] < start_var
        error = estimates.state[row, 3] - true_bias
        assert abs(error) <= 3.0 * math.sqrt(estimates.covariance[row, 3, 3])


def test_a_stop_holds_the_position():
    trip, spans = trip_with_stops(seed=3, stops_at_s=(15.0,), stop_s=STOP_S)
    speed = trip.speed
    start_s, end_s = spans[0]
    stopped = (speed.stamp_s >= start_s) & (speed.stamp_s < end_s)
    # The same stop seen by an encoder that creeps at 0.5 mm/s (under rest_speed_m_s).
    speeds = np.where(stopped, 0.5 * EkfConfig().rest_speed_m_s, speed.speed_m_s)
    creeping = dataclasses.replace(trip, speed=dataclasses.replace(speed, speed_m_s=speeds))
    exact, creep = _drive(trip).estimates, _drive(creeping).estimates
    # The inserted stop drops the speed from 0.96 m/s to 0 in one sample, beyond
    # max_acceleration_m_s2: the spike gate takes it one odometry sample late
    # (core/input_spikes.py), and the stop is known from then on.
    period = float(np.median(np.diff(speed.stamp_s)))
    held = slice(_at(exact, start_s + period + EkfConfig().zero_rate_min_still_s) + 1,
                 _at(exact, end_s) + 1)
    before = slice(_at(exact, start_s) + 1, held.start)
    # Before the platform is known to stand still the creep moves the estimate; once it
    # is, the prediction holds the position and the creep adds nothing more (the
    # landmark updates at rest then pull both estimates together).
    moved = creep.state[before, :2] - exact.state[before, :2]
    assert np.abs(moved[-1]).max() > 0.0
    gap = np.hypot(*(creep.state[held, :2] - exact.state[held, :2]).T)
    assert gap.max() <= gap[0] + 1e-6, (gap[0], gap.max())   # the creep would add 2 mm


def test_a_turn_on_the_spot_is_no_stop():
    trip, spans = trip_with_stops(seed=3, stops_at_s=(15.0,), stop_s=STOP_S)
    imu = trip.imu
    turning = (imu.stamp_s >= spans[0][0]) & (imu.stamp_s < spans[0][1])
    rates = imu.angular_velocity_rad_s.copy()
    # Speed 0 but turning at 20 deg/s: its gyro spread is small, its mean is no bias.
    rates[turning, 2] += math.radians(20.0)
    trip = dataclasses.replace(trip, imu=dataclasses.replace(imu, angular_velocity_rad_s=rates),
                               scans=())
    assert _drive(trip).stats.zero_rate_updates == 0


@pytest.mark.shared_data
def test_the_2016_static_start_teaches_the_bias_of_the_static_window(shared_data):
    from gyro_ekf.core.calibration import estimate_gyro_bias
    from gyro_ekf.io.matlab import load_course_log

    trip = load_course_log([shared_data('2016_project1'),
                            shared_data('2021_aas01/MapMTRN4010.mat')])
    calibration = estimate_gyro_bias(trip.imu.stamp_s, trip.imu.angular_velocity_rad_s,
                                     speed_stamp_s=trip.speed.stamp_s,
                                     speed_m_s=trip.speed.speed_m_s)
    run = _drive(trip)     # the bias starts at 0 +- 2 deg/s: no calibration seeds it
    estimates = run.estimates
    row = _at(estimates, trip.start_s + STATIC_START_2016_S)
    bias_deg_s = math.degrees(estimates.state[row, 3])
    sigma_deg_s = math.degrees(math.sqrt(estimates.covariance[row, 3, 3]))
    static_deg_s = math.degrees(calibration.bias_rad_s[2])
    print(f'at {estimates.stamp_s[row]:.2f} s: {bias_deg_s:.4f} +- {sigma_deg_s:.4f} deg/s; '
          f'static window {static_deg_s:.4f} deg/s')
    assert abs(bias_deg_s - static_deg_s) <= 0.01
    assert sigma_deg_s <= 0.01
    # Without zero-rate updates the sigma is well above it.
    off = _drive(trip, **OFF).estimates
    assert math.degrees(math.sqrt(off.covariance[row, 3, 3])) > 0.01


def _stop_rates(trip, spans, change):
    """The trip with the z gyro samples inside its stops replaced by change(samples)."""
    imu = trip.imu
    inside = np.zeros(imu.stamp_s.size, dtype=bool)
    for start_s, end_s in spans:
        inside |= (imu.stamp_s >= start_s) & (imu.stamp_s < end_s)
    rates = imu.angular_velocity_rad_s.copy()
    rates[inside, 2] = change(rates[inside, 2])
    return dataclasses.replace(trip, imu=dataclasses.replace(imu, angular_velocity_rad_s=rates))


def test_a_shaken_stop_teaches_nothing():
    trip, spans = trip_with_stops(seed=3, stops_at_s=(15.0,), stop_s=STOP_S)
    rng = np.random.default_rng(8)
    # Vibration: 3 deg/s of spread, twice zero_rate_max_spread_rad_s.
    shaken = _stop_rates(trip, spans, lambda w: w + math.radians(3.0) * rng.standard_normal(
        w.size))
    assert _drive(shaken).stats.zero_rate_updates == 0
    assert _drive(trip).stats.zero_rate_updates > 0


def test_a_gyro_without_noise_at_rest_counts_no_more_than_the_noise_floor():
    trip, spans = trip_with_stops(seed=3, stops_at_s=(15.0,), stop_s=STOP_S)
    true_bias = trip.true_gyro_bias_rad_s[2]
    # Every sample of the stop reads the bias exactly: no spread.
    exact = _stop_rates(trip, spans, lambda w: np.full_like(w, true_bias))
    run = _drive(exact)
    estimates = run.estimates
    row = _at(estimates, spans[0][1])
    n = run.stats.zero_rate_updates
    floor = EkfConfig().zero_rate_min_noise_rad_s
    assert n > 0
    # n samples at the floor's sigma give at most n / floor^2 of information.
    assert 1.0 / estimates.covariance[row, 3, 3] <= 1.0 / estimates.covariance[
        _at(estimates, spans[0][0]), 3, 3] + n / floor ** 2
    assert abs(estimates.state[row, 3] - true_bias) <= 3.0 * math.sqrt(
        estimates.covariance[row, 3, 3])


def _still_driver(sigma_rad_s, n, seed, stated_variance=None, config=None):
    """A driver standing still for n gyro samples at 200 Hz of white noise sigma_rad_s."""
    driver = EventDriver(config or EkfConfig(gyro_noise_rad_s=math.radians(0.25)))
    rng = np.random.default_rng(seed)
    driver.on_speed(0.0, 0.0)
    for k in range(n):
        stamp = 0.005 * k
        if k % 2 == 0:
            driver.on_speed(stamp, 0.0)
        driver.step_imu(stamp, -0.0157 + sigma_rad_s * rng.standard_normal(), stated_variance)
    return driver


@pytest.mark.parametrize('seed', [0, 1, 2])
def test_a_gyro_noisier_than_stated_is_measured_at_a_stop(seed):
    # Standing still the gyro reads its bias and white noise: the stop's spread is the
    # noise. Three times the stated sigma is nine times its variance, and the prediction
    # uses it from the stop on (the watch's factor never falls below it).
    stated = math.radians(0.25)
    driver = _still_driver(3.0 * stated, 1600, seed)
    stats = driver.stats
    assert stats.zero_rate_updates > 0
    # The spread of ~1500 samples is known to sqrt(2 / 1500) = 3.7 % of its variance.
    assert stats.gyro_rest_noise_scale == pytest.approx(9.0, rel=0.15)
    assert stats.gyro_rest_noise_rad_s == pytest.approx(3.0 * stated, rel=0.08)
    assert driver.ekf.rate_noise_scale == stats.gyro_rest_noise_scale
    assert driver.bias_watch.noise_floor == stats.gyro_rest_noise_scale
    assert stats.gyro_rest_noise_samples == driver._stop_n


@pytest.mark.parametrize('seed', [0, 1, 2, 3, 4])
def test_a_gyro_as_noisy_as_stated_or_quieter_keeps_its_stated_noise(seed):
    stated = math.radians(0.25)
    for sigma in (stated, 0.5 * stated):
        driver = _still_driver(sigma, 1600, seed)
        assert driver.stats.zero_rate_updates > 0
        assert driver.stats.gyro_rest_noise_scale == 1.0
        assert driver.ekf.rate_noise_scale == 1.0


def test_the_stop_judges_the_noise_against_the_messages_own_variance():
    # REP-145: an IMU message's angular_velocity_covariance states its noise; a stop that
    # spreads twice its sigma is judged against it, not against gyro_noise_rad_s.
    stated = math.radians(0.1)
    driver = _still_driver(2.0 * stated, 1600, 5, stated_variance=stated ** 2,
                           config=EkfConfig(gyro_noise_rad_s=math.radians(1.5)))
    assert driver.stats.gyro_rest_noise_scale == pytest.approx(4.0, rel=0.15)


@pytest.mark.parametrize('stated_variance', [0.0, -1e-6, math.inf, math.nan])
def test_a_message_variance_that_says_nothing_judges_nothing(stated_variance):
    # Zero, negative, infinite or NaN: no figure to hold the spread against, so nothing is
    # measured or scaled (an infinite one would have read every gyro as quieter).
    driver = _still_driver(math.radians(0.75), 1600, 6, stated_variance=stated_variance)
    assert driver.stats.gyro_rest_noise_samples == 0
    assert driver.stats.gyro_rest_noise_scale == 1.0
    assert driver.ekf.rate_noise_scale == 1.0


def test_a_trip_whose_gyro_is_three_times_noisier_than_stated_is_no_wander():
    # The simulated gyro's yaw axis at 0.75 deg/s of white noise, the trip stating 0.25.
    # Before the stops measured it, the LiDARs' blocks read the excess as a wander
    # (0.025-0.047 deg/s found on all 30 such trips tried) and the NEES share fell to
    # 0.85-0.89 (docs/stress.md); now the static start measures it and says so.
    from gyro_ekf.analysis.offline import run_trip
    from gyro_ekf.analysis.summary import summarize
    from gyro_ekf.analysis.stress import base_config
    from gyro_ekf.core.simulator import simulate_trip
    stated = base_config(120.0).gyro_noise_z_rad_s
    trip = simulate_trip(dataclasses.replace(base_config(120.0),
                                             gyro_noise_z_rad_s=3.0 * stated), 3)
    trip = dataclasses.replace(trip, noise=dataclasses.replace(trip.noise, gyro_rad_s=stated))
    summary = summarize(run_trip(trip))
    online = summary['online_bias']
    assert online['gyro_rest_noise_scale'] == pytest.approx(9.0, rel=0.15)
    assert online['gyro_wander_deg_s'] == 0.0
    assert summary['ground_truth']['nees_share_in_band'] >= 0.9
    assert summary['health']['verdict'] == 'degraded'
    assert summary['health']['reasons'][0].startswith(
        'the gyro was noisier than configured: standing still its samples spread 0.7')
