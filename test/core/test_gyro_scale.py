"""The gyro's scale measured against a LiDAR-held heading (core/gyro_scale.py)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from gyro_ekf.core.gyro_scale import MIN_WINDOWS, WINDOW_S, GyroScaleWatch


def _drive(watch: GyroScaleWatch, scale_error: float, bias_of_t, seconds: float = 160.0,
           seed: int = 0, start_s: float = 0.0) -> None:
    """Feed scans at 40 Hz of a platform weaving (turn rate varying every few seconds)."""
    rng = np.random.default_rng(seed)
    dt = 0.025
    t = np.arange(0.0, seconds, dt)
    rate = 0.4 * np.sin(2.0 * math.pi * t / 7.0) + 0.2 * np.sin(2.0 * math.pi * t / 3.1)
    heading = np.cumsum(rate) * dt
    measured = (1.0 + scale_error) * rate + np.array([bias_of_t(s) for s in t])
    turned = np.cumsum(measured) * dt
    # The heading the LiDARs hold: the truth within a few hundredths of a degree.
    held = heading + rng.normal(0.0, math.radians(0.03), t.size)
    for stamp, yaw, angle in zip(t + start_s, held, turned):
        watch.add(float(stamp), math.atan2(math.sin(yaw), math.cos(yaw)), float(angle))


@pytest.mark.parametrize('scale_error', [-0.02, -0.005, 0.01, 0.03])
def test_a_scale_error_is_measured_and_found(scale_error):
    watch = GyroScaleWatch()
    _drive(watch, scale_error, lambda t: 0.01)
    scale, sigma = watch.estimate()
    assert scale == pytest.approx(scale_error, abs=3e-4)
    assert sigma < 3e-4
    assert watch.found()
    report = watch.report()
    assert report['found'] and report['windows'] >= MIN_WINDOWS
    # Configured as it is: nothing to say.
    configured = GyroScaleWatch(configured=scale_error)
    _drive(configured, scale_error, lambda t: 0.01)
    assert not configured.found()


def test_an_exact_gyro_whose_bias_steps_and_ramps_is_no_scale():
    # The bias is free in every window: a step between windows and a ramp are not a scale,
    # nor applied as one.
    watch = GyroScaleWatch(learn=True)
    _drive(watch, 0.0, lambda t: 0.01 + 0.002 * t / 60.0 + (0.005 if t > 3 * WINDOW_S else 0.0))
    scale, _ = watch.estimate()
    assert abs(scale) < 5e-4
    assert not watch.found()
    assert watch.in_use == 0.0 and watch.applied == 0


@pytest.mark.parametrize('windows', [3, 4, 5, 6])
def test_few_windows_cross_the_threshold_by_chance_about_1_percent_of_the_time(windows):
    # The standard error comes from the windows' own scatter, so with few windows the
    # threshold is Student's t, not a normal 4: exact gyros whose windows scatter by 0.5 %
    # (MIN_SCALE_DIFFERENCE out of the way) would otherwise find a scale 6 % of the time at
    # three windows.
    rng = np.random.default_rng(windows)
    trials, crossed, crossed_at_4 = 20000, 0, 0
    for _ in range(trials):
        watch = GyroScaleWatch()
        weights = rng.uniform(0.5, 2.0, windows)
        alphas = 1.0 + rng.normal(0.0, 0.005, windows) / np.sqrt(weights)
        watch.windows = [(float(w), float(w * a)) for w, a in zip(weights, alphas)]
        scale, sigma = watch.estimate()
        crossed += abs(scale) > watch._sigmas() * sigma
        crossed_at_4 += abs(scale) > 4.0 * sigma
    assert 0.005 < crossed / trials < 0.015 if windows < 6 else crossed / trials < 0.015
    if windows == 3:
        assert crossed_at_4 / trials > 0.04


def test_nothing_is_said_before_enough_windows():
    watch = GyroScaleWatch()
    _drive(watch, 0.03, lambda t: 0.0, seconds=WINDOW_S * (MIN_WINDOWS - 1))
    assert watch.estimate() is None and not watch.found()
    assert watch.report()['scale_error'] is None


def test_a_steady_circle_is_not_informative():
    # A constant turn rate cannot be told from a bias: no window counts.
    watch = GyroScaleWatch()
    for k in range(int(200.0 / 0.025)):
        t = k * 0.025
        watch.add(t, math.remainder(0.3 * t, math.tau), 1.02 * 0.3 * t)
    assert watch.report()['windows'] == 0


def test_restore_puts_the_watch_back():
    watch = GyroScaleWatch()
    _drive(watch, 0.01, lambda t: 0.0, seconds=100.0)
    saved, before = watch.save(), watch.report()
    _drive(watch, 0.02, lambda t: 0.0, seconds=100.0, seed=1, start_s=100.0)
    assert watch.report() != before
    watch.restore(saved)
    assert watch.report() == before


def test_a_restarted_window_drops_a_heading_jump():
    restarted, kept = GyroScaleWatch(), GyroScaleWatch()
    for k in range(int(200.0 / 0.025)):
        t = k * 0.025
        yaw = 0.3 * math.sin(t / 2.0)
        # The filter's heading reset by 5 deg at 70 s (a mount moved back): not a turn.
        shown = yaw + (math.radians(5.0) if t >= 70.0 else 0.0)
        if k == int(70.0 / 0.025):
            restarted.restart_window()
        restarted.add(t, shown, yaw)
        kept.add(t, shown, yaw)
    assert restarted.estimate()[0] == pytest.approx(0.0, abs=1e-6)
    assert abs(kept.estimate()[0]) > 1e-3  # taken into a window, the jump reads as a scale


def _drive_counting(watch: GyroScaleWatch, scale_error: float, seconds: float) -> list[float]:
    """_drive, returning the stamps at which the scale in use changed."""
    changes = []
    add = watch.add

    def counting(stamp: float, yaw: float, angle: float) -> bool:
        changed = add(stamp, yaw, angle)
        if changed:
            changes.append(stamp)
        return changed

    watch.add = counting
    _drive(watch, scale_error, lambda t: 0.01, seconds=seconds)
    return changes


@pytest.mark.parametrize('scale_error', [-0.02, 0.01])
def test_learnt_a_scale_found_is_applied_once_and_kept(scale_error):
    watch = GyroScaleWatch(learn=True)
    changes = _drive_counting(watch, scale_error, 400.0)
    # Applied when the windows first find it (the MIN_WINDOWS-th closing), then kept: the
    # windows after it agree with it within their errors.
    assert len(changes) == 1 and watch.applied == 1
    assert changes[0] == pytest.approx(MIN_WINDOWS * WINDOW_S, abs=WINDOW_S)
    assert watch.applied_at_s == changes[0]
    assert watch.in_use == pytest.approx(scale_error, abs=3e-4)
    report = watch.report()
    assert report['in_use'] == watch.in_use and report['applied'] == 1
    assert report['found']  # still off the configured one: the verdict says it


def test_not_learnt_or_exact_nothing_is_applied():
    said = GyroScaleWatch()
    assert _drive_counting(said, 0.01, 400.0) == [] and said.found()
    assert said.in_use == 0.0 and said.applied == 0 and said.applied_at_s is None
    exact = GyroScaleWatch(learn=True)
    assert _drive_counting(exact, 0.0, 400.0) == [] and exact.in_use == 0.0
    # Configured as it is: nothing to apply either.
    configured = GyroScaleWatch(configured=0.01, learn=True)
    assert _drive_counting(configured, 0.01, 400.0) == [] and configured.in_use == 0.01


def test_restore_puts_the_scale_in_use_back():
    # One continuous drive, saved a second before the window that applies the scale and
    # restored after it: the same figures, and the same scale applied again at the same
    # scan when the scans are fed once more.
    scans = []

    class Recorder:
        def add(self, stamp, yaw, angle):
            scans.append((stamp, yaw, angle))

    _drive(Recorder(), 0.01, lambda t: 0.0, seconds=200.0)
    cut = next(k for k, (stamp, _, _) in enumerate(scans)
               if stamp >= WINDOW_S * MIN_WINDOWS - 1.0)
    watch = GyroScaleWatch(learn=True)
    for scan in scans[:cut]:
        assert not watch.add(*scan)
    saved, before = watch.save(), watch.report()
    mean_square_rate = watch.mean_square_rate
    changed = [scan[0] for scan in scans[cut:] if watch.add(*scan)]
    assert len(changed) == 1 and watch.applied == 1 and watch.in_use != 0.0
    after = watch.report()
    watch.restore(saved)
    assert watch.report() == before and watch.mean_square_rate == mean_square_rate
    assert watch.applied == 0 and watch.in_use == 0.0 and watch.applied_at_s is None
    assert [scan[0] for scan in scans[cut:] if watch.add(*scan)] == changed
    assert watch.report() == after
