"""Metrics on hand-made cases whose answers are known in closed form."""

from __future__ import annotations

import math

import numpy as np
import pytest

from gyro_ekf.analysis import metrics


def test_chi_square_bands_are_the_two_sided_95_percent_quantiles():
    assert metrics.chi_square_band(2) == pytest.approx((0.050636, 7.377759), rel=1e-5)
    assert metrics.chi_square_band(3) == pytest.approx((0.215795, 9.348404), rel=1e-5)


@pytest.mark.parametrize('dof', [1, 2, 3, 4, 5])
def test_chi_square_quantiles_match_scipy(dof):
    from scipy.stats import chi2
    for p in (0.025, 0.5, 0.95, 0.975, 0.999):
        assert metrics.chi_square_quantile(p, dof) == pytest.approx(chi2.ppf(p, dof), rel=1e-9)


def test_known_offset_gives_known_rmse_max_and_nees():
    stamps = np.arange(0.0, 10.0, 0.01)
    truth = np.column_stack([np.cos(stamps), np.sin(stamps), stamps % 6.0 - 3.0])
    state = np.column_stack([truth[:, 0] + 0.03, truth[:, 1] + 0.04,
                             truth[:, 2] + 0.01, np.zeros(stamps.size)])
    covariance = np.tile(np.diag([1e-4, 1e-4, 1e-4, 1e-6]), (stamps.size, 1, 1))
    comparison = metrics.compare_with_truth(stamps, state, covariance, stamps, truth)
    assert metrics.rmse(comparison.errors[:, :2]) == pytest.approx(0.05)
    assert comparison.position_error_m.max() == pytest.approx(0.05)
    assert metrics.rmse(comparison.errors[:, 2]) == pytest.approx(0.01)
    # (0.03^2 + 0.04^2 + 0.01^2) / 1e-4 = 26
    assert comparison.nees == pytest.approx(np.full(stamps.size, 26.0))
    assert metrics.share_inside(comparison.nees, *metrics.chi_square_band(3)) == 0.0


def test_consistent_gaussian_errors_fill_the_band():
    rng = np.random.default_rng(4)
    n = 20_000
    sigma = np.array([0.02, 0.01, 0.005])
    errors = rng.normal(size=(n, 3)) * sigma
    covariance = np.tile(np.diag(sigma ** 2), (n, 1, 1))
    nees = metrics.normalized_squared_error(errors, covariance)
    assert nees.mean() == pytest.approx(3.0, rel=0.03)
    inside = metrics.share_inside(nees, *metrics.chi_square_band(3))
    assert inside == pytest.approx(0.95, abs=0.01)
    # A filter claiming twice the sigma is conservative: too many samples below the band
    # (about 84 % inside: the 0.9 bar of issue 5 rejects it).
    conservative = metrics.normalized_squared_error(errors, 4.0 * covariance)
    assert conservative.mean() == pytest.approx(0.75, rel=0.03)
    assert metrics.share_inside(conservative, *metrics.chi_square_band(3)) < 0.87


def test_nees_of_a_singular_covariance_uses_the_pseudo_inverse():
    P = np.zeros((2, 3, 3))
    P[:, 0, 0] = 4.0
    errors = np.array([[2.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    nees = metrics.normalized_squared_error(errors, P)
    assert nees[0] == pytest.approx(1.0)
    assert math.isinf(nees[1])


def test_each_nees_sample_is_judged_in_the_band_of_its_covariance_rank():
    rng = np.random.default_rng(7)
    n = 20_000
    # A filter sure of the position (held exactly) and unsure of the heading, consistent:
    # its NEES is chi-square with 1 dof, which the 3-dof band would call too small.
    sigma = 0.01
    errors = np.zeros((n, 3))
    errors[:, 2] = rng.normal(size=n) * sigma
    P = np.zeros((n, 3, 3))
    P[:, 2, 2] = sigma ** 2
    nees = metrics.normalized_squared_error(errors, P)
    dof = metrics.covariance_rank(P)
    assert set(dof.tolist()) == {1}
    inside, below, above = metrics.nees_band_outcome(nees, dof)
    assert inside.mean() == pytest.approx(0.95, abs=0.01)
    assert below.mean() == pytest.approx(0.025, abs=0.005)
    assert metrics.share_inside(nees, *metrics.chi_square_band(3)) < 0.7
    # A pose claimed exact (P = 0): a zero error is the claim holding, any other is inf.
    exact = np.zeros((2, 3, 3))
    nees = metrics.normalized_squared_error(np.array([[0.0, 0.0, 0.0], [1e-3, 0.0, 0.0]]),
                                            exact)
    inside, below, above = metrics.nees_band_outcome(nees, metrics.covariance_rank(exact))
    assert inside.tolist() == [True, False] and above.tolist() == [False, True]
    # Full rank: the 3-dof band, as share_inside.
    full = np.tile(np.diag([4e-4, 1e-4, 2.5e-5]), (3, 1, 1))
    assert metrics.covariance_rank(full).tolist() == [3, 3, 3]
    nees = np.array([0.1, 3.0, 10.0])
    inside, below, above = metrics.nees_band_outcome(nees, metrics.covariance_rank(full))
    assert (inside.tolist(), below.tolist(), above.tolist()) == (
        [False, True, False], [True, False, False], [False, False, True])


def test_estimates_are_interpolated_to_truth_stamps_and_exact_on_shared_stamps():
    stamps = np.array([0.0, 0.1, 0.1, 0.2])
    state = np.array([[0.0, 0.0, math.pi - 0.05, 0.0], [1.0, 0.0, math.pi - 0.01, 0.0],
                      [2.0, 0.0, -math.pi + 0.01, 0.0], [3.0, 0.0, -math.pi + 0.05, 0.0]])
    covariance = np.array([np.eye(4) * v for v in (1.0, 2.0, 3.0, 4.0)])
    est, P, inside = metrics.interpolate_estimates(stamps, state, covariance,
                                                   np.array([0.1, 0.15, 0.3]))
    assert inside.tolist() == [True, True, False]
    assert est[0, 0] == 2.0                       # the last row at a shared stamp
    assert est[1, 0] == pytest.approx(2.5)
    assert abs(est[1, 2]) == pytest.approx(math.pi - 0.03)   # through pi, not through 0
    assert P[1, 0, 0] == pytest.approx(3.5)


def test_settling_time_is_the_last_stamp_outside_the_band():
    stamps = np.arange(10.0)
    assert metrics.settling_time(stamps, np.array([5, 3, 0, 2, 0, 0, 0, 0, 0, 0.5]), 1.0) \
        == 3.0
    assert metrics.settling_time(stamps, np.zeros(10), 1.0) == 0.0
    assert metrics.settling_time(stamps, np.r_[np.zeros(9), 2.0], 1.0) is None


def test_longest_gap_counts_from_the_start_and_to_the_end():
    assert metrics.longest_gap(np.array([5.0, 6.0, 7.5]), 0.0, 9.0) == (5.0, 0.0)
    assert metrics.longest_gap(np.array([1.0, 2.0]), 0.0, 10.0) == (8.0, 2.0)
    assert metrics.longest_gap(np.zeros(0), 0.0, 4.0) == (4.0, 0.0)


def test_dead_reckoning_follows_a_circle_and_removes_the_bias():
    stamps = np.arange(0.0, 2.0 * math.pi + 1e-9, 0.001)   # one turn at 1 rad/s
    bias = 0.02
    poses = metrics.dead_reckon(stamps, np.full(stamps.size, 1.0 + bias), stamps,
                                np.ones(stamps.size), np.array([0.0, 0.0, 0.0]), bias)
    assert poses[-1, :2] == pytest.approx([0.0, 0.0], abs=0.01)
    quarter = np.searchsorted(stamps, math.pi / 2)
    assert poses[quarter, :2] == pytest.approx([1.0, 1.0], abs=0.01)
    straight = metrics.dead_reckon(stamps, np.full(stamps.size, bias), stamps,
                                   np.full(stamps.size, 2.0), np.array([1.0, 2.0, 0.5]), bias)
    assert straight[-1] == pytest.approx(
        [1.0 + 2.0 * stamps[-1] * math.cos(0.5), 2.0 + 2.0 * stamps[-1] * math.sin(0.5), 0.5])


def test_dead_reckoning_holds_inputs_between_samples():
    poses = metrics.dead_reckon(np.array([0.0, 1.0, 2.0]), np.zeros(3), np.array([0.5]),
                                np.array([1.0]), np.zeros(3))
    # No speed before its first sample at 0.5 s, then 1 m/s held.
    assert poses[:, 0] == pytest.approx([0.0, 0.5, 1.5])
