"""Each LiDAR's noise measured from its innovations: the estimator alone, then in a run."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from gyro_ekf.analysis.offline import run_trip
from gyro_ekf.analysis.summary import summarize
from gyro_ekf.core.config import EkfConfig, make_config
from gyro_ekf.core.errors import CoreError
from gyro_ekf.core.noise_online import NoiseMatch
from gyro_ekf.core.simulator import SimulationConfig, simulate_trip
from gyro_ekf.core.validation import validate_trip
from gyro_ekf.io.params_file import PipelineParams

CONFIGURED = (0.02 ** 2, math.radians(0.1) ** 2)
"""Configured range (m^2) and bearing (rad^2) noise variances."""


def _feed(match: NoiseMatch, true_r: tuple[float, float], pose_part: tuple[float, float],
          n: int, seed: int = 0) -> None:
    """Feed n updates whose innovations have covariance pose_part + true_r, as a filter
    with a right P and the estimator's R in use would see them."""
    rng = np.random.default_rng(seed)
    for _ in range(n):
        used = match.variances
        y = tuple(rng.normal(0.0, math.sqrt(p + r)) for p, r in zip(pose_part, true_r))
        match.add(y, (pose_part[0] + used[0], 0.0, pose_part[1] + used[1]), used)


def test_the_measured_noise_replaces_the_configured_once_it_has_enough_updates():
    match = NoiseMatch(*CONFIGURED, window=1000, min_updates=300, limit=4.0)
    true_r = (0.013 ** 2, math.radians(0.11) ** 2)
    pose_part = (0.003 ** 2, math.radians(0.03) ** 2)
    _feed(match, true_r, pose_part, 299)
    assert match.variances == CONFIGURED and not match.in_use
    _feed(match, true_r, pose_part, 2701, seed=1)
    assert match.in_use
    range_var, bearing_var = match.variances
    # 1000-update mean of chi-square(1) samples: about 4.5 % standard error on a variance.
    assert range_var == pytest.approx(true_r[0], rel=0.15)
    assert bearing_var == pytest.approx(true_r[1], rel=0.15)
    np.testing.assert_array_equal(match.R, np.diag(match.variances))
    report = match.report()
    assert report['range_sigma_m'] == pytest.approx(0.013, rel=0.08)
    assert report['configured_range_sigma_m'] == pytest.approx(0.02)
    assert report['updates'] == 3000 and report['in_use']
    assert report['measured_range_sigma_m'] == pytest.approx(report['range_sigma_m'])


def test_with_limit_one_the_noise_is_measured_but_not_used():
    match = NoiseMatch(*CONFIGURED, window=1000, min_updates=300, limit=1.0)
    _feed(match, (0.013 ** 2, math.radians(0.11) ** 2), (1e-6, 1e-9), 1000)
    assert match.variances == CONFIGURED
    report = match.report()
    assert not report['in_use']
    assert report['measured_range_sigma_m'] == pytest.approx(0.013, rel=0.08)


def test_the_measured_noise_stays_within_its_limits():
    match = NoiseMatch(*CONFIGURED, window=500, min_updates=100, limit=4.0)
    # A sensor far quieter than configured, then one far noisier.
    _feed(match, (1e-8, 1e-12), (1e-6, 1e-9), 1000)
    assert match.variances == pytest.approx((CONFIGURED[0] / 4.0, CONFIGURED[1] / 4.0))
    match = NoiseMatch(*CONFIGURED, window=500, min_updates=100, limit=4.0)
    _feed(match, (100.0 * CONFIGURED[0], 100.0 * CONFIGURED[1]), (1e-6, 1e-9), 1000)
    assert match.variances == pytest.approx((CONFIGURED[0] * 4.0, CONFIGURED[1] * 4.0))


def test_updates_whose_s_is_mostly_the_pose_uncertainty_are_left_out():
    match = NoiseMatch(*CONFIGURED, window=1000, min_updates=1, limit=4.0)
    # Settling: S is three times R in range; such an update says little about R.
    match.add((0.05, 0.0), (3.0 * CONFIGURED[0], 0.0, CONFIGURED[1]), CONFIGURED)
    assert match.updates == 0 and match.variances == CONFIGURED


def test_save_and_restore_put_the_estimate_back():
    match = NoiseMatch(*CONFIGURED, window=1000, min_updates=50, limit=4.0)
    _feed(match, (0.01 ** 2, math.radians(0.08) ** 2), (1e-6, 1e-9), 100)
    saved, before = match.save(), match.variances
    _feed(match, (0.03 ** 2, math.radians(0.2) ** 2), (1e-6, 1e-9), 500, seed=2)
    assert match.variances != before
    match.restore(saved)
    assert match.variances == before and match.updates == 100


def test_the_window_and_limit_are_checked_where_they_enter():
    with pytest.raises(CoreError, match='lidar_noise_window'):
        make_config(EkfConfig, {'lidar_noise_window': -1})
    with pytest.raises(CoreError, match='lidar_noise_limit'):
        make_config(EkfConfig, {'lidar_noise_limit': 0.5})


def _run(**ekf):
    trip = simulate_trip(SimulationConfig(duration_s=60.0), 4)
    trip, report = validate_trip(trip, trip.name)
    params = PipelineParams()
    params = dataclasses.replace(params, ekf=dataclasses.replace(params.ekf, **ekf))
    return summarize(run_trip(trip, params), report)


# The simulator's poles, placed from 1.5 cm per-beam noise, are 0.7-1.8 cm off in range
# (1.3 cm overall) and 0.1 deg in bearing: less than the configured 2 cm.
SIM_RANGE_SIGMA_M = (0.008, 0.016)
SIM_BEARING_SIGMA_DEG = (0.07, 0.14)


def test_by_default_a_trip_measures_and_reports_its_lidar_noise_and_keeps_the_configured():
    noise = _run()['online_noise']['scan']
    assert noise['updates'] >= 300 and not noise['in_use']
    assert SIM_RANGE_SIGMA_M[0] <= noise['measured_range_sigma_m'] <= SIM_RANGE_SIGMA_M[1]
    assert (SIM_BEARING_SIGMA_DEG[0] <= noise['measured_bearing_sigma_deg']
            <= SIM_BEARING_SIGMA_DEG[1])
    assert noise['range_sigma_m'] == noise['configured_range_sigma_m'] == pytest.approx(0.02)


def test_with_a_limit_the_measured_noise_is_used():
    summary = _run(lidar_noise_limit=4.0)
    noise = summary['online_noise']['scan']
    assert noise['in_use']
    assert SIM_RANGE_SIGMA_M[0] <= noise['range_sigma_m'] <= SIM_RANGE_SIGMA_M[1]
    # The figures in use are refreshed every 20 updates.
    assert noise['range_sigma_m'] == pytest.approx(noise['measured_range_sigma_m'], rel=0.02)
    truth = summary['ground_truth']
    assert truth['position_rmse_m'] <= 0.02 and truth['nees_share_in_band'] >= 0.9


def test_window_zero_measures_nothing():
    assert _run(lidar_noise_window=0)['online_noise'] == {}
