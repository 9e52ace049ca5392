"""Chi-square gated nearest-neighbour association with ambiguity and duplicate rejection."""

from __future__ import annotations

import math

import numpy as np
import pytest

from gyro_ekf.core.association import (AssociationOutcome, associate, gate_threshold,
                                       mahalanobis_sq)
from gyro_ekf.core.errors import CoreError
from gyro_ekf.core.models import observe, observe_with_jacobian
from gyro_ekf.core.types import LidarMount

MOUNT = LidarMount(0.46, 0.0, 0.0)
STATE = np.array([1.0, -2.0, 0.7, 0.01])
P = np.diag([0.05 ** 2, 0.05 ** 2, math.radians(1.0) ** 2, 1e-6])
R = np.diag([0.1 ** 2, math.radians(1.0) ** 2])
LANDMARKS = np.array([[5.0, 2.0], [2.0, 4.0], [-1.0, 6.0], [8.0, -3.0]])


def _z(landmarks):
    return observe(STATE, np.asarray(landmarks, dtype=float), MOUNT)


def test_gate_threshold_closed_form():
    assert gate_threshold(0.99) == pytest.approx(9.2103, abs=1e-4)
    assert gate_threshold(0.95) == pytest.approx(5.9915, abs=1e-4)
    for bad in (0.0, 1.0, -0.1, 1.5):
        with pytest.raises(CoreError, match='gate probability'):
            gate_threshold(bad)


def test_exact_observations_all_match():
    z = _z(LANDMARKS[[2, 0, 3]])
    result = associate(z, STATE, P, R, LANDMARKS, MOUNT, 0.99)
    assert result.matched_count == 3 and len(result) == 3
    assert [a.landmark_index for a in result.associations] == [2, 0, 3]
    assert all(a.mahalanobis_sq == pytest.approx(0.0, abs=1e-12) for a in result.associations)
    np.testing.assert_array_equal(result.matched_pairs(), [[0, 2], [1, 0], [2, 3]])
    assert result.gate_threshold == pytest.approx(-2.0 * math.log(0.01))


def test_mahalanobis_matches_a_direct_computation():
    rng = np.random.default_rng(3)
    z = _z(LANDMARKS) + rng.normal(0.0, [0.1, 0.02], size=(4, 2))
    d2 = mahalanobis_sq(z, STATE, P, R, LANDMARKS, MOUNT)
    eps = 1e-6
    for i in range(4):
        for j in range(4):
            # H by finite differences of observe, S and the innovation by hand.
            H = np.zeros((2, 4))
            for col in range(4):
                step = np.zeros(4)
                step[col] = eps
                diff = _z_at(STATE + step, LANDMARKS[j]) - _z_at(STATE - step, LANDMARKS[j])
                H[:, col] = diff / (2 * eps)
            S = H @ P @ H.T + R
            y = z[i] - _z_at(STATE, LANDMARKS[j])
            y[1] = (y[1] + math.pi) % (2 * math.pi) - math.pi
            assert d2[i, j] == pytest.approx(y @ np.linalg.solve(S, y), rel=1e-5)


def _z_at(state, landmark):
    return observe(state, landmark, MOUNT)


def test_bearing_innovation_is_wrapped():
    # A landmark straight behind the sensor: bearing near +-pi on either side.
    state = np.array([0.0, 0.0, 0.0, 0.0])
    landmark = np.array([[-5.0, 0.0]])
    z = np.array([[5.46, math.pi - 1e-3]])
    h = observe(state, landmark, MOUNT)
    assert h[0, 1] == pytest.approx(-math.pi)
    result = associate(z, state, P, R, landmark, MOUNT)
    assert result.associations[0].outcome is AssociationOutcome.MATCHED


def test_outside_gate_is_unmatched():
    z = _z(LANDMARKS[[0]]) + np.array([[1.5, 0.0]])     # 15 sigma in range
    result = associate(z, STATE, P, R, LANDMARKS, MOUNT)
    item = result.associations[0]
    assert item.outcome is AssociationOutcome.UNMATCHED
    assert item.landmark_index == -1
    assert item.mahalanobis_sq > result.gate_threshold
    assert result.unmatched_count == 1 and result.matched_count == 0


def test_gate_edge_follows_the_probability():
    # Pure range offset: d2 = dr^2 / S_rr, so choose dr to land between two gates.
    S_rr = 1.0 / mahalanobis_sq(_z(LANDMARKS[[0]]) + [[1.0, 0.0]], STATE, P, R,
                                LANDMARKS[[0]], MOUNT)[0, 0]
    dr = math.sqrt(8.0 * S_rr)                        # d2 = 8: inside 0.99, outside 0.95
    z = _z(LANDMARKS[[0]]) + [[dr, 0.0]]
    assert associate(z, STATE, P, R, LANDMARKS[[0]], MOUNT, 0.99).matched_count == 1
    assert associate(z, STATE, P, R, LANDMARKS[[0]], MOUNT, 0.95).unmatched_count == 1


def test_two_landmarks_in_gate_is_ambiguous():
    close_pair = np.array([[5.0, 2.0], [5.0, 2.15], [-1.0, 6.0]])
    z = _z([[5.0, 2.075], [-1.0, 6.0]])
    result = associate(z, STATE, P, R, close_pair, MOUNT)
    assert result.associations[0].outcome is AssociationOutcome.AMBIGUOUS
    assert result.associations[0].landmark_index == -1
    assert result.associations[1].outcome is AssociationOutcome.MATCHED
    assert result.associations[1].landmark_index == 2
    assert (result.ambiguous_count, result.matched_count) == (1, 1)


def test_two_detections_on_one_landmark_are_duplicates():
    z = np.vstack([_z(LANDMARKS[[1]]), _z(LANDMARKS[[1]]) + [[0.05, 0.005]],
                   _z(LANDMARKS[[3]])])
    result = associate(z, STATE, P, R, LANDMARKS, MOUNT)
    outcomes = [a.outcome for a in result.associations]
    assert outcomes == [AssociationOutcome.DUPLICATE, AssociationOutcome.DUPLICATE,
                        AssociationOutcome.MATCHED]
    assert result.duplicate_count == 2 and result.matched_count == 1
    assert result.matched_pairs().tolist() == [[2, 3]]


def test_counts_add_up_on_a_mixed_scan():
    landmarks = np.vstack([LANDMARKS, [[5.0, 2.15]]])   # 0 and 4 are close together
    z = np.vstack([
        _z([[5.0, 2.075]]),                  # between 0 and 4: ambiguous
        _z(landmarks[[1]]),                  # matched
        _z(landmarks[[3]]),                  # duplicate (with the next)
        _z(landmarks[[3]]) + [[0.03, 0.0]],  # duplicate
        _z([[20.0, 20.0]]),                  # unmatched
    ])
    result = associate(z, STATE, P, R, landmarks, MOUNT)
    counts = {o: result.count(o) for o in AssociationOutcome}
    assert counts == {AssociationOutcome.MATCHED: 1, AssociationOutcome.UNMATCHED: 1,
                      AssociationOutcome.AMBIGUOUS: 1, AssociationOutcome.DUPLICATE: 2}
    assert result.mahalanobis_sq.shape == (5, 5)


def test_empty_inputs():
    result = associate(np.zeros((0, 2)), STATE, P, R, LANDMARKS, MOUNT)
    assert len(result) == 0 and result.mahalanobis_sq.shape == (0, 4)
    result = associate(_z(LANDMARKS[:2]), STATE, P, R, np.zeros((0, 2)), MOUNT)
    assert result.unmatched_count == 2
    assert all(math.isinf(a.mahalanobis_sq) for a in result.associations)


def test_bad_covariance_is_refused():
    with pytest.raises(CoreError, match='positive definite'):
        associate(_z(LANDMARKS[:1]), STATE, np.zeros((4, 4)), np.zeros((2, 2)), LANDMARKS,
                  MOUNT)


def test_distance_association_pairs_clear_nearest_landmarks_only():
    from gyro_ekf.core.association import associate_by_distance
    landmarks = np.array([[5.0, 0.0], [5.0, 3.0], [0.0, 8.0], [0.0, 8.6]])
    state = np.array([0.0, 0.0, 0.0, 0.0])
    points = np.array([[5.6, 0.0],    # 0.6 m off landmark 0, landmark 1 is 3 m away: match
                       [0.0, 8.3],    # halfway between landmarks 2 and 3: ambiguous
                       [9.0, 9.0],    # nothing within 1 m: unmatched
                       [5.2, 3.3],    # clear nearest is landmark 1 ...
                       [4.8, 2.7]])   # ... and so is this one: both duplicates
    z = np.column_stack([np.hypot(points[:, 0], points[:, 1]),
                         np.arctan2(points[:, 1], points[:, 0])])
    P = np.diag([1e-6, 1e-6, 1e-8, 1e-8])
    R = np.diag([0.02 ** 2, 0.0035 ** 2])
    result = associate_by_distance(z, state, P, R, landmarks, max_distance_m=1.0, ratio=0.3)
    outcomes = [a.outcome for a in result.associations]
    assert outcomes == [AssociationOutcome.MATCHED, AssociationOutcome.AMBIGUOUS,
                        AssociationOutcome.UNMATCHED, AssociationOutcome.DUPLICATE,
                        AssociationOutcome.DUPLICATE]
    assert result.associations[0].landmark_index == 0
    # The same detections all fall outside the tight chi-square gate.
    gated = associate(z, state, P, R, landmarks)
    assert gated.count(AssociationOutcome.MATCHED) == 0


@pytest.mark.parametrize('seed', range(4))
def test_small_scans_in_plain_floats_match_the_numpy_path(seed, monkeypatch):
    from gyro_ekf.core import association
    rng = np.random.default_rng(seed)
    for _ in range(200):
        landmarks = rng.uniform(-10.0, 10.0, size=(rng.integers(1, 8), 2))
        # The filter's five states (bias and wander): h does not depend on the last two.
        state = np.r_[rng.uniform(-3.0, 3.0, 2), rng.uniform(-math.pi, math.pi), 0.01, 0.001]
        root = rng.normal(size=(5, 5)) * rng.uniform(0.001, 0.3)
        cov = root @ root.T + 1e-6 * np.eye(5)
        mount = LidarMount(rng.uniform(-0.5, 0.5), rng.uniform(-0.2, 0.2),
                           float(rng.choice([0.0, math.pi, 0.3])))
        h = observe(state, landmarks, mount)
        z = h[rng.integers(0, len(landmarks), rng.integers(1, 8))]
        z = z + rng.normal(size=z.shape) * [0.05, 0.01]
        assert z.size // 2 * len(landmarks) <= association.SCALAR_PAIRS_MAX
        map_var = float(rng.choice([0.0, 0.01 ** 2, 0.1 ** 2]))
        small = associate(z.tolist(), state, cov, R, landmarks, mount, 0.99, map_var)
        # The driver's entry: the filter's packed row and plain lists, the same to the bit.
        row = np.r_[state, cov[np.triu_indices(5)]].tolist()
        packed = association.associate_packed(z.tolist(), row, R, landmarks.tolist(), mount,
                                              0.99, map_var)
        np.testing.assert_array_equal(packed.mahalanobis_sq, small.mahalanobis_sq)
        assert packed.associations == small.associations
        monkeypatch.setattr(association, 'SCALAR_PAIRS_MAX', 0)
        large = associate(z, state, cov, R, landmarks, mount, 0.99, map_var)
        large_packed = association.associate_packed(z.tolist(), row, R, landmarks.tolist(),
                                                    mount, 0.99, map_var)
        np.testing.assert_array_equal(large_packed.mahalanobis_sq, large.mahalanobis_sq)
        monkeypatch.undo()
        np.testing.assert_allclose(small.mahalanobis_sq, large.mahalanobis_sq, rtol=1e-9,
                                   atol=1e-9)
        assert [(a.landmark_index, a.outcome) for a in small.associations] == \
            [(a.landmark_index, a.outcome) for a in large.associations]


def test_map_uncertainty_widens_the_gate_by_range_and_bearing():
    # An isotropic map error of sigma adds sigma^2 to the range variance and
    # (sigma / range)^2 to the bearing variance: the same innovation counts for less.
    state = np.array([0.0, 0.0, 0.0, 0.0])
    landmarks = np.array([[4.0, 0.0]])
    z = np.array([[4.05, 0.01]])
    exact = mahalanobis_sq(z, state, P, R, landmarks)[0, 0]
    sigma = 0.03
    widened = mahalanobis_sq(z, state, P, R, landmarks, landmark_var_m2=sigma ** 2)[0, 0]
    h, H = observe_with_jacobian(state, landmarks, LidarMount())
    S = H[0] @ P @ H[0].T + R + np.diag([sigma ** 2, (sigma / 4.0) ** 2])
    y = z[0] - h[0]
    assert widened == pytest.approx(float(y @ np.linalg.solve(S, y)), rel=1e-12)
    assert widened < exact


def test_a_landmark_at_the_sensor_matches_nothing_in_either_path(monkeypatch):
    from gyro_ekf.core import association
    landmarks = np.array([[0.0, 0.0], [5.0, 0.0]])
    state = np.array([0.0, 0.0, 0.0, 0.0])
    z = np.array([[5.0, 0.0], [0.5, 0.1]])
    small = associate(z, state, P, R, landmarks, LidarMount(), 0.99)
    assert [a.landmark_index for a in small.associations] == [1, -1]
    assert math.isinf(small.mahalanobis_sq[0, 0])
    monkeypatch.setattr(association, 'SCALAR_PAIRS_MAX', 0)
    with np.errstate(divide='ignore', invalid='ignore'):
        large = associate(z, state, P, R, landmarks, LidarMount(), 0.99)
    assert [a.landmark_index for a in large.associations] == [1, -1]
