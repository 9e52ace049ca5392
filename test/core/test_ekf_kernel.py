"""The private kernel equals the textbook EKF (ekf.Textbook with models.py) to 1e-12.

The kernel is the filter's only fast path: the same lines unrolled on plain floats. Each
of its functions is compared with the readable definition on random states, covariances,
inputs and mounts; then whole runs of the filter on either are compared.
"""

import math

import numpy as np
import pytest

from gyro_ekf.core import _ekf_kernel as kernel
from gyro_ekf.core import models
from gyro_ekf.core.config import EkfConfig
from gyro_ekf.core.ekf import (GyroBiasEkf, Textbook, _full, _packed, innovation,
                               innovation_covariance, normalised_innovation_sq)
from gyro_ekf.core.errors import CoreError
from gyro_ekf.core.types import BIAS, WANDER, YAW, LidarMount

RNG = np.random.default_rng(4010)
MOUNTS = [LidarMount(), LidarMount(0.46, 0.0, 0.0), LidarMount(0.4, -0.12, math.pi),
          LidarMount(0.2, 0.3, 0.7)]
TOL = 1e-12


def _state():
    # Yaw away from +-pi, so a rounding difference cannot wrap one side and not the other.
    return [RNG.uniform(-5, 5), RNG.uniform(-5, 5), RNG.uniform(-3.0, 3.0),
            RNG.uniform(-0.05, 0.05), RNG.uniform(-0.01, 0.01)]


def _covariance():
    """A random positive definite P with the scales of m, m, rad, rad/s and rad/s."""
    root = RNG.normal(size=(5, 5)) @ np.diag([0.3, 0.3, 0.05, 0.005, 0.002])
    return root.T @ root + np.diag([1e-6, 1e-6, 1e-8, 1e-10, 1e-10])


def _landmark(state):
    angle = RNG.uniform(-math.pi, math.pi)
    return (np.array(state[:2]) + RNG.uniform(1.0, 20.0) * np.array(
        [math.cos(angle), math.sin(angle)])).tolist()


def _equal(kernel_value, textbook_value):
    """Equal to 1e-12 of the value's own scale (relative, and absolute for entries near 0)."""
    a = np.asarray(kernel_value, dtype=np.float64)
    b = np.asarray(textbook_value, dtype=np.float64)
    np.testing.assert_allclose(a, b, rtol=TOL, atol=TOL * max(1.0e-30, np.max(np.abs(b))))


# Typical size of each state entry (m, m, rad, rad/s, rad/s): 1e-12 of it is the tolerance.
STATE_SCALE = np.array([5.0, 5.0, math.pi, 0.05, 0.01])


def _equal_angle(kernel_rad, textbook_rad):
    difference = math.remainder(kernel_rad - textbook_rad, 2 * math.pi)
    assert abs(difference) <= TOL * math.pi, (kernel_rad, textbook_rad)


def _equal_states(kernel_state, textbook_state):
    a, b = np.array(kernel_state), np.array(textbook_state)
    _equal_angle(a[YAW], b[YAW])
    a[YAW] = b[YAW]
    assert np.all(np.abs(a - b) <= TOL * STATE_SCALE[:a.size]), (a, b)


@pytest.mark.parametrize('hold_position', [False, True])
def test_predict_equals_the_textbook(hold_position):
    for _ in range(200):
        s, P = _state(), _covariance()
        args = (RNG.uniform(-1.0, 2.0), RNG.uniform(-1.0, 1.0), RNG.uniform(1e-4, 0.2),
                RNG.uniform(0.0, 0.1), RNG.uniform(0.0, 1e-3), RNG.uniform(0.0, 1e-3),
                RNG.uniform(0.0, 1e-8), hold_position, RNG.uniform(0.0, 1e-3),
                RNG.uniform(0.5, 5.0))
        fast_s, fast_p = kernel.predict(list(s), _packed(P), *args)
        slow_s, slow_p = Textbook.predict(list(s), _packed(P), *args)
        _equal_states(fast_s, slow_s)
        _equal(_full(fast_p), _full(slow_p))


@pytest.mark.parametrize('mount', MOUNTS)
def test_h_H_R_and_S_equal_the_textbook(mount):
    # What an update and the association gate share: h, H, R (with the map's share and a
    # cross term), P H^T, S, S^-1 and y^T S^-1 y.
    for _ in range(100):
        s, P = _state(), _covariance()
        landmark = _landmark(s)
        sensor = np.array([[RNG.uniform(1e-4, 1e-2), 1e-5], [1e-5, RNG.uniform(1e-6, 1e-4)]])
        map_var, scale = float(RNG.choice([0.0, 1e-4])), float(RNG.choice([1.0, 2.5]))
        (r, bearing), rows, pht, (rr, rb), (s00, s01, s11) = kernel.innovation_terms(
            s, _packed(P), *landmark, mount, sensor[0, 0], sensor[0, 1], sensor[1, 1],
            map_var, scale)
        # The gate's short form: the same h and S, to the bit.
        assert kernel.innovation_terms(
            s, _packed(P), *landmark, mount, sensor[0, 0], sensor[0, 1], sensor[1, 1],
            map_var, scale, full=False) == ((r, bearing), (s00, s01, s11))
        h, H = models.observe_with_jacobian(np.array(s), landmark, mount)
        _equal(r, h[0])
        _equal_angle(bearing, h[1])
        _equal(rows, H[:, :3].ravel())
        assert not H[:, BIAS].any() and not H[:, WANDER].any()
        R = scale * models.observation_noise(h[0], sensor, map_var)
        _equal([rr, rb], np.diag(R))
        S = innovation_covariance(H, P, R)
        _equal([[s00, s01], [s01, s11]], S)
        _equal(np.reshape(pht, (2, 5)).T, P @ H.T)
        y = RNG.normal(size=2) * [0.1, 0.02]
        _equal(kernel.mahalanobis_sq(*y, *kernel.inverse(s00, s01, s11)),
               normalised_innovation_sq(y, S))


def test_the_mahalanobis_table_is_the_distance_of_every_pair():
    from gyro_ekf.core.angles import wrap_scalar
    # Bearings on both sides of +-pi among them, where the difference wraps.
    observations = [[float(r), float(b)] for r, b in zip(RNG.uniform(0.5, 20.0, 7),
                                                         RNG.uniform(-math.pi, math.pi, 7))]
    observations += [[5.0, math.pi - 1e-3], [5.0, -math.pi + 1e-3]]
    predictions = [(float(r), float(b), float(i00), 0.3 * float(i01), float(i11))
                   for r, b, i00, i01, i11 in zip(
                       RNG.uniform(0.5, 20.0, 9), RNG.uniform(-math.pi, math.pi, 9),
                       RNG.uniform(1.0, 400.0, 9), RNG.uniform(-1.0, 1.0, 9),
                       RNG.uniform(100.0, 1e4, 9))]
    predictions.append((5.0, -math.pi + 2e-3, 100.0, 0.0, 1e4))
    table = kernel.mahalanobis_table(observations, predictions)
    assert table == [[kernel.mahalanobis_sq(r - h0, wrap_scalar(b - h1), i00, i01, i11)
                      for h0, h1, i00, i01, i11 in predictions] for r, b in observations]
    # Across +-pi the bearings are 3e-3 rad apart, not 2 pi.
    assert table[-2][-1] == pytest.approx(1e4 * (math.pi - 1e-3 - (-math.pi + 2e-3)
                                                 - 2.0 * math.pi) ** 2)


@pytest.mark.parametrize('mount', MOUNTS)
@pytest.mark.parametrize('noise_scale', [1.0, 3.5])
def test_update_equals_the_textbook(mount, noise_scale):
    for _ in range(100):
        s, P = _state(), _covariance()
        landmark = _landmark(s)
        z = models.observe(np.array(s), landmark, mount) + RNG.normal(size=2) * [0.05, 0.01]
        args = (float(z[0]), float(z[1]), *landmark, mount, RNG.uniform(1e-4, 1e-2),
                RNG.uniform(1e-6, 1e-4), float(RNG.choice([0.0, 1e-4])), noise_scale)
        fast = kernel.update(list(s), _packed(P), *args)
        slow = Textbook.update(list(s), _packed(P), *args)
        _equal_states(fast[0], slow[0])
        _equal(_full(fast[1]), _full(slow[1]))
        # y = z - h(x) cancels (both ~10 m, apart by cm): equal to 1e-12 of the range, and
        # the NIS, quadratic in y, to the same absolute error over sqrt(S), ~1e-9 of itself.
        assert abs(fast[2][0] - slow[2][0]) <= TOL * z[0]
        _equal_angle(fast[2][1], slow[2][1])
        _equal(fast[3], slow[3])
        _equal(fast[4], slow[4])
        assert fast[5] == pytest.approx(slow[5], rel=1e-9)


def test_zero_rate_update_equals_the_textbook():
    for _ in range(200):
        s, P = _state(), _covariance()
        rate, variance = s[BIAS] + s[WANDER] + RNG.normal() * 0.01, RNG.uniform(1e-6, 1e-3)
        fast_s, fast_p, fast_nis = kernel.update_bias(list(s), _packed(P), rate, variance)
        slow_s, slow_p, slow_nis = Textbook.update_bias(list(s), _packed(P), rate, variance)
        _equal_states(fast_s, slow_s)
        _equal(_full(fast_p), _full(slow_p))
        _equal(fast_nis, slow_nis)


def test_both_refuse_an_innovation_covariance_that_is_not_positive_definite():
    s, P = _state(), -_covariance()
    landmark = _landmark(s)
    args = (5.0, 0.1, *landmark, LidarMount(), 0.0, 0.0, 0.0, 1.0)
    for maths in (kernel, Textbook):
        with pytest.raises(CoreError, match='not positive definite'):
            maths.update(list(s), _packed(P), *args)
        with pytest.raises(CoreError, match='not positive'):
            maths.update_bias(list(s), _packed(P), 0.0, 0.0)


def test_innovation_wraps_the_bearing():
    y = innovation([5.0, math.pi - 0.01], np.array([4.0, -math.pi + 0.01]))
    _equal(y, [1.0, -0.02])


def test_a_filter_run_on_the_kernel_equals_one_on_the_textbook():
    # A wander modelled (from the start, as configured), so its rows take part.
    config = EkfConfig(landmark_sigma_m=0.01, gyro_wander_rad_s=0.001, gyro_wander_tau_s=1.5)
    mount = MOUNTS[3]
    fast = GyroBiasEkf(config, pose=[1.0, -2.0, 0.3], bias_rad_s=0.01)
    slow = GyroBiasEkf(config, pose=[1.0, -2.0, 0.3], bias_rad_s=0.01, textbook=True)
    assert fast._maths is kernel and slow._maths is Textbook
    landmarks = RNG.uniform(-20, 20, size=(10, 2))
    for k in range(3000):
        speed, rate = 0.5 + 0.3 * math.sin(0.01 * k), 0.3 * math.sin(0.003 * k) + 0.01
        hold = 1000 <= k < 1200
        variances = (1e-3, 1e-4) if k % 7 == 0 else (None, None)
        for ekf in (fast, slow):
            ekf.predict(0.0 if hold else speed, rate, 0.005, *variances, hold_position=hold)
        if hold and k % 10 == 0:
            nis = [ekf.update_zero_rate(rate, 1e-4) for ekf in (fast, slow)]
            assert nis[0] == pytest.approx(nis[1], rel=1e-9)
        if k % 40 == 0:
            truth = fast.x
            for landmark in landmarks[:4]:
                z = models.observe(truth, landmark, mount) + RNG.normal(size=2) * [0.03, 0.01]
                nis = [ekf.update(z, landmark, mount, 1.0 + (k % 3)) for ekf in (fast, slow)]
                assert nis[0] == pytest.approx(nis[1], rel=1e-9)
    # Rounding differences do not grow: the two runs agree to about 1e-12 of each value.
    np.testing.assert_allclose(fast.x, slow.x, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(fast.P, slow.P, rtol=1e-9, atol=1e-12 * np.abs(slow.P).max())
    for name in ('x_prior', 'P_prior', 'y', 'S', 'K'):
        np.testing.assert_allclose(getattr(fast, name), getattr(slow, name), rtol=1e-9,
                                   atol=1e-12 * np.abs(getattr(slow, name)).max())


def test_without_a_wander_the_first_four_states_are_the_reports_filter():
    # The fifth state is the wander: with it and its covariance 0 and no wander modelled,
    # predict, update and zero-rate update give the four-state filter's numbers exactly
    # (the report's model: models.py on a four-entry state) and leave c and its row at 0.
    from gyro_ekf.core.ekf import _correct
    s4, P4 = _state()[:4], _covariance()[:4, :4]
    s5, P5 = s4 + [0.0], np.zeros((5, 5))
    P5[:4, :4] = P4
    speed, rate, dt = 0.7, 0.2, 0.01
    J4, Q4 = (models.process_jacobian(np.array(s4), speed, dt),
              models.process_noise(np.array(s4), dt, 0.05, 0.004, 0.003, 1e-5))
    x4 = models.predict_state(np.array(s4), speed, rate, dt)
    p4 = J4 @ P4 @ J4.T + Q4
    fast_s, fast_p = kernel.predict(s5, _packed(P5), speed, rate, dt, 0.05 ** 2, 0.004 ** 2,
                                    0.003 ** 2, 1e-10, False, 0.0, 2.0)
    _equal_states(fast_s[:4], x4)
    _equal(_full(fast_p)[:4, :4], p4)
    assert fast_s[WANDER] == 0.0 and not _full(fast_p)[WANDER].any()
    landmark = _landmark(s4)
    R = np.diag([1e-3, 1e-5])
    z_hat, H = models.observe_with_jacobian(np.array(s4), landmark, MOUNTS[1])
    z = z_hat + [0.05, -0.01]
    a4, b4, _, _ = _correct(np.array(s4), P4, innovation(z, z_hat), H, R)
    fast = kernel.update(s5, _packed(P5), float(z[0]), float(z[1]), *landmark, MOUNTS[1],
                         1e-3, 1e-5, 0.0, 1.0)
    _equal_states(fast[0][:4], a4)
    _equal(_full(fast[1])[:4, :4], b4)
    assert fast[0][WANDER] == 0.0 and not _full(fast[1])[WANDER].any()
