"""Nearest-neighbour data association of pole detections to a known landmark map.

For detection i with observation z_i = [range m, bearing rad] (sensor frame, ROS
convention, see ``models.points_to_range_bearing``) and landmark j, with the filter's own
h, H, R and S (``models.py``, ``ekf.py``)::

    h_j, H_j = observe_with_jacobian(x, l_j, mount)     expected observation, (2,), (2, n)
    R_j = observation_noise(range_j, R, s2)            R plus the map's uncertainty
    S_j = H_j P H_j^T + R_j                            innovation covariance, (2, 2)
    y_ij = z_i - h_j, bearing wrapped                  innovation, (2,)
    d2_ij = y_ij^T S_j^-1 y_ij                         squared Mahalanobis distance

(s2: variance of a landmark's position along any axis).

Landmark j lies inside detection i's gate when d2_ij <= g, where g is the chi-square
quantile with 2 degrees of freedom at the gate probability p; for 2 dof it has the closed
form g = -2 ln(1 - p) (9.2103 at p = 0.99), so no scipy is needed.

Outcomes, per detection:

* UNMATCHED: no landmark inside the gate.
* AMBIGUOUS: two or more landmarks inside the gate; a wrong pairing would corrupt the
  filter more than a skipped one helps, so it is refused.
* DUPLICATE: exactly one landmark inside the gate, but that landmark is also inside the
  gate of another detection of the same scan (a pole seen twice, or a clutter return next
  to it); all such detections are refused. AMBIGUOUS takes precedence over DUPLICATE.
* MATCHED: otherwise; paired with its one gated landmark.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from gyro_ekf.core import _ekf_kernel as kernel
from gyro_ekf.core.ekf import (innovation, innovation_covariance, normalised_innovation_sq,
                               unpack_rows)
from gyro_ekf.core.errors import CoreError
from gyro_ekf.core.models import RANGE, observation_noise, observe_with_jacobian, sensor_to_map
from gyro_ekf.core.types import STATE_SIZE, FloatArray, LidarMount

_NO_MOUNT = LidarMount()


class AssociationOutcome(enum.IntEnum):
    """What happened to one detection."""

    MATCHED = 0
    UNMATCHED = 1
    AMBIGUOUS = 2
    DUPLICATE = 3


class Association(NamedTuple):
    """The association of one detection.

    A named tuple: one is made for every detection of every scan, and a frozen dataclass
    took four times as long to build.

    Attributes:
        detection_index: row of the detection in the z given to ``associate``.
        landmark_index: row of the matched landmark, or -1 unless MATCHED.
        outcome: what happened.
        mahalanobis_sq: squared Mahalanobis distance to the nearest landmark (the NIS of
            the pair when MATCHED); inf when the map is empty.
    """

    detection_index: int
    landmark_index: int
    outcome: AssociationOutcome
    mahalanobis_sq: float


@dataclass(frozen=True, slots=True)
class AssociationResult:
    """Associations of all detections of one scan.

    Attributes:
        associations: one per detection, in detection order.
        gate_threshold: squared Mahalanobis distance of the gate, -2 ln(1 - p).
        mahalanobis_sq: every detection against every landmark, shape (n, k).
    """

    associations: tuple[Association, ...]
    gate_threshold: float
    mahalanobis_sq: FloatArray

    def __len__(self) -> int:
        return len(self.associations)

    def count(self, outcome: AssociationOutcome) -> int:
        """Count the detections with the given outcome."""
        return sum(1 for item in self.associations if item.outcome is outcome)

    @property
    def matched_count(self) -> int:
        """Detections paired with a landmark."""
        return self.count(AssociationOutcome.MATCHED)

    @property
    def unmatched_count(self) -> int:
        """Detections with no landmark inside the gate."""
        return self.count(AssociationOutcome.UNMATCHED)

    @property
    def ambiguous_count(self) -> int:
        """Detections with two or more landmarks inside the gate."""
        return self.count(AssociationOutcome.AMBIGUOUS)

    @property
    def duplicate_count(self) -> int:
        """Detections refused because another detection gated the same landmark."""
        return self.count(AssociationOutcome.DUPLICATE)

    def matched(self) -> list[Association]:
        """Return the MATCHED associations, in detection order."""
        matched = AssociationOutcome.MATCHED  # once, not per association
        return [a for a in self.associations if a.outcome is matched]

    def matched_pairs(self) -> NDArray[np.int64]:
        """Return (detection index, landmark index) of every MATCHED detection, shape (m, 2)."""
        pairs = [(a.detection_index, a.landmark_index) for a in self.matched()]
        return np.array(pairs, dtype=np.int64).reshape(-1, 2)


def gate_threshold(gate_probability: float) -> float:
    """Chi-square quantile with 2 dof: -2 ln(1 - p).

    Raises:
        CoreError: p is not inside (0, 1).
    """
    if not 0.0 < gate_probability < 1.0:
        raise CoreError(f'gate probability {gate_probability} must lie strictly between 0 '
                        'and 1')
    return -2.0 * math.log1p(-gate_probability)


def mahalanobis_sq(z: FloatArray, state: FloatArray, P: FloatArray, R: FloatArray,
                   landmarks_xy_m: FloatArray, mount: LidarMount = _NO_MOUNT,
                   landmark_var_m2: float = 0.0) -> FloatArray:
    """Squared Mahalanobis distance of every detection to every landmark.

    Args:
        z: observations, shape (n, 2): range m, bearing rad (ROS convention).
        state: platform state [x m, y m, yaw rad, bias rad/s], shape (4,).
        P: state covariance, shape (4, 4).
        R: observation noise covariance, shape (2, 2), [m^2, rad^2].
        landmarks_xy_m: landmark positions in the map frame, shape (k, 2), m.
        mount: the LiDAR's pose on the platform.
        landmark_var_m2: variance of each landmark's map position along any axis, m^2
            (``observation_noise`` adds it to R).

    Returns:
        d2, shape (n, k).
    """
    z = np.asarray(z, dtype=np.float64).reshape(-1, 2)
    landmarks = np.asarray(landmarks_xy_m, dtype=np.float64).reshape(-1, 2)
    if landmarks.shape[0] == 0 or z.shape[0] == 0:
        return np.zeros((z.shape[0], landmarks.shape[0]))
    h, H = observe_with_jacobian(state, landmarks, mount)           # (k, 2), (k, 2, n)
    S = innovation_covariance(H, np.asarray(P, dtype=np.float64),
                              observation_noise(h[:, RANGE], R, landmark_var_m2))
    # A landmark at the sensor has no bearing (NaN in H): it must never be anyone's nearest.
    at_sensor = ~np.isfinite(S).all(axis=(1, 2))
    S[at_sensor] = np.eye(2)
    if not np.all(np.linalg.eigvalsh(S) > 0.0):
        raise CoreError('mahalanobis_sq: innovation covariance is not positive definite; '
                        'check P and R')
    d2 = normalised_innovation_sq(innovation(z[:, None, :], h[None, :, :]), S[None])  # (n, k)
    d2[:, at_sensor] = np.inf
    return d2


def associate(z: FloatArray, state: FloatArray, P: FloatArray, R: FloatArray,
              landmarks_xy_m: FloatArray, mount: LidarMount = _NO_MOUNT,
              gate_probability: float = 0.99, landmark_var_m2: float = 0.0
              ) -> AssociationResult:
    """Associate the detections of one scan with the map.

    Args:
        z: observations, shape (n, 2): range m, bearing rad (ROS convention, 0 = forward).
        state: platform state [x m, y m, yaw rad, bias rad/s (, wander rad/s)], shape (4,)
            or (5,): an estimate's four entries, or the filter's five.
        P: state covariance, shape (4, 4) or (5, 5).
        R: observation noise covariance, shape (2, 2), [m^2, rad^2].
        landmarks_xy_m: landmark positions in the map frame, shape (k, 2), m.
        mount: the LiDAR's pose on the platform.
        gate_probability: probability mass of the chi-square (2 dof) gate.
        landmark_var_m2: variance of each landmark's map position along any axis, m^2.

    Returns:
        One association per detection, with counts.

    Raises:
        CoreError: gate probability outside (0, 1), or S not positive definite.
    """
    threshold = gate_threshold(gate_probability)
    z = np.asarray(z, dtype=np.float64).reshape(-1, 2)
    landmarks = np.asarray(landmarks_xy_m, dtype=np.float64).reshape(-1, 2)
    if 0 < z.shape[0] * landmarks.shape[0] <= SCALAR_PAIRS_MAX:
        state = np.asarray(state, dtype=np.float64).ravel()
        P = np.asarray(P, dtype=np.float64)
        if state.size < STATE_SIZE:
            # An estimate without the wander: h does not depend on it, so a wander of 0
            # with no variance changes nothing but the kernel's layout.
            full = np.zeros((STATE_SIZE, STATE_SIZE))
            full[:state.size, :state.size] = P
            state, P = np.r_[state, np.zeros(STATE_SIZE - state.size)], full
        row = np.concatenate([state, P[_UPPER_TRIANGLE]]).tolist()
        return _associate_scalar(z.tolist(), row, R, landmarks.tolist(), mount, threshold,
                                 landmark_var_m2)
    d2 = mahalanobis_sq(z, state, P, R, landmarks, mount, landmark_var_m2)
    n, k = d2.shape
    if k == 0:
        return AssociationResult(
            associations=tuple(Association(i, -1, AssociationOutcome.UNMATCHED, math.inf)
                               for i in range(n)),
            gate_threshold=threshold, mahalanobis_sq=d2)
    inside = d2 <= threshold                                   # (n, k)
    gated_landmarks = inside.sum(axis=1)                       # per detection
    gating_detections = inside.sum(axis=0)                     # per landmark
    nearest = np.argmin(d2, axis=1)
    nearest_d2 = d2[np.arange(n), nearest]
    outcome = np.full(n, AssociationOutcome.UNMATCHED, dtype=np.int64)
    single = gated_landmarks == 1
    contested = single & (gating_detections[nearest] > 1)
    outcome[single] = AssociationOutcome.MATCHED
    outcome[contested] = AssociationOutcome.DUPLICATE
    outcome[gated_landmarks > 1] = AssociationOutcome.AMBIGUOUS
    landmark = np.where(outcome == AssociationOutcome.MATCHED, nearest, -1)
    return AssociationResult(associations=_associations(landmark, outcome, nearest_d2),
                             gate_threshold=threshold, mahalanobis_sq=d2)


_OUTCOMES = tuple(AssociationOutcome)
# The members as module globals: in Python 3.11 a class attribute (AssociationOutcome.X) is
# looked up in full every time, a module global is cached. The scalar path runs per detection.
_MATCHED, _UNMATCHED = AssociationOutcome.MATCHED, AssociationOutcome.UNMATCHED
_AMBIGUOUS, _DUPLICATE = AssociationOutcome.AMBIGUOUS, AssociationOutcome.DUPLICATE


_UPPER_TRIANGLE = np.triu_indices(STATE_SIZE)
"""P's upper triangle row by row: the kernel's packed covariance."""

SCALAR_PAIRS_MAX = 64
"""Up to this many detection-landmark pairs, ``associate`` works in plain floats.

A scan of a small map (the 2016 trip: 4 detections, 5 poles) costs numpy more in call
overhead than in arithmetic; the two paths compute the same quantities to rounding (tests
compare them) and a given input always takes the same path, so live and offline runs agree
to the bit.
"""


def associate_packed(z: list[list[float]], packed_row: list[float], R: FloatArray,
                     landmarks: list[list[float]], mount: LidarMount = _NO_MOUNT,
                     gate_probability: float = 0.99, landmark_var_m2: float = 0.0
                     ) -> AssociationResult:
    """``associate`` for a caller that holds the filter's plain floats (the event driver).

    Args:
        z: observations as [range m, bearing rad] lists.
        packed_row: the state and P's upper triangle, ``GyroBiasEkf.packed_row`` order.
        R, mount, gate_probability, landmark_var_m2: as for ``associate``.
        landmarks: landmark positions as [x m, y m] lists.

    Small scans stay in plain floats (no array is built at all: on the 2016 trip that was
    a few per cent of the run); larger ones go through ``associate``. Same outcomes either
    way, to the bit (the scalar path is the one ``associate`` takes for them too).
    """
    if 0 < len(z) * len(landmarks) <= SCALAR_PAIRS_MAX:
        return _associate_scalar(z, packed_row, R, landmarks, mount,
                                 gate_threshold(gate_probability), landmark_var_m2)
    states, covariances = unpack_rows(np.array(packed_row, dtype=np.float64))
    return associate(np.array(z, dtype=np.float64).reshape(-1, 2), states[0], covariances[0],
                     R, np.array(landmarks, dtype=np.float64).reshape(-1, 2), mount,
                     gate_probability, landmark_var_m2)


def _mahalanobis_rows(z: list[list[float]], packed_row: list[float], R: FloatArray,
                      landmarks: list[list[float]], mount: LidarMount,
                      landmark_var_m2: float = 0.0) -> list[list[float]]:
    """mahalanobis_sq in plain floats (the filter's kernel): d2[i][j], detection i, landmark j.

    ``packed_row``: the state, then P's upper triangle (``GyroBiasEkf.packed_row``).
    """
    pose = packed_row[:3]
    p = packed_row[STATE_SIZE:]
    (r_range, r_cross), (_, r_bearing) = np.asarray(R, dtype=np.float64).tolist()
    per_landmark = []
    at_sensor = False
    for lx, ly in landmarks:
        try:
            (range_m, bearing), (s00, s01, s11) = kernel.innovation_terms(
                pose, p, lx, ly, mount, r_range, r_cross, r_bearing, landmark_var_m2, 1.0,
                full=False)
        except ZeroDivisionError:
            # A landmark at the sensor has no bearing: nothing can match it (NaN, then inf).
            at_sensor = True
            per_landmark.append((0.0, 0.0, math.nan, math.nan, math.nan))
            continue
        try:
            i00, i01, i11 = kernel.inverse(s00, s01, s11)
        except CoreError as err:
            raise CoreError(f'mahalanobis_sq: {err}; check P and R') from None
        per_landmark.append((range_m, bearing, i00, i01, i11))
    rows = kernel.mahalanobis_table(z, per_landmark)
    if at_sensor:
        rows = [[math.inf if math.isnan(d2) else d2 for d2 in row] for row in rows]
    return rows


def _associate_scalar(z: list[list[float]], packed_row: list[float], R: FloatArray,
                      landmarks: list[list[float]], mount: LidarMount, threshold: float,
                      landmark_var_m2: float = 0.0) -> AssociationResult:
    """associate() for small scans, in plain floats (same outcomes, see SCALAR_PAIRS_MAX)."""
    d2 = _mahalanobis_rows(z, packed_row, R, landmarks, mount, landmark_var_m2)
    # Per detection, how many landmarks lie inside its gate; per landmark, how many
    # detections gate it (one pass, plain loops: a scan has a handful of each).
    gated = []
    gating_detections = [0] * len(landmarks)
    for row in d2:
        inside = 0
        for j, distance in enumerate(row):
            if distance <= threshold:
                inside += 1
                gating_detections[j] += 1
        gated.append(inside)
    associations = []
    for i, (row, inside) in enumerate(zip(d2, gated)):
        # The first of the smallest, as argmin in associate (min with a key costs more).
        nearest = row.index(min(row))
        if inside > 1:
            outcome, landmark = _AMBIGUOUS, -1
        elif not inside:
            outcome, landmark = _UNMATCHED, -1
        elif gating_detections[nearest] > 1:
            outcome, landmark = _DUPLICATE, -1
        else:
            outcome, landmark = _MATCHED, nearest
        associations.append(Association(i, landmark, outcome, row[nearest]))
    return AssociationResult(associations=tuple(associations), gate_threshold=threshold,
                             mahalanobis_sq=np.array(d2, dtype=np.float64))


def _associations(landmark: NDArray[np.int64], outcome: NDArray[np.int64],
                  mahalanobis: FloatArray) -> tuple[Association, ...]:
    # tolist() once: per-element numpy scalars would cost more than the association.
    return tuple(map(Association, range(len(landmark)), landmark.tolist(),
                     [_OUTCOMES[o] for o in outcome.tolist()], mahalanobis.tolist()))


def associate_by_distance(z: FloatArray, state: FloatArray, P: FloatArray, R: FloatArray,
                          landmarks_xy_m: FloatArray, mount: LidarMount = _NO_MOUNT,
                          max_distance_m: float = 1.0, ratio: float = 0.3,
                          landmark_var_m2: float = 0.0) -> AssociationResult:
    """Re-associate by map-frame distance, for a filter that has lost its landmarks.

    After a long stretch without updates the covariance no longer describes the error
    (unmodelled slip, a bias that walked off), so the chi-square gate rejects every
    detection and the filter never recovers. Geometry still works: a detection placed in
    the map at the prior pose is paired with its nearest landmark when that landmark is
    within ``max_distance_m`` and clearly nearer than the second nearest
    (nearest <= ratio * second). The Mahalanobis distances are still reported.

    Args:
        z: observations, shape (n, 2): range m, bearing rad (ROS convention).
        state: platform state, shape (4,).
        P: state covariance, shape (4, 4) (only for the reported distances).
        R: observation noise covariance, shape (2, 2).
        landmarks_xy_m: landmark positions, shape (k, 2), m.
        mount: the LiDAR's pose on the platform.
        max_distance_m: farthest a detection may lie from its landmark, m.
        ratio: nearest distance must be at most this share of the second nearest.
        landmark_var_m2: variance of each landmark's map position, m^2 (for the reported
            distances).

    Returns:
        One association per detection: MATCHED, UNMATCHED (too far), AMBIGUOUS (fails the
        ratio test) or DUPLICATE (two detections chose the same landmark).
    """
    z = np.asarray(z, dtype=np.float64).reshape(-1, 2)
    landmarks = np.asarray(landmarks_xy_m, dtype=np.float64).reshape(-1, 2)
    d2 = mahalanobis_sq(z, state, P, R, landmarks, mount, landmark_var_m2)
    n, k = d2.shape
    if k == 0:
        return associate(z, state, P, R, landmarks, mount, landmark_var_m2=landmark_var_m2)
    points = sensor_to_map(state, np.column_stack([z[:, 0] * np.cos(z[:, 1]),
                                                   z[:, 0] * np.sin(z[:, 1])]), mount)
    distance = np.hypot(points[:, None, 0] - landmarks[None, :, 0],
                        points[:, None, 1] - landmarks[None, :, 1])       # (n, k)
    nearest = np.argmin(distance, axis=1)
    ordered = np.sort(distance, axis=1)
    second = ordered[:, 1] if k > 1 else np.full(n, math.inf)
    near = ordered[:, 0] <= max_distance_m
    clear = ordered[:, 0] <= ratio * second
    outcome = np.full(n, AssociationOutcome.UNMATCHED, dtype=np.int64)
    outcome[near & clear] = AssociationOutcome.MATCHED
    outcome[near & ~clear] = AssociationOutcome.AMBIGUOUS
    matched = outcome == AssociationOutcome.MATCHED
    chosen = np.bincount(nearest[matched], minlength=k)
    outcome[matched & (chosen[nearest] > 1)] = AssociationOutcome.DUPLICATE
    landmark = np.where(outcome == AssociationOutcome.MATCHED, nearest, -1)
    return AssociationResult(
        associations=_associations(landmark, outcome, d2[np.arange(n), nearest]),
        gate_threshold=math.inf, mahalanobis_sq=d2)
