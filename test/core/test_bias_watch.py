"""The bias watch: quiet on white innovations, opens the bias on a drift the filter lags."""

from __future__ import annotations

import math

import numpy as np
import pytest
from health_trips import simulated_run

from gyro_ekf.core import bias_watch
from gyro_ekf.core.bias_watch import BiasWatch

SCANS_PER_S = 10.0
POLES = 5
S_BB = math.radians(0.12) ** 2


YAW_SIGMA = math.radians(0.03)
"""Yaw error of the filter after a scan's updates (what its corrections carry)."""


def _feed(watch, seconds, bearing_mean_rad=0.0, drift_rad_s=0.0, seed=0, start_s=0.0):
    """Scans of POLES updates; each scan's yaw correction takes back drift_rad_s / scan rate
    and moves the yaw error from one draw of YAW_SIGMA to the next."""
    rng = np.random.default_rng(seed)
    openings = []
    error = rng.normal(0.0, YAW_SIGMA)
    for k in range(int(seconds * SCANS_PER_S)):
        stamp = start_s + k / SCANS_PER_S
        variance = watch.close(stamp)
        if variance is not None:
            openings.append((stamp, variance))
        for _ in range(POLES):
            watch.add(stamp, bearing_mean_rad + rng.normal(0.0, math.sqrt(S_BB)), S_BB)
        new_error = rng.normal(0.0, YAW_SIGMA)
        watch.corrected(-drift_rad_s / SCANS_PER_S + new_error - error)
        error = new_error
    return openings


def test_white_innovations_open_nothing_in_an_hour():
    watch = BiasWatch()
    assert _feed(watch, 3600.0) == []
    assert watch.openings == 0 and watch.walk == 0.0


def test_a_drift_opens_the_bias_by_the_error_its_corrections_imply():
    # A bias 0.2 deg/s too small: the prediction runs ahead 0.2 deg/s, the updates take it
    # back, and their bearing innovations share one sign.
    error = math.radians(0.2)
    watch = BiasWatch()
    openings = _feed(watch, 10.0, bearing_mean_rad=-0.5 * math.sqrt(S_BB), drift_rad_s=error)
    assert openings, 'a drift of 0.2 deg/s was not seen'
    assert openings[0][1] == pytest.approx(error ** 2, rel=0.25)
    assert watch.last_error_rad_s == pytest.approx(error, rel=0.25)
    # Drifts make the bias a random walk while they last: it ends once QUIET_S pass
    # without one (a step learnt is a constant again), not a whole WALK_WINDOW_S later.
    assert watch.walk > 0.0
    last = openings[-1][0]
    seen = []
    for k in range(int(bias_watch.WALK_WINDOW_S)):
        more = _feed(watch, 1.0, start_s=10.0 + k, seed=k)
        last = max([last] + [stamp for stamp, _ in more])
        seen.append((10.0 + k + 1.0 - last, watch.walk))
    assert all(walk > 0.0 for quiet, walk in seen if quiet < bias_watch.QUIET_S - 0.2)
    assert all(walk == 0.0 for quiet, walk in seen if quiet > bias_watch.QUIET_S + 0.2)
    assert seen[-1][0] > bias_watch.QUIET_S < bias_watch.WALK_WINDOW_S


def test_drifts_that_recur_keep_the_bias_walking():
    # A ramp: the filter lags again and again, each drift within QUIET_S of the last.
    error = math.radians(0.2)
    watch = BiasWatch()
    for k in range(6):
        _feed(watch, 10.0, bearing_mean_rad=-0.5 * math.sqrt(S_BB), drift_rad_s=error,
              seed=k, start_s=10.0 * k)
        assert watch.walk > 0.0
    assert watch.openings >= 6


def test_alike_innovations_without_a_drift_open_the_bias_by_almost_nothing():
    # A constant bearing offset (a mount yaw error) is absorbed once: no drift to take back.
    watch = BiasWatch()
    openings = _feed(watch, 10.0, bearing_mean_rad=-0.5 * math.sqrt(S_BB))
    assert openings, 'alike innovations were not seen'
    assert all(variance < math.radians(0.1) ** 2 for _, variance in openings)


def _map_error_feed(watch, map_variance, seconds=600.0):
    """Scans of 3 poles whose map errors (one draw per pole per 20 s) repeat at every look."""
    rng = np.random.default_rng(4)
    sensor = S_BB - 0.8 * S_BB
    openings = 0
    for k in range(int(seconds * SCANS_PER_S)):
        stamp = k / SCANS_PER_S
        if k % int(20 * SCANS_PER_S) == 0:
            offsets = rng.normal(0.0, math.sqrt(0.8 * S_BB), 3)
        openings += watch.close(stamp) is not None
        for pole in range(3):
            watch.add(stamp, offsets[pole] + rng.normal(0.0, math.sqrt(sensor)), S_BB,
                      pole, map_variance)
    return openings


def test_a_stated_map_error_is_no_drift():
    # 80 % of S_bb is the map's: a pole's looks share it, and are alike by design.
    assert _map_error_feed(BiasWatch(), map_variance=0.8 * S_BB) == 0
    # Taken as independent, those same innovations look like drifts.
    assert _map_error_feed(BiasWatch(), map_variance=0.0) > 0


def test_a_block_across_a_dropout_is_not_judged():
    watch = BiasWatch()
    for stamp in (0.0, 0.1):
        assert watch.close(stamp) is None
        watch.add(stamp, 10.0 * math.sqrt(S_BB), S_BB)
        watch.corrected(-0.1)
    assert watch.close(3.0 * bias_watch.BLOCK_S) is None
    assert watch.openings == 0


def test_a_drift_found_elsewhere_counts_as_the_watchs_own():
    # core/gyro_wander.py's held(): a wander that held one sign is a bias that moved; the
    # walk and a ramp's line (which asks for the last drift's sign) take it as a drift.
    watch = BiasWatch()
    assert watch.drift_sign() == 0.0 and watch.walk == 0.0
    assert watch.found(30.0, -2e-4) == pytest.approx(4e-8)
    assert watch.openings == 1 and watch.last_error_rad_s == -2e-4
    assert watch.drift_sign() == -1.0
    assert watch.walk == pytest.approx(4e-8 / bias_watch.WALK_WINDOW_S)


def test_a_bias_step_is_followed_and_said():
    _, trip, run, summary = simulated_run(90.0, gyro_bias_step_rad_s=math.radians(0.4),
                                          gyro_bias_step_at_s=30.0)
    assert run.result.stats.bias_openings >= 1
    error = abs(math.degrees(run.result.estimates.state[-1, 3] - trip.true_gyro_bias_rad_s[2]))
    assert error < 0.02, f'final bias {error:.4f} deg/s off after a 0.4 deg/s step'
    assert summary['online_bias']['reopened'] == run.result.stats.bias_openings
    # Followed, but not silently: a gyro whose bias jumps is worth a warning.
    assert summary['health']['verdict'] == 'degraded'
    assert any(r.startswith('the gyro bias changed during the run')
               for r in summary['health']['reasons']), summary['health']['reasons']


def test_a_strong_drift_closes_its_block_early():
    # The innovations of a step the filter lags share one sign by two of their sigmas:
    # the block is a drift long before it is BLOCK_S old.
    watch = BiasWatch()
    openings = _feed(watch, bias_watch.BLOCK_S, bearing_mean_rad=-2.0 * math.sqrt(S_BB),
                     drift_rad_s=math.radians(0.5))
    assert openings, 'a strong drift was not seen within one block'
    stamp, variance = openings[0]
    assert bias_watch.EARLY_MIN_S <= stamp < bias_watch.BLOCK_S and variance > 0.0


def test_white_innovations_never_close_a_block_early():
    watch = BiasWatch()
    rng = np.random.default_rng(7)
    for k in range(int(600.0 * SCANS_PER_S)):
        stamp = k / SCANS_PER_S
        if watch.due(stamp):
            assert watch.close(stamp) is None
        for _ in range(POLES):
            watch.add(stamp, rng.normal(0.0, math.sqrt(S_BB)), S_BB)
        # Every block ran its full length.
        assert watch.block is None or watch.block[1] >= bias_watch.BLOCK_S
    assert watch.openings == 0


def test_a_bias_step_is_caught_before_its_block_ends():
    _, trip, run, _ = simulated_run(60.0, gyro_bias_step_rad_s=math.radians(0.5),
                                    gyro_bias_step_at_s=30.0)
    assert run.result.stats.bias_openings >= 1
    # The heading error the step leaves before the bias is opened: 0.76 deg here; caught
    # only at the end of a 2-s block it ran to 1.3 deg and more.
    estimates, truth = run.result.estimates, trip.ground_truth
    after = (truth.stamp_s >= 30.0) & (truth.stamp_s <= 40.0)
    yaw = np.interp(truth.stamp_s[after], estimates.stamp_s, np.unwrap(estimates.state[:, 2]))
    error = np.degrees(np.abs(np.angle(np.exp(1j * (yaw - truth.pose[after, 2])))))
    assert error.max() < 1.0, f'the heading ran {error.max():.2f} deg off after the step'


def test_a_clean_trip_never_opens_the_bias():
    _, _, run, summary = simulated_run(90.0)
    assert run.result.stats.bias_openings == 0
    assert summary['health']['verdict'] == 'ok', summary['health']['reasons']


def test_a_slow_drift_no_block_shows_alone_is_found_by_the_window():
    # 0.03 deg/s: each block's innovations lean the same way by too little for its own
    # test, but the window's ten implied errors share a sign beyond their scatter.
    error = math.radians(0.03)
    watch = BiasWatch()
    openings = _feed(watch, 60.0, bearing_mean_rad=-0.1 * math.sqrt(S_BB), drift_rad_s=error)
    assert openings, 'a slow drift of 0.03 deg/s was not seen'
    assert watch.last_error_rad_s == pytest.approx(error, rel=0.3)
    # Already known: a bias sigma that covers it opens nothing.
    known = BiasWatch()
    for k in range(600):
        stamp = k / SCANS_PER_S
        if known.due(stamp):
            assert known.close(stamp, bias_variance=error ** 2) is None
        known.add(stamp, -0.1 * math.sqrt(S_BB), S_BB)
        known.corrected(-error / SCANS_PER_S)
    assert known.openings == 0


def test_a_drift_too_small_for_one_block_is_found_by_a_run_of_them():
    # 0.05 deg/s: each block's innovations lean by a Z of about -2.5, below the single-block
    # limit (4.4); four blocks together are a Z of about -5, beyond the runs' limit (4.9),
    # long before the slow-drift window has its NOISE_BLOCKS blocks.
    error = math.radians(0.05)
    watch = BiasWatch()
    openings = _feed(watch, 60.0, bearing_mean_rad=-0.25 * math.sqrt(S_BB),
                     drift_rad_s=error)
    assert openings, 'a drift of 0.05 deg/s was not seen'
    assert openings[0][0] < bias_watch.NOISE_BLOCKS * bias_watch.BLOCK_S
    assert watch.last_error_rad_s == pytest.approx(error, rel=0.3)


def _wandering(watch, seconds, block_sigma, seed=0):
    """Innovations alike within each block, their common part of either sign block to block."""
    rng = np.random.default_rng(seed)
    offset = 0.0
    for k in range(int(seconds * SCANS_PER_S)):
        stamp = k / SCANS_PER_S
        if watch.due(stamp):
            watch.close(stamp)
            offset = rng.normal(0.0, block_sigma)
        elif k == 0:
            offset = rng.normal(0.0, block_sigma)
        for _ in range(POLES):
            watch.add(stamp, offset + rng.normal(0.0, math.sqrt(S_BB)), S_BB)
        watch.corrected(rng.normal(0.0, 1e-5))


def test_a_gyro_noisier_than_stated_scales_its_noise_and_a_consistent_one_does_not():
    noisy = BiasWatch()
    # A common part of 0.2 sigma per look, over 100 looks a block: block Z^2 about 5.
    _wandering(noisy, 120.0, 0.2 * math.sqrt(S_BB))
    assert noisy.noise_scale > 2.0
    # No drift: whatever block opened the bias, its corrections implied next to nothing.
    assert abs(noisy.last_error_rad_s) < math.radians(0.001)
    consistent = BiasWatch()
    _wandering(consistent, 600.0, 0.0)
    assert consistent.noise_scale == 1.0


def test_the_noise_factor_never_falls_below_what_a_stop_measured():
    # A stop's gyro spread measured the noise (events.EventDriver._judge_stop_noise): the
    # blocks may raise the factor further, never take it back below that floor.
    watch = BiasWatch()
    watch.set_noise_floor(4.5)
    assert watch.noise_scale == 4.5 and watch.noise_floor == 4.5
    watch.set_noise_floor(4.0)  # a longer stop's figure: the factor it set follows it
    assert watch.noise_scale == 4.0 and watch.noise_floor == 4.0
    raised = watch.copy()
    raised.noise_scale = 6.0  # as the blocks raise it: a lower floor leaves it
    raised.set_noise_floor(3.0)
    assert raised.noise_scale == 6.0 and raised.noise_floor == 3.0
    # Blocks whose innovations are all 0 (Z^2 = 0, under the low bound): without the
    # floor they take the factor back to 1 (the control below), with it to the floor.

    def quiet(w):
        for k in range(int(120.0 * SCANS_PER_S)):
            stamp = k / SCANS_PER_S
            if w.due(stamp):
                w.close(stamp)
            for _ in range(POLES):
                w.add(stamp, 0.0, S_BB)
            w.corrected(0.0)
    quiet(watch)
    assert watch.noise_scale == 4.0
    assert watch.copy().noise_floor == 4.0
    control = BiasWatch()
    control.noise_scale = 4.0
    quiet(control)
    assert control.noise_scale == 1.0
