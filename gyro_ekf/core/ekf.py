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

Because the bias enters yaw through ``-T`` in J, landmark updates that correct yaw also
correct the bias: that is how the filter finds the bias online.
"""

from __future__ import annotations

import math

import numpy as np

from gyro_ekf.core.angles import wrap_scalar
from gyro_ekf.core.config import EkfConfig
from gyro_ekf.core.errors import CoreError
from gyro_ekf.core.types import BIAS, STATE_SIZE, YAW, FloatArray, LidarMount

_IDENTITY = np.eye(STATE_SIZE)
_NO_MOUNT = LidarMount()


def initial_covariance(config: EkfConfig) -> FloatArray:
    """P0 = diag(sigma_pos^2, sigma_pos^2, sigma_yaw^2, sigma_b^2), shape (4, 4)."""
    return np.diag([config.initial_position_sigma_m ** 2, config.initial_position_sigma_m ** 2,
                    config.initial_yaw_sigma_rad ** 2, config.initial_bias_sigma_rad_s ** 2])


class GyroBiasEkf:
    """EKF over [x, y, yaw, bias] with speed/yaw-rate inputs and landmark updates.

    Attributes:
        x: state estimate, shape (4,): m, m, rad, rad/s.
        P: state covariance, shape (4, 4).
        x_prior, P_prior: state and covariance before the last update (read-only).
        y: last innovation, shape (2,): m, rad (read-only).
        S: last innovation covariance, shape (2, 2) (read-only).
        K: last Kalman gain, shape (4, 2) (read-only).
        nis: last normalised innovation squared y^T S^-1 y (read-only).
        R: observation noise covariance, shape (2, 2).
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
        self.R = np.diag([self.config.range_noise_m ** 2, self.config.bearing_noise_rad ** 2])
        self._sigma_v2 = self.config.speed_noise_m_s ** 2
        self._sigma_w2 = self.config.gyro_noise_rad_s ** 2
        self._q_pos2 = self.config.position_process_noise_m_s ** 2
        self._q_b2 = self.config.bias_random_walk_rad_s2 ** 2
        self._F = np.eye(STATE_SIZE)
        self.reset(pose, bias_rad_s, covariance)

    def reset(self, pose: FloatArray | None = None, bias_rad_s: float | None = None,
              covariance: FloatArray | None = None) -> None:
        """Restart from a pose and bias with the given (or configured) covariance."""
        pose = np.zeros(3) if pose is None else np.asarray(pose, dtype=np.float64)
        bias = self.config.initial_bias_rad_s if bias_rad_s is None else float(bias_rad_s)
        self.x = np.array([pose[0], pose[1], wrap_scalar(float(pose[2])), bias])
        self.P = (initial_covariance(self.config) if covariance is None
                  else np.array(covariance, dtype=np.float64))
        if self.P.shape != (STATE_SIZE, STATE_SIZE):
            raise CoreError(f'initial covariance has shape {self.P.shape}, expected (4, 4)')
        self.x_prior = self.x.copy()
        self.P_prior = self.P.copy()
        self.y = np.zeros(2)
        self.S = np.zeros((2, 2))
        self.K = np.zeros((STATE_SIZE, 2))
        self.nis = 0.0

    def set_pose(self, pose: FloatArray, pose_covariance: FloatArray) -> None:
        """Replace the pose and its 3x3 covariance; keep the bias, its variance, drop coupling."""
        bias, bias_var = self.x[BIAS], self.P[BIAS, BIAS]
        covariance = np.zeros((STATE_SIZE, STATE_SIZE))
        covariance[:3, :3] = pose_covariance
        covariance[BIAS, BIAS] = bias_var
        self.reset(pose, bias, covariance)

    def set_bias(self, bias_rad_s: float, sigma_rad_s: float) -> None:
        """Seed the bias state and its variance (e.g. from a static calibration)."""
        self.x[BIAS] = bias_rad_s
        self.P[BIAS, :] = 0.0
        self.P[:, BIAS] = 0.0
        self.P[BIAS, BIAS] = sigma_rad_s ** 2

    def predict(self, speed_m_s: float, rate_rad_s: float, dt_s: float) -> None:
        """Propagate over dt_s seconds with constant speed (m/s) and measured yaw rate (rad/s)."""
        if dt_s <= 0.0:
            return
        x, y, yaw, bias = self.x
        c, s = math.cos(yaw), math.sin(yaw)
        # J: identity plus the yaw and bias couplings.
        F = self._F
        F[0, 2] = -dt_s * speed_m_s * s
        F[1, 2] = dt_s * speed_m_s * c
        F[2, 3] = -dt_s
        # Q = Ju Pu Ju^T + Q2, written out: speed noise spreads along the heading.
        t2 = dt_s * dt_s
        qv = t2 * self._sigma_v2
        qp = t2 * self._q_pos2
        Q = np.array([
            [qv * c * c + qp, qv * c * s, 0.0, 0.0],
            [qv * c * s, qv * s * s + qp, 0.0, 0.0],
            [0.0, 0.0, t2 * self._sigma_w2, 0.0],
            [0.0, 0.0, 0.0, t2 * self._q_b2],
        ])
        self.x = np.array([x + dt_s * speed_m_s * c, y + dt_s * speed_m_s * s,
                           wrap_scalar(yaw + dt_s * (rate_rad_s - bias)), bias])
        P = F @ self.P @ F.T + Q
        self.P = 0.5 * (P + P.T)

    def innovation(self, z: FloatArray, landmark_xy_m: FloatArray,
                   mount: LidarMount = _NO_MOUNT) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Innovation y (2,), its covariance S (2, 2) and H (2, 4) for one observation."""
        z_hat, H = observe_one(self.x, landmark_xy_m, mount)
        y = np.array([z[0] - z_hat[0], wrap_scalar(z[1] - z_hat[1])])
        S = H @ self.P @ H.T + self.R
        return y, S, H

    def update(self, z: FloatArray, landmark_xy_m: FloatArray,
               mount: LidarMount = _NO_MOUNT) -> float:
        """Correct with z = [range m, bearing rad] (0 = sensor forward) of a known landmark.

        Returns:
            The normalised innovation squared (NIS) of this observation.
        """
        self.x_prior = self.x.copy()
        self.P_prior = self.P.copy()
        y, S, H = self.innovation(z, landmark_xy_m, mount)
        S_inv = _inverse_2x2(S)
        PHt = self.P @ H.T
        K = PHt @ S_inv
        self.x = self.x + K @ y
        self.x[YAW] = wrap_scalar(self.x[YAW])
        I_KH = _IDENTITY - K @ H
        P = I_KH @ self.P @ I_KH.T + K @ self.R @ K.T
        self.P = 0.5 * (P + P.T)
        self.y, self.S, self.K = y, S, K
        self.nis = float(y @ S_inv @ y)
        return self.nis


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


def _inverse_2x2(S: FloatArray) -> FloatArray:
    a, b, c, d = S[0, 0], S[0, 1], S[1, 0], S[1, 1]
    det = a * d - b * c
    if not det > 0.0:
        raise CoreError(f'innovation covariance is not positive definite: {S.tolist()}')
    return np.array([[d, -b], [-c, a]]) / det
