"""A LiDAR's stamps against the gyro's, from its headings (core/time_offset.py)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from gyro_ekf.core.time_offset import (MATERIAL_FACTOR, MIN_WINDOWS, WINDOW_S,
                                       TimeOffsetWatch, t_limit)

SCAN_S = 0.1
HEADING_SIGMA = math.radians(0.02)


def _scans(offset_s: float, seconds: float = 120.0, seed: int = 0, bias: float = 0.01,
           scale_error: float = 0.0, turn_rad_s: float = 0.4, ramp: float = 0.0
           ) -> list[tuple]:
    """Scans at 10 Hz of a platform weaving; each LiDAR heading as seen offset_s earlier.

    Returns (stamp, LiDAR heading, gyro's raw integral, rate less the bias, heading
    variance) per scan.
    """
    rng = np.random.default_rng(seed)
    dt = 0.005
    t = np.arange(0.0, seconds, dt)
    rate = turn_rad_s * np.sin(2.0 * math.pi * t / 7.0) + 0.5 * turn_rad_s * np.sin(
        2.0 * math.pi * t / 3.1)
    heading = np.cumsum(rate) * dt
    turned = np.cumsum((1.0 + scale_error) * rate + bias + ramp * t) * dt
    scans = []
    for k in range(0, t.size, round(SCAN_S / dt)):
        # The LiDAR saw the platform offset_s before the stamp it carries.
        seen = float(np.interp(t[k] - offset_s, t, heading))
        seen += rng.normal(0.0, math.radians(0.03))
        scans.append((float(t[k]), math.remainder(seen, math.tau), float(turned[k]),
                      float(rate[k]), HEADING_SIGMA ** 2))
    return scans


def _watch(scans: list[tuple]) -> TimeOffsetWatch:
    watch = TimeOffsetWatch()
    for scan in scans:
        watch.add(*scan)
    return watch


@pytest.mark.parametrize('offset_s', [-0.05, -0.01, 0.01, 0.03])
def test_an_offset_is_measured_and_found(offset_s):
    watch = _watch(_scans(offset_s))
    offset, sigma = watch.estimate()
    assert offset == pytest.approx(offset_s, abs=1e-3)
    assert abs(offset) > t_limit(watch.report()['windows']) * sigma
    assert watch.found()
    report = watch.report()
    assert report['found'] and report['windows'] >= MIN_WINDOWS
    assert report['offset_s'] == offset and report['offset_sigma_s'] == sigma


def test_scans_on_time_are_not_found_nor_a_gyro_scale_error():
    for scale_error in (0.0, 0.02):
        watch = _watch(_scans(0.0, scale_error=scale_error))
        offset, _ = watch.estimate()
        assert abs(offset) < 1e-3
        assert not watch.found()


@pytest.mark.parametrize('offset_s', [0.0, 0.03])
def test_a_bias_that_ramps_is_no_offset(offset_s):
    # A ramp of 1 deg/s per minute: the gyro's integral bends by a quadratic in each window,
    # free in each window's fit as the bias and its rate are. Left out of it, such a bend
    # leaked into the rate's regressor where the turns came at the same times of the
    # windows (two bias_ramp trips of stress seed 85 read 4.1 and -3.0 ms, found).
    plain = _watch(_scans(offset_s)).estimate()
    for ramp in (math.radians(1.0) / 60.0, -math.radians(3.0) / 60.0):
        ramped = _watch(_scans(offset_s, ramp=ramp)).estimate()
        assert ramped == pytest.approx(plain, rel=1e-6, abs=1e-9)


def test_an_offset_too_small_to_matter_is_measured_but_not_found():
    # Slow turns: 10 ms behind at about 2.7 deg/s RMS (0.027 deg) is under MATERIAL_FACTOR
    # heading sigmas (0.02 deg), though far beyond its standard error.
    watch = _watch(_scans(0.01, turn_rad_s=0.06, seconds=200.0))
    offset, sigma = watch.estimate()
    assert offset == pytest.approx(0.01, abs=1e-3)
    assert abs(offset) > t_limit(watch.report()['windows']) * sigma
    report = watch.report()
    effect = abs(offset) * math.radians(report['rate_rms_deg_s'])
    assert effect < MATERIAL_FACTOR * math.radians(report['heading_sigma_deg'])
    assert not watch.found()


def test_the_limit_is_students_t_on_the_windows_scatter():
    # 6 windows leave 5 dof: 6.87 standard errors at 1e-3; many windows near the normal's.
    assert t_limit(MIN_WINDOWS) == 6.87
    assert t_limit(11) == 4.59
    assert t_limit(1000) == 3.55


def test_nothing_is_said_before_enough_windows():
    watch = _watch(_scans(0.03, seconds=WINDOW_S * (MIN_WINDOWS - 1)))
    assert watch.estimate() is None and not watch.found()
    assert watch.report()['offset_s'] is None and not watch.report()['found']


def test_a_steady_turn_is_not_informative():
    # A constant rate's lag is a constant heading offset: no window counts.
    watch = TimeOffsetWatch()
    for k in range(1200):
        t = k * SCAN_S
        watch.add(t, math.remainder(0.3 * (t - 0.03), math.tau), 0.3 * t, 0.3,
                  HEADING_SIGMA ** 2)
    assert watch.report()['windows'] == 0


def test_restore_across_a_window_close_puts_the_watch_back():
    # Saved a second before a window closes and restored two seconds later (core/lagged.py
    # replays a late scan so, within at most 5 s): the same figures, and the same ones
    # again when the scans are fed once more.
    scans = _scans(0.03, seconds=150.0)
    cut = next(k for k, scan in enumerate(scans) if scan[0] >= WINDOW_S * MIN_WINDOWS - 1.0)
    later = next(k for k, scan in enumerate(scans) if scan[0] >= scans[cut][0] + 2.0)
    watch = _watch(scans[:cut])
    saved, before = watch.save(), watch.report()
    for scan in scans[cut:later]:
        watch.add(*scan)
    assert watch.report() != before  # the MIN_WINDOWS-th window closed: an offset now
    watch.restore(saved)
    assert watch.report() == before
    for scan in scans[cut:]:
        watch.add(*scan)
    assert watch.report() == _watch(scans).report()


def test_a_restarted_window_drops_its_scans():
    # The filter's heading was reset (a mount moved back): the open window's scans, which
    # straddle it, are dropped, and the next window starts at the next scan.
    scans = _scans(0.03, seconds=19.0)
    restarted, kept = TimeOffsetWatch(), TimeOffsetWatch()
    for scan in scans:
        if scan[0] == pytest.approx(9.0):
            restarted.restart_window()
        restarted.add(*scan)
        kept.add(*scan)
    assert kept.report()['windows'] == 1 and restarted.report()['windows'] == 0
