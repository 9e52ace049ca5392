"""A LiDAR's stamps that scatter about when its scans were taken: measured and said
(core/stamp_jitter.py)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from gyro_ekf.analysis.offline import run_trip
from gyro_ekf.analysis.summary import summarize
from gyro_ekf.core.stamp_jitter import MAX_SCAN_SIGMA_S, MIN_SCANS, StampJitterWatch
from gyro_ekf.core.simulator import SimulationConfig, simulate_trip


def _watched(scatter_s, scans=2000, seed=0, common=0.0, told=True):
    """A watch fed scans whose stamps are off by N(2 ms, scatter_s^2).

    Each scan has four poles of g = 1e5 / s^2 each (3.2 ms of stamp noise per pole), and a
    pose error of variance ``common`` (in j^T W e units) that all four share.
    """
    rng = np.random.default_rng(seed)
    watch = StampJitterWatch()
    for _ in range(scans):
        delta = 0.002 + scatter_s * rng.standard_normal()
        shared = math.sqrt(common) * rng.standard_normal() / 4.0
        for _ in range(4):
            g = 1e5
            # a = j^T W e with e = -j delta + noise: mean -g delta, variance g.
            watch.add(-g * delta + math.sqrt(g) * rng.standard_normal() + shared, g)
        watch.close_scan(common=common if told else 0.0)
    return watch


def test_the_scatter_of_the_stamps_is_measured_about_their_offset():
    watch = _watched(0.003)
    variance, sigma, share = watch.estimate()
    assert math.sqrt(variance) == pytest.approx(0.003, rel=0.1)
    # A scan's g is 4e5: 9e-6 s^2 of scatter is 3.6 times its noise variance.
    assert share == pytest.approx(3.6, rel=0.2)
    assert watch.found()
    report = watch.report()
    assert report['found'] and report['scans'] == 2000
    assert report['jitter_s'] == pytest.approx(0.003, rel=0.1)


def test_stamps_on_time_are_not_found():
    for seed in range(5):
        watch = _watched(0.0, seed=seed)
        variance, sigma, _ = watch.estimate()
        assert abs(variance) < 4.0 * sigma
        assert not watch.found()


def test_a_scatter_too_small_to_matter_is_measured_but_not_found():
    watch = _watched(0.0008)  # 0.26 of a scan's noise variance
    variance, sigma, share = watch.estimate()
    assert variance > 6.0 * sigma and share < 1.0
    assert not watch.found()


def test_the_pose_error_a_scans_poles_share_is_no_scatter():
    # Told of it, the watch takes it as noise; not told, it reads as scatter.
    common = 4.0 * 4e5  # four times a scan's own noise in j^T W e
    assert not _watched(0.0, common=common).found()
    untold = _watched(0.0, common=common, told=False)
    assert untold.found()


def test_slow_scans_and_too_few_scans_say_nothing():
    watch = StampJitterWatch()
    # One pole of g below 1 / MAX_SCAN_SIGMA_S^2: its stamp is not told within 10 ms.
    watch.add(0.0, 0.5 / MAX_SCAN_SIGMA_S ** 2)
    watch.close_scan()
    assert watch.scans == 0
    assert _watched(0.01, scans=MIN_SCANS - 1).estimate() is None
    assert not StampJitterWatch.scan_is_informative(4, 0.01, 0.05, 0.015 ** 2, 0.002 ** 2)
    assert StampJitterWatch.scan_is_informative(4, 0.3, 0.5, 0.015 ** 2, 0.002 ** 2)


def test_save_and_restore():
    watch = _watched(0.003, scans=200)
    saved = watch.save()
    before = watch.report()
    watch.add(5.0, 1e5)
    watch.close_scan()
    watch.restore(saved)
    assert watch.report() == before


@pytest.fixture(scope='module')
def trips():
    """A clean 60-s simulated trip and the same with its scans' stamps scattered by 5 ms."""
    trip = simulate_trip(SimulationConfig(duration_s=60.0), seed=4)
    scans = trip.scans[0]
    scattered = scans.stamp_s + np.random.default_rng(4).normal(0.0, 0.005, scans.stamp_s.size)
    late = dataclasses.replace(trip, scans=(dataclasses.replace(scans, stamp_s=scattered),))
    return trip, late


def test_a_lidar_whose_stamps_scatter_is_named_first(trips):
    clean, scattered = trips
    summary = summarize(run_trip(scattered))
    jitter = summary['stamp_jitter']['scan']
    assert jitter['found'] and 0.003 <= jitter['jitter_s'] <= 0.0055
    reasons = summary['health']['reasons']
    assert reasons[0].startswith("LiDAR scan's stamps scatter by at least"), reasons
    assert 'stamp them by the LiDAR\'s own clock' in reasons[0]
    on_time = summarize(run_trip(clean))
    assert not on_time['stamp_jitter']['scan']['found']
    assert not any('scatter' in reason for reason in on_time['health']['reasons'])
