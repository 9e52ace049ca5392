"""Process and observation models of the gyro-bias EKF, with their Jacobians.

State ``x = [x, y, yaw, b]`` (m, m, rad, rad/s); inputs ``u = [v, w]`` (speed m/s, measured
yaw rate rad/s, bias included). From the MTRN4010 Project 3 report
(``../shared/course-notes/003_3aeb4dcf00f2eae3.txt``), over a step of T seconds::

    x   += T v cos(yaw)          J = [[1, 0, -T v sin(yaw),  0],
    y   += T v sin(yaw)               [0, 1,  T v cos(yaw),  0],
    yaw += T (w - b)                  [0, 0,  1,            -T],
    b   += 0 (+ random walk)          [0, 0,  0,             1]]

    Q = Ju Pu Ju^T + Q2,   Ju = [[T cos(yaw), 0], [T sin(yaw), 0], [0, T], [0, 0]],
    Pu = diag(sigma_v^2, sigma_w^2),   Q2 = diag(q^2 T, q^2 T, 0, (q_b T)^2).

The report's Q2 has (q_pos T)^2 for x and y; here they follow a random walk of density q
(m/sqrt(s)), so the position noise per second does not depend on the IMU rate.

Observation of a landmark at (xa, ya) by a LiDAR mounted at (Lx, Ly, alpha) on the
platform (``../shared/data/mtrn4010/README.md``, "Observation model")::

    xL = x + Lx cos(yaw) - Ly sin(yaw),  yL = y + Lx sin(yaw) + Ly cos(yaw)
    h  = [hypot(xa - xL, ya - yL),  atan2(ya - yL, xa - xL) - yaw - alpha + bearing_zero]

``bearing_zero`` is 0 in ROS convention (0 = forward) and pi/2 for the course's raw
2016 scans (0 = right); with Lx = Ly = alpha = 0 and pi/2 it is exactly the report's h,
and ``observation_jacobian`` is the report's H.
"""

from __future__ import annotations

import math

import numpy as np

from gyro_ekf.core.angles import wrap_angle, wrap_scalar
from gyro_ekf.core.types import FloatArray, LidarMount

_NO_MOUNT = LidarMount()


def predict_state(state: FloatArray, speed_m_s: float, rate_rad_s: float,
                  dt_s: float) -> FloatArray:
    """Propagate the state over dt_s with constant inputs. Shape (4,) in and out."""
    x, y, yaw, bias = state
    return np.array([
        x + dt_s * speed_m_s * math.cos(yaw),
        y + dt_s * speed_m_s * math.sin(yaw),
        wrap_scalar(yaw + dt_s * (rate_rad_s - bias)),
        bias,
    ])


def process_jacobian(state: FloatArray, speed_m_s: float, dt_s: float) -> FloatArray:
    """J = df/dx at the prior state, shape (4, 4)."""
    yaw = state[2]
    return np.array([
        [1.0, 0.0, -dt_s * speed_m_s * math.sin(yaw), 0.0],
        [0.0, 1.0, dt_s * speed_m_s * math.cos(yaw), 0.0],
        [0.0, 0.0, 1.0, -dt_s],
        [0.0, 0.0, 0.0, 1.0],
    ])


def input_jacobian(state: FloatArray, dt_s: float) -> FloatArray:
    """Ju = df/du (u = [speed, rate]) at the prior state, shape (4, 2)."""
    yaw = state[2]
    return np.array([
        [dt_s * math.cos(yaw), 0.0],
        [dt_s * math.sin(yaw), 0.0],
        [0.0, dt_s],
        [0.0, 0.0],
    ])


def process_noise(state: FloatArray, dt_s: float, speed_sigma_m_s: float,
                  rate_sigma_rad_s: float, position_walk_m_sqrt_s: float,
                  bias_walk_rad_s2: float) -> FloatArray:
    """Q = Ju Pu Ju^T + Q2 over one step, shape (4, 4)."""
    ju = input_jacobian(state, dt_s)
    pu = np.diag([speed_sigma_m_s ** 2, rate_sigma_rad_s ** 2])
    position_var = position_walk_m_sqrt_s ** 2 * dt_s
    q2 = np.diag([position_var, position_var, 0.0, (bias_walk_rad_s2 * dt_s) ** 2])
    return ju @ pu @ ju.T + q2


def sensor_position(state: FloatArray, mount: LidarMount = _NO_MOUNT) -> tuple[float, float]:
    """Position (m) of the LiDAR origin in the map frame."""
    x, y, yaw = state[0], state[1], state[2]
    c, s = math.cos(yaw), math.sin(yaw)
    return x + mount.x_m * c - mount.y_m * s, y + mount.x_m * s + mount.y_m * c


def observe(state: FloatArray, landmark_xy_m: FloatArray, mount: LidarMount = _NO_MOUNT,
            bearing_zero_rad: float = 0.0) -> FloatArray:
    """Predict [range m, bearing rad] of landmarks: shape (2,) for one, (k, 2) for (k, 2)."""
    xl, yl = sensor_position(state, mount)
    landmarks = np.asarray(landmark_xy_m, dtype=np.float64)
    dx = landmarks[..., 0] - xl
    dy = landmarks[..., 1] - yl
    bearing = wrap_angle(np.arctan2(dy, dx) - state[2] - mount.yaw_rad + bearing_zero_rad)
    return np.stack([np.hypot(dx, dy), bearing], axis=-1)


def observation_jacobian(state: FloatArray, landmark_xy_m: FloatArray,
                         mount: LidarMount = _NO_MOUNT) -> FloatArray:
    """H = dh/dx, shape (2, 4) for one landmark or (k, 2, 4) for (k, 2) landmarks."""
    return observe_with_jacobian(state, landmark_xy_m, mount)[1]


def observe_with_jacobian(state: FloatArray, landmark_xy_m: FloatArray,
                          mount: LidarMount = _NO_MOUNT) -> tuple[FloatArray, FloatArray]:
    """Predict h and H together from one geometry (association needs both per landmark).

    Returns:
        h: [range m, bearing rad (0 = sensor forward)], shape (..., 2).
        H: dh/dx, shape (..., 2, 4).
    """
    yaw = float(state[2])
    c, s = math.cos(yaw), math.sin(yaw)
    xl, yl = sensor_position(state, mount)
    # d(xL)/d(yaw) and d(yL)/d(yaw): the sensor swings around the reference point.
    dxl_dyaw = -mount.x_m * s - mount.y_m * c
    dyl_dyaw = mount.x_m * c - mount.y_m * s
    landmarks = np.asarray(landmark_xy_m, dtype=np.float64)
    dx = landmarks[..., 0] - xl
    dy = landmarks[..., 1] - yl
    r2 = dx * dx + dy * dy
    r = np.sqrt(r2)
    h = np.empty(landmarks.shape[:-1] + (2,))
    h[..., 0] = r
    h[..., 1] = wrap_angle(np.arctan2(dy, dx) - yaw - mount.yaw_rad)
    jac = np.zeros(landmarks.shape[:-1] + (2, 4))
    jac[..., 0, 0] = -dx / r
    jac[..., 0, 1] = -dy / r
    jac[..., 0, 2] = -(dx * dxl_dyaw + dy * dyl_dyaw) / r
    jac[..., 1, 0] = dy / r2
    jac[..., 1, 1] = -dx / r2
    jac[..., 1, 2] = (dy * dxl_dyaw - dx * dyl_dyaw) / r2 - 1.0
    return h, jac


def sensor_to_map(state: FloatArray, points_sensor_m: FloatArray,
                  mount: LidarMount = _NO_MOUNT) -> FloatArray:
    """Points (k, 2) in the sensor frame to the map frame at the given platform pose."""
    xl, yl = sensor_position(state, mount)
    heading = state[2] + mount.yaw_rad
    c, s = math.cos(heading), math.sin(heading)
    points = np.asarray(points_sensor_m, dtype=np.float64).reshape(-1, 2)
    return np.column_stack([xl + c * points[:, 0] - s * points[:, 1],
                            yl + s * points[:, 0] + c * points[:, 1]])


def sensor_point_to_map(state: list[float] | FloatArray, x_m: float, y_m: float,
                        mount: LidarMount = _NO_MOUNT) -> tuple[float, float]:
    """One sensor-frame point to the map frame in plain floats (sensor_to_map for one)."""
    xl, yl = (float(v) for v in sensor_position(state, mount))
    heading = float(state[2]) + mount.yaw_rad
    ch, sh = math.cos(heading), math.sin(heading)
    return xl + ch * x_m - sh * y_m, yl + sh * x_m + ch * y_m


def points_to_range_bearing(points_sensor_m: FloatArray) -> FloatArray:
    """Points (k, 2) in the sensor frame to observations (k, 2): range m, bearing rad."""
    points = np.asarray(points_sensor_m, dtype=np.float64).reshape(-1, 2)
    return np.column_stack([np.hypot(points[:, 0], points[:, 1]),
                            np.arctan2(points[:, 1], points[:, 0])])
