"""The EKF's consistency (Monte Carlo NEES) and an independent step check against filterpy."""

import dataclasses
import math

import numpy as np
import pytest
from scipy.stats import chi2

from gyro_ekf.core import models
from gyro_ekf.core.config import EkfConfig
from gyro_ekf.core.ekf import GyroBiasEkf
from gyro_ekf.core.types import LidarMount

MOUNT = LidarMount(0.4, 0.1, 0.2)
LANDMARKS = np.array([[x, y] for x in range(-10, 11, 5) for y in range(-10, 11, 5)], float)


def _simulate_and_filter(seed, config, duration_s=60.0, dt_s=0.01, obs_every=20):
    """Truth from the filter's own discrete model, so a consistent filter has NEES ~ chi2(n).

    n is 4 (x, y, yaw, b) without a wander; with one configured (gyro_wander_rad_s) the
    truth's gyro wanders as the filter's fifth state says, and n is 5.
    """
    rng = np.random.default_rng(seed)
    true_bias = rng.normal(0.0, config.initial_bias_sigma_rad_s)
    sigma_c, tau = config.gyro_wander_rad_s, config.gyro_wander_tau_s
    phi = math.exp(-dt_s / tau)
    truth = np.array([0.0, 0.0, 0.3, true_bias, rng.normal(0.0, sigma_c)])
    n = 5 if sigma_c > 0.0 else 4
    ekf = GyroBiasEkf(config, pose=truth[:3])
    R_sqrt = np.sqrt(np.diag(ekf.R))
    steps = int(duration_s / dt_s)
    nees = []
    for k in range(steps):
        t = k * dt_s
        speed, rate = 0.6 + 0.3 * math.sin(0.3 * t), 0.4 * math.sin(0.2 * t)
        error_rate = truth[3] + truth[4]
        truth = models.predict_state(truth, speed, rate + error_rate, dt_s, tau)
        truth[4] += rng.normal(0.0, sigma_c * math.sqrt(1.0 - phi * phi))
        ekf.predict(speed + rng.normal(0, config.speed_noise_m_s),
                    rate + error_rate + rng.normal(0, config.gyro_noise_rad_s), dt_s)
        if k % obs_every == 0 and k > 0:
            xl, yl = models.sensor_position(truth, MOUNT)
            near = np.hypot(*(LANDMARKS - [xl, yl]).T) < 12.0
            for landmark in LANDMARKS[near]:
                z = models.observe(truth, landmark, MOUNT) + rng.normal(0, 1, 2) * R_sqrt
                ekf.update(z, landmark, MOUNT)
            error = (truth - ekf.x)[:n]
            error[2] = (error[2] + math.pi) % (2 * math.pi) - math.pi
            # The first second is skipped: P0 trusts the pose exactly, so P starts singular.
            if t >= 1.0:
                nees.append(float(error @ np.linalg.solve(ekf.P[:n, :n], error)))
    return np.array(nees), true_bias, ekf


CONSISTENT = EkfConfig(gyro_noise_rad_s=math.radians(1.0), speed_noise_m_s=0.05,
                       range_noise_m=0.05, bearing_noise_rad=math.radians(1.0),
                       position_random_walk_m_sqrt_s=0.0, bias_random_walk_rad_s2=0.0)


@pytest.mark.parametrize('config, dof', [
    (CONSISTENT, 4),
    # A gyro that wanders (0.2 deg/s over 2 s), told to the filter: its fifth state.
    (dataclasses.replace(CONSISTENT, gyro_wander_rad_s=math.radians(0.2)), 5)])
def test_average_nees_inside_chi_square_band_over_monte_carlo(config, dof):
    runs = 25
    nees = np.array([_simulate_and_filter(seed, config)[0] for seed in range(runs)])
    average = nees.mean(axis=0)
    low, high = chi2.ppf([0.025, 0.975], dof * runs) / runs
    inside = np.mean((average >= low) & (average <= high))
    print(f'ANEES over {runs} runs: mean {average.mean():.2f}, band [{low:.2f}, {high:.2f}],'
          f' share inside {inside:.3f}')
    assert low <= average.mean() <= high
    assert inside >= 0.9


def test_bias_converges_to_truth():
    for seed in (1, 2, 3):
        _, true_bias, ekf = _simulate_and_filter(seed, CONSISTENT, duration_s=90.0)
        sigma = math.sqrt(ekf.P[3, 3])
        assert ekf.P[4, 4] == 0.0 and ekf.x[4] == 0.0  # no wander modelled
        assert abs(ekf.x[3] - true_bias) < 3 * sigma
        assert sigma < math.radians(0.02)


def test_covariance_stays_symmetric_positive_definite():
    _, _, ekf = _simulate_and_filter(7, EkfConfig(gyro_wander_rad_s=1e-3), duration_s=20.0)
    np.testing.assert_array_equal(ekf.P, ekf.P.T)
    assert np.all(np.linalg.eigvalsh(ekf.P) > 0)


def test_one_cycle_matches_filterpy_extended_kalman_filter():
    from filterpy import kalman as filterpy
    # With a wander modelled, so the fifth state's rows take part.
    config = EkfConfig(initial_position_sigma_m=0.1, initial_yaw_sigma_rad=0.05,
                       gyro_wander_rad_s=1e-3)
    ours = GyroBiasEkf(config, pose=[1.0, 2.0, 0.5], bias_rad_s=0.01)
    theirs = filterpy.ExtendedKalmanFilter(dim_x=5, dim_z=2)
    theirs.x = ours.x.reshape(5, 1).copy()
    theirs.P = ours.P.copy()
    theirs.R = ours.R.copy()
    speed, rate, dt = 0.8, 0.1, 0.02
    tau = config.gyro_wander_tau_s
    theirs.F = models.process_jacobian(theirs.x.ravel(), speed, dt, tau)
    theirs.Q = models.process_noise(theirs.x.ravel(), dt, config.speed_noise_m_s,
                                    config.gyro_noise_rad_s,
                                    config.position_random_walk_m_sqrt_s,
                                    config.bias_random_walk_rad_s2, config.gyro_wander_rad_s,
                                    tau)
    theirs.x = models.predict_state(theirs.x.ravel(), speed, rate, dt, tau).reshape(5, 1)
    theirs.P = theirs.F @ theirs.P @ theirs.F.T + theirs.Q
    ours.predict(speed, rate, dt)
    np.testing.assert_allclose(ours.x, theirs.x.ravel(), atol=1e-15)
    np.testing.assert_allclose(ours.P, theirs.P, rtol=1e-12, atol=1e-18)
    landmark = np.array([4.0, 5.0])
    z = models.observe(ours.x, landmark, MOUNT) + [0.05, 0.01]
    # The map's uncertainty (config.landmark_sigma_m) moves the landmark's range by sigma
    # and its bearing by sigma / range: filterpy gets it written out as R.
    expected_range = float(models.observe(ours.x, landmark, MOUNT)[0])
    map_var = config.landmark_sigma_m ** 2
    assert map_var > 0.0
    R = ours.R + np.diag([map_var, map_var / expected_range ** 2])
    np.testing.assert_allclose(ours.observation_noise(expected_range), R, rtol=1e-15)
    theirs.update(z.reshape(2, 1),
                  lambda x: models.observation_jacobian(x.ravel(), landmark, MOUNT),
                  lambda x: models.observe(x.ravel(), landmark, MOUNT).reshape(2, 1), R=R)
    ours.update(z, landmark, MOUNT)
    np.testing.assert_allclose(ours.x, theirs.x.ravel(), atol=1e-12)
    np.testing.assert_allclose(ours.P, theirs.P, rtol=1e-9, atol=1e-15)


def test_zero_or_negative_step_leaves_the_filter_unchanged():
    ekf = GyroBiasEkf(EkfConfig(), pose=[1.0, 1.0, 0.0])
    x, P = ekf.x.copy(), ekf.P.copy()
    ekf.predict(1.0, 0.5, 0.0)
    np.testing.assert_array_equal(ekf.x, x)
    np.testing.assert_array_equal(ekf.P, P)


@pytest.mark.parametrize('textbook', [False, True])
def test_the_odometry_walk_adds_to_the_position_random_walk(textbook):
    # Q2's x and y terms are (q^2 + odometry_walk) T, in the kernel and the readable maths.
    config = EkfConfig(position_random_walk_m_sqrt_s=0.004)
    grown = []
    for walk in (0.0, 3e-4):
        ekf = GyroBiasEkf(config, pose=[0.0, 0.0, 0.0], textbook=textbook)
        ekf.odometry_walk = walk
        ekf.predict(0.0, 0.0, 0.5, speed_variance=0.0, rate_variance=0.0)
        grown.append(ekf.P[:2, :2])
    np.testing.assert_allclose(grown[0], np.diag([0.004 ** 2 * 0.5] * 2), rtol=1e-12)
    np.testing.assert_allclose(grown[1] - grown[0], np.diag([3e-4 * 0.5] * 2), rtol=1e-9)


def test_packed_rows_unpack_to_the_state_and_covariance():
    from gyro_ekf.core.ekf import unpack_rows
    ekf = GyroBiasEkf(EkfConfig(), pose=np.array([1.0, 2.0, 0.3]))
    rows, states, covariances = [], [], []
    for step in range(5):
        ekf.predict(0.5, 0.1 * step, 0.01)
        ekf.update(np.array([3.0 + 0.01 * step, 0.2]), np.array([4.0, 3.0]))
        rows.append(ekf.packed_row())
        states.append(ekf.x)
        covariances.append(ekf.P)
        assert ekf.x_values == tuple(ekf.x.tolist())
    unpacked_states, unpacked_covariances = unpack_rows(rows)
    np.testing.assert_array_equal(unpacked_states, states)
    np.testing.assert_array_equal(unpacked_covariances, covariances)


def test_a_scaled_update_uses_scaled_noise_and_reports_the_nis_of_the_sensor():
    config = EkfConfig(initial_position_sigma_m=0.1, initial_yaw_sigma_rad=0.05)
    landmark = np.array([4.0, 5.0])
    scaled = GyroBiasEkf(config, pose=[1.0, 2.0, 0.5], bias_rad_s=0.01)
    plain = GyroBiasEkf(config, pose=[1.0, 2.0, 0.5], bias_rad_s=0.01)
    z = models.observe(scaled.x, landmark, MOUNT) + [0.05, 0.01]
    y = z - models.observe(scaled.x, landmark, MOUNT)
    H = models.observation_jacobian(scaled.x, landmark, MOUNT)
    P0 = scaled.P
    R = scaled.observation_noise(float(models.observe(scaled.x, landmark, MOUNT)[0]))
    nis = scaled.update(z, landmark, MOUNT, noise_scale=5.0)
    # The NIS measures the sensor (unscaled R); the correction uses 5 R.
    assert nis == pytest.approx(float(y @ np.linalg.solve(H @ P0 @ H.T + R, y)), rel=1e-9)
    S = H @ P0 @ H.T + 5.0 * R
    K = P0 @ H.T @ np.linalg.inv(S)
    A = np.eye(5) - K @ H
    np.testing.assert_allclose(scaled.P, A @ P0 @ A.T + K @ (5.0 * R) @ K.T, rtol=1e-9,
                               atol=1e-15)
    plain.update(z, landmark, MOUNT)
    assert np.trace(scaled.P) > np.trace(plain.P)
