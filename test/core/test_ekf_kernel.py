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
from gyro_ekf.core.types import BIAS, YAW, LidarMount

RNG = np.random.default_rng(4010)
MOUNTS = [LidarMount(), LidarMount(0.46, 0.0, 0.0), LidarMount(0.4, -0.12, math.pi),
          LidarMount(0.2, 0.3, 0.7)]
TOL = 1e-12


def _state():
    # Yaw away from +-pi, so a rounding difference cannot wrap one side and not the other.
    return [RNG.uniform(-5, 5), RNG.uniform(-5, 5), RNG.uniform(-3.0, 3.0),
            RNG.uniform(-0.05, 0.05)]


def _covariance():
    """A random positive definite P with the scales of m, m, rad and rad/s."""
    root = RNG.normal(size=(4, 4)) @ np.diag([0.3, 0.3, 0.05, 0.005])
    return root.T @ root + np.diag([1e-6, 1e-6, 1e-8, 1e-10])


def _landmark(state):
    angle = RNG.uniform(-math.pi, math.pi)
    return (np.array(state[:2]) + RNG.uniform(1.0, 20.0) * np.array(
        [math.cos(angle), math.sin(angle)])).tolist()


def _equal(kernel_value, textbook_value):
    """Equal to 1e-12 of the value's own scale (relative, and absolute for entries near 0)."""
    a = np.asarray(kernel_value, dtype=np.float64)
    b = np.asarray(textbook_value, dtype=np.float64)
    np.testing.assert_allclose(a, b, rtol=TOL, atol=TOL * max(1.0e-30, np.max(np.abs(b))))


# Typical size of each state entry (m, m, rad, rad/s): 1e-12 of it is the tolerance.
STATE_SCALE = np.array([5.0, 5.0, math.pi, 0.05])


def _equal_angle(kernel_rad, textbook_rad):
    difference = math.remainder(kernel_rad - textbook_rad, 2 * math.pi)
    assert abs(difference) <= TOL * math.pi, (kernel_rad, textbook_rad)


def _equal_states(kernel_state, textbook_state):
    a, b = np.array(kernel_state), np.array(textbook_state)
    _equal_angle(a[YAW], b[YAW])
    a[YAW] = b[YAW]
    assert np.all(np.abs(a - b) <= TOL * STATE_SCALE), (a, b)


@pytest.mark.parametrize('hold_position', [False, True])
def test_predict_equals_the_textbook(hold_position):
    for _ in range(200):
        s, P = _state(), _covariance()
        args = (RNG.uniform(-1.0, 2.0), RNG.uniform(-1.0, 1.0), RNG.uniform(1e-4, 0.2),
                RNG.uniform(0.0, 0.1), RNG.uniform(0.0, 1e-3), RNG.uniform(0.0, 1e-3),
                RNG.uniform(0.0, 1e-8), hold_position)
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
        h, H = models.observe_with_jacobian(np.array(s), landmark, mount)
        _equal(r, h[0])
        _equal_angle(bearing, h[1])
        _equal(rows, H[:, :3].ravel())
        assert not H[:, BIAS].any()
        R = scale * models.observation_noise(h[0], sensor, map_var)
        _equal([rr, rb], np.diag(R))
        S = innovation_covariance(H, P, R)
        _equal([[s00, s01], [s01, s11]], S)
        _equal(np.reshape(pht, (2, 4)).T, P @ H.T)
        y = RNG.normal(size=2) * [0.1, 0.02]
        _equal(kernel.mahalanobis_sq(*y, *kernel.inverse(s00, s01, s11)),
               normalised_innovation_sq(y, S))


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
        rate, variance = s[BIAS] + RNG.normal() * 0.01, RNG.uniform(1e-6, 1e-3)
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
    config = EkfConfig(landmark_sigma_m=0.01)
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


def test_the_textbook_update_takes_a_longer_state():
    # An uncorrelated fifth state the observation ignores: the first four entries update as
    # without it, and the fifth keeps its value and variance.
    from gyro_ekf.core.ekf import _correct
    s, P = _state(), _covariance()
    landmark = _landmark(s)
    x4 = np.array(s)
    x5, P5 = np.r_[x4, 0.4], np.zeros((5, 5))
    P5[:4, :4], P5[4, 4] = P, 0.02
    R = np.diag([1e-3, 1e-5])
    results = []
    for x, cov in ((x4, P), (x5, P5)):
        z_hat, H = models.observe_with_jacobian(x, landmark, MOUNTS[1])
        y = innovation(z_hat + [0.05, -0.01], z_hat)
        results.append(_correct(x, cov, y, H, R))
    (a4, P4, S4, K4), (a5, Q5, S5, K5) = results
    _equal(a5[:4], a4)
    _equal(Q5[:4, :4], P4)
    assert a5[4] == 0.4 and Q5[4, 4] == 0.02 and not Q5[4, :4].any()
    _equal(S5, S4)
    _equal(K5[:4], K4)
