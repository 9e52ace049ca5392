"""Extended Kalman filter for pose and gyro bias: state [x, y, yaw, b].

The models are those of the MTRN4010 Project 3 report
(``../shared/course-notes/003_3aeb4dcf00f2eae3.txt``), written out in ``models.py``.

Predict (prior), over a step of T seconds with speed v and measured yaw rate w::

    x- = f(x, u, T)
    P- = J P J^T + Q,        Q = Ju Pu Ju^T + Q2

Update (posterior) with one range/bearing observation z of a known landmark::

    y = z - h(x-)            (bearing wrapped to [-pi, pi))
    S = H P- H^T + R
    K = P- H^T S^-1
    x = x- + K y
    P = (I - K H) P- (I - K H)^T + K R K^T     (Joseph form: stays symmetric and positive
                                                 semi-definite despite rounding)

R is the sensor noise diag(sigma_r^2, sigma_b^2) plus what an uncertain map adds
(``observation_noise``): a real map is surveyed to about a centimetre, a simulator's map
is exact.

Because the bias enters yaw through ``-T`` in J, landmark updates that correct yaw also
correct the bias: that is how the filter finds the bias online.

Standing still (the driver decides when, ``events.py``), a gyro sample w measures the bias
alone: z = w, h(x) = b, H = [0, 0, 0, 1] (a zero-rate update, ``update_zero_rate``), and the
prediction holds the position (no translation, no speed noise).

The arithmetic is written out on plain floats over the 10 distinct entries of the
symmetric P rather than as 4x4 numpy products: J and H are sparse, and at this size
numpy's per-call overhead costs several times the arithmetic itself (see `make bench`,
which checks the results against filterpy's ExtendedKalmanFilter). ``x`` and ``P`` are
read as fresh numpy arrays.
"""

from __future__ import annotations

import math

import numpy as np

from gyro_ekf.core.angles import wrap_scalar
from gyro_ekf.core.config import EkfConfig
from gyro_ekf.core.errors import CoreError
from gyro_ekf.core.types import BIAS, STATE_SIZE, FloatArray, LidarMount

_NO_MOUNT = LidarMount()


def initial_covariance(config: EkfConfig) -> FloatArray:
    """P0 = diag(sigma_pos^2, sigma_pos^2, sigma_yaw^2, sigma_b^2), shape (4, 4)."""
    return np.diag([config.initial_position_sigma_m ** 2, config.initial_position_sigma_m ** 2,
                    config.initial_yaw_sigma_rad ** 2, config.initial_bias_sigma_rad_s ** 2])


class GyroBiasEkf:
    """EKF over [x, y, yaw, bias] with speed/yaw-rate inputs and landmark updates.

    Attributes (arrays are fresh copies; change the filter through its methods):
        x: state estimate, shape (4,): m, m, rad, rad/s.
        P: state covariance, shape (4, 4), symmetric.
        x_prior, P_prior: state and covariance before the last update.
        y: last innovation, shape (2,): m, rad.
        S: last innovation covariance, shape (2, 2).
        K: last Kalman gain, shape (4, 2).
        nis: last normalised innovation squared y^T S^-1 y.
        R: sensor noise covariance, shape (2, 2) (``observation_noise`` adds the map's).
        landmark_var_m2: variance of a landmark's map position along any axis, m^2.
    """

    def __init__(self, config: EkfConfig | None = None, pose: FloatArray | None = None,
                 bias_rad_s: float | None = None, covariance: FloatArray | None = None):
        """Start at a pose (x m, y m, yaw rad) with the configured priors.

        Args:
            config: noise model and priors; defaults to EkfConfig().
            pose: initial pose, shape (3,); zeros when None.
            bias_rad_s: initial bias; config.initial_bias_rad_s when None.
            covariance: initial P, shape (4, 4); initial_covariance(config) when None.
        """
        self.config = config or EkfConfig()
        self._r_range = self.config.range_noise_m ** 2
        self._r_bearing = self.config.bearing_noise_rad ** 2
        self.landmark_var_m2 = self.config.landmark_sigma_m ** 2
        self.R = np.diag([self._r_range, self._r_bearing])
        self._sigma_v2 = self.config.speed_noise_m_s ** 2
        self._sigma_w2 = self.config.gyro_noise_rad_s ** 2
        self._q_pos2 = self.config.position_random_walk_m_sqrt_s ** 2
        self._q_b2 = self.config.bias_random_walk_rad_s2 ** 2
        self.reset(pose, bias_rad_s, covariance)

    # State: _s = [x, y, yaw, b]; covariance: _p = upper triangle of P, row by row:
    # [p00, p01, p02, p03, p11, p12, p13, p22, p23, p33].

    @property
    def x(self) -> FloatArray:
        """State estimate, shape (4,)."""
        return np.array(self._s)

    @property
    def P(self) -> FloatArray:
        """State covariance, shape (4, 4)."""
        return _full(self._p)

    @property
    def bias_rad_s(self) -> float:
        """Bias estimate, rad/s."""
        return self._s[3]

    @property
    def bias_var(self) -> float:
        """Variance of the bias estimate, (rad/s)^2."""
        return self._p[9]

    @property
    def x_prior(self) -> FloatArray:
        """State before the last update, shape (4,)."""
        return np.array(self._s_prior)

    @property
    def P_prior(self) -> FloatArray:
        """Covariance before the last update, shape (4, 4)."""
        return _full(self._p_prior)

    @property
    def y(self) -> FloatArray:
        """Last innovation, shape (2,): m, rad."""
        return np.array(self._y)

    @property
    def S(self) -> FloatArray:
        """Last innovation covariance, shape (2, 2)."""
        s00, s01, s11 = self._S
        return np.array([[s00, s01], [s01, s11]])

    @property
    def K(self) -> FloatArray:
        """Last Kalman gain, shape (4, 2)."""
        return np.array(self._K).reshape(4, 2)

    def reset(self, pose: FloatArray | None = None, bias_rad_s: float | None = None,
              covariance: FloatArray | None = None) -> None:
        """Restart from a pose and bias with the given (or configured) covariance."""
        pose = np.zeros(3) if pose is None else np.asarray(pose, dtype=np.float64)
        bias = self.config.initial_bias_rad_s if bias_rad_s is None else float(bias_rad_s)
        P = (initial_covariance(self.config) if covariance is None
             else np.asarray(covariance, dtype=np.float64))
        if P.shape != (STATE_SIZE, STATE_SIZE):
            raise CoreError(f'initial covariance has shape {P.shape}, expected (4, 4)')
        # A NaN here would surface much later as "SVD did not converge" in an update.
        if pose.shape != (3,) or not np.isfinite(pose).all() or not math.isfinite(bias):
            raise CoreError(f'initial state {pose.tolist()} with bias {bias} is not finite')
        if not np.isfinite(P).all():
            raise CoreError('initial covariance is not finite')
        self._s = [float(pose[0]), float(pose[1]), wrap_scalar(float(pose[2])), bias]
        self._p = _packed(0.5 * (P + P.T))
        self._s_prior = list(self._s)
        self._p_prior = list(self._p)
        self._y = (0.0, 0.0)
        self._S = (0.0, 0.0, 0.0)
        self._K = (0.0,) * 8
        self.nis = 0.0

    def save(self) -> tuple:
        """Return everything ``restore`` needs to put the filter back as it is now."""
        return (list(self._s), list(self._p), self._s_prior, self._p_prior, self._y,
                self._S, self._K, self.nis)

    def restore(self, saved: tuple) -> None:
        """Put the filter back into a state returned by ``save``."""
        s, p, self._s_prior, self._p_prior, self._y, self._S, self._K, self.nis = saved
        self._s, self._p = list(s), list(p)

    def packed_row(self) -> list[float]:
        """Return the state and the covariance's upper triangle as 14 plain floats.

        Order: x, y, yaw, b, then P row by row (p00, p01, p02, p03, p11, p12, p13, p22,
        p23, p33); ``unpack_rows`` turns a stack of them back into states and covariances.
        For callers that keep every estimate: building two arrays per step would cost more
        than the step.
        """
        return self._s + self._p

    def set_pose(self, pose: FloatArray, pose_covariance: FloatArray) -> None:
        """Replace the pose and its 3x3 covariance; keep the bias, its variance, drop coupling."""
        bias, bias_var = self._s[3], self._p[9]
        covariance = np.zeros((STATE_SIZE, STATE_SIZE))
        covariance[:3, :3] = pose_covariance
        covariance[BIAS, BIAS] = bias_var
        self.reset(pose, bias, covariance)

    def set_bias(self, bias_rad_s: float, sigma_rad_s: float) -> None:
        """Seed the bias state and its variance (e.g. from a static calibration)."""
        self._s[3] = float(bias_rad_s)
        p = self._p
        p[3] = p[6] = p[8] = 0.0
        p[9] = float(sigma_rad_s) ** 2

    def predict(self, speed_m_s: float, rate_rad_s: float, dt_s: float,
                speed_variance: float | None = None, rate_variance: float | None = None,
                hold_position: bool = False) -> None:
        """Propagate over dt_s seconds with constant speed (m/s) and measured yaw rate (rad/s).

        speed_variance ((m/s)^2) and rate_variance ((rad/s)^2), when given, replace the
        configured sigma_v^2 and sigma_w^2 of Pu for this step (the inputs' own message
        covariances). ``hold_position`` (standing still): x and y do not move and gain no
        speed noise (the position random walk still applies); yaw still integrates the
        rate minus the bias.
        """
        if dt_s <= 0.0:
            return
        # Plain floats: numpy scalars would spread into the state and slow every step.
        speed_m_s, rate_rad_s, dt_s = float(speed_m_s), float(rate_rad_s), float(dt_s)
        x, y, yaw, bias = self._s
        c, s = math.cos(yaw), math.sin(yaw)
        step = 0.0 if hold_position else dt_s * speed_m_s
        self._s = [x + step * c, y + step * s, wrap_scalar(yaw + dt_s * (rate_rad_s - bias)),
                   bias]
        # J = I + E with E[0,2] = a, E[1,2] = b, E[2,3] = d; first M = J P (rows) ...
        a, b, d = -step * s, step * c, -dt_s
        p00, p01, p02, p03, p11, p12, p13, p22, p23, p33 = self._p
        m00 = p00 + a * p02
        m01 = p01 + a * p12
        m02 = p02 + a * p22
        m03 = p03 + a * p23
        m11 = p11 + b * p12
        m12 = p12 + b * p22
        m13 = p13 + b * p23
        m22 = p22 + d * p23
        m23 = p23 + d * p33
        # ... then J P J^T = M J^T, plus Q = Ju Pu Ju^T + Q2 written out (speed noise lies
        # along the heading).
        t2 = dt_s * dt_s
        # Held, the odometry's zero is exact (no speed noise); the position random walk
        # stays: landmark looks at rest repeat their errors and move the estimate by
        # millimetres, which a frozen position covariance would not cover.
        qv = 0.0 if hold_position else t2 * (
            self._sigma_v2 if speed_variance is None else speed_variance)
        qw = t2 * (self._sigma_w2 if rate_variance is None else rate_variance)
        qp = dt_s * self._q_pos2
        self._p = [
            m00 + a * m02 + qv * c * c + qp,
            m01 + b * m02 + qv * c * s,
            m02 + d * m03,
            m03,
            m11 + b * m12 + qv * s * s + qp,
            m12 + d * m13,
            m13,
            m22 + d * m23 + qw,
            m23,
            p33 + t2 * self._q_b2,
        ]

    def update_zero_rate(self, rate_rad_s: float, variance: float) -> float:
        """Correct with a gyro sample taken standing still: z = w = b + noise.

        h(x) = b and H = [0, 0, 0, 1], so S = P[3, 3] + R and K = P[:, 3] / S; the Joseph
        form (I - K H) P (I - K H)^T + K R K^T reduces to P - P[:, 3] P[3, :] / S. The
        innovation, gain and prior of the last landmark update are kept.

        Args:
            rate_rad_s: the measured yaw rate, bias included, rad/s.
            variance: R, the sample's noise variance, (rad/s)^2.

        Returns:
            The NIS (w - b)^2 / S.

        Raises:
            CoreError: S is not positive.
        """
        p = self._p
        p03, p13, p23, p33 = p[3], p[6], p[8], p[9]
        s = p33 + variance
        if not s > 0.0:
            raise CoreError(f'zero-rate innovation variance {s} is not positive')
        x, y, yaw, bias = self._s
        innovation = float(rate_rad_s) - bias
        k0, k1, k2, k3 = p03 / s, p13 / s, p23 / s, p33 / s
        self._s = [x + k0 * innovation, y + k1 * innovation,
                   wrap_scalar(yaw + k2 * innovation), bias + k3 * innovation]
        self._p = [p[0] - p03 * k0, p[1] - p03 * k1, p[2] - p03 * k2, p[3] - p03 * k3,
                   p[4] - p13 * k1, p[5] - p13 * k2, p[6] - p13 * k3,
                   p[7] - p23 * k2, p[8] - p23 * k3, p33 - p33 * k3]
        return innovation * innovation / s

    def innovation(self, z: FloatArray, landmark_xy_m: FloatArray,
                   mount: LidarMount = _NO_MOUNT) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Innovation y (2,), its covariance S (2, 2) and H (2, 4) for one observation."""
        z_hat, H = observe_one(self._s, landmark_xy_m, mount)
        y = np.array([z[0] - z_hat[0], wrap_scalar(z[1] - z_hat[1])])
        return y, H @ self.P @ H.T + self.observation_noise(float(z_hat[0])), H

    def observation_noise(self, range_m: float) -> FloatArray:
        """R of one landmark at a predicted range (m): sensor noise plus map uncertainty.

        A landmark's map position off by sigma along any axis moves its range by sigma and
        its bearing by sigma / range, so the map adds diag(sigma^2, sigma^2 / range^2).
        """
        m2 = self.landmark_var_m2
        return np.diag([self._r_range + m2, self._r_bearing + m2 / (range_m * range_m)])

    def update(self, z: FloatArray, landmark_xy_m: FloatArray,
               mount: LidarMount = _NO_MOUNT, noise_scale: float = 1.0) -> float:
        """Correct with z = [range m, bearing rad] (0 = sensor forward) of a known landmark.

        ``noise_scale`` multiplies R (sensor and map) for this observation only; the NIS
        is still taken against the unscaled R, so it keeps measuring the sensor.

        Returns:
            The normalised innovation squared (NIS) of this observation.

        Raises:
            CoreError: the innovation covariance is not positive definite.
        """
        x, y, yaw, bias = self._s
        p00, p01, p02, p03, p11, p12, p13, p22, p23, p33 = p = self._p
        # One conversion each: indexing numpy scalars one by one costs more than the maths.
        z_range, z_bearing = z.tolist() if isinstance(z, np.ndarray) else z
        lx, ly = (landmark_xy_m.tolist() if isinstance(landmark_xy_m, np.ndarray)
                  else landmark_xy_m)
        # h and H (H has no bias column).
        c, s = math.cos(yaw), math.sin(yaw)
        xl = x + mount.x_m * c - mount.y_m * s
        yl = y + mount.x_m * s + mount.y_m * c
        dxl = -mount.x_m * s - mount.y_m * c
        dyl = mount.x_m * c - mount.y_m * s
        dx = lx - xl
        dy = ly - yl
        r2 = dx * dx + dy * dy
        r = math.sqrt(r2)
        h00, h01, h02 = -dx / r, -dy / r, -(dx * dxl + dy * dyl) / r
        h10, h11, h12 = dy / r2, -dx / r2, (dy * dxl - dx * dyl) / r2 - 1.0
        y0 = z_range - r
        y1 = wrap_scalar(z_bearing - (math.atan2(dy, dx) - yaw - mount.yaw_rad))
        # P H^T, shape (4, 2): column 0 for range, 1 for bearing.
        a0 = p00 * h00 + p01 * h01 + p02 * h02
        a1 = p01 * h00 + p11 * h01 + p12 * h02
        a2 = p02 * h00 + p12 * h01 + p22 * h02
        a3 = p03 * h00 + p13 * h01 + p23 * h02
        b0 = p00 * h10 + p01 * h11 + p02 * h12
        b1 = p01 * h10 + p11 * h11 + p12 * h12
        b2 = p02 * h10 + p12 * h11 + p22 * h12
        b3 = p03 * h10 + p13 * h11 + p23 * h12
        # S = H P H^T + R and its inverse.
        rr = (self._r_range + self.landmark_var_m2) * noise_scale
        rb = (self._r_bearing + self.landmark_var_m2 / r2) * noise_scale
        s00 = h00 * a0 + h01 * a1 + h02 * a2 + rr
        s01 = h00 * b0 + h01 * b1 + h02 * b2
        s11 = h10 * b0 + h11 * b1 + h12 * b2 + rb
        det = s00 * s11 - s01 * s01
        if not (det > 0.0 and s00 > 0.0):
            raise CoreError(f'innovation covariance is not positive definite: '
                            f'[[{s00}, {s01}], [{s01}, {s11}]]')
        i00, i01, i11 = s11 / det, -s01 / det, s00 / det
        # K = P H^T S^-1.
        k00, k01 = a0 * i00 + b0 * i01, a0 * i01 + b0 * i11
        k10, k11 = a1 * i00 + b1 * i01, a1 * i01 + b1 * i11
        k20, k21 = a2 * i00 + b2 * i01, a2 * i01 + b2 * i11
        k30, k31 = a3 * i00 + b3 * i01, a3 * i01 + b3 * i11
        self._s_prior, self._p_prior = self._s, p
        self._s = [x + k00 * y0 + k01 * y1, y + k10 * y0 + k11 * y1,
                   wrap_scalar(yaw + k20 * y0 + k21 * y1), bias + k30 * y0 + k31 * y1]
        # Joseph form P = A P A^T + K R K^T with A = I - K H, evaluated as B = A P (row i:
        # B_ij = P_ij - k_i0 a_j - k_i1 b_j), then A P A^T = B - (B H^T) K^T.
        b00 = p00 - k00 * a0 - k01 * b0
        b01 = p01 - k00 * a1 - k01 * b1
        b02 = p02 - k00 * a2 - k01 * b2
        b03 = p03 - k00 * a3 - k01 * b3
        b10 = p01 - k10 * a0 - k11 * b0
        b11 = p11 - k10 * a1 - k11 * b1
        b12 = p12 - k10 * a2 - k11 * b2
        b13 = p13 - k10 * a3 - k11 * b3
        b20 = p02 - k20 * a0 - k21 * b0
        b21 = p12 - k20 * a1 - k21 * b1
        b22 = p22 - k20 * a2 - k21 * b2
        b23 = p23 - k20 * a3 - k21 * b3
        b30 = p03 - k30 * a0 - k31 * b0
        b31 = p13 - k30 * a1 - k31 * b1
        b32 = p23 - k30 * a2 - k31 * b2
        b33 = p33 - k30 * a3 - k31 * b3
        # C = B H^T; each row minus K R is what multiplies K^T.
        c00 = b00 * h00 + b01 * h01 + b02 * h02 - rr * k00
        c01 = b00 * h10 + b01 * h11 + b02 * h12 - rb * k01
        c10 = b10 * h00 + b11 * h01 + b12 * h02 - rr * k10
        c11 = b10 * h10 + b11 * h11 + b12 * h12 - rb * k11
        c20 = b20 * h00 + b21 * h01 + b22 * h02 - rr * k20
        c21 = b20 * h10 + b21 * h11 + b22 * h12 - rb * k21
        c30 = b30 * h00 + b31 * h01 + b32 * h02 - rr * k30
        c31 = b30 * h10 + b31 * h11 + b32 * h12 - rb * k31
        self._p = [
            b00 - c00 * k00 - c01 * k01, b01 - c00 * k10 - c01 * k11,
            b02 - c00 * k20 - c01 * k21, b03 - c00 * k30 - c01 * k31,
            b11 - c10 * k10 - c11 * k11, b12 - c10 * k20 - c11 * k21,
            b13 - c10 * k30 - c11 * k31, b22 - c20 * k20 - c21 * k21,
            b23 - c20 * k30 - c21 * k31, b33 - c30 * k30 - c31 * k31,
        ]
        self._y = (y0, y1)
        self._S = (s00, s01, s11)
        self._K = (k00, k01, k10, k11, k20, k21, k30, k31)
        if noise_scale != 1.0:
            u00 = s00 - rr + rr / noise_scale
            u11 = s11 - rb + rb / noise_scale
            det = u00 * u11 - s01 * s01
            i00, i01, i11 = u11 / det, -s01 / det, u00 / det
        self.nis = y0 * (i00 * y0 + i01 * y1) + y1 * (i01 * y0 + i11 * y1)
        return self.nis


_UPPER = [(i, j) for i in range(STATE_SIZE) for j in range(i, STATE_SIZE)]


PACKED_ROW_SIZE = STATE_SIZE + len(_UPPER)


def _full_index() -> np.ndarray:
    # Column of a packed row that holds P[i, j], for every i, j.
    index = np.empty((STATE_SIZE, STATE_SIZE), dtype=np.int64)
    for k, (i, j) in enumerate(_UPPER):
        index[i, j] = index[j, i] = STATE_SIZE + k
    return index


_FULL_INDEX = _full_index()


def unpack_rows(rows: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Split ``GyroBiasEkf.packed_row`` rows (n, 14) into states (n, 4) and P (n, 4, 4)."""
    rows = np.asarray(rows, dtype=np.float64).reshape(-1, PACKED_ROW_SIZE)
    return rows[:, :STATE_SIZE], rows[:, _FULL_INDEX]


def _packed(P: FloatArray) -> list[float]:
    return [float(P[i, j]) for i, j in _UPPER]


def _full(packed: list[float]) -> FloatArray:
    p00, p01, p02, p03, p11, p12, p13, p22, p23, p33 = packed
    return np.array([[p00, p01, p02, p03], [p01, p11, p12, p13], [p02, p12, p22, p23],
                     [p03, p13, p23, p33]])


def observe_one(state: FloatArray, landmark_xy_m: FloatArray,
                mount: LidarMount = _NO_MOUNT) -> tuple[FloatArray, FloatArray]:
    """Compute h and H of one landmark in plain floats (the hot path of every update).

    Same maths as models.observe and models.observation_jacobian, which the tests check.

    Returns:
        z_hat (2,): range m, bearing rad (0 = sensor forward); H (2, 4).
    """
    x, y, yaw = state[0], state[1], state[2]
    c, s = math.cos(yaw), math.sin(yaw)
    xl = x + mount.x_m * c - mount.y_m * s
    yl = y + mount.x_m * s + mount.y_m * c
    dxl_dyaw = -mount.x_m * s - mount.y_m * c
    dyl_dyaw = mount.x_m * c - mount.y_m * s
    dx = landmark_xy_m[0] - xl
    dy = landmark_xy_m[1] - yl
    r2 = dx * dx + dy * dy
    r = math.sqrt(r2)
    z_hat = np.array([r, wrap_scalar(math.atan2(dy, dx) - yaw - mount.yaw_rad)])
    H = np.array([
        [-dx / r, -dy / r, -(dx * dxl_dyaw + dy * dyl_dyaw) / r, 0.0],
        [dy / r2, -dx / r2, (dy * dxl_dyaw - dx * dyl_dyaw) / r2 - 1.0, 0.0],
    ])
    return z_hat, H
