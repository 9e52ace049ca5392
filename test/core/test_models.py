"""Process and observation models against finite differences and the Project 3 report."""

import math

import numpy as np
import pytest

from gyro_ekf.core import models
from gyro_ekf.core.ekf import GyroBiasEkf
from gyro_ekf.core.config import EkfConfig
from gyro_ekf.core.types import LidarMount

RNG = np.random.default_rng(20160101)
MOUNTS = [LidarMount(), LidarMount(0.46, 0.0, 0.0), LidarMount(0.4, -0.12, math.pi),
          LidarMount(0.2, 0.3, 0.7)]


def _random_state():
    return np.array([RNG.uniform(-5, 5), RNG.uniform(-5, 5), RNG.uniform(-math.pi, math.pi),
                     RNG.uniform(-0.05, 0.05)])


def _numeric_jacobian(fun, state, eps=1e-6):
    columns = []
    for i in range(state.size):
        step = np.zeros_like(state)
        step[i] = eps
        diff = fun(state + step) - fun(state - step)
        if diff.shape[-1] == 2:  # wrap the bearing difference
            diff[..., 1] = (diff[..., 1] + math.pi) % (2 * math.pi) - math.pi
        columns.append(diff / (2 * eps))
    return np.stack(columns, axis=-1)


@pytest.mark.parametrize('trial', range(20))
def test_process_jacobian_matches_finite_differences(trial):
    state = _random_state()
    speed, rate, dt = RNG.uniform(-1, 2), RNG.uniform(-1, 1), RNG.uniform(0.001, 0.2)

    def f(s):
        out = models.predict_state(s, speed, rate, dt)
        out[2] = s[2] + dt * (rate - s[3])  # compare unwrapped yaw
        return out

    np.testing.assert_allclose(models.process_jacobian(state, speed, dt),
                               _numeric_jacobian(f, state), atol=1e-7)


@pytest.mark.parametrize('mount', MOUNTS)
def test_observation_jacobian_matches_finite_differences(mount):
    for _ in range(20):
        state = _random_state()
        landmark = state[:2] + RNG.uniform(1, 10) * np.array(
            [math.cos(a := RNG.uniform(-math.pi, math.pi)), math.sin(a)])
        numeric = _numeric_jacobian(lambda s: models.observe(s, landmark, mount), state)
        np.testing.assert_allclose(models.observation_jacobian(state, landmark, mount),
                                   numeric, atol=1e-6)


def test_vectorised_observation_matches_single():
    state = _random_state()
    landmarks = RNG.uniform(-10, 10, size=(7, 2))
    many = models.observe(state, landmarks, MOUNTS[2])
    jac = models.observation_jacobian(state, landmarks, MOUNTS[2])
    fused_h, fused_jac = models.observe_with_jacobian(state, landmarks, MOUNTS[2])
    np.testing.assert_allclose(fused_h, many, atol=1e-12)
    np.testing.assert_array_equal(fused_jac, jac)
    for k in range(7):
        np.testing.assert_allclose(many[k], models.observe(state, landmarks[k], MOUNTS[2]))
        np.testing.assert_allclose(jac[k],
                                   models.observation_jacobian(state, landmarks[k], MOUNTS[2]))


def test_observation_is_the_reports_h_and_H_with_course_conventions():
    for _ in range(20):
        x, y, phi, _b = _random_state()
        xa, ya = RNG.uniform(-10, 10, size=2)
        dx, dy = xa - x, ya - y
        r2 = dx * dx + dy * dy
        report_h = np.array([math.sqrt(r2), math.atan2(dy, dx) - phi + math.pi / 2])
        report_H = np.array([[-dx / math.sqrt(r2), -dy / math.sqrt(r2), 0, 0],
                             [dy / r2, -dx / r2, -1, 0]])
        state = np.array([x, y, phi, _b])
        h = models.observe(state, [xa, ya], LidarMount(), bearing_zero_rad=math.pi / 2)
        assert h[0] == pytest.approx(report_h[0])
        assert math.cos(h[1] - report_h[1]) == pytest.approx(1.0)
        np.testing.assert_allclose(models.observation_jacobian(state, [xa, ya]), report_H)


def test_jacobians_equal_the_report_with_its_numbers():
    # Report: J and Ju of the kinematic model, with Pu = diag(0.3^2, (1.7 pi/180)^2).
    T, v, phi = 0.005, 0.7, 0.4
    J = np.array([[1, 0, -T * v * math.sin(phi), 0], [0, 1, T * v * math.cos(phi), 0],
                  [0, 0, 1, -T], [0, 0, 0, 1]])
    Ju = np.array([[T * math.cos(phi), 0], [T * math.sin(phi), 0], [0, T], [0, 0]])
    state = np.array([1.0, 2.0, phi, 0.01])
    np.testing.assert_allclose(models.process_jacobian(state, v, T), J)
    np.testing.assert_allclose(models.input_jacobian(state, T), Ju)
    assert EkfConfig().initial_bias_sigma_rad_s == pytest.approx(2 * math.pi / 180)


def test_Q2_departs_from_the_report_as_a_random_walk_per_root_second():
    # The report writes Q2 = diag((0.03 T)^2, (0.03 T)^2, 0, (q_b T)^2): a position noise
    # of 0.03 m per step, so its size depends on the step length T. The project reads the
    # 0.03 as a random walk in m/sqrt(s) instead, variance 0.03^2 T per step, so the
    # filter's uncertainty after one second is the same at 200 Hz and at 1 kHz. The bias
    # term keeps the report's form, with q_b read as 1 deg/s per 10 minutes.
    T, v, phi = 0.005, 0.7, 0.4
    q_b = (math.pi / 180) / 600
    state = np.array([1.0, 2.0, phi, 0.01])
    Ju = models.input_jacobian(state, T)
    Pu = np.diag([0.3 ** 2, (1.7 * math.pi / 180) ** 2])
    report_Q2 = np.diag([(0.03 * T) ** 2, (0.03 * T) ** 2, 0, (q_b * T) ** 2])
    project_Q2 = np.diag([0.03 ** 2 * T, 0.03 ** 2 * T, 0, (q_b * T) ** 2])
    Q = models.process_noise(state, T, 0.3, 1.7 * math.pi / 180, 0.03, q_b)
    np.testing.assert_allclose(Q, Ju @ Pu @ Ju.T + project_Q2, rtol=1e-12, atol=0)
    # The departure is real: the report's position term is T times smaller.
    assert not np.allclose(Q, Ju @ Pu @ Ju.T + report_Q2, rtol=1e-6, atol=0)
    # Summed over one second of steps the project's position variance is 0.03^2 whatever T.
    for step_s in (0.001, 0.005, 0.02):
        per_step = models.process_noise(state, step_s, 0.3, 0.0, 0.03, q_b)
        position_var = per_step[0, 0] - (step_s * math.cos(phi) * 0.3) ** 2
        assert position_var / step_s == pytest.approx(0.03 ** 2)
    # The filter's written-out Q is the same: from P = 0 one step gives P = Q.
    config = EkfConfig(speed_noise_m_s=0.3, gyro_noise_rad_s=1.7 * math.pi / 180,
                       position_random_walk_m_sqrt_s=0.03, bias_random_walk_rad_s2=q_b,
                       initial_bias_sigma_rad_s=0.0)
    ekf = GyroBiasEkf(config, pose=state[:3], bias_rad_s=state[3])
    ekf.predict(v, 0.2, T)
    # (Its fifth state, the wander, has no variance and no noise while none is modelled.)
    np.testing.assert_allclose(ekf.P[:4, :4], Q, rtol=1e-12, atol=1e-30)
    assert not ekf.P[4].any()
    assert config.bias_random_walk_rad_s2 == pytest.approx(q_b)


def test_sensor_frame_round_trip():
    state = _random_state()
    mount = MOUNTS[3]
    landmarks = RNG.uniform(-10, 10, size=(5, 2))
    z = models.observe(state, landmarks, mount)
    points = np.column_stack([z[:, 0] * np.cos(z[:, 1]), z[:, 0] * np.sin(z[:, 1])])
    np.testing.assert_allclose(models.sensor_to_map(state, points, mount), landmarks,
                               atol=1e-9)
    np.testing.assert_allclose(models.points_to_range_bearing(points), z, atol=1e-12)


def test_the_wander_is_a_gauss_markov_state_the_heading_integrates():
    # The fifth state c: yaw += T (w - b - c), c *= exp(-T / tau), Q adds s^2 (1 - phi^2)
    # (c's variance stays s^2), h ignores it, a gyro at rest reads b + c. Without a fifth
    # entry the models are the report's four-state ones.
    state = np.r_[_random_state(), 0.003]
    speed, rate, dt, tau, sigma = 0.8, 0.2, 0.01, 2.0, 0.0005
    phi = math.exp(-dt / tau)
    mount = MOUNTS[3]
    landmark = RNG.uniform(-10, 10, size=2)
    f5 = models.predict_state(state, speed, rate, dt, tau)
    four = np.r_[state[:3], state[3] + state[4]]
    np.testing.assert_allclose(f5[:3], models.predict_state(four, speed, rate, dt)[:3],
                               rtol=1e-15)
    assert f5[4] == pytest.approx(phi * 0.003, rel=1e-15)
    J5 = models.process_jacobian(state, speed, dt, tau)
    np.testing.assert_array_equal(J5[:4, :4], models.process_jacobian(state[:4], speed, dt))
    np.testing.assert_array_equal(J5[:, 4], [0, 0, -dt, 0, phi])
    np.testing.assert_array_equal(J5[4], [0, 0, 0, 0, phi])
    Q5 = models.process_noise(state, dt, 0.3, 0.03, 0.01, 1e-4, sigma, tau)
    np.testing.assert_array_equal(Q5[:4, :4],
                                  models.process_noise(state[:4], dt, 0.3, 0.03, 0.01, 1e-4))
    assert Q5[4, 4] == pytest.approx(sigma ** 2 * (1 - phi ** 2), rel=1e-15)
    assert not Q5[4, :4].any()
    # Stationary: from c's variance s^2, one step keeps it s^2.
    assert phi ** 2 * sigma ** 2 + Q5[4, 4] == pytest.approx(sigma ** 2, rel=1e-12)
    h5, H5 = models.observe_with_jacobian(state, landmark, mount)
    h4, H4 = models.observe_with_jacobian(state[:4], landmark, mount)
    np.testing.assert_array_equal(h5, h4)
    np.testing.assert_array_equal(H5[:, :4], H4)
    assert not H5[:, 4].any()
    hb, Hb = models.observe_bias(state)
    np.testing.assert_array_equal(hb, [state[3] + state[4]])
    np.testing.assert_array_equal(Hb, [[0, 0, 0, 1, 1]])
    np.testing.assert_array_equal(models.observe_bias(state[:4])[1], [[0, 0, 0, 1]])


def test_map_uncertainty_adds_its_variance_to_range_and_over_range_squared_to_bearing():
    sensor = np.diag([0.05 ** 2, 0.01 ** 2])
    R = models.observation_noise(np.array([2.0, 8.0]), sensor, 0.03 ** 2)
    np.testing.assert_allclose(R[0], sensor + np.diag([0.03 ** 2, (0.03 / 2.0) ** 2]),
                               rtol=1e-15)
    np.testing.assert_allclose(R[1], sensor + np.diag([0.03 ** 2, (0.03 / 8.0) ** 2]),
                               rtol=1e-15)
    np.testing.assert_array_equal(models.observation_noise(5.0, sensor, 0.0), sensor)


def test_points_less_range_moves_each_point_toward_the_sensor_along_its_ray():
    from gyro_ekf.core.models import points_less_range
    points = np.array([[3.0, 4.0], [-2.0, 0.0], [0.01, 0.0]])
    moved = points_less_range(points, 0.5)
    np.testing.assert_allclose(moved[0], [2.7, 3.6])
    np.testing.assert_allclose(moved[1], [-1.5, 0.0])
    np.testing.assert_array_equal(moved[2], points[2])  # nearer than the offset: left
    np.testing.assert_allclose(points_less_range(points[:2], -0.5)[1], [-2.5, 0.0])
    assert points_less_range(points, 0.0) is not None
    np.testing.assert_array_equal(points_less_range(points, 0.0), points)
