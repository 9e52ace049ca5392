"""Event driver: ordering, hold semantics, time going backwards, whole trips (trip_run)."""

import dataclasses
import math

import numpy as np
import pytest

from gyro_ekf.core.config import EkfConfig
from gyro_ekf.core.errors import TimeWentBackwardsError
from gyro_ekf.core.event_records import EventKind
from gyro_ekf.core.events import EventDriver
from gyro_ekf.core import trip_run
from gyro_ekf.core.simulator import SimulationConfig, simulate_trip
from gyro_ekf.core.trip_run import drive_trip, iter_trip_events
from gyro_ekf.core.types import ImuSeries, SpeedSeries, Trip


def _config_for(trip):
    """Defaults, except the noise figures the trip states about its gyro and speed."""
    return dataclasses.replace(EkfConfig(), gyro_noise_rad_s=trip.noise.gyro_rad_s,
                               speed_noise_m_s=trip.noise.speed_m_s)


@pytest.fixture(scope='module')
def simulated_runs():
    runs = []
    for seed in (11, 12, 13):
        trip = simulate_trip(SimulationConfig(duration_s=90.0), seed=seed)
        runs.append((trip, drive_trip(trip, EventDriver(_config_for(trip), trip.landmarks,
                                                        trip.initial_pose))))
    return runs


def test_bias_converges_to_the_injected_bias_on_simulated_trips(simulated_runs):
    for trip, run in simulated_runs:
        final = run.estimates.state[-1]
        sigma = math.sqrt(run.estimates.covariance[-1, 3, 3])
        error_deg_s = math.degrees(final[3] - trip.true_gyro_bias_rad_s[2])
        print(f'{trip.name}: bias error {error_deg_s:+.4f} deg/s, sigma '
              f'{math.degrees(sigma):.4f} deg/s')
        assert abs(error_deg_s) < 0.02
        assert abs(final[3] - trip.true_gyro_bias_rad_s[2]) < 4 * sigma


def test_position_follows_ground_truth(simulated_runs):
    for trip, run in simulated_runs:
        truth = trip.ground_truth
        est = run.estimates
        x = np.interp(truth.stamp_s, est.stamp_s, est.state[:, 0])
        y = np.interp(truth.stamp_s, est.stamp_s, est.state[:, 1])
        rmse = math.sqrt(np.mean((x - truth.pose[:, 0]) ** 2 + (y - truth.pose[:, 1]) ** 2))
        assert rmse < 0.02
        stats = run.stats.snapshot()
        assert stats['imu'] == len(trip.imu.stamp_s) == len(est.stamp_s)
        assert stats['outcomes']['matched'] > 0.95 * stats['detections']


def test_one_row_per_imu_sample_in_time_order(simulated_runs):
    trip, run = simulated_runs[0]
    np.testing.assert_array_equal(run.estimates.stamp_s, trip.imu.stamp_s)
    assert np.all(np.diff(run.estimates.stamp_s) >= 0)


def test_rows_are_the_same_whatever_the_blocks_they_are_copied_in(simulated_runs, monkeypatch):
    # drive_trip keeps the filter's rows as plain floats and copies them a block at a time.
    trip, run = simulated_runs[0]
    monkeypatch.setattr(trip_run, 'ROW_BLOCK', 7)  # no divisor of the row count
    assert len(trip.imu.stamp_s) % 7
    blocked = drive_trip(trip, EventDriver(_config_for(trip), trip.landmarks,
                                           trip.initial_pose))
    for name in ('stamp_s', 'state', 'covariance'):
        np.testing.assert_array_equal(getattr(blocked.estimates, name),
                                      getattr(run.estimates, name))


def test_rows_handed_on_as_they_become_final_into_given_arrays(simulated_runs):
    # on_rows sees every row once, in order, with the updates since the last call, and the
    # rows are those of a plain run; `into` holds them (no copy of its own).
    trip, run = simulated_runs[0]
    into = trip_run.estimate_arrays(len(trip.imu.stamp_s),
                                    bytearray(8 * 22 * len(trip.imu.stamp_s)))
    seen = []

    def on_rows(start, estimates, updates):
        assert np.shares_memory(estimates.state, into.state)
        seen.append((start, len(estimates.stamp_s), updates.stamp_s.copy(),
                     estimates.state.copy()))
    streamed = drive_trip(trip, EventDriver(_config_for(trip), trip.landmarks,
                                            trip.initial_pose), on_rows=on_rows, into=into)
    assert streamed.estimates.state is into.state
    assert [start for start, *_ in seen] == list(np.cumsum([0] + [k for _, k, *_ in seen])[:-1])
    assert sum(k for _, k, *_ in seen) == len(trip.imu.stamp_s)
    np.testing.assert_array_equal(np.concatenate([s for *_, s in seen]), run.estimates.state)
    np.testing.assert_array_equal(np.concatenate([u for _, _, u, _ in seen]),
                                  run.updates.stamp_s)
    # Before the run's end, the updates handed on with rows are stamped at or before the
    # last of them (and all those are in).
    for start, k, updates, _ in seen[:-1]:
        if k:
            assert np.all(updates <= trip.imu.stamp_s[start + k - 1])
    for name in ('stamp_s', 'covariance', 'wander_rad_s'):
        np.testing.assert_array_equal(getattr(into, name), getattr(run.estimates, name))
    with pytest.raises(ValueError, match='3 rows for'):
        drive_trip(trip, EventDriver(_config_for(trip), trip.landmarks, trip.initial_pose),
                   into=trip_run.estimate_arrays(3))


def _tiny_trip():
    imu_t = np.array([0.0, 0.01, 0.02, 0.03])
    speed_t = np.array([0.0, 0.02])
    return Trip('tiny', ImuSeries(imu_t, np.zeros((4, 3))), SpeedSeries(speed_t, np.ones(2)))


def test_equal_stamps_order_speed_then_observation_then_imu():
    events = list(iter_trip_events(_tiny_trip()))
    assert [(t, k) for t, k, _, _ in events[:3]] == [
        (0.0, EventKind.SPEED), (0.0, EventKind.IMU), (0.01, EventKind.IMU)]
    assert events[3][:2] == (0.02, EventKind.SPEED) and events[4][:2] == (0.02, EventKind.IMU)


def test_inputs_are_held_between_samples():
    driver = EventDriver(EkfConfig(), pose=[0.0, 0.0, 0.0], bias_rad_s=0.0)
    driver.on_speed(0.0, 2.0)
    driver.on_imu(0.0, 0.0)
    estimate = driver.on_imu(0.5, 1.0)  # 0.5 s at the held 2 m/s and 0 rad/s
    assert estimate.state[0] == pytest.approx(1.0)
    assert estimate.state[2] == pytest.approx(0.0)
    estimate = driver.on_imu(0.75, 1.0)  # now the held rate is 1 rad/s
    assert estimate.state[2] == pytest.approx(0.25)


def test_long_gaps_are_split_into_bounded_prediction_steps():
    config = EkfConfig(max_prediction_step_s=0.1)
    one = EventDriver(config, pose=[0, 0, 0])
    many = EventDriver(config, pose=[0, 0, 0])
    for driver in (one, many):
        driver.on_speed(0.0, 1.0)
        driver.on_imu(0.0, 0.3)
    one.on_imu(1.0, 0.3)
    for k in range(1, 11):
        many.on_imu(k / 10, 0.3)
    np.testing.assert_allclose(one.ekf.x, many.ekf.x, atol=1e-12)
    np.testing.assert_allclose(one.ekf.P, many.ekf.P, atol=1e-15)


def test_time_going_backwards_raises_and_reset_recovers():
    driver = EventDriver(EkfConfig(), pose=[1.0, 2.0, 0.5])
    driver.on_imu(10.0, 0.1)
    with pytest.raises(TimeWentBackwardsError, match='went back 9.0000 s'):
        driver.on_imu(1.0, 0.1)
    driver.reset(pose=[1.0, 2.0, 0.5])
    assert driver.on_imu(1.0, 0.1).stamp_s == 1.0
    assert driver.stats.imu == 1


def _recovery_run(scan_period_s: float) -> tuple[EventDriver, list[float]]:
    """A filter 0.4 m off the truth with a tiny covariance, its three poles seen every
    scan_period_s for 4 s: return it and the stamps of the scans it matched."""
    from gyro_ekf.core.models import observe
    from gyro_ekf.core.types import LandmarkMap, LidarMount
    landmarks = LandmarkMap(np.array([[4.0, 1.0], [4.0, -2.0], [-3.0, 3.0]]))
    config = EkfConfig(recovery_after_s=1.0)
    driver = EventDriver(config, landmarks, pose=[0.4, 0.0, 0.0], bias_rad_s=0.0)
    truth = np.array([0.0, 0.0, 0.0, 0.0])
    mount = LidarMount()
    matched_at = []
    for k in range(int(round(4.0 / scan_period_s))):
        stamp = scan_period_s * k
        driver.on_imu(stamp, 0.0)
        z = observe(truth, landmarks.xy_m, mount)
        points = np.column_stack([z[:, 0] * np.cos(z[:, 1]), z[:, 0] * np.sin(z[:, 1])])
        report = driver.on_detections(stamp, points, mount)
        if report.nis.size:
            matched_at.append(stamp)
    return driver, matched_at


def test_driver_recovers_landmarks_after_a_gap_by_map_distance():
    # Scans every 0.5 s: six detections beside their poles in a second, too few to call
    # the filter starved; after a second without an update, the gap recovery.
    driver, matched_at = _recovery_run(0.5)
    assert matched_at and matched_at[0] > 1.0  # the gate refused them until the recovery
    assert driver.stats.recoveries > 0
    assert driver.stats.gate_starved == 0
    assert np.hypot(*driver.ekf.x[:2]) < 0.05  # pulled back onto the truth


def test_driver_starved_by_its_gate_recovers_before_a_gap():
    # Scans every 0.1 s: by the third, nine detections lay beside their poles and none
    # was matched (core/gate_starved.py), so the recovery does not wait out the second.
    driver, matched_at = _recovery_run(0.1)
    assert matched_at and matched_at[0] < 0.5
    assert driver.stats.gate_starved > 0
    assert np.hypot(*driver.ekf.x[:2]) < 0.05


def test_a_report_places_the_detections_at_the_prior_pose(simulated_runs):
    from gyro_ekf.core.models import sensor_to_map
    trip, _ = simulated_runs[0]
    driver = EventDriver(_config_for(trip), trip.landmarks, trip.initial_pose)
    scans = trip.scans[0]
    angles = scans.angles_rad
    from gyro_ekf.core.detection import detect_poles
    updated = 0
    for index in range(40):
        stamp = float(scans.stamp_s[index])
        found = detect_poles(scans.ranges_m[index], angles,
                             None if scans.intensities is None else scans.intensities[index])
        driver.on_imu(stamp, 0.0)
        before = driver.ekf.x
        report = driver.on_detections(stamp, found.points_sensor_m, scans.mount)
        np.testing.assert_array_equal(report.prior_state, before)
        np.testing.assert_allclose(report.points_map_m,
                                   sensor_to_map(before, found.points_sensor_m, scans.mount))
        updated += report.nis.size
    assert updated > 0


def test_a_gap_far_beyond_the_prediction_step_costs_bounded_steps():
    from gyro_ekf.core.events import MAX_PREDICTION_STEPS

    class CountingEkf:
        def __init__(self, ekf):
            self.ekf, self.calls = ekf, 0

        def __getattr__(self, name):
            return getattr(self.ekf, name)

        def predict(self, *args):
            self.calls += 1
            return self.ekf.predict(*args)

    driver = EventDriver(EkfConfig(max_prediction_step_s=0.1), pose=[0, 0, 0])
    driver.ekf = counting = CountingEkf(driver.ekf)
    driver.on_speed(0.0, 1.0)
    driver.on_imu(0.0, 0.0)
    estimate = driver.on_imu(4e8, 0.0)  # predicted 0.1 s at a time: 4e9 steps
    assert counting.calls <= MAX_PREDICTION_STEPS + 1
    assert np.isfinite(estimate.state).all() and np.isfinite(estimate.covariance).all()
    assert estimate.state[0] == pytest.approx(4e8)
    assert driver.stats.long_gaps == 1
    # A gap within the bound is still split into max_prediction_step_s steps.
    counting.calls = 0
    driver.on_imu(4e8 + 1.0, 0.0)
    assert 10 <= counting.calls <= 11 and driver.stats.long_gaps == 1


def test_a_stamp_that_is_not_finite_is_refused():
    from gyro_ekf.core.errors import CoreError
    driver = EventDriver(EkfConfig(), pose=[0, 0, 0])
    driver.on_imu(1.0, 0.0)
    with pytest.raises(CoreError, match='imu stamp nan is not finite'):
        driver.on_imu(math.nan, 0.0)
    assert driver.stamp_s == 1.0


def _frozen_scans(driver, truth, landmarks, mount, start_s, count, bearing_error_rad):
    from gyro_ekf.core.models import observe
    z = observe(truth, landmarks.xy_m, mount)
    z[:, 1] += bearing_error_rad  # the same beams every scan: the same error
    points = np.column_stack([z[:, 0] * np.cos(z[:, 1]), z[:, 0] * np.sin(z[:, 1])])
    for k in range(count):
        stamp = start_s + 0.1 * k
        driver.on_imu(stamp, 0.0)
        driver.on_detections(stamp, points, mount)
    return start_s + 0.1 * count


def test_repeated_observations_at_rest_do_not_make_the_filter_overconfident():
    from gyro_ekf.core.types import LandmarkMap, LidarMount
    landmarks = LandmarkMap(np.array([[4.0, 1.0], [5.0, -2.0], [3.0, 3.0]]))
    truth = np.array([0.0, 0.0, 0.0, 0.0])
    mount = LidarMount()
    error = math.radians(0.2)   # twice the default bearing sigma
    yaw_z = {}
    for rest_speed in (-1.0, 0.001):   # never at rest / the default
        # A quiet gyro, so that the yaw sigma comes from the landmark updates.
        config = EkfConfig(rest_speed_m_s=rest_speed, landmark_sigma_m=0.0,
                           gyro_noise_rad_s=1e-4, initial_bias_sigma_rad_s=1e-4,
                           initial_position_sigma_m=0.01, initial_yaw_sigma_rad=0.01)
        driver = EventDriver(config, landmarks, pose=truth[:3], bias_rad_s=0.0)
        driver.on_speed(0.0, 0.0)
        _frozen_scans(driver, truth, landmarks, mount, 0.0, 100, error)
        yaw_z[rest_speed] = abs(driver.ekf.x[2]) / math.sqrt(driver.ekf.P[2, 2])
    # 100 scans taken as independent shrink the yaw sigma far below the one error they all
    # share; weighted, the error stays about as many sigmas off as one scan's would be.
    assert yaw_z[-1.0] > 5.0
    assert yaw_z[0.001] < 3.0


def test_moving_ends_the_down_weighting_of_a_stop():
    from gyro_ekf.core.types import LandmarkMap, LidarMount
    landmarks = LandmarkMap(np.array([[4.0, 1.0], [5.0, -2.0]]))
    truth = np.array([0.0, 0.0, 0.0, 0.0])
    mount = LidarMount()

    def yaw_variance_drop(driver, start_s):
        before = driver.ekf.P[2, 2]
        _frozen_scans(driver, truth, landmarks, mount, start_s, 1, 0.0)
        return driver.ekf.P[2, 2] / before

    config = EkfConfig(initial_yaw_sigma_rad=0.01)
    driver = EventDriver(config, landmarks, pose=truth[:3], bias_rad_s=0.0)
    driver.on_speed(0.0, 0.0)
    end = _frozen_scans(driver, truth, landmarks, mount, 0.0, 30, 0.0)
    at_rest = yaw_variance_drop(driver, end)
    driver.on_speed(end + 0.1, 1e-3 + 1e-6)       # moves (above rest_speed_m_s) ...
    driver.on_speed(end + 0.1001, 0.0)           # ... and stops again
    after_moving = yaw_variance_drop(driver, end + 0.2)
    fresh = EventDriver(config, landmarks, pose=truth[:3], bias_rad_s=0.0)
    fresh.on_speed(0.0, 0.0)
    first = yaw_variance_drop(fresh, 0.0)
    assert at_rest > 0.95          # the 31st look at the same poles adds little
    assert after_moving < 0.5      # a new stop counts from one again
    assert first < 0.5
    # Without odometry the platform is not known to stand still: no down-weighting, so
    # the same 30 scans shrink P further than at a known stop (zero-rate updates off: they
    # teach the bias at the stop, and so keep the heading's variance from growing).
    still = dataclasses.replace(config, zero_rate_max_spread_rad_s=0.0)
    stopped = EventDriver(still, landmarks, pose=truth[:3], bias_rad_s=0.0)
    stopped.on_speed(0.0, 0.0)
    blind = EventDriver(still, landmarks, pose=truth[:3], bias_rad_s=0.0)
    for driver in (stopped, blind):
        _frozen_scans(driver, truth, landmarks, mount, 0.0, 30, 0.0)
    assert np.trace(blind.ekf.P[:3, :3]) < 0.5 * np.trace(stopped.ekf.P[:3, :3])


def test_turning_on_the_spot_is_not_standing_still():
    from gyro_ekf.core.types import LandmarkMap, LidarMount
    landmarks = LandmarkMap(np.array([[4.0, 1.0], [5.0, -2.0]]))
    truth = np.array([0.0, 0.0, 0.0, 0.0])
    mount = LidarMount()
    config = EkfConfig(initial_yaw_sigma_rad=0.01)
    drops = []
    for turn_rate in (0.0, math.radians(5.0)):
        driver = EventDriver(config, landmarks, pose=truth[:3], bias_rad_s=0.0)
        driver.on_speed(0.0, 0.0)
        end = _frozen_scans(driver, truth, landmarks, mount, 0.0, 30, 0.0)
        driver.on_imu(end, turn_rate)     # speed 0, but turning (or not) ...
        driver.on_imu(end + 0.001, 0.0)   # ... then still again
        before = driver.ekf.P[2, 2]
        _frozen_scans(driver, truth, landmarks, mount, end + 0.002, 1, 0.0)
        drops.append(driver.ekf.P[2, 2] / before)
    # Still, the 31st look at the same poles counts 1/31; after the turn it counts fully.
    assert drops[1] < 0.5 * drops[0]


def test_a_restored_driver_repeats_the_down_weighting_of_a_stop():
    # Late-scan replay restores the driver: the counts of the stop must come back too.
    from gyro_ekf.core.types import LandmarkMap, LidarMount
    landmarks = LandmarkMap(np.array([[4.0, 1.0], [5.0, -2.0]]))
    truth = np.array([0.0, 0.0, 0.0, 0.0])
    mount = LidarMount()
    driver = EventDriver(EkfConfig(initial_yaw_sigma_rad=0.01), landmarks, pose=truth[:3],
                         bias_rad_s=0.0)
    driver.on_speed(0.0, 0.0)
    end = _frozen_scans(driver, truth, landmarks, mount, 0.0, 10, 0.0)
    saved = driver.save()
    _frozen_scans(driver, truth, landmarks, mount, end, 10, 0.0)
    first = driver.ekf.P.copy()
    driver.restore(saved)
    _frozen_scans(driver, truth, landmarks, mount, end, 10, 0.0)
    np.testing.assert_array_equal(driver.ekf.P, first)


def _dropout_growth(trip, config):
    """Position variance (x + y) gained over the longest span without an update, m^2, s."""
    run = drive_trip(trip, EventDriver(config, trip.landmarks, trip.initial_pose))
    updates = np.unique(run.updates.stamp_s)
    k = int(np.argmax(np.diff(updates)))
    stamps = run.estimates.stamp_s
    first = int(np.searchsorted(stamps, updates[k], side='right'))
    last = int(np.searchsorted(stamps, updates[k + 1], side='left')) - 1
    variance = run.estimates.covariance[:, 0, 0] + run.estimates.covariance[:, 1, 1]
    return variance[last] - variance[first], stamps[last] - stamps[first]


def test_the_position_walk_pauses_in_a_lidar_gap():
    # q_pos stands for the detection errors' change between landmark updates: over a
    # LiDAR dropout there are none, and the walk added 2 q^2 per second to the position's
    # variance while the error stayed at millimetres (NEES below its band).
    trip = simulate_trip(SimulationConfig(duration_s=60.0, lidar_dropouts=1,
                                          lidar_dropout_s=6.0), seed=14)
    config = _config_for(trip)
    growth, span = _dropout_growth(trip, config)
    # What the odometry and the gyro add over the same span, with no walk at all.
    motion, _ = _dropout_growth(trip, dataclasses.replace(config,
                                                          position_random_walk_m_sqrt_s=0.0))
    assert span > 5.0  # the dropout
    walk = 2.0 * config.position_random_walk_m_sqrt_s ** 2
    print(f'dropout of {span:.2f} s: position variance +{growth * 1e6:.1f} mm^2, '
          f'{motion * 1e6:.1f} without a walk; the walk alone adds {walk * span * 1e6:.1f}')
    # The walk for recovery_after_s (1 s), then the odometry and the gyro alone: +81 mm^2
    # here, +80 without any walk (the two filters start the gap knowing different things);
    # with the walk kept throughout, +206.
    assert growth < motion + 0.5 * walk * span


def test_a_lidar_dropout_leaves_the_pose_covariance_consistent():
    # Stress seed 81 at 60 s, lidar_dropout 2 (4.9 s without scans): with the walk the
    # position sigma went 2.6 -> 8.2 mm over the dropout, its error 3 mm; NEES share 0.887
    # with the verdict ok (a silent failure of the suite). Its verdict is degraded now
    # besides (8 % of the run dead-reckoned: the next test).
    from gyro_ekf.analysis.offline import run_trip
    from gyro_ekf.analysis.stress import CLASSES, trip_jobs
    from gyro_ekf.analysis.summary import summarize
    dropout = tuple(c for c in CLASSES if c.name == 'lidar_dropout')
    run = run_trip(trip_jobs(3, 81, 60.0, dropout)[2].simulate())
    assert summarize(run)['ground_truth']['nees_share_in_band'] >= 0.9


def test_a_lidar_dropout_under_the_gap_limit_is_said_when_it_is_a_share_of_the_run():
    # Stress seed 34 at 90 s, lidar_dropout 16: 4.8 s without scans, under the 5-s gap
    # limit, and the NEES share 0.891 (its misses below the band) with the verdict ok.
    from gyro_ekf.analysis.offline import run_trip
    from gyro_ekf.analysis.stress import CLASSES, trip_jobs
    from gyro_ekf.analysis.summary import summarize
    from gyro_ekf.core import health
    dropout = tuple(c for c in CLASSES if c.name == 'lidar_dropout')
    run = run_trip(trip_jobs(17, 34, 90.0, dropout)[16].simulate())
    summary = summarize(run)
    association = summary['association']
    assert association['longest_gap_s'] < health.VERDICT_MAX_GAP_S
    share = association['dead_reckoned_s'] / association['since_first_update_s']
    assert share > health.VERDICT_MAX_DEAD_RECKONED_SHARE
    assert summary['health']['verdict'] == 'degraded'
    assert any('dead-reckoned' in reason for reason in summary['health']['reasons'])
    # The driver counts the gaps it closed, as the EKF node's verdict reads them: here the
    # dropout, closed long before the end.
    assert run.result.stats.dead_reckoned_s == pytest.approx(association['dead_reckoned_s'])


def test_before_the_first_landmark_update_there_is_no_position_walk():
    # The 2023 course log drives 10 s before its first pole is in view: no detection
    # error has entered yet for the walk to cover (its NEES share 0.912 -> 0.918).
    trip = simulate_trip(SimulationConfig(duration_s=20.0, static_s=0.0), seed=14)
    trip = dataclasses.replace(trip, scans=())
    config = _config_for(trip)
    finals = []
    for walk in (config.position_random_walk_m_sqrt_s, 0.0):
        run = drive_trip(trip, EventDriver(dataclasses.replace(
            config, position_random_walk_m_sqrt_s=walk), trip.landmarks, trip.initial_pose))
        assert run.updates.stamp_s.size == 0
        finals.append(run.estimates.covariance[-1, :2, :2])
    np.testing.assert_array_equal(finals[0], finals[1])
