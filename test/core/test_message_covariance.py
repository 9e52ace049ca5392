"""Message covariances: a message's own gyro or speed variance replaces the configured noise.

REP-145: 0 (and -1) mean "not given"; NaN, inf, other negatives and variances beyond the
input's plausible range are ignored (the configured noise applies) and counted.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from gyro_ekf.analysis.offline import run_trip
from gyro_ekf.io.params_file import PipelineParams
from gyro_ekf.core.config import EkfConfig, with_stated_noise
from gyro_ekf.core.ekf import GyroBiasEkf
from gyro_ekf.core.events import EventDriver
from gyro_ekf.core.simulator import SimulationConfig, simulate_trip
from gyro_ekf.core.validation import message_variance, message_variances, validate_trip


@pytest.mark.parametrize('value, used, bad', [
    (1e-4, 1e-4, False), (35.0 ** 2, 35.0 ** 2, False),
    (0.0, None, False), (-1.0, None, False),
    (math.nan, None, True), (math.inf, None, True), (-2.0, None, True), (-1e-9, None, True),
    (35.0 ** 2 * 1.001, None, True)])
def test_a_variance_is_used_not_given_or_bad(value, used, bad):
    assert message_variance(value, 35.0) == (used, bad)


def test_the_series_version_agrees_with_the_scalar_one():
    values = np.array([1e-4, 0.0, -1.0, math.nan, -2.0, 4.0, 1e9])
    used, bad = message_variances(values, 35.0)
    expected = [message_variance(v, 35.0) for v in values.tolist()]
    assert bad == sum(b for _, b in expected)
    assert [None if math.isnan(v) else v for v in used.tolist()] == [u for u, _ in expected]
    assert message_variances(np.zeros(3), 35.0) == (None, 0)


def test_predict_with_a_variance_is_predict_with_that_sigma():
    sigma_w, sigma_v = 0.01, 0.2
    configured = GyroBiasEkf(dataclasses.replace(EkfConfig(), gyro_noise_rad_s=sigma_w,
                                                 speed_noise_m_s=sigma_v))
    given = GyroBiasEkf(EkfConfig())
    for _ in range(50):
        configured.predict(1.5, 0.2, 0.01)
        given.predict(1.5, 0.2, 0.01, speed_variance=sigma_v ** 2, rate_variance=sigma_w ** 2)
    assert np.array_equal(configured.P, given.P)
    assert not np.array_equal(GyroBiasEkf(EkfConfig()).P, given.P)


def test_the_driver_holds_a_variance_with_its_input_until_the_next_message():
    driver = EventDriver(EkfConfig())
    driver.on_speed(0.0, 1.0, variance=0.04)
    driver.on_imu(0.0, 0.0, variance=1e-4)
    driver.on_imu(1.0, 0.0)  # 1 s predicted with the variances held from the messages
    held = EventDriver(dataclasses.replace(EkfConfig(), speed_noise_m_s=0.2,
                                           gyro_noise_rad_s=0.01))
    held.on_speed(0.0, 1.0)
    held.on_imu(0.0, 0.0)
    held.on_imu(1.0, 0.0)
    assert np.allclose(driver.ekf.P, held.ekf.P, rtol=1e-12, atol=0.0)
    assert driver.rate_variance is None  # the last IMU message gave none


@pytest.fixture(scope='module')
def trip():
    return simulate_trip(SimulationConfig(duration_s=20.0), seed=5)


def test_an_offline_run_with_message_variances_equals_one_with_those_sigmas(trip):
    sigma_w, sigma_v = trip.noise.gyro_rad_s * 2.0, trip.noise.speed_m_s * 3.0
    with_messages = dataclasses.replace(
        trip, imu=dataclasses.replace(trip.imu, yaw_rate_variance=np.full(
            len(trip.imu.stamp_s), sigma_w ** 2)),
        speed=dataclasses.replace(trip.speed, speed_variance=np.full(
            len(trip.speed.stamp_s), sigma_v ** 2)))
    checked, report = validate_trip(with_messages, 'sim')
    assert report.covariances_used == {'imu.angular_velocity_covariance[8]': len(
        trip.imu.stamp_s), 'speed.twist.covariance[0]': len(trip.speed.stamp_s)}
    from_messages = run_trip(checked).result.estimates
    # The other stated figures (range, bearing, map) as the message run takes them.
    configured = PipelineParams(ekf=dataclasses.replace(
        with_stated_noise(EkfConfig(), trip.noise), gyro_noise_rad_s=sigma_w,
        speed_noise_m_s=sigma_v))
    from_config = run_trip(trip, configured, use_stated_noise=False).result.estimates
    assert np.array_equal(from_messages.state, from_config.state)
    assert np.array_equal(from_messages.covariance, from_config.covariance)
    ignored = run_trip(checked, use_message_covariance=False).result.estimates
    assert not np.array_equal(ignored.covariance, from_messages.covariance)


def test_bad_variances_are_counted_and_the_configured_noise_used(trip):
    n = len(trip.imu.stamp_s)
    variances = np.zeros(n)
    variances[[10, 20, 30]] = [math.nan, -5.0, 1e12]
    bad = dataclasses.replace(trip, imu=dataclasses.replace(trip.imu,
                                                            yaw_rate_variance=variances))
    checked, report = validate_trip(bad, 'sim')
    assert report.covariances_ignored == {'imu.angular_velocity_covariance[8]': 3}
    assert 'ignored bad message covariances (3 imu.angular_velocity_covariance[8])' in \
        report.warning()
    assert report.to_dict()['covariances_ignored'] == {'imu.angular_velocity_covariance[8]': 3}
    assert checked.imu.yaw_rate_variance is None  # nothing left to use
    assert np.array_equal(run_trip(checked).result.estimates.covariance,
                          run_trip(trip).result.estimates.covariance)
