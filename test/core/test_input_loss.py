"""Samples an input lost, counted from its own stamps (core/input_loss.py), and the verdict."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from gyro_ekf.analysis.offline import run_trip
from gyro_ekf.analysis.summary import summarize
from gyro_ekf.core.health import VERDICT_MIN_RECEIVED_SHARE
from gyro_ekf.core.input_loss import REFERENCE_INTERVALS, InputLoss, silences
from gyro_ekf.core.simulator import SimulationConfig, simulate_trip

PERIOD_S = 0.005


def _fed(stamps) -> InputLoss:
    loss = InputLoss()
    for stamp in stamps:
        loss.add(float(stamp))
    return loss


def test_a_regular_stream_lost_nothing():
    loss = _fed(np.arange(2000) * PERIOD_S)
    assert loss.received == 2000 and loss.lost == 0 and loss.share == 1.0
    assert loss.period_s == pytest.approx(PERIOD_S)
    assert loss.longest_s == pytest.approx(PERIOD_S)
    # The longest interval before the period is known, and after it.
    assert _fed([0.0, 0.3, 0.31]).longest_s == pytest.approx(0.3)
    gap = _fed(np.concatenate([np.arange(100), np.arange(140, 200)]) * PERIOD_S)
    assert gap.longest_s == pytest.approx(41 * PERIOD_S) and gap.lost == 40


def test_jitter_of_under_half_a_period_is_no_loss():
    rng = np.random.default_rng(0)
    stamps = np.arange(2000) * PERIOD_S + rng.uniform(-0.2, 0.2, 2000) * PERIOD_S
    assert _fed(np.sort(stamps)).lost == 0


def test_every_lost_sample_is_counted_from_the_stamps():
    stamps = np.arange(4000) * PERIOD_S
    # Two of every three lost after the reference, a gap of 1 s, and one sample in the
    # reference intervals themselves.
    kept = [k for k in range(4000)
            if k != 10 and (k < 100 or k % 3 == 0 or k >= 3000) and not 3200 <= k < 3400]
    loss = _fed(stamps[kept])
    lost_thirds = sum(1 for k in range(100, 3000) if k % 3 != 0)
    assert loss.lost == 1 + lost_thirds + 200
    assert loss.received == len(kept)
    assert loss.share == pytest.approx(len(kept) / 4000)
    assert loss.report() == {'received': len(kept), 'lost': 4000 - len(kept),
                             'share': loss.share, 'period_s': pytest.approx(PERIOD_S),
                             'longest_interval_s': pytest.approx(201 * PERIOD_S),
                             'last_s': pytest.approx(3999 * PERIOD_S),
                             'stamp_scatter_s': pytest.approx(0.0, abs=1e-12),
                             'misplaced': 0, 'scatters': False}


def test_a_stream_that_loses_most_samples_from_its_start_keeps_its_period():
    # 60 % lost at random from the first sample: most intervals are two periods or more.
    rng = np.random.default_rng(3)
    keep = rng.random(4000) > 0.6
    loss = _fed((np.arange(4000) * PERIOD_S)[keep])
    assert loss.period_s == pytest.approx(PERIOD_S)
    first, last = np.flatnonzero(keep)[[0, -1]]
    assert loss.received + loss.lost == last - first + 1


def test_one_stamp_glitch_does_not_set_the_period():
    stamps = list(np.arange(2000) * PERIOD_S)
    stamps.insert(5, stamps[5] - 1e-5)
    loss = _fed(stamps)
    assert loss.period_s == pytest.approx(PERIOD_S, rel=1e-3) and loss.lost == 0


def test_stamps_taken_in_pairs_are_no_loss():
    # Two samples 0.1 ms apart every 10 ms (a driver that stamps them on the host in
    # pairs): half the intervals are tiny, and none is a lost sample.
    pairs = np.arange(2000) * 2 * PERIOD_S
    loss = _fed(np.sort(np.concatenate([pairs, pairs + 1e-4])))
    assert loss.lost == 0 and loss.share == 1.0


@pytest.mark.parametrize('seed', range(5))
def test_stamp_jitter_of_a_quarter_period_costs_at_most_a_few_samples(seed):
    rng = np.random.default_rng(seed)
    stamps = np.sort(np.arange(4000) * PERIOD_S + rng.uniform(-0.25, 0.25, 4000) * PERIOD_S)
    loss = _fed(stamps)
    assert loss.period_s == pytest.approx(PERIOD_S, rel=0.01)
    assert loss.share > 0.995


def _scattered(sigma: float, lost: float, seed: int, n: int = 8000) -> np.ndarray:
    """Stamps of a 5-ms grid scattered by a normal law of sigma periods (a driver that
    stamps on arrival; sorted, as the filter takes them), a share ``lost`` of them lost."""
    rng = np.random.default_rng(seed)
    stamps = np.sort((np.arange(n) + rng.normal(0.0, sigma, n)) * PERIOD_S)
    return stamps[rng.random(n) >= lost]


@pytest.mark.parametrize('seed', range(4))
@pytest.mark.parametrize('sigma', [0.05, 0.1, 0.15])
@pytest.mark.parametrize('lost', [0.0, 0.2])
def test_stamps_scattered_about_their_grid_are_counted_by_slot(seed, sigma, lost):
    # Counted interval by interval, stamps scattered by 0.15 of a period read as 2-4 %
    # lost, and with 20 % lost the count was off further; by slot, the count is the
    # loss's own to within a few samples, and nothing is said of the stamps.
    stamps = _scattered(sigma, lost, seed)
    loss = _fed(stamps)
    implied = round((stamps[-1] - stamps[0]) / PERIOD_S) + 1
    assert abs(loss.received + loss.lost - implied) <= 3
    assert loss.period_s == pytest.approx(PERIOD_S, rel=0.002)
    assert loss.scatter_s == pytest.approx(sigma * PERIOD_S, rel=0.35)
    assert not loss.scatters


@pytest.mark.parametrize('seed', range(4))
def test_stamps_scattered_by_a_third_of_a_period_lose_nothing_and_are_said(seed):
    # The grid cannot be told from the scatter any more: the stream is said to scatter,
    # and a stream that lost nothing does not read as lossy (it read 37-61 % received).
    loss = _fed(_scattered(0.4, 0.0, seed))
    assert loss.scatters and loss.share > 0.98
    assert loss.scatter_s > 0.2 * PERIOD_S


def test_nothing_is_judged_before_the_period_is_known_and_repeats_cost_nothing():
    loss = _fed([0.0, 0.0, 0.5, 0.5])
    assert loss.period_s is None and loss.lost == 0 and loss.share == 1.0
    # A sample at the stamp of the one before (a repeat), before and after the period is
    # known: received, no interval, nothing lost.
    stamps = np.arange(200) * PERIOD_S
    repeated = _fed(np.sort(np.concatenate([stamps, stamps[[3, 150]]])))
    assert repeated.received == 202 and repeated.lost == 0
    assert repeated.last_s == pytest.approx(199 * PERIOD_S)
    assert _fed(np.arange(REFERENCE_INTERVALS + 1) * PERIOD_S).period_s == pytest.approx(
        PERIOD_S)


def test_restore_puts_the_counts_back():
    loss = _fed(np.arange(10) * PERIOD_S)
    saved, before = loss.save(), loss.report()
    for stamp in np.arange(10, 200, 2) * PERIOD_S:
        loss.add(float(stamp))
    assert loss.report() != before
    loss.restore(saved)
    assert loss.report() == before
    for stamp in np.arange(10, 200, 2) * PERIOD_S:
        loss.add(float(stamp))
    assert loss.lost == 94


def _imu_kept(trip, keep):
    imu = trip.imu
    return dataclasses.replace(trip, imu=dataclasses.replace(
        imu, stamp_s=imu.stamp_s[keep], angular_velocity_rad_s=imu.angular_velocity_rad_s[keep],
        linear_acceleration_m_s2=None if imu.linear_acceleration_m_s2 is None
        else imu.linear_acceleration_m_s2[keep],
        yaw_rate_variance=None if imu.yaw_rate_variance is None
        else imu.yaw_rate_variance[keep]))


def test_a_run_whose_gyro_lost_most_samples_says_so():
    # As a best-effort link that overflows loses them: at random, 60 % of the gyro's
    # samples after the static start. The filter holds each last rate; the run says it.
    trip = simulate_trip(SimulationConfig(duration_s=40.0), 2)
    rng = np.random.default_rng(1)
    keep = (trip.imu.stamp_s < 8.0) | (rng.random(len(trip.imu.stamp_s)) > 0.6)
    lossy = summarize(run_trip(_imu_kept(trip, keep)))
    gyro = lossy['input_loss']['gyro']
    assert gyro['received'] == int(keep.sum())
    assert gyro['share'] < VERDICT_MIN_RECEIVED_SHARE
    assert gyro['share'] == pytest.approx(keep.mean(), abs=0.01)
    assert lossy['input_loss']['odometry']['lost'] == 0
    said = [r for r in lossy['health']['reasons'] if r.startswith('gyro: ')]
    assert len(said) == 1 and 'of the samples its stamps imply arrived' in said[0]
    assert lossy['health']['verdict'] == 'degraded'
    # The same trip whole: nothing lost, nothing said.
    whole = summarize(run_trip(trip))
    assert whole['input_loss']['gyro'] == {'received': len(trip.imu.stamp_s), 'lost': 0,
                                           'share': 1.0, 'period_s': pytest.approx(0.005),
                                           'longest_interval_s': pytest.approx(0.005),
                                           'last_s': trip.imu.stamp_s[-1],
                                           'stamp_scatter_s': pytest.approx(0.0, abs=1e-9),
                                           'misplaced': 0, 'scatters': False}
    assert not [r for r in whole['health']['reasons'] if r.startswith('gyro: ')]


def test_a_run_whose_gyro_stamps_scatter_says_so_and_not_that_samples_were_lost():
    # A USB IMU stamped on arrival: 2 ms of scatter at 200 Hz. The run keeps its bounds
    # (the hold integrates over intervals off by the scatter, which does not add up).
    trip = simulate_trip(SimulationConfig(duration_s=40.0), 2)
    rng = np.random.default_rng(4)
    imu = trip.imu
    stamps = np.sort(imu.stamp_s + rng.normal(0.0, 0.002, len(imu.stamp_s)))
    scattered = summarize(run_trip(dataclasses.replace(
        trip, imu=dataclasses.replace(imu, stamp_s=stamps))))
    said = [r for r in scattered['health']['reasons'] if r.startswith('gyro: ')]
    assert len(said) == 1 and 'its stamps scatter about its' in said[0], said
    assert scattered['input_loss']['gyro']['share'] > VERDICT_MIN_RECEIVED_SHARE
    assert scattered['input_loss']['gyro']['scatters']
    assert scattered['health']['verdict'] == 'degraded'
    assert scattered['ground_truth']['position_rmse_m'] < 0.02


def test_silences_count_the_time_since_the_last_sample_too():
    gyro = _fed(np.arange(400) * PERIOD_S).report()
    stopped = _fed(np.arange(100) * 0.01).report()
    # The odometry stopped at 0.99 s while the gyro went on to 1.995 s: silent for 1 s.
    gaps = silences({'gyro': gyro, 'odometry': stopped, 'none': InputLoss().report()}, 1.995)
    assert gaps == {'gyro': pytest.approx(PERIOD_S), 'odometry': pytest.approx(1.005)}
    assert silences({'gyro': gyro}, None) == {'gyro': pytest.approx(PERIOD_S)}
