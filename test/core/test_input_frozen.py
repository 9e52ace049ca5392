"""A gyro that repeats one value is frozen; its repeats are left out (core/input_frozen.py)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from gyro_ekf.analysis.offline import run_trip
from gyro_ekf.analysis.summary import summarize
from gyro_ekf.core.input_frozen import MIN_PAIRS, MIN_REPEATS, FrozenWatch
from gyro_ekf.core.simulator import SimulationConfig, simulate_trip

PERIOD_S = 0.005


def _fed(watch, values):
    """Feed a watch at 200 Hz; return the mask of the samples it left out."""
    return np.array([watch.left_out(i * PERIOD_S, float(v)) for i, v in enumerate(values)])


def _gyro(n, seed=0, lsb=None):
    """A gyro at rest: bias plus white noise of 0.25 deg/s, quantised to `lsb` if given."""
    values = 0.017 + np.random.default_rng(seed).normal(0.0, np.radians(0.25), n)
    return values if lsb is None else np.round(values / lsb) * lsb


@pytest.mark.parametrize('lsb', [None, np.radians(0.125), np.radians(0.5)])
def test_a_live_gyro_is_never_frozen(lsb):
    # Unquantised, two samples are never the same float; quantised at half its noise or
    # twice it, repeats are common (a third, and two thirds, of the pairs) but not in runs
    # beyond chance.
    watch = FrozenWatch()
    assert not _fed(watch, _gyro(200_000, lsb=lsb)).any()
    assert watch.report() == {'runs': 0, 'samples': 0, 'longest_s': 0.0, 'first_at_s': None}


@pytest.mark.parametrize('lsb', [None, np.radians(0.125)])
def test_a_freeze_is_found_and_its_repeats_left_out(lsb):
    values = _gyro(20_000, seed=1, lsb=lsb)
    values[5000:6000] = values[5000]  # 5 s of one value: a driver that hung
    values[12000:12400] = values[12000]
    watch = FrozenWatch()
    left_out = _fed(watch, values)
    # The first repeats are taken (the freeze is not known yet), the rest left out: the
    # first left out is repeat MIN_REPEATS or a little later (the stream's repeat share).
    # (Quantised, the sample before a freeze may hold its value already: the run's start.)
    start = 5000 - int(values[4999] == values[5000])
    first = np.flatnonzero(left_out[start:6000])[0]
    assert MIN_REPEATS <= first <= 40
    assert left_out[start + first:6000].all()
    second_start = 12000 - int(values[11999] == values[12000])
    second = np.flatnonzero(left_out[second_start:12400])[0]
    assert left_out.sum() == watch.samples == (6000 - start - first) + (
        12400 - second_start - second)
    assert not left_out[:5000].any() and not left_out[6000:12000].any()
    assert watch.runs == 2 and watch.first_at_s == pytest.approx(start * PERIOD_S)
    assert watch.longest_s == pytest.approx((5999 - start) * PERIOD_S)


def test_a_noise_free_gyro_at_rest_reading_exactly_0_is_not_frozen():
    # A simulator's gyro without noise: exactly 0 at rest, for seconds; the same value
    # otherwise is a freeze.
    values = np.concatenate([_gyro(1500), np.zeros(2000), _gyro(1000, seed=1)])
    watch = FrozenWatch()
    assert not _fed(watch, values).any() and watch.runs == 0
    values[1500:3500] = 0.001
    assert _fed(FrozenWatch(), values).sum() > 1900


def test_a_stream_that_repeats_by_its_nature_is_not_judged():
    # Two pairs in three repeat (quantised far coarser than its noise), or every one (a
    # constant rate, as a noise-free simulator or a test gives): no run is a freeze.
    rng = np.random.default_rng(2)
    values = np.cumsum(rng.random(60_000) > 2.0 / 3.0).astype(float)
    values = np.concatenate([values, np.full(2000, -1.0)])
    watch = FrozenWatch()
    assert not _fed(watch, values).any() and watch.runs == 0
    watch = FrozenWatch()
    assert not _fed(watch, np.full(5000, 0.02)).any() and watch.runs == 0
    # Nor one before it has shown MIN_PAIRS pairs.
    values = _gyro(MIN_PAIRS + 500)
    values[MIN_PAIRS // 2:MIN_PAIRS] = values[MIN_PAIRS // 2]
    assert not _fed(FrozenWatch(), values).any()


def test_save_and_restore_put_a_run_back():
    values = _gyro(2000, seed=3)
    values[1000:1100] = values[1000]
    watch = FrozenWatch()
    _fed(watch, values[:1010])
    saved = watch.save()
    later = [watch.left_out((1010 + i) * PERIOD_S, float(v)) for i, v in enumerate(values[1010:])]
    watch.restore(saved)
    assert watch.save() == saved
    again = [watch.left_out((1010 + i) * PERIOD_S, float(v)) for i, v in enumerate(values[1010:])]
    assert again == later and watch.runs == 1


def test_the_course_logs_gyros_are_never_frozen(shared_data):
    # Real gyros, the 2021 log's quantised: repeats, but 3 in a row at most.
    from gyro_ekf.io.matlab import load_course_log
    for paths in ([shared_data('2016_project1'), shared_data('2021_aas01/MapMTRN4010.mat')],
                  [shared_data('2021_aas01')], [shared_data('2022_sim/data019b.mat')],
                  [shared_data('2023_sim/DataUsr_006k.mat')]):
        imu = load_course_log(paths).imu
        watch = FrozenWatch()
        for stamp, rate in zip(imu.stamp_s, imu.angular_velocity_rad_s[:, 2]):
            watch.left_out(float(stamp), float(rate))
        assert watch.runs == 0, paths


@pytest.fixture(scope='module')
def frozen_trip():
    """A clean simulated trip whose gyro freezes three times for 5 s while driving."""
    trip = simulate_trip(SimulationConfig(duration_s=120.0), seed=0)
    rates = trip.imu.angular_velocity_rad_s.copy()
    for start_s in (30.0, 60.0, 90.0):
        index = np.flatnonzero((trip.imu.stamp_s >= start_s)
                               & (trip.imu.stamp_s < start_s + 5.0))
        rates[index] = rates[index[0]]
    return trip, dataclasses.replace(trip, imu=dataclasses.replace(
        trip.imu, angular_velocity_rad_s=rates))


def test_a_trip_whose_gyro_froze_is_within_the_bounds_and_says_so(frozen_trip):
    # Taken as samples, the three freezes turned the heading by the turns they hid: the
    # bias ended tens of deg/s off and the pose was lost, and no reason named the gyro.
    clean, frozen = frozen_trip
    summary = summarize(run_trip(frozen))
    assert summary['gyro_frozen']['runs'] == 3
    assert summary['gyro_frozen']['longest_s'] == pytest.approx(5.0, abs=0.01)
    truth = summary['ground_truth']
    assert truth['position_rmse_m'] <= 0.02 and truth['nees_share_in_band'] >= 0.9
    assert abs(truth['bias_error_final_deg_s']) <= 0.02
    assert summary['health']['verdict'] == 'degraded'
    assert summary['health']['reasons'][0].startswith(
        'gyro: it repeated one value sample after sample 3 time(s) (the first at 30.0 s, '
        'the longest for 5.00 s)'), summary['health']['reasons']
    summary = summarize(run_trip(clean))
    assert summary['gyro_frozen']['runs'] == 0
    assert not any('repeated one value' in r for r in summary['health']['reasons'])
