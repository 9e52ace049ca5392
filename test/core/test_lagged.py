"""Late observations are replayed into the history: the filter ends as strict ordering ends."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from gyro_ekf.core.config import EkfConfig
from gyro_ekf.core.detection import detect_poles_in_scans
from gyro_ekf.core.errors import CoreError
from gyro_ekf.core.event_records import EventKind
from gyro_ekf.core.events import EventDriver
from gyro_ekf.core.trip_run import drive_trip, iter_trip_events
from gyro_ekf.core.lagged import LaggedObservations, ObservationFate
from gyro_ekf.core.simulator import SimulationConfig, simulate_trip


@pytest.fixture(scope='module')
def trip():
    return simulate_trip(SimulationConfig(duration_s=20.0, static_s=0.0), seed=5)


def _driver(trip):
    config = dataclasses.replace(EkfConfig(), gyro_noise_rad_s=trip.noise.gyro_rad_s,
                                 speed_noise_m_s=trip.noise.speed_m_s)
    return EventDriver(config, trip.landmarks, trip.initial_pose)


def _detections(trip):
    scans = trip.scans[0]
    found = detect_poles_in_scans(scans.ranges_m, scans.angles_rad, scans.intensities)
    return scans, found


def _feed_with_delay(trip, lagged, delay_s, rng=None):
    """Inputs in stamp order; each scan is handed over once the inputs are delay_s past it."""
    scans, found = _detections(trip)
    waiting = []   # (due stamp, scan index)
    fates = []
    estimates = {}
    for stamp_s, kind, _, index in iter_trip_events(trip):
        if kind is EventKind.OBSERVATION:
            delay = delay_s if rng is None else rng.uniform(0.0, delay_s)
            waiting.append((stamp_s + delay, index))
            continue
        for due, scan in [w for w in waiting if w[0] <= stamp_s]:
            waiting.remove((due, scan))
            fates.append(lagged.observation(float(scans.stamp_s[scan]),
                                            found[scan].points_sensor_m, scans.mount))
        if kind is EventKind.IMU:
            estimates[stamp_s] = lagged.on_imu(stamp_s, float(
                trip.imu.yaw_rate_rad_s[index]))
        else:
            lagged.on_speed(stamp_s, float(trip.speed.speed_m_s[index]))
    for _, scan in waiting:
        fates.append(lagged.observation(float(scans.stamp_s[scan]),
                                        found[scan].points_sensor_m, scans.mount))
    lagged.flush()
    return fates, estimates


def test_late_observations_end_in_the_strictly_ordered_state(trip):
    strict = drive_trip(trip, _driver(trip))
    lagged = LaggedObservations(_driver(trip), history_s=0.5)
    fates, estimates = _feed_with_delay(trip, lagged, 0.15, np.random.default_rng(1))
    assert fates.count(ObservationFate.REPLAYED) > 0.5 * len(fates)
    assert ObservationFate.TOO_LATE not in fates
    # The same arithmetic in the same order: equal to the last bit.
    # (An estimate carries the first four states; the wander stays inside the filter.)
    assert lagged.driver.ekf.x[:4].tolist() == strict.estimates.state[-1].tolist()
    assert lagged.driver.ekf.P[:4, :4].tolist() == strict.estimates.covariance[-1].tolist()
    assert lagged.driver.stats.snapshot() == strict.stats.snapshot()
    assert lagged.stats.replays == fates.count(ObservationFate.REPLAYED)
    # Poses handed out before a scan arrived were predictions: close, not equal.
    early = np.array([estimates[t].state[:2] for t in strict.estimates.stamp_s])
    assert np.max(np.hypot(*(early - strict.estimates.state[:, :2]).T)) < 0.05


def test_observations_ahead_of_the_inputs_wait_for_them(trip):
    strict = drive_trip(trip, _driver(trip))
    lagged = LaggedObservations(_driver(trip), history_s=0.5)
    scans, found = _detections(trip)
    # Every scan is handed over before the inputs reach its stamp: nothing is replayed.
    fates = [lagged.observation(float(t), d.points_sensor_m, scans.mount)
             for t, d in zip(scans.stamp_s, found)]
    assert set(fates) == {ObservationFate.HELD} and lagged.held == len(fates)
    for stamp_s, kind, _, index in iter_trip_events(trip):
        if kind is EventKind.IMU:
            lagged.on_imu(stamp_s, float(trip.imu.yaw_rate_rad_s[index]))
        elif kind is EventKind.SPEED:
            lagged.on_speed(stamp_s, float(trip.speed.speed_m_s[index]))
    lagged.flush()
    assert lagged.held == 0 and lagged.stats.replays == 0
    assert lagged.driver.ekf.x[:4].tolist() == strict.estimates.state[-1].tolist()


def test_observations_older_than_the_history_are_dropped(trip):
    lagged = LaggedObservations(_driver(trip), history_s=0.05)
    fates, _ = _feed_with_delay(trip, lagged, 0.3)
    # All but the last few scans, handed over after the inputs ended, come too late.
    too_late = fates.count(ObservationFate.TOO_LATE)
    assert too_late >= len(fates) - 5 and lagged.stats.too_late == too_late
    assert lagged.driver.stats.scans == len(fates) - too_late


def test_history_must_be_a_finite_non_negative_time(trip):
    for bad in (-0.1, float('nan'), float('inf')):
        with pytest.raises(CoreError, match='history_s'):
            LaggedObservations(_driver(trip), bad)


def _inputs_until(trip, lagged, until_s, after_s=-1.0):
    """Speed and IMU samples stamped in (after_s, until_s], in order."""
    for stamp_s, kind, _, index in iter_trip_events(trip):
        if stamp_s <= after_s:
            continue
        if stamp_s > until_s:
            return
        if kind is EventKind.IMU:
            lagged.on_imu(stamp_s, float(trip.imu.yaw_rate_rad_s[index]))
        elif kind is EventKind.SPEED:
            lagged.on_speed(stamp_s, float(trip.speed.speed_m_s[index]))


def test_a_refused_late_observation_changes_neither_filter_nor_history(trip, monkeypatch):
    scans, found = _detections(trip)
    lagged = LaggedObservations(_driver(trip), history_s=0.5)
    _inputs_until(trip, lagged, 2.0)
    before = lagged.driver.save()
    real = EventDriver.on_detections

    def refuse(self, stamp_s, points, mount):
        raise CoreError('innovation covariance is not positive definite (test)')

    monkeypatch.setattr(EventDriver, 'on_detections', refuse)
    late = int(np.searchsorted(scans.stamp_s, 1.8))
    with pytest.raises(CoreError, match='test'):
        lagged.observation(float(scans.stamp_s[late]), found[late].points_sensor_m,
                           scans.mount)
    monkeypatch.setattr(EventDriver, 'on_detections', real)
    assert lagged.driver.ekf.x.tolist() == before[0][0]
    assert lagged.driver.stamp_s == before[2]
    # The history is intact: the same scan is replayed once the filter takes it.
    fate = lagged.observation(float(scans.stamp_s[late]), found[late].points_sensor_m,
                              scans.mount)
    assert fate == ObservationFate.REPLAYED and lagged.driver.stamp_s == before[2]


def test_a_refused_held_observation_does_not_take_the_imu_sample_down(trip, monkeypatch):
    scans, found = _detections(trip)
    refused = []
    lagged = LaggedObservations(_driver(trip), history_s=0.5,
                                on_refused=lambda stamp, err: refused.append(stamp))
    _inputs_until(trip, lagged, 1.0)
    ahead = int(np.searchsorted(scans.stamp_s, 1.5))
    assert lagged.observation(float(scans.stamp_s[ahead]), found[ahead].points_sensor_m,
                              scans.mount) == ObservationFate.HELD
    imu_before = lagged.driver.stats.imu

    def refuse(self, stamp_s, points, mount):
        raise CoreError('refused for the test')

    monkeypatch.setattr(EventDriver, 'on_detections', refuse)
    _inputs_until(trip, lagged, 2.0, after_s=1.0)
    assert refused == [float(scans.stamp_s[ahead])] and lagged.stats.refused == 1
    assert lagged.driver.stats.imu > imu_before and lagged.held == 0


def test_after_an_outside_change_nothing_older_is_replayed(trip):
    scans, found = _detections(trip)
    lagged = LaggedObservations(_driver(trip), history_s=0.5)
    _inputs_until(trip, lagged, 2.0)
    lagged.driver.ekf.set_bias(0.01, 0.001)
    lagged.forget_history()
    late = int(np.searchsorted(scans.stamp_s, 1.9))
    fate = lagged.observation(float(scans.stamp_s[late]), found[late].points_sensor_m,
                              scans.mount)
    assert fate == ObservationFate.TOO_LATE
    assert lagged.driver.ekf.bias_rad_s == 0.01   # not undone by a replay
    _inputs_until(trip, lagged, 2.5, after_s=2.0)   # new history builds up again
    late = int(np.searchsorted(scans.stamp_s, 2.3))
    assert lagged.observation(float(scans.stamp_s[late]), found[late].points_sensor_m,
                              scans.mount) == ObservationFate.REPLAYED


def test_held_observations_are_bounded(trip):
    scans, found = _detections(trip)
    lagged = LaggedObservations(_driver(trip), history_s=0.5, max_held=3)
    _inputs_until(trip, lagged, 0.5)
    for index in range(10, 20):
        lagged.observation(float(scans.stamp_s[index]), found[index].points_sensor_m,
                           scans.mount)
    assert lagged.held == 3 and lagged.driver.stats.scans == 7
    with pytest.raises(CoreError, match='max_held'):
        LaggedObservations(_driver(trip), 0.5, max_held=0)


def test_a_gyro_scale_applied_between_replays_ends_as_strict_ordering_ends():
    # The scale is applied as a window closes (core/gyro_scale.py) while late scans are
    # replayed around it: save and restore must carry the scale in use, the restarted
    # bias watch and the input counters, or the two paths part.
    scaled = simulate_trip(SimulationConfig(duration_s=140.0, static_s=0.0,
                                            gyro_scale_error=0.015), seed=5)
    strict_driver = _driver(scaled)
    strict = drive_trip(scaled, strict_driver)
    assert strict_driver.gyro_scale.applied == 1
    lagged = LaggedObservations(_driver(scaled), history_s=0.5)
    fates, _ = _feed_with_delay(scaled, lagged, 0.15, np.random.default_rng(2))
    assert fates.count(ObservationFate.REPLAYED) > 0.5 * len(fates)
    driver = lagged.driver
    assert driver.gyro_scale.report() == strict_driver.gyro_scale.report()
    assert driver._gyro_scale == strict_driver._gyro_scale != 1.0
    assert {k: v.report() for k, v in driver.input_loss.items()} == {
        k: v.report() for k, v in strict_driver.input_loss.items()}
    assert driver.ekf.x[:4].tolist() == strict.estimates.state[-1].tolist()
    assert driver.stats.snapshot() == strict.stats.snapshot()


def test_lone_input_spikes_are_dropped_as_strict_ordering_drops_them():
    """The spike gates' held-back samples are saved and replayed with the rest."""
    clean = simulate_trip(SimulationConfig(duration_s=20.0, static_s=2.0), seed=5)
    rng = np.random.default_rng(5)
    speed = clean.speed.speed_m_s.copy()
    speed[rng.choice(np.arange(400, len(speed), 2), 10, replace=False)] += 2.0
    rates = clean.imu.angular_velocity_rad_s.copy()
    rates[rng.choice(np.arange(800, len(rates), 2), 10, replace=False), 2] += 1.0
    trip = dataclasses.replace(clean, speed=dataclasses.replace(clean.speed, speed_m_s=speed),
                               imu=dataclasses.replace(clean.imu, angular_velocity_rad_s=rates))
    strict = drive_trip(trip, _driver(trip))
    lagged = LaggedObservations(_driver(trip), history_s=0.5)
    fates, _ = _feed_with_delay(trip, lagged, 0.15, np.random.default_rng(1))
    assert fates.count(ObservationFate.REPLAYED) > 0.5 * len(fates)
    spikes = lagged.driver.input_spikes
    assert spikes['odometry'].spikes == 10 and spikes['gyro'].spikes == 10
    assert lagged.driver.ekf.x[:4].tolist() == strict.estimates.state[-1].tolist()
    assert lagged.driver.stats.snapshot() == strict.stats.snapshot()
