"""The held yaw rate: the heading variance of an IMU gap, from the yaw acceleration seen."""

from __future__ import annotations

import math

import numpy as np
import pytest

from gyro_ekf.analysis.offline import run_trip
from gyro_ekf.analysis.summary import summarize
from gyro_ekf.core import held_rate
from gyro_ekf.core.held_rate import HeldRate
from gyro_ekf.core.simulator import SimulationConfig, simulate_trip
from gyro_ekf.core.validation import validate_trip


def _turning(held, seconds, acceleration, rate_hz=200.0, noise=0.0, seed=0, start_s=0.0):
    """Feed a rate that swings as a sine whose acceleration has RMS ``acceleration``."""
    rng = np.random.default_rng(seed)
    omega = 1.0  # rad/s of the swing: acceleration amplitude = rate amplitude * omega
    amplitude = acceleration * math.sqrt(2.0) / omega
    for k in range(int(seconds * rate_hz)):
        t = start_s + k / rate_hz
        held.sample(t, amplitude * math.sin(omega * t) + noise * rng.standard_normal())


def test_the_mean_square_acceleration_is_what_the_gyro_shows():
    held = HeldRate()
    _turning(held, 300.0, acceleration=0.5)
    assert held.acceleration2 == pytest.approx(0.25, rel=0.1)


def test_white_noise_makes_it_larger_never_smaller():
    quiet, noisy = HeldRate(), HeldRate()
    _turning(quiet, 300.0, acceleration=0.5)
    _turning(noisy, 300.0, acceleration=0.5, noise=math.radians(0.25))
    assert noisy.acceleration2 > quiet.acceleration2


def test_a_hold_gains_alpha2_a4_over_4_in_pieces_that_add_up():
    held = HeldRate()
    _turning(held, 300.0, acceleration=0.5)
    whole = held.heading_variance(0.0, 0.8)
    assert whole == pytest.approx(0.25 * held.acceleration2 * 0.8 ** 4)
    pieces = sum(held.heading_variance(a, a + 0.1) for a in np.arange(0.0, 0.8, 0.1))
    assert pieces == pytest.approx(whole, rel=1e-9, abs=1e-12)
    # An ordinary sample period gains nothing.
    assert held.heading_variance(0.0, held_rate.MIN_AGE_S) == 0.0


def test_save_and_restore():
    held = HeldRate()
    _turning(held, 10.0, acceleration=0.5)
    saved = held.save()
    _turning(held, 10.0, acceleration=2.0, start_s=10.0)
    changed = held.acceleration2
    held.restore(saved)
    assert held.acceleration2 != changed
    assert held.save() == saved


def _summary(**changes):
    trip = simulate_trip(SimulationConfig(duration_s=90.0, **changes), 2)
    trip, report = validate_trip(trip, trip.name)
    return summarize(run_trip(trip), report)


def test_imu_gaps_while_driving_keep_the_trip_consistent_and_say_so():
    summary = _summary(imu_gaps=3, imu_gap_s=0.9)
    truth = summary['ground_truth']
    assert truth['position_rmse_m'] <= 0.02
    assert abs(truth['bias_error_final_deg_s']) <= 0.02
    assert truth['nees_share_in_band'] >= 0.9
    assert summary['health']['verdict'] == 'degraded'
    assert any(r.startswith('gyro silent for') for r in summary['health']['reasons'])
