"""Online odometry calibration: a speed-scale error is fitted and divided out; a first
LiDAR off its mount is found against the odometry, moved and named in the verdict; a LiDAR
mount moved online is named in the verdict with the first LiDAR."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from gyro_ekf.analysis.offline import run_trip
from gyro_ekf.analysis.summary import summarize
from gyro_ekf.core.odometry_online import OdometryFit, OdometryTracker
from gyro_ekf.core.simulator import SimulationConfig, simulate_trip

# The heading's variance given with each pose: 0.01 deg, a LiDAR-held heading's.
HEADING_VAR = math.radians(0.01) ** 2


def _summary(seed=3, **changes):
    return summarize(run_trip(simulate_trip(SimulationConfig(**changes),
                                            seed)))


def _turned_lidar_run(seed, yaw_error_deg):
    """One LiDAR yaw_error_deg off its stated yaw: the trip and its run."""
    trip = simulate_trip(SimulationConfig(lidar_yaw_error_rad=math.radians(yaw_error_deg)),
                         seed)
    return trip, run_trip(trip)


def _heading_error_deg(run, trip, after_s):
    """The run's heading minus the true heading at each estimate after after_s, deg."""
    estimates, truth = run.result.estimates, trip.ground_truth
    late = estimates.stamp_s > after_s
    heading = np.interp(estimates.stamp_s[late], truth.stamp_s, np.unwrap(truth.pose[:, 2]))
    return np.degrees(np.angle(np.exp(1j * (estimates.state[late, 2] - heading))))


@pytest.mark.parametrize('error', [0.03, -0.025])
def test_a_speed_scale_error_is_fitted_divided_out_and_named(error):
    summary = _summary(speed_scale_error=error)
    odometry = summary['online_odometry']
    assert odometry['applied'] >= 1
    assert odometry['scale'] == pytest.approx(1.0 + error, abs=0.002)
    assert odometry['first_lidar_offset_applied'] == 0
    # Divided out from the first fit on (after 20 m), the pose keeps within 2 cm, and
    # its covariance holds the error before (the scale not yet known is a position random
    # walk; 0.895 and 0.904 without it); the verdict says the wheel is off.
    assert summary['ground_truth']['position_rmse_m'] <= 0.02
    assert summary['ground_truth']['nees_share_in_band'] >= 0.9
    assert summary['health']['verdict'] == 'degraded'
    assert any('odometry reads' in r for r in summary['health']['reasons'])


def test_a_right_odometry_is_left_as_it_reads():
    summary = _summary()
    odometry = summary['online_odometry']
    assert odometry['applied'] == 0 and odometry['scale'] == 1.0
    assert odometry['first_lidar_offset_applied'] == 0
    assert odometry['estimate']['scale'] == pytest.approx(1.0, abs=0.002)
    assert summary['health']['verdict'] == 'ok'


@pytest.mark.parametrize('offset', [(0.005, -0.026), (-0.02, 0.025)])
def test_a_first_lidar_off_its_mount_is_found_moved_and_named(offset):
    # Two LiDARs: without the odometry the rear one's online mount would absorb the
    # difference (stress seed 0, mount_offset trip 5: RMSE 2.6 cm, verdict ok). Moving
    # from the start (no start check): found by the fit of the odometry path.
    summary = _summary(second_lidar=True, lidar_x_error_m=offset[0],
                       lidar_y_error_m=offset[1], static_s=0.0)
    odometry = summary['online_odometry']
    assert odometry['first_lidar_start_check'] is None
    assert odometry['first_lidar_offset_applied'] >= 1
    assert (odometry['first_lidar_offset_in_use_x_m'],
            odometry['first_lidar_offset_in_use_y_m']) == pytest.approx(offset, abs=0.005)
    # The rear LiDAR's mount, estimated again against the moved pose, is its stated one.
    rear = summary['online_mounts']['scan2']
    assert rear['used']['x_m'] == pytest.approx(rear['stated']['x_m'], abs=0.01)
    assert rear['used']['y_m'] == pytest.approx(rear['stated']['y_m'], abs=0.01)
    assert summary['health']['verdict'] == 'degraded'
    assert any('LiDAR scan sits off its stated mount' in r
               for r in summary['health']['reasons'])


@pytest.mark.parametrize('seed, yaw_error_deg', [(3, 0.5), (4, -0.8)])
def test_a_first_lidar_turned_off_the_odometry_direction_is_found_turned_and_named(
        seed, yaw_error_deg):
    # One LiDAR, its yaw off its stated mount: the pose's heading follows the LiDAR, the
    # odometry moves along the heading, so the odometry path turns away from the path the
    # map holds, by the same angle.
    trip, run = _turned_lidar_run(seed, yaw_error_deg)
    summary = summarize(run)
    odometry = summary['online_odometry']
    assert odometry['first_lidar_offset_applied'] >= 1
    assert odometry['first_lidar_yaw_in_use_deg'] == pytest.approx(yaw_error_deg, abs=0.05)
    assert summary['health']['verdict'] == 'degraded'
    assert any('LiDAR scan sits off its stated mount' in r and 'yaw' in r
               for r in summary['health']['reasons'])
    # Turned back, the heading is right for the rest of the trip.
    error = _heading_error_deg(run, trip, after_s=60.0)
    assert np.sqrt(np.mean(error ** 2)) <= 0.05


def test_the_start_check_moves_a_first_lidar_off_its_mount_before_the_trip_begins():
    # 8 s standing still at the trusted start pose: 2 s of scans place the LiDAR. (With a
    # second LiDAR that agrees there, it takes over instead: test_mount_online.py.)
    trip = simulate_trip(SimulationConfig(lidar_x_error_m=0.06), 3)
    run = run_trip(trip)
    check = run.result.odometry.report()['first_lidar_start_check']
    assert check['scans'] >= 20
    assert (check['x_m'], check['y_m']) == pytest.approx((0.06, 0.0), abs=0.01)
    summary = summarize(run)
    assert summary['online_odometry']['first_lidar_offset_in_use_x_m'] == pytest.approx(
        0.06, abs=0.005)
    # Moved at 2 s: the pose is right for the rest of the static start and the trip.
    estimates = run.result.estimates
    truth = trip.ground_truth
    late = estimates.stamp_s > 3.0
    error = np.hypot(*(estimates.state[late, i] - np.interp(
        estimates.stamp_s[late], truth.stamp_s, truth.pose[:, i]) for i in (0, 1)))
    assert np.sqrt(np.mean(error ** 2)) <= 0.01
    assert summary['ground_truth']['nees_share_in_band'] >= 0.9
    assert summary['health']['verdict'] == 'degraded'


@pytest.mark.parametrize('seed, yaw_error_deg', [(3, 1.5), (4, -2.0)])
def test_the_start_check_turns_a_first_lidar_far_off_its_yaw_before_the_trip_begins(
        seed, yaw_error_deg):
    # Far beyond the check's scatter (0.22 deg on 100 clean starts): turned at 2 s, not
    # after the 20 m the path fit needs; the path fit then refines what is left.
    trip, run = _turned_lidar_run(seed, yaw_error_deg)
    check = run.result.odometry.report()['first_lidar_start_check']
    assert check['yaw_deg'] == pytest.approx(yaw_error_deg, abs=0.2)
    summary = summarize(run)
    assert summary['online_odometry']['first_lidar_yaw_in_use_deg'] == pytest.approx(
        yaw_error_deg, abs=0.05)
    error = _heading_error_deg(run, trip, after_s=SimulationConfig().static_s)
    assert np.abs(error).max() <= 0.3
    assert summary['ground_truth']['position_rmse_m'] <= 0.02
    assert summary['health']['verdict'] == 'degraded'


def test_the_start_checks_f_limit_is_the_f_quantile_and_tends_to_the_gaussians():
    from scipy import stats
    from gyro_ekf.core.odometry_online import offset_f_limit
    for dof in (1.0, 3.0, 7.0, 17.0, 60.0):
        # Squared distance over 2 is F(2, dof).
        assert offset_f_limit(1e-3, dof) == pytest.approx(
            2.0 * stats.f.ppf(1.0 - 1e-3, 2, dof), rel=1e-6)
    assert offset_f_limit(1e-3, 1e6) == pytest.approx(-2.0 * math.log(1e-3), rel=1e-4)
    assert offset_f_limit(1e-3, 7.0) > offset_f_limit(1e-3, 17.0) > -2.0 * math.log(1e-3)


def _suspect_start_run(stress_class, index):
    """Run stress seed 40's trip whose start check is suspect (beyond 3 sigmas) but within
    the F test; check it ends within the bounds; return the odometry report and summary."""
    from gyro_ekf.analysis.stress import stress_trip
    run = run_trip(stress_trip(stress_class, 40, index))
    report = run.result.odometry.report()
    check = report['first_lidar_start_check']
    assert math.hypot(check['x_m'], check['y_m']) > 3.0 * check['sigma_m']
    assert check['sigmas'] < check['sigmas_limit']
    summary = summarize(run)
    assert summary['ground_truth']['position_rmse_m'] <= 0.02
    assert summary['ground_truth']['nees_share_in_band'] >= 0.9
    return report, summary


def test_a_clean_start_a_little_beyond_3_sigmas_leaves_the_mount_alone():
    # Stress seed 40, scene 24, exact mounts: the stop's fit reads the LiDAR 2.1 cm off at
    # 3.07 of its sigmas, on 5 poles a scan. Moved there by 3 sigmas alone, the mount held
    # the pose 1-2 cm off for 40 s (NEES share 0.63, a false degraded verdict in every
    # class); the F test on 2 P - 3 = 7 dof asks for 6.6 sigmas.
    report, summary = _suspect_start_run('clean', 24)
    assert report['first_lidar_offset_applied'] == 0
    assert summary['health']['verdict'] == 'ok'


def test_a_suspect_start_still_hands_the_body_frame_to_a_lidar_that_agrees():
    # Stress seed 40, mount_offset 0: the first LiDAR 2.0 cm off, beyond 3 sigmas of the
    # stop's fit but within the F test. Alone it would stay; the rear LiDAR keeps its
    # stated mount at the start pose, which corroborates it, and takes over.
    _, summary = _suspect_start_run('mount_offset', 0)
    assert any('scan2 defines the body frame' in r for r in summary['health']['reasons'])


def test_a_lidar_dropout_leaves_an_exact_mount_alone():
    # Stress seed 43, lidar_dropout 7 (2.4 s without scans): a fit whose window spanned the
    # dropout read the exact LiDAR's yaw 0.133 deg off at 12 sigmas and turned its mount;
    # the heading held 0.13 deg off for 35 s (NEES share 0.67, a false degraded verdict).
    from gyro_ekf.analysis.stress import stress_trip
    run = run_trip(stress_trip('lidar_dropout', 43, 7))
    assert run.result.odometry.report()['first_lidar_offset_applied'] == 0
    summary = summarize(run)
    assert summary['ground_truth']['nees_share_in_band'] >= 0.9
    assert summary['health']['verdict'] == 'ok'


def test_after_a_turn_a_path_fit_refines_the_yaw_below_the_first_limit():
    tracker = OdometryTracker()
    tracker.yaw_rad = 0.0
    settings = tracker.settings
    assert settings.yaw_refinement_rad < settings.yaw_limit_rad
    # The same fit, 0.05 deg at a sigma of 0.01 deg with the heading's 0.015 deg: within 3
    # sigmas of both, not enough to turn a LiDAR at its stated yaw; beyond 3 of the fit's
    # own, enough to refine one already turned.
    tracker.fit = OdometryFit(stamp_s=60.0, scale=1.0, scale_sigma=0.0005,
                              offset_m=(0.0, 0.0), offset_sigma_m=(0.001, 0.001),
                              yaw_rad=math.radians(0.05), yaw_sigma_rad=math.radians(0.01),
                              heading_sigma_rad=math.radians(0.015), rms_m=0.002,
                              samples=300, distance_m=25.0)
    assert not tracker.yaw_found()
    tracker.yaw_rad = math.radians(-1.5)
    assert tracker.yaw_found()


def test_a_yaw_turned_alone_leaves_the_offset_to_its_first_limit():
    # An offset read under the 1 cm limit at 5 sigmas: once an offset was moved, a
    # refinement; after a turn of the yaw alone, no offset was proven yet, and the path
    # fits' offsets scatter more than their sigmas say.
    tracker = OdometryTracker()
    tracker.fit = OdometryFit(stamp_s=70.0, scale=1.0, scale_sigma=0.0005,
                              offset_m=(-0.0052, 0.0004), offset_sigma_m=(0.001, 0.001),
                              yaw_rad=0.0, yaw_sigma_rad=math.radians(0.005),
                              heading_sigma_rad=math.radians(0.02), rms_m=0.002,
                              samples=300, distance_m=23.0)
    tracker.yaw_rad, tracker.offset_applied = math.radians(-0.216), 1
    assert not tracker.offset_found()
    tracker.offset_m = (0.012, 0.0)
    assert tracker.offset_found()


def test_a_lone_lidar_turned_on_a_moving_start_keeps_its_exact_offset():
    # Stress seed 52, found by a helper: a lone LiDAR 0.2 deg off, no static start. Its
    # run turned the yaw at 35 s, then moved the exact mount 5.2 mm in x at 70 s (a fit
    # read -5.2 +- 1.0 mm; the next +6.1 +- 1.4), and calibrate-mounts wrote that offset:
    # its file's run held the pose 5 mm off, NEES share 0.77, verdict ok.
    trip = simulate_trip(SimulationConfig(duration_s=90.0, static_s=0.0,
                                          lidar_yaw_error_rad=math.radians(-0.2)), 52)
    odometry = summarize(run_trip(trip))['online_odometry']
    assert odometry['first_lidar_yaw_in_use_deg'] == pytest.approx(-0.2, abs=0.03)
    assert (odometry['first_lidar_offset_in_use_x_m'],
            odometry['first_lidar_offset_in_use_y_m']) == (0.0, 0.0)


def test_a_first_turn_is_judged_with_the_headings_sigma():
    # Stress seed 20, mount_yaw 36: a first LiDAR 0.084 deg off read at -0.081 deg, sigma
    # 0.005 deg, with the heading's 0.019 deg: 4.3 sigmas, beyond the 0.05 deg limit.
    tracker = OdometryTracker()
    fit = OdometryFit(stamp_s=60.0, scale=1.0, scale_sigma=0.0005, offset_m=(0.0, 0.0),
                      offset_sigma_m=(0.001, 0.001), yaw_rad=math.radians(-0.081),
                      yaw_sigma_rad=math.radians(0.005), heading_sigma_rad=math.radians(0.019),
                      rms_m=0.002, samples=300, distance_m=25.0)
    tracker.fit = fit
    assert tracker.yaw_found()
    # A heading known only to 0.03 deg: 2.6 sigmas, the same reading may be its error.
    tracker.fit = dataclasses.replace(fit, heading_sigma_rad=math.radians(0.03))
    assert not tracker.yaw_found()


def test_an_exact_second_lidar_vouches_against_a_first_turn_by_chance():
    # Stress seed 14, second_lidar 5: both mounts exact. The path fit read the first
    # LiDAR's yaw -0.076 deg off at 43 s, 3.3 of its sigmas with the heading's, and turned
    # it: the heading was held that far off for 30 s (NEES share 0.798). The second LiDAR,
    # its stated mount confirmed and read right, agrees with the first on the heading; for
    # the odometry to be right both would be off alike: no turn.
    from gyro_ekf.analysis.stress import stress_trip
    summary = summarize(run_trip(stress_trip('second_lidar', 14, 5)))
    odometry = summary['online_odometry']
    assert odometry['first_lidar_offset_applied'] == 0
    vouched = odometry['first_lidar_turn_vouched']
    assert vouched['by'] == 'scan2' and abs(vouched['yaw_deg']) > 0.05
    assert abs(vouched['yaw_deg']) > 3.0 * vouched['yaw_sigma_deg']
    assert summary['ground_truth']['nees_share_in_band'] >= 0.9


def test_a_turn_vouched_against_that_the_last_fit_still_reads_is_said():
    # Two LiDARs on one bracket turned on the body agree with each other and not with the
    # odometry: not turned, and the verdict says where the heading may be.
    from gyro_ekf.core.odometry_online import verdict_reasons
    report = {'scale': 1.0, 'scale_sigma': 0.001, 'first_lidar_offset_applied': 0,
              'first_lidar_offset_found': False, 'first_lidar_yaw_found': True,
              'estimate': {'first_lidar_offset_x_m': 0.0, 'first_lidar_offset_y_m': 0.0,
                           'first_lidar_yaw_deg': 0.3},
              'first_lidar_turn_vouched': {'stamp_s': 40.0, 'yaw_deg': 0.3,
                                           'yaw_sigma_deg': 0.02, 'by': 'scan2'}}
    (said,) = verdict_reasons(report, ['scan'])
    assert said.startswith('LiDAR scan sits off its stated mount against the odometry by')
    assert said.endswith('(not turned: LiDAR scan2, its stated mount confirmed, agrees with '
                         'it, so both would be off alike, as on one bracket turned on the '
                         'body)')
    assert verdict_reasons({**report, 'first_lidar_yaw_found': False}, ['scan']) == []


def test_an_offset_read_beyond_5_mm_under_the_move_limit_is_said():
    # A helper's probe: a lone LiDAR 9 mm off, moving from the start. The path fit read it
    # at 8.8 +- 0.4 mm, under the 1 cm a mount is moved by: the pose followed the LiDAR
    # (NEES share 0.18) and the verdict said ok.
    trip = simulate_trip(SimulationConfig(duration_s=40.0, static_s=0.0,
                                          lidar_x_error_m=0.009), 414)
    summary = summarize(run_trip(trip))
    odometry = summary['online_odometry']
    assert odometry['first_lidar_offset_applied'] == 0
    read = odometry['first_lidar_offset_read']
    assert (read['x_m'], read['y_m']) == pytest.approx((0.009, 0.0), abs=0.002)
    assert summary['health']['verdict'] == 'degraded'
    assert any(r.startswith('LiDAR scan reads x +8.') and 'beyond 5 mm but under the 1 cm'
               in r for r in summary['health']['reasons'])
    # Exact mounts read 3.4 mm at most (final fits of 573 stress trips); not said at 4 mm,
    # nor beyond 5 mm within 3 sigmas, nor without a fit of 20 m driven.
    from gyro_ekf.core.odometry_online import verdict_reasons
    report = {**odometry, 'first_lidar_offset_read': {**read, 'x_m': 0.004, 'y_m': 0.0}}
    assert verdict_reasons(report, ['scan']) == []
    report = {**odometry, 'first_lidar_offset_read': {**read, 'sigma_m': 0.003}}
    assert verdict_reasons(report, ['scan']) == []
    assert verdict_reasons({**odometry, 'first_lidar_offset_read': None}, ['scan']) == []


def test_the_start_check_needs_a_trusted_start_and_keeps_an_exact_mount():
    from gyro_ekf.core.config import EkfConfig
    from gyro_ekf.core.events import EventDriver
    trusted = EventDriver(EkfConfig(), pose=np.zeros(3))
    assert trusted.odometry._start_pose == (0.0, 0.0, 0.0)
    loose = EventDriver(EkfConfig(initial_position_sigma_m=0.1), pose=np.zeros(3))
    assert loose.odometry._start_pose is None
    # Exact mounts: the check's offset stays within its 3 sigmas and nothing moves.
    run = run_trip(simulate_trip(SimulationConfig(second_lidar=True), 3))
    report = run.result.odometry.report()
    check = report['first_lidar_start_check']
    assert max(abs(check['x_m']), abs(check['y_m'])) <= 3.0 * check['sigma_m']
    assert report['first_lidar_offset_applied'] == 0


def test_a_mount_moved_online_is_named_with_the_first_lidar():
    from gyro_ekf.core.health import RunFigures, verdict
    stated = {'x_m': 0.46, 'y_m': 0.0, 'yaw_deg': 180.0}
    report = {'name': 'scan2', 'stated': stated,
              'used': {'x_m': 0.455, 'y_m': 0.025, 'yaw_deg': 180.02}}
    sensors = [{'name': 'scan', 'exclusions': 0, 'disagreed_s': 0.0, 'disagreement': None},
               {'name': 'scan2', 'exclusions': 0, 'disagreed_s': 0.0, 'disagreement': None}]
    base = dict(detections=100, matched=99, updates=99, nis_mean=2.0, longest_gap_s=0.1,
                start_gap_s=0.1, sensors=sensors)
    found = verdict(RunFigures(**base, mounts=[report]))
    assert found['verdict'] == 'degraded'
    assert 'scan2' in found['reasons'][0] and 'or scan ' in found['reasons'][0]
    same = verdict(RunFigures(**base, mounts=[{**report, 'used': stated}]))
    assert same['verdict'] == 'ok'


def test_save_and_restore_put_the_estimator_back_exactly():
    rng = np.random.default_rng(1)
    tracker = OdometryTracker()
    yaw, x, y = 0.0, 0.0, 0.0
    rows = []
    for k in range(1500):
        yaw += 0.02 * math.sin(k / 50.0)
        x += 0.1 * math.cos(yaw)
        y += 0.1 * math.sin(yaw)
        rows.append((k * 0.1, yaw, [x + rng.normal(0, 0.003), y + rng.normal(0, 0.003), yaw]))

    def feed(part):
        out = []
        for stamp, heading, pose in part:
            tracker.advance(0.1 * 1.03, heading)  # reads 3 % fast
            out.append(tracker.observe(stamp, pose, HEADING_VAR))
        return out

    feed(rows[:1200])
    saved = tracker.save()
    first = (feed(rows[1200:]), tracker.report())
    tracker.restore(saved)
    assert (feed(rows[1200:]), tracker.report()) == first
    assert tracker.scale == pytest.approx(1.03, abs=0.001)


def test_the_estimator_is_off_at_zero():
    import dataclasses

    from gyro_ekf.core.config import EkfConfig
    from gyro_ekf.io.params_file import PipelineParams
    off = dataclasses.replace(PipelineParams(), ekf=dataclasses.replace(
        EkfConfig(), odometry_online_min_change=0.0))
    trip = simulate_trip(SimulationConfig(speed_scale_error=0.03, lidar_x_error_m=0.05), 3)
    report = run_trip(trip, off).result.odometry.report()
    assert report['applied'] == 0 and report['scale'] == 1.0 and report['fits'] == 0
    assert report['first_lidar_offset_applied'] == 0
    assert report['first_lidar_start_check'] is None


def _driven_rows(seconds, seed=1):
    """(stamp, heading, LiDAR-held pose) every 0.1 s of a 1 m/s drive with gentle turns."""
    rng = np.random.default_rng(seed)
    yaw, x, y = 0.0, 0.0, 0.0
    rows = []
    for k in range(int(seconds * 10)):
        yaw += 0.02 * math.sin(k / 50.0)
        x += 0.1 * math.cos(yaw)
        y += 0.1 * math.sin(yaw)
        rows.append((k * 0.1, yaw, [x + rng.normal(0, 0.003), y + rng.normal(0, 0.003), yaw]))
    return rows


def test_the_scale_not_yet_known_is_a_position_random_walk():
    # (sigma_k v)^2 tau: the prior before any fit, then what the fits say of the scale in
    # use (their disagreement while not applied, their sigma once applied); none at rest.
    trackers = {}
    for error in (0.006, 0.03):
        tracker = trackers[error] = OdometryTracker()
        settings = tracker.settings
        assert tracker.walk_density(0.0) == 0.0
        assert tracker.walk_density(0.5) == pytest.approx(
            (0.5 * settings.prior_scale_sigma) ** 2 * settings.scale_time_s)
        for stamp, heading, pose in _driven_rows(60.0):
            tracker.advance(0.1 * (1.0 + error), heading)
            tracker.observe(stamp, pose, HEADING_VAR)
        assert tracker.fits > 5
    # 0.6 % off, below the 1 % that is applied: the walk carries the disagreement.
    small = trackers[0.006]
    assert small.applied == 0
    assert small.scale_uncertainty() == pytest.approx(0.006, abs=0.001)
    # 3 % off, applied: what is left is the fit's sigma, a walk a thousand times smaller.
    large = trackers[0.03]
    assert large.applied >= 1
    assert large.scale_uncertainty() == pytest.approx(
        math.hypot(large.fit.scale - large.scale, large.fit.scale_sigma) / large.scale)
    assert large.scale_uncertainty() < 0.001
    assert large.walk_density(1.0) < 1e-6
    assert large.report()['scale_uncertainty'] == large.scale_uncertainty()


def test_a_fit_across_a_lidar_gap_leaves_the_walk_on_the_fit_before_and_moves_nothing():
    # 5 s driven with no LiDAR-held pose, the path laid along a heading that drifted 0.05
    # rad: fits whose window spans the gap say nothing of the scale, nor of the mount (one
    # turned an exact LiDAR's mount: stress seed 43, lidar_dropout 7).
    tracker = OdometryTracker()
    rows = _driven_rows(120.0)
    before, spanning = None, 0
    for stamp, heading, pose in rows:
        gap = 40.0 <= stamp < 45.0
        tracker.advance(0.1, heading + (0.05 if gap else 0.0))
        if gap:
            continue
        if stamp < 40.0:
            before = tracker.scale_uncertainty()
        fit = tracker.fit
        assert tracker.observe(stamp, pose, HEADING_VAR) is None
        if 45.0 <= stamp < 40.0 + tracker.settings.window_s:
            assert tracker.scale_uncertainty() == before
            if tracker.fit is not fit:
                assert tracker.fit.spans_gap
                assert not (tracker.offset_found() or tracker.yaw_found())
                spanning += 1
    assert before < 0.005
    assert spanning >= 5
    assert tracker.offset_applied == 0
    # Once the window has left the gap, the fits count again.
    assert not tracker.fit.spans_gap
    assert tracker.scale_uncertainty() != before
    assert tracker.scale_uncertainty() < 0.005
