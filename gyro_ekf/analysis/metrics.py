"""Accuracy and consistency metrics of a filter run (pure numpy).

Conventions:

- Errors are estimate minus truth; yaw errors are wrapped to [-pi, pi).
- Runs are compared with ground truth at the truth stamps: the estimates (IMU rate,
  100-200 Hz) are interpolated to them, not the sparse truth (about 6 Hz in the course's
  simulated logs) to the estimates, which would leave ~1 deg heading artefacts in 50 deg/s
  turns. Yaw is unwrapped before interpolating, so a crossing of +-pi goes the short way.
- NEES of the pose, ``e^T P^-1 e`` with e = [x, y, yaw] error and P the pose block of the
  covariance, is chi-square with 3 degrees of freedom for a consistent filter; NIS of one
  range/bearing update, ``y^T S^-1 y``, is chi-square with 2.
- Band: the **two-sided** 95 % interval of a single sample, ``[q(0.025), q(0.975)]`` of the
  chi-square distribution (3 dof: [0.216, 9.348]; 2 dof: [0.0506, 7.378]). A consistent
  filter puts about 95 % of its samples inside; an overconfident one has too many above,
  a conservative one (P too large) too many below. Samples are correlated in time, so the
  share is a diagnostic, not a significance test.
"""

from __future__ import annotations

from dataclasses import dataclass
import math

import numpy as np
from numpy.typing import NDArray

from gyro_ekf.core.angles import wrap_angle
from gyro_ekf.core.types import FloatArray

BoolArray = NDArray[np.bool_]

BAND_PROBABILITY = 0.95
"""Probability mass of the two-sided per-sample chi-square band."""


def chi_square_cdf(x: float, dof: int) -> float:
    """Chi-square cumulative distribution in closed form (no scipy: keeps `run` start-up fast).

    Even dof: 1 - exp(-x/2) sum_{i<k/2} (x/2)^i / i!; odd dof: erf(sqrt(x/2)) minus
    exp(-x/2) sum_{i<=(k-3)/2} (x/2)^(i+1/2) / Gamma(i+3/2).
    """
    if x <= 0.0:
        return 0.0
    half = x / 2.0
    if dof % 2 == 0:
        return 1.0 - math.exp(-half) * sum(half ** i / math.factorial(i)
                                           for i in range(dof // 2))
    tail = sum(half ** (i + 0.5) / math.gamma(i + 1.5) for i in range((dof - 1) // 2))
    return math.erf(math.sqrt(half)) - math.exp(-half) * tail


def chi_square_quantile(probability: float, dof: int) -> float:
    """Return x with chi_square_cdf(x, dof) = probability (bisection to 1e-12 relative)."""
    if not 0.0 < probability < 1.0 or dof < 1:
        raise ValueError(f'need 0 < probability < 1 and dof >= 1, got {probability}, {dof}')
    low, high = 0.0, max(1.0, float(dof))
    while chi_square_cdf(high, dof) < probability:
        high *= 2.0
    for _ in range(200):
        middle = 0.5 * (low + high)
        if chi_square_cdf(middle, dof) < probability:
            low = middle
        else:
            high = middle
        if high - low <= 1e-12 * high:
            break
    return 0.5 * (low + high)


def chi_square_band(dof: int, probability: float = BAND_PROBABILITY) -> tuple[float, float]:
    """Return the two-sided chi-square interval holding `probability` of a single sample.

    Args:
        dof: degrees of freedom (>= 1).
        probability: mass inside the band, in (0, 1).

    Returns:
        (low, high): the (1 - p)/2 and (1 + p)/2 quantiles.
    """
    tail = (1.0 - probability) / 2.0
    return chi_square_quantile(tail, dof), chi_square_quantile(1.0 - tail, dof)


def share_inside(values: FloatArray, low: float, high: float) -> float:
    """Return the share of finite values inside [low, high] (nan when there are none)."""
    values = np.asarray(values, dtype=np.float64)
    values = values[np.isfinite(values)]
    if values.size == 0:
        return math.nan
    return float(np.mean((values >= low) & (values <= high)))


def covariance_rank(covariances: FloatArray) -> NDArray[np.int64]:
    """Rank of each covariance (n, d, d) -> (n,): its eigenvalues above 1e-12 of the largest."""
    P = np.asarray(covariances, dtype=np.float64)
    if P.shape[0] == 0:
        return np.zeros(0, dtype=np.int64)
    eigenvalues = np.linalg.eigvalsh(P)
    largest = np.maximum(eigenvalues[:, -1:], np.finfo(float).tiny)
    return np.sum(eigenvalues > 1e-12 * largest, axis=1).astype(np.int64)


def nees_band_outcome(nees: FloatArray, dof: NDArray[np.int64],
                      probability: float = BAND_PROBABILITY
                      ) -> tuple[BoolArray, BoolArray, BoolArray]:
    """Return (inside, below, above) the two-sided band of each NEES sample's own dof.

    A consistent filter's NEES is chi-square with as many dof as its covariance has rank
    (the error lies in P's range; ``normalized_squared_error`` uses the pseudo-inverse
    there). So each sample is judged against the band of its rank: 3 for a pose the filter
    is unsure of in every direction; 1 where it holds the position exactly and only the
    heading is uncertain; 0 where it claims the whole pose exactly, when the only
    consistent NEES is 0 (a held start pose, ``core/held_start.py``: the claim holds, and
    a zero error is no sign of a covariance too large). An error where P says none can be
    is inf, above every band.
    """
    nees = np.asarray(nees, dtype=np.float64)
    dof = np.asarray(dof, dtype=np.int64)
    low, high = np.zeros(nees.shape), np.zeros(nees.shape)
    for rank in np.unique(dof).tolist():
        if rank > 0:
            low[dof == rank], high[dof == rank] = chi_square_band(rank, probability)
    below, above = nees < low, nees > high
    return ~(below | above), below, above


def pose_errors(estimated_pose: FloatArray, true_pose: FloatArray) -> FloatArray:
    """Return estimate minus truth, shape (n, 3): x m, y m, yaw rad (wrapped)."""
    est = np.asarray(estimated_pose, dtype=np.float64).reshape(-1, 3)
    true = np.asarray(true_pose, dtype=np.float64).reshape(-1, 3)
    errors = est - true
    errors[:, 2] = wrap_angle(errors[:, 2])
    return errors


def rmse(values: FloatArray) -> float:
    """Return the RMS of the rows' norms: shape (n,) or (n, d) -> scalar (nan if empty)."""
    values = np.asarray(values, dtype=np.float64)
    if values.size == 0:
        return math.nan
    squared = values ** 2 if values.ndim == 1 else np.sum(values ** 2, axis=1)
    return float(math.sqrt(np.mean(squared)))


def normalized_squared_error(errors: FloatArray, covariances: FloatArray) -> FloatArray:
    """``e^T P^-1 e`` per row: errors (n, d), covariances (n, d, d) -> (n,).

    A singular P (e.g. an exactly known initial pose) uses the pseudo-inverse, so a zero
    error there counts as 0 and an error in a direction P calls impossible as inf.
    """
    e = np.asarray(errors, dtype=np.float64)
    P = np.asarray(covariances, dtype=np.float64)
    if e.shape[0] == 0:
        return np.zeros(0)
    out = np.empty(e.shape[0])
    det = np.linalg.det(P)
    scale = np.einsum('nii->n', P) ** e.shape[1]
    regular = det > 1e-12 * np.maximum(scale, np.finfo(float).tiny)
    if np.any(regular):
        solved = np.linalg.solve(P[regular], e[regular][..., None])[..., 0]
        out[regular] = np.einsum('ni,ni->n', e[regular], solved)
    for i in np.flatnonzero(~regular):
        pinv = np.linalg.pinv(P[i])
        residual = e[i] - P[i] @ (pinv @ e[i])
        norm = float(np.linalg.norm(e[i]))
        out[i] = math.inf if np.linalg.norm(residual) > 1e-9 * max(norm, 1e-12) else float(
            e[i] @ pinv @ e[i])
    return out


def longest_gap(event_stamp_s: FloatArray, start_s: float, end_s: float
                ) -> tuple[float, float]:
    """Return the longest time without an event, counting from start_s to end_s.

    Args:
        event_stamp_s: stamps of the events (e.g. scans with an associated landmark),
            shape (k,), s, in order.
        start_s: start of the span, s.
        end_s: end of the span, s.

    Returns:
        (duration s, stamp s where the longest gap starts).
    """
    events = np.asarray(event_stamp_s, dtype=np.float64)
    edges = np.concatenate([[start_s], events[(events > start_s) & (events < end_s)], [end_s]])
    gaps = np.diff(edges)
    worst = int(np.argmax(gaps))
    return float(gaps[worst]), float(edges[worst])


def settling_time(stamp_s: FloatArray, error: FloatArray, tolerance: float) -> float | None:
    """Return when an error enters its tolerance band for good.

    Args:
        stamp_s: shape (n,), s, increasing.
        error: shape (n,), any unit.
        tolerance: half-width of the band, same unit.

    Returns:
        The stamp of the last sample outside +-tolerance (the error stays inside from the
        next sample on); stamp_s[0] if it never leaves; None if it is outside at the end.
    """
    stamps = np.asarray(stamp_s, dtype=np.float64)
    outside = np.flatnonzero(~(np.abs(np.asarray(error, dtype=np.float64)) <= tolerance))
    if stamps.size == 0:
        return None
    if outside.size == 0:
        return float(stamps[0])
    if outside[-1] == stamps.size - 1:
        return None
    return float(stamps[outside[-1]])


def dead_reckon(imu_stamp_s: FloatArray, yaw_rate_rad_s: FloatArray, speed_stamp_s: FloatArray,
                speed_m_s: FloatArray, initial_pose: FloatArray, bias_rad_s: float = 0.0
                ) -> FloatArray:
    """Integrate speed and yaw rate with the EKF's process model, without corrections.

    Both inputs are held between samples (zero-order hold, as EventDriver does); before the
    first sample of a stream the speed is 0 and the yaw rate equals the bias. Euler steps
    between consecutive stamps of either stream.

    Args:
        imu_stamp_s: gyro stamps, shape (n,), s, non-decreasing.
        yaw_rate_rad_s: measured yaw rates, shape (n,), rad/s, bias included.
        speed_stamp_s: speed stamps, shape (m,), s, non-decreasing.
        speed_m_s: speeds, shape (m,), m/s.
        initial_pose: x m, y m, yaw rad at the first stamp of either stream, shape (3,).
        bias_rad_s: gyro bias subtracted from every rate, rad/s.

    Returns:
        Poses at the IMU stamps, shape (n, 3): x m, y m, yaw rad (wrapped).
    """
    imu_t = np.asarray(imu_stamp_s, dtype=np.float64)
    rates = np.asarray(yaw_rate_rad_s, dtype=np.float64)
    speed_t = np.asarray(speed_stamp_s, dtype=np.float64)
    speeds = np.asarray(speed_m_s, dtype=np.float64)
    if imu_t.size == 0:
        return np.zeros((0, 3))
    stamps = np.union1d(imu_t, speed_t)
    # Held inputs on each interval [stamps[k], stamps[k+1]): the latest sample at or before.
    i_rate = np.searchsorted(imu_t, stamps[:-1], side='right') - 1
    i_speed = np.searchsorted(speed_t, stamps[:-1], side='right') - 1
    rate = np.where(i_rate >= 0, rates[np.maximum(i_rate, 0)] - bias_rad_s, 0.0)
    speed = np.where(i_speed >= 0, speeds[np.maximum(i_speed, 0)] if speeds.size else 0.0, 0.0)
    dt = np.diff(stamps)
    x0, y0, yaw0 = (float(v) for v in np.asarray(initial_pose, dtype=np.float64))
    yaw = yaw0 + np.concatenate([[0.0], np.cumsum(rate * dt)])
    step = speed * dt
    x = x0 + np.concatenate([[0.0], np.cumsum(step * np.cos(yaw[:-1]))])
    y = y0 + np.concatenate([[0.0], np.cumsum(step * np.sin(yaw[:-1]))])
    at = np.searchsorted(stamps, imu_t)
    return np.column_stack([x[at], y[at], wrap_angle(yaw[at])])


def interpolate_estimates(stamp_s: FloatArray, state: FloatArray, covariance: FloatArray,
                          at_s: FloatArray) -> tuple[FloatArray, FloatArray, BoolArray]:
    """Interpolate estimates and covariances linearly to other stamps.

    Used to compare with a sparse ground truth: the estimates come at the IMU rate
    (100-200 Hz), so interpolating them is far more accurate than interpolating a 6 Hz
    truth across a turn. A stamp equal to an estimate stamp takes that row exactly (the
    last one when several share it). Covariances are interpolated entry by entry (a convex
    combination of two covariances is one too).

    Args:
        stamp_s: estimate stamps, shape (n,), s, non-decreasing.
        state: shape (n, 4): x m, y m, yaw rad, bias rad/s.
        covariance: shape (n, 4, 4).
        at_s: wanted stamps, shape (g,), s.

    Returns:
        state (g', 4) with yaw wrapped, covariance (g', 4, 4) for the wanted stamps inside
        the estimates' span, and the mask (g,) of those stamps.
    """
    stamps = np.asarray(stamp_s, dtype=np.float64)
    wanted = np.asarray(at_s, dtype=np.float64)
    if stamps.size == 0:
        return np.zeros((0, 4)), np.zeros((0, 4, 4)), np.zeros(wanted.size, dtype=bool)
    inside = (wanted >= stamps[0]) & (wanted <= stamps[-1])
    t = wanted[inside]
    state = np.asarray(state, dtype=np.float64)
    yaw = np.unwrap(state[:, 2])
    P = np.asarray(covariance, dtype=np.float64)
    upper = np.clip(np.searchsorted(stamps, t, side='right'), 1, stamps.size - 1) \
        if stamps.size > 1 else np.zeros(t.size, dtype=np.int64)
    lower = np.maximum(upper - 1, 0)
    exact = stamps[np.searchsorted(stamps, t, side='right') - 1] == t
    span = stamps[upper] - stamps[lower]
    frac = np.where(span > 0, (t - stamps[lower]) / np.where(span > 0, span, 1.0), 0.0)
    frac = np.where(exact, 0.0, frac)
    lower = np.where(exact, np.searchsorted(stamps, t, side='right') - 1, lower)
    # In place, one temporary at a time: a one-hour trip has ~10^5 truth stamps.
    out_state = state[lower]
    out_state[:, 2] = yaw[lower]
    step = state[upper]
    step[:, 2] = yaw[upper]
    step -= out_state
    step *= frac[:, None]
    out_state += step
    out_state[:, 2] = wrap_angle(out_state[:, 2])
    out_P = P[lower]
    step_P = P[upper]
    step_P -= out_P
    step_P *= frac[:, None, None]
    out_P += step_P
    return out_state, out_P, inside


@dataclass(frozen=True, slots=True)
class TruthComparison:
    """Estimates against ground truth at the truth stamps inside the estimates' span.

    Attributes:
        stamp_s: shape (g,), s.
        errors: estimate minus truth, shape (g, 3): x m, y m, yaw rad.
        sigmas: filter standard deviations of x, y, yaw, shape (g, 3): m, m, rad.
        nees: pose NEES, shape (g,).
        dof: the rank of each pose covariance, the NEES's dof (3 unless the filter holds
            some of the pose exactly), shape (g,).
    """

    stamp_s: FloatArray
    errors: FloatArray
    sigmas: FloatArray
    nees: FloatArray
    dof: NDArray[np.int64]

    @property
    def position_error_m(self) -> FloatArray:
        """Euclidean position error, shape (g,), m."""
        return np.hypot(self.errors[:, 0], self.errors[:, 1])


def compare_with_truth(stamp_s: FloatArray, state: FloatArray, covariance: FloatArray,
                       truth_stamp_s: FloatArray, truth_pose: FloatArray) -> TruthComparison:
    """Compute errors, sigmas and NEES of a run at the ground-truth stamps.

    The estimates are interpolated to the truth stamps (see interpolate_estimates).

    Args:
        stamp_s: estimate stamps, shape (n,), s.
        state: estimates, shape (n, 4): x m, y m, yaw rad, bias rad/s.
        covariance: shape (n, 4, 4).
        truth_stamp_s: shape (g,), s.
        truth_pose: shape (g, 3): x m, y m, yaw rad.
    """
    est, P, inside = interpolate_estimates(stamp_s, state, covariance, truth_stamp_s)
    truth = np.asarray(truth_pose, dtype=np.float64).reshape(-1, 3)[inside]
    P = P[:, :3, :3]
    errors = pose_errors(est[:, :3], truth)
    sigmas = np.sqrt(np.maximum(np.einsum('nii->ni', P), 0.0))
    return TruthComparison(stamp_s=np.asarray(truth_stamp_s, dtype=np.float64)[inside],
                           errors=errors, sigmas=sigmas,
                           nees=normalized_squared_error(errors, P),
                           dof=covariance_rank(P))
