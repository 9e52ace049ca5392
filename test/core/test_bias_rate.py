"""The bias rate: a ramping bias is followed, a clean trip, a step or no drift finds no rate."""

from __future__ import annotations

import math

import numpy as np
import pytest
from health_trips import simulated_run

from gyro_ekf.core import bias_rate
from gyro_ekf.core.bias_rate import BiasRate
from gyro_ekf.core.ekf import GyroBiasEkf
from gyro_ekf.core.types import BIAS

BLOCK_SIGMA = math.radians(0.03)
"""Scatter of a block's true-bias estimate b + db (the simulator's, driving)."""

RATE = math.radians(0.6) / 60.0
"""A ramp of 0.6 deg/s per minute, rad/s^2."""


def _blocks(rate, drift_sign, seconds=60.0, step=0.0, seed=0, window_s=40.0):
    """Feed 2-s blocks of m = rate t (+ step halfway) + noise; return the estimator and
    what it asked to open the bias by."""
    rng = np.random.default_rng(seed)
    estimator = BiasRate(window_s)
    openings = []
    for k in range(int(seconds / 2.0)):
        t = 1.0 + 2.0 * k
        m = rate * t + (step if t > seconds / 2.0 else 0.0) + rng.normal(0.0, BLOCK_SIGMA)
        lag = estimator.add(t, m, 0.0, drift_sign, 0.0)
        if lag is not None:
            openings.append((t, lag))
    return estimator, openings


def test_a_ramp_with_a_drift_its_way_gives_its_rate_and_opens_the_lag():
    estimator, openings = _blocks(RATE, drift_sign=1.0)
    assert estimator.rate_rad_s2 == pytest.approx(RATE, rel=0.2)
    assert 0.0 < estimator.sigma_rad_s2 < RATE / bias_rate.T_ON
    assert estimator.found == 1 and len(openings) == 1
    # The filter's bias was 0 all along: the line's present value is the lag it opens.
    t, lag = openings[0]
    assert math.sqrt(lag) == pytest.approx(RATE * t, rel=0.3)
    assert estimator.walk == pytest.approx(estimator.sigma_rad_s2 ** 2 * 40.0)


@pytest.mark.parametrize('drift_sign', [0.0, -1.0])
def test_a_ramp_without_a_drift_its_way_gives_no_rate(drift_sign):
    estimator, openings = _blocks(RATE, drift_sign)
    assert estimator.rate_rad_s2 == 0.0 and estimator.walk == 0.0
    assert estimator.found == 0 and openings == []


def _paused_ramp(pause, seed, window_s=40.0):
    """A ramp that pauses over pause = (start s, end s); the watch's drift is seen only
    before 40 s (while a rate is followed no drift shows)."""
    rng = np.random.default_rng(seed)
    estimator = BiasRate(window_s)
    level = 0.0
    for k in range(80):
        t = 1.0 + 2.0 * k
        if not pause[0] <= t < pause[1]:
            level += 2.0 * RATE
        estimator.add(t, level + rng.normal(0.0, BLOCK_SIGMA), 0.0, 1.0 if t < 40.0 else 0.0,
                      0.0)
    return estimator


@pytest.mark.parametrize('seed', range(3))
def test_a_rate_dropped_comes_back_within_a_window_without_a_new_drift(seed):
    # Paused for 30 s, the ramp's line fails and the rate is dropped; when the ramp goes on
    # within a window of the rate's last use, the rate comes back on its own sign.
    estimator = _paused_ramp((40.0, 70.0), seed)
    assert estimator.found == 2
    assert estimator.rate_rad_s2 == pytest.approx(RATE, rel=0.3)
    # Paused for longer than the window, a ramp that starts again is a new one: it waits
    # for a drift of its own.
    estimator = _paused_ramp((40.0, 130.0), seed)
    assert estimator.found == 1 and estimator.rate_rad_s2 == 0.0


SLOW_RATE = math.radians(0.06) / 60.0
"""A ramp of 0.06 deg/s per minute: within the 40-s line's scatter, 0.12 deg/s in 2 min."""


@pytest.mark.parametrize('seed', range(5))
def test_a_slow_ramp_is_found_by_the_long_line(seed):
    # Over 40 s, 20 blocks bound the slope to 0.035 deg/s per minute: the short line alone
    # does not find this ramp; the line over three windows does, and its rate's
    # uncertainty walks the bias over the long window.
    estimator, openings = _blocks(SLOW_RATE, drift_sign=1.0, seconds=120.0, seed=seed)
    assert estimator.found >= 1 and openings
    assert estimator.rate_rad_s2 == pytest.approx(SLOW_RATE, rel=0.3)
    assert estimator.walk == pytest.approx(
        estimator.sigma_rad_s2 ** 2 * bias_rate.LONG_WINDOWS * 40.0)
    short = BiasRate(40.0)
    assert short._judge(estimator._blocks[-20:], 119.0, 1.0, False) is None


def test_a_step_is_no_ramp():
    estimator, _ = _blocks(0.0, drift_sign=1.0, step=math.radians(0.3))
    assert estimator.found == 0


def test_blocks_without_a_ramp_give_no_rate():
    for seed in range(20):
        estimator, _ = _blocks(0.0, drift_sign=1.0, seconds=200.0, seed=seed)
        assert estimator.found == 0, seed


def test_window_zero_is_off():
    estimator, _ = _blocks(RATE, drift_sign=1.0, window_s=0.0)
    assert estimator.found == 0 and estimator.rate_rad_s2 == 0.0


@pytest.mark.parametrize('textbook', [False, True])
def test_the_prediction_moves_the_bias_by_its_rate(textbook):
    ekf = GyroBiasEkf(textbook=textbook)
    ekf.bias_rate_found = RATE
    before = ekf.x
    ekf.predict(1.0, 0.1, 0.5)
    assert ekf.x[BIAS] - before[BIAS] == pytest.approx(0.5 * RATE, rel=1e-12)


def test_a_ramping_bias_is_followed_and_said():
    config, _, run, summary = simulated_run(120.0, gyro_bias_ramp_rad_s2=-RATE)
    end = run.result.estimates.stamp_s[-1] - run.trip.imu.stamp_s[0]
    truth = float(config.gyro_bias_z_at(np.array([end]))[0])
    error = math.degrees(run.result.estimates.state[-1, BIAS] - truth)
    assert abs(error) < 0.02, f'final bias {error:.4f} deg/s off on a 0.6 deg/s/min ramp'
    assert summary['online_bias']['rate_found'] >= 1
    assert summary['online_bias']['rate_deg_s_per_min'] == pytest.approx(-0.6, rel=0.2)
    # Followed, but not silently: the bias changed, and the verdict says so.
    assert summary['health']['verdict'] == 'degraded'
    assert any(r.startswith('the gyro bias changed during the run')
               for r in summary['health']['reasons']), summary['health']['reasons']


def test_a_clean_trip_finds_no_rate():
    _, _, run, summary = simulated_run(120.0)
    assert run.result.stats.bias_rate_found == 0
    assert summary['online_bias']['rate_deg_s_per_min'] == 0.0
    assert summary['online_bias']['rate_found'] == 0


GYRO_SIGMA = math.radians(0.25)
"""White noise of one gyro sample at rest (the simulator's), rad/s."""


def _stop(rate, seconds=20.0, step=0.0, seed=0, bias=0.0, hz=200.0):
    """Feed a stop's gyro samples w = bias + rate t (+ step halfway) + noise to add_rest;
    return the estimator and what it asked to open the bias by."""
    rng = np.random.default_rng(seed)
    estimator = BiasRate(40.0)
    openings = []
    for k in range(int(seconds * hz)):
        t = k / hz
        w = bias + rate * t + (step if t > seconds / 2.0 else 0.0) + rng.normal(0.0, GYRO_SIGMA)
        # The filter's bias is taken to sit at the stop's first value (it lags the ramp).
        lag = estimator.add_rest(t, w, bias)
        if lag is not None:
            openings.append((t, lag))
    return estimator, openings


def test_a_ramp_at_rest_is_found_from_the_gyro_samples_alone():
    rate = math.radians(0.5) / 60.0
    estimator, openings = _stop(rate)
    assert estimator.rate_rad_s2 == pytest.approx(rate, rel=0.25)
    assert 0.0 < estimator.sigma_rad_s2 < rate / bias_rate.REST_T_ON
    assert estimator.found == 1 and len(openings) == 1
    # Opened by how far the line's present value lies from the filter's bias.
    t, lag = openings[0]
    assert math.sqrt(lag) == pytest.approx(rate * t, rel=0.3)
    # Found at rest, kept once moving until the blocks of driving can judge it ...
    estimator.end_rest()
    for k in range(bias_rate.MIN_BLOCKS - 1):
        assert estimator.add(21.0 + 2.0 * k, 0.0, 0.0, 0.0, 0.0) is None
        assert estimator.rate_rad_s2 == pytest.approx(rate, rel=0.25)
    # ... and they, flat, drop it.
    estimator.add(21.0 + 2.0 * bias_rate.MIN_BLOCKS, 0.0, 0.0, 0.0, 0.0)
    assert estimator.rate_rad_s2 == 0.0


def test_a_still_gyro_or_a_step_at_rest_gives_no_rate():
    for seed in range(20):
        estimator, openings = _stop(0.0, seconds=60.0, seed=seed, bias=-0.015)
        assert estimator.found == 0 and openings == [], seed
    estimator, _ = _stop(0.0, step=math.radians(0.2))
    assert estimator.found == 0


def test_a_ramp_during_a_long_static_start_is_followed_and_said():
    rate = -math.radians(0.6) / 60.0
    static_s = 20.0
    config, _, run, summary = simulated_run(60.0, static_s=static_s,
                                            gyro_bias_ramp_rad_s2=rate)
    estimates = run.result.estimates
    at = int(np.searchsorted(estimates.stamp_s, estimates.stamp_s[0] + static_s - 1.0))
    truth = float(config.gyro_bias_z_at(np.array([estimates.stamp_s[at]
                                                  - run.trip.imu.stamp_s[0]]))[0])
    error = math.degrees(estimates.state[at, BIAS] - truth)
    # A running mean of the stop would lag by half of it: 0.1 deg/s here.
    assert abs(error) < 0.02, f'bias {error:.4f} deg/s off at the end of the static start'
    assert summary['online_bias']['rate_deg_s_per_min'] == pytest.approx(-0.6, rel=0.25)
    assert summary['health']['verdict'] == 'degraded'
    assert any('standing still, the gyro samples ramped' in r
               for r in summary['health']['reasons']), summary['health']['reasons']
    # The same static start without a ramp finds none.
    _, _, run, summary = simulated_run(60.0, static_s=static_s)
    assert run.result.stats.bias_rate_found == 0
