"""Whiteness test of each LiDAR's innovations: quiet if consistent, loud on a slow error."""

from __future__ import annotations

import math

import numpy as np
import pytest

from gyro_ekf.analysis import metrics
from gyro_ekf.analysis.offline import run_trip
from gyro_ekf.analysis.summary import summarize
from gyro_ekf.core import health
from gyro_ekf.core.config import EkfConfig
from gyro_ekf.core.simulator import SimulationConfig, simulate_trip

S = np.diag([0.02 ** 2, 0.002 ** 2])
"""Innovation covariance of the synthetic updates: 2 cm, 0.11 deg."""
S_PACKED = (S[0, 0], S[0, 1], S[1, 1])
POLES = 6
SCANS_PER_S = 10.0


def _feed(monitor, seconds, bearing_offset=None, seed=0, key='scan'):
    """Scans of POLES updates each, innovations drawn from S (plus the offset asked for)."""
    rng = np.random.default_rng(seed)
    sigma = np.sqrt(np.diag(S))
    for k in range(int(seconds * SCANS_PER_S)):
        stamp = k / SCANS_PER_S
        for _ in range(POLES):
            y = rng.normal(0.0, sigma)
            if bearing_offset is not None:
                y[1] += bearing_offset(stamp)
            monitor.innovation(key, stamp, tuple(y), S_PACKED, [5.0, 0.3])
        monitor.record(key, stamp, POLES, POLES, 2.0 * POLES, 0.0, name=key)


def _whiteness_reasons(monitor):
    return [r for r in health.verdict(health.RunFigures(
        detections=1, matched=1, updates=1, nis_mean=2.0, longest_gap_s=0.0, start_gap_s=0.0,
        sensors=monitor.report()))['reasons'] if 'not white' in r]


@pytest.mark.parametrize('dof', [10, 24, 42, 100, 160])
@pytest.mark.parametrize('significance', [1e-2, 1e-3, 2.5e-4])
def test_the_approximate_quantile_is_within_one_percent(dof, significance):
    exact = metrics.chi_square_quantile(1.0 - significance, dof)
    assert health.chi_square_upper(significance, dof) == pytest.approx(exact, rel=0.01)


@pytest.mark.parametrize('seed', range(5))
def test_white_innovations_pass_and_their_chi_square_has_its_expected_size(seed):
    monitor = health.HealthMonitor(EkfConfig(landmark_sigma_m=0.0))
    _feed(monitor, 120.0, seed=seed)
    figures = monitor.report()[0]['whiteness']
    assert figures['blocks'] == 24 and figures['updates'] == 1200 * POLES
    # chi-square with 24 dof: mean 24, sd 7; 80 is beyond its 1e-7 quantile.
    for component in ('range_chi2', 'bearing_chi2'):
        assert 2.0 < figures[component] < 80.0
    assert _whiteness_reasons(monitor) == []


def test_a_slow_bearing_error_of_half_a_sigma_is_named():
    monitor = health.HealthMonitor(EkfConfig(landmark_sigma_m=0.0))
    # A heading error wandering with a 20 s period, half the bearing sigma at its peak.
    _feed(monitor, 120.0, bearing_offset=lambda t: 0.001 * math.sin(2.0 * math.pi * t / 20.0))
    reasons = _whiteness_reasons(monitor)
    assert reasons[0].startswith('LiDAR scan bearing innovations are not white: 5-s block '
                                 'sums give chi-square ')
    assert 'on 24 blocks, above' in reasons[0] and 'significance 0.001' in reasons[0]
    assert not any(' range ' in r for r in reasons)


def test_a_shift_of_every_detection_in_the_lidar_frame_is_named_as_such():
    # A 5 mm mount offset (a quarter of the range sigma) seen on poles all around: its
    # range and bearing shares change sign with the bearing and cancel; x does not.
    monitor = health.HealthMonitor(EkfConfig(landmark_sigma_m=0.0))
    rng = np.random.default_rng(3)
    sigma = np.sqrt(np.diag(S))
    r, shift = 5.0, np.array([0.005, 0.0])
    for k in range(1200):
        for pole in range(POLES):
            bearing = 2.0 * math.pi * pole / POLES
            c, s = math.cos(bearing), math.sin(bearing)
            y = rng.normal(0.0, sigma) + [c * shift[0] + s * shift[1],
                                          (-s * shift[0] + c * shift[1]) / r]
            monitor.innovation('scan', k / 10.0, tuple(y), S_PACKED, [r, bearing])
        monitor.record('scan', k / 10.0, POLES, POLES, 2.0 * POLES, 0.0)
    reasons = _whiteness_reasons(monitor)
    assert len(reasons) == 1, reasons
    assert reasons[0].startswith('LiDAR scan sensor-frame x innovations are not white')


def test_too_few_blocks_are_not_judged():
    monitor = health.HealthMonitor(EkfConfig(landmark_sigma_m=0.0))
    _feed(monitor, 45.0, bearing_offset=lambda t: 0.002)
    assert monitor.report()[0]['whiteness']['blocks'] == 9
    assert _whiteness_reasons(monitor) == []


def test_with_a_stated_map_error_the_test_is_not_judged():
    # Each pole's map error repeats at every look at it: correlated by design.
    monitor = health.HealthMonitor(EkfConfig(landmark_sigma_m=0.01))
    _feed(monitor, 120.0, bearing_offset=lambda t: 0.002)
    figures = monitor.report()[0]['whiteness']
    assert not figures['judged'] and figures['bearing_chi2'] > 1000.0
    assert _whiteness_reasons(monitor) == []


def test_save_and_restore_keep_the_test_independent():
    monitor = health.HealthMonitor(EkfConfig(landmark_sigma_m=0.0))
    _feed(monitor, 30.0)
    saved = monitor.save()
    before = monitor.report()[0]['whiteness']
    _feed(monitor, 30.0, seed=1)
    assert monitor.report()[0]['whiteness'] != before
    monitor.restore(saved)
    assert monitor.report()[0]['whiteness'] == before


def _trip_summary(ekf: EkfConfig | None = None, **changes):
    from gyro_ekf.io.params_file import PipelineParams
    config = SimulationConfig(duration_s=70.0, **changes)
    params = None if ekf is None else PipelineParams(ekf=ekf)
    return summarize(run_trip(simulate_trip(config, seed=3), params))


def test_a_clean_trip_is_white_and_ok():
    summary = _trip_summary()
    assert summary['health']['verdict'] == 'ok', summary['health']['reasons']
    assert summary['health']['lidars'][0]['whiteness']['blocks'] >= health.WHITENESS_MIN_BLOCKS


def test_coloured_gyro_noise_makes_the_bearing_innovations_not_white():
    # A Gauss-Markov wander of 0.03 deg/s over 3 s on the gyro, to a filter that does not
    # learn it: the heading innovations keep one sign for seconds at a time while the NIS
    # mean stays inside its band.
    wander = {'gyro_colored_noise_rad_s': math.radians(0.03), 'gyro_colored_noise_tau_s': 3.0}
    summary = _trip_summary(EkfConfig(learn_gyro_wander=False), **wander)
    section = summary['health']
    assert section['verdict'] == 'degraded'
    assert any(r.startswith('LiDAR scan bearing innovations are not white')
               for r in section['reasons']), section['reasons']
    assert not any(r.startswith('mean NIS') for r in section['reasons'])
    # Learnt (the default), the wander is the filter's fifth state: its innovations are
    # white again (core/gyro_wander.py).
    learnt = _trip_summary(**wander)
    assert learnt['online_bias']['gyro_wander_found_s'] is not None
    assert not any(r.startswith('LiDAR scan bearing innovations are not white')
                   for r in learnt['health']['reasons']), learnt['health']['reasons']


def test_a_bias_step_is_caught_by_the_bias_watch():
    # 0.05 deg/s at 30 s. Until the trip's start pose was held at rest, the bias watch
    # took long enough that the innovations were not white either (chi-square 57 on 15
    # blocks); now it re-opens the bias within a few blocks and they stay white.
    summary = _trip_summary(gyro_bias_step_rad_s=math.radians(0.05), gyro_bias_step_at_s=30.0)
    section = summary['health']
    assert section['verdict'] == 'degraded'
    assert any(r.startswith('the gyro bias changed during the run')
               for r in section['reasons']), section['reasons']
    assert summary['ground_truth']['nees_share_in_band'] >= 0.9


def test_an_hour_of_white_innovations_passes_window_by_window():
    monitor = health.HealthMonitor(EkfConfig(landmark_sigma_m=0.0))
    _feed(monitor, 3600.0, seed=7)
    figures = monitor.report()[0]['whiteness']
    assert figures['window'] == 30 and figures['total_blocks'] == 720
    assert all(figures['worst'][c]['blocks'] == health.WHITENESS_WINDOW_BLOCKS
               for c in health.WHITENESS_COMPONENTS)
    assert _whiteness_reasons(monitor) == []


def test_a_slow_error_in_one_window_of_a_long_run_is_named_with_its_window():
    monitor = health.HealthMonitor(EkfConfig(landmark_sigma_m=0.0))
    # The wander of the 120-s test above, only in the eleventh 2-minute window.
    _feed(monitor, 1800.0, bearing_offset=lambda t: 0.001 * math.sin(
        2.0 * math.pi * t / 20.0) if 1200.0 <= t < 1320.0 else 0.0)
    reasons = _whiteness_reasons(monitor)
    assert reasons[0].startswith("LiDAR scan bearing innovations are not white in the run's "
                                 "2-minute window 11: 5-s block sums give chi-square ")
    assert 'on 24 blocks' in reasons[0] and 'significance 8.26446e-06' in reasons[0]
    assert not any(' range ' in r for r in reasons)
    assert all('window 11:' in r for r in reasons)


@pytest.mark.parametrize('offset_m', [0.01, -0.006])
def test_ranges_that_read_long_or_short_at_every_pole_are_said_so(offset_m):
    # Half a range sigma or less, at every update: the range test fails, and the mean of
    # the blocks' mean range innovations says by how much and which way.
    monitor = health.HealthMonitor(EkfConfig(landmark_sigma_m=0.0))
    rng = np.random.default_rng(5)
    sigma = np.sqrt(np.diag(S))
    for k in range(1200):
        for _ in range(POLES):
            y = rng.normal(0.0, sigma) + [offset_m, 0.0]
            monitor.innovation('scan', k / 10.0, tuple(y), S_PACKED, [5.0, 0.3])
        monitor.record('scan', k / 10.0, POLES, POLES, 2.0 * POLES, 0.0)
    figures = monitor.report()[0]['whiteness']
    assert figures['range_mean_m'] == pytest.approx(offset_m, abs=0.001)
    assert abs(figures['range_mean_t']) > health.RANGE_MEAN_T
    reasons = [r for r in _whiteness_reasons(monitor) if ' range ' in r]
    assert len(reasons) == 1, reasons
    assert f'its ranges read {100.0 * offset_m:+.1f} cm against the map' in reasons[0]
    assert ('thinner' if offset_m > 0 else 'thicker') in reasons[0]


def test_poles_thicker_than_the_detector_takes_them_for_are_named():
    # 8-cm poles, detected as the configured 5-cm ones: every centre lands short of its
    # pole, and the run says which way to look (no clean trip says it: above).
    summary = _trip_summary(pole_radius_m=0.08)
    reasons = [r for r in summary['health']['reasons'] if 'range innovations' in r]
    assert len(reasons) == 1, summary['health']['reasons']
    assert "poles thicker than the detector's pole_radius_m" in reasons[0]
    assert summary['health']['lidars'][0]['whiteness']['range_mean_m'] < -0.01
