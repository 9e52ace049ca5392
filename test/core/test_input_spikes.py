"""Lone samples far from both neighbours are left out and said (core/input_spikes.py)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from gyro_ekf.analysis.offline import run_trip
from gyro_ekf.io.params_file import PipelineParams
from gyro_ekf.analysis.summary import summarize
from gyro_ekf.core.config import EkfConfig
from gyro_ekf.core.input_spikes import SPIKE_SIGMAS, WARM_SAMPLES, SpikeGate
from gyro_ekf.core.simulator import SimulationConfig, simulate_trip

PERIOD_S = 0.01
SIGMA = 0.01


def _stream(n, seed=0, sigma=SIGMA, level=0.5):
    rng = np.random.default_rng(seed)
    return np.arange(n) * PERIOD_S, level + rng.normal(0.0, sigma, n)


def _fed(gate, stamps, values):
    """Feed a gate; return the value in use after each sample (None before the first)."""
    in_use, used = None, []
    for stamp, value in zip(stamps, values):
        taken = gate.admit(float(stamp), float(value))
        if taken is not None:
            in_use = taken
        used.append(in_use)
    return used


def test_a_lone_spike_is_held_back_and_dropped():
    stamps, values = _stream(400)
    values[200] += 2.0
    values[300] -= 0.5
    gate = SpikeGate(SIGMA, max_change_per_s=10.0)
    used = _fed(gate, stamps, values)
    assert gate.spikes == 2 and gate.steps == 0
    assert gate.largest == pytest.approx(2.0, abs=0.1)
    # The spike never reached the filter: the value before it was held over its interval.
    assert used[200] == values[199] and used[201] == values[201]
    assert used[300] == values[299]
    assert max(abs(u - 0.5) for u in used[1:]) < 0.1
    assert gate.report() == {'spikes': 2, 'largest': gate.largest, 'steps': 0,
                             'limit': gate.last_limit}
    # The limit: ten sigmas of a difference of two samples (or of what the stream shows)
    # plus what max_change_per_s allows in one interval.
    assert SPIKE_SIGMAS * np.sqrt(2.0) * SIGMA + 10.0 * PERIOD_S <= gate.last_limit < 0.5


def test_a_change_that_stays_is_taken_one_sample_late():
    stamps, values = _stream(400)
    values[200:] += 1.0  # a collision: the speed changes in one sample and stays
    gate = SpikeGate(SIGMA, max_change_per_s=10.0)
    used = _fed(gate, stamps, values)
    assert gate.spikes == 0 and gate.steps == 1
    assert used[200] == values[199]
    assert used[201:] == values[201:].tolist()
    # Two bad samples in a row are a change as far as a gate of one sample can tell.
    stamps, values = _stream(400)
    values[200:202] += 2.0
    gate = SpikeGate(SIGMA, max_change_per_s=10.0)
    _fed(gate, stamps, values)
    assert gate.spikes == 0 and gate.steps == 2


def test_a_stream_noisier_than_configured_widens_its_own_limit():
    # Three times the configured noise: ten configured sigmas would be 3.3 true ones, a suspect
    # in a thousand samples; the stream's own spread keeps every sample.
    stamps, values = _stream(20_000, seed=1, sigma=3.0 * SIGMA)
    gate = SpikeGate(SIGMA, max_change_per_s=0.0)
    _fed(gate, stamps, values)
    assert gate.spikes == 0 and gate.steps == 0
    # And a spike is still a spike on it.
    values[15_000] += 2.0
    gate = SpikeGate(SIGMA, max_change_per_s=0.0)
    _fed(gate, stamps, values)
    assert gate.spikes == 1


def test_the_stream_shows_its_own_white_noise_once_warm():
    stamps, values = _stream(5_000, seed=2, sigma=3.0 * SIGMA)
    gate = SpikeGate(SIGMA, max_change_per_s=0.0)
    _fed(gate, stamps[:WARM_SAMPLES - 1], values[:WARM_SAMPLES - 1])
    assert gate.white_sigma() is None
    _fed(gate, stamps[WARM_SAMPLES - 1:], values[WARM_SAMPLES - 1:])
    assert gate.white_sigma() == pytest.approx(3.0 * SIGMA, rel=0.15)


def test_a_steady_acceleration_is_no_noise():
    # 3 m/s^2 at 100 Hz changes the speed 0.03 m/s per sample, three times this noise: its
    # first differences would read 2 times the noise, its second ones read the noise.
    stamps, values = _stream(3_000, seed=3)
    gate = SpikeGate(SIGMA, max_change_per_s=10.0)
    _fed(gate, stamps, values + 3.0 * stamps)
    assert gate.spikes == 0 and gate.white_sigma() == pytest.approx(SIGMA, rel=0.15)


def test_odometry_noisier_than_its_messages_say_is_taken_at_its_own_spread():
    # The simulated odometry's messages state 0.01 m/s; 0.1 m/s more white noise while
    # moving (a driver's constant covariance, a coarse encoder) left the pose
    # overconfident. Its own sample-to-sample spread is taken as its noise instead.
    trip = simulate_trip(SimulationConfig(duration_s=120.0), seed=0)
    speed = trip.speed.speed_m_s
    noisy = np.where(speed != 0.0, speed + np.random.default_rng(0).normal(
        0.0, 0.1, speed.size), speed)
    trip = dataclasses.replace(trip, speed=dataclasses.replace(trip.speed, speed_m_s=noisy))
    not_learnt = dataclasses.replace(PipelineParams(), ekf=dataclasses.replace(
        EkfConfig(), learn_speed_noise=False))
    before = summarize(run_trip(trip, not_learnt))
    assert before['speed_noise']['widened_samples'] == 0
    assert before['ground_truth']['nees_share_in_band'] < 0.9
    after = summarize(run_trip(trip))
    noise = after['speed_noise']
    # From the spread's warm-up on, while moving: most of the trip's 12 000 samples.
    assert noise['widened_samples'] > 10_000
    assert noise['measured_m_s'] == pytest.approx(0.1, rel=0.25)
    assert noise['stated_m_s'] == pytest.approx(0.01)
    truth = after['ground_truth']
    assert truth['nees_share_in_band'] >= 0.9 and truth['position_rmse_m'] <= 0.02
    # Said, as a gyro noisier than stated is: the driver's covariance is worth fixing.
    assert after['health']['verdict'] == 'degraded'
    assert [r for r in after['health']['reasons'] if r.startswith('the odometry was noisier')
            ] == [r for r in after['health']['reasons']], after['health']['reasons']
    assert 'times the 0.010 m/s stated' in after['health']['reasons'][0]
    assert not [r for r in before['health']['reasons'] if 'odometry was noisier' in r]


def test_nothing_is_judged_before_the_stream_has_shown_its_spread():
    stamps, values = _stream(200)
    values[WARM_SAMPLES - 10] += 2.0
    gate = SpikeGate(SIGMA, max_change_per_s=10.0)
    used = _fed(gate, stamps, values)
    assert gate.spikes == 0 and used[WARM_SAMPLES - 10] == values[WARM_SAMPLES - 10]


def test_save_and_restore_take_a_held_suspect_back():
    stamps, values = _stream(300)
    values[150] += 2.0
    gate = SpikeGate(SIGMA, max_change_per_s=10.0)
    _fed(gate, stamps[:150], values[:150])
    saved = gate.save()
    assert gate.admit(float(stamps[150]), float(values[150])) is None
    gate.restore(saved)
    assert gate.save() == saved
    _fed(gate, stamps[150:], values[150:])
    assert gate.spikes == 1


@pytest.fixture(scope='module')
def spiky_trip():
    """A clean simulated trip with 20 speed samples 2 m/s off and 20 gyro samples 1 rad/s off."""
    trip = simulate_trip(SimulationConfig(duration_s=60.0), seed=3)
    rng = np.random.default_rng(3)
    speed = trip.speed.speed_m_s.copy()
    speed[rng.choice(np.arange(len(speed) // 8, len(speed), 2), 20, replace=False)] += 2.0
    rates = trip.imu.angular_velocity_rad_s.copy()
    rates[rng.choice(np.arange(len(rates) // 8, len(rates), 2), 20, replace=False), 2] += 1.0
    spiky = dataclasses.replace(
        trip, speed=dataclasses.replace(trip.speed, speed_m_s=speed),
        imu=dataclasses.replace(trip.imu, angular_velocity_rad_s=rates))
    return trip, spiky


def test_a_trip_with_spikes_is_within_the_bounds_and_says_so(spiky_trip):
    clean, spiky = spiky_trip
    summary = summarize(run_trip(spiky))
    spikes = summary['input_spikes']
    assert spikes['odometry']['spikes'] == 20 and spikes['gyro']['spikes'] == 20
    assert spikes['odometry']['largest'] == pytest.approx(2.0, abs=0.1)
    truth = summary['ground_truth']
    assert truth['position_rmse_m'] <= 0.02 and truth['nees_share_in_band'] >= 0.9
    assert abs(truth['bias_error_final_deg_s']) <= 0.02
    health = summary['health']
    assert health['verdict'] == 'degraded'
    said = [r for r in health['reasons'] if 'lone sample' in r]
    assert said[0].startswith('gyro: 20 lone sample(s)') and 'rad/s' in said[0]
    assert said[1].startswith('odometry: 20 lone sample(s)') and '+2' in said[1]
    assert 'max_acceleration_m_s2' in said[1]
    # The clean trip: nothing dropped, nothing said.
    summary = summarize(run_trip(clean))
    assert all(s['spikes'] == 0 and s['steps'] == 0
               for s in summary['input_spikes'].values())
    assert not any('lone sample' in r for r in summary['health']['reasons'])
