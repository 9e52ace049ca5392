"""The report's models, each written once: f, J, Ju, Q, h, H (and R's map term).

State ``x = [x, y, yaw, b]`` (m, m, rad, rad/s; entries named X, Y, YAW, BIAS in
``types.py``); inputs ``u = [v, w]`` (speed m/s, measured yaw rate rad/s, bias included).
From the MTRN4010 Project 3 report (``../shared/course-notes/003_3aeb4dcf00f2eae3.txt``),
over a step of T seconds::

    x   += T v cos(yaw)          J = [[1, 0, -T v sin(yaw),  0],
    y   += T v sin(yaw)               [0, 1,  T v cos(yaw),  0],
    yaw += T (w - b)                  [0, 0,  1,            -T],
    b   += 0 (+ random walk)          [0, 0,  0,             1]]

    Q = Ju Pu Ju^T + Q2,   Ju = [[T cos(yaw), 0], [T sin(yaw), 0], [0, T], [0, 0]],
    Pu = diag(sigma_v^2, sigma_w^2),   Q2 = diag(q^2 T, q^2 T, 0, (q_b T)^2).

The report's Q2 has (q_pos T)^2 for x and y; here they follow a random walk of density q
(m/sqrt(s)), so the position noise per second does not depend on the IMU rate.

The gyro's wander (a fifth state c, WANDER, when the state has one): a first-order
Gauss-Markov process of stationary sigma s and correlation time tau, added to the bias::

    yaw += T (w - b - c)         J[YAW, WANDER] = -T
    c   *= phi,  phi = exp(-T / tau)        J[WANDER, WANDER] = phi
    Q2[WANDER, WANDER] = s^2 (1 - phi^2)     (keeps c's variance at s^2)

With s = 0 and c = 0 (no wander found) the first four rows are the report's exactly.

Observation of a landmark at (xa, ya) by a LiDAR mounted at (Lx, Ly, alpha) on the
platform (``../shared/data/mtrn4010/README.md``, "Observation model")::

    xL = x + Lx cos(yaw) - Ly sin(yaw),  yL = y + Lx sin(yaw) + Ly cos(yaw)
    h  = [hypot(xa - xL, ya - yL),  atan2(ya - yL, xa - xL) - yaw - alpha + bearing_zero]

``bearing_zero`` is 0 in ROS convention (0 = forward) and pi/2 for the course's raw
2016 scans (0 = right); with Lx = Ly = alpha = 0 and pi/2 it is exactly the report's h,
and ``observation_jacobian`` is the report's H. Standing still, a gyro sample measures
the bias alone: h = b (+ c), H = [0, 0, 0, 1 (, 1)] (``observe_bias``).

Every function takes a state whose first entries are X, Y, YAW, BIAS and, when it has a
fifth, WANDER (a four-entry state is the report's model without the wander). The filter's
hot path (``_ekf_kernel.py``) unrolls these same lines; tests check it against them.
"""

from __future__ import annotations

import math

import numpy as np

from gyro_ekf.core.angles import wrap_angle, wrap_scalar
from gyro_ekf.core.types import BIAS, WANDER, X, Y, YAW, FloatArray, LidarMount

_NO_MOUNT = LidarMount()

SPEED, RATE = 0, 1
"""Entries of the input u = [v, w] (columns of Ju, rows of Pu)."""

RANGE, BEARING = 0, 1
"""Entries of an observation z = [range, bearing] (rows of h and H)."""


def _has_wander(state: FloatArray) -> bool:
    return np.size(state) > WANDER


def wander_decay(dt_s: float, wander_tau_s: float) -> float:
    """Return phi = exp(-T / tau): how much of the wander is left after dt_s."""
    return math.exp(-dt_s / wander_tau_s)


def predict_state(state: FloatArray, speed_m_s: float, rate_rad_s: float,
                  dt_s: float, wander_tau_s: float = math.inf) -> FloatArray:
    """f: the state after dt_s with constant inputs, shape (n,) in and out."""
    x = np.array(state, dtype=np.float64)
    yaw = x[YAW]
    x[X] += dt_s * speed_m_s * math.cos(yaw)
    x[Y] += dt_s * speed_m_s * math.sin(yaw)
    error = x[BIAS]
    if _has_wander(x):
        error += x[WANDER]
        x[WANDER] *= wander_decay(dt_s, wander_tau_s)
    x[YAW] = wrap_scalar(yaw + dt_s * (rate_rad_s - error))
    return x


def process_jacobian(state: FloatArray, speed_m_s: float, dt_s: float,
                     wander_tau_s: float = math.inf) -> FloatArray:
    """J = df/dx at the prior state, shape (n, n)."""
    yaw = state[YAW]
    J = np.eye(np.size(state))
    J[X, YAW] = -dt_s * speed_m_s * math.sin(yaw)
    J[Y, YAW] = dt_s * speed_m_s * math.cos(yaw)
    J[YAW, BIAS] = -dt_s
    if _has_wander(state):
        J[YAW, WANDER] = -dt_s
        J[WANDER, WANDER] = wander_decay(dt_s, wander_tau_s)
    return J


def input_jacobian(state: FloatArray, dt_s: float) -> FloatArray:
    """Ju = df/du (u = [speed, rate]) at the prior state, shape (n, 2)."""
    yaw = state[YAW]
    Ju = np.zeros((np.size(state), 2))
    Ju[X, SPEED] = dt_s * math.cos(yaw)
    Ju[Y, SPEED] = dt_s * math.sin(yaw)
    Ju[YAW, RATE] = dt_s
    return Ju


def process_noise(state: FloatArray, dt_s: float, speed_sigma_m_s: float,
                  rate_sigma_rad_s: float, position_walk_m_sqrt_s: float,
                  bias_walk_rad_s2: float, wander_sigma_rad_s: float = 0.0,
                  wander_tau_s: float = math.inf) -> FloatArray:
    """Q = Ju Pu Ju^T + Q2 over one step, shape (n, n)."""
    Ju = input_jacobian(state, dt_s)
    Pu = np.diag([speed_sigma_m_s ** 2, rate_sigma_rad_s ** 2])
    Q2 = np.zeros((np.size(state), np.size(state)))
    Q2[X, X] = Q2[Y, Y] = position_walk_m_sqrt_s ** 2 * dt_s
    Q2[BIAS, BIAS] = (bias_walk_rad_s2 * dt_s) ** 2
    if _has_wander(state):
        Q2[WANDER, WANDER] = wander_sigma_rad_s ** 2 * (
            1.0 - wander_decay(dt_s, wander_tau_s) ** 2)
    return Ju @ Pu @ Ju.T + Q2


def sensor_position(state: FloatArray, mount: LidarMount = _NO_MOUNT) -> tuple[float, float]:
    """Position (m) of the LiDAR origin in the map frame: (xL, yL)."""
    x, y, yaw = state[X], state[Y], state[YAW]
    c, s = math.cos(yaw), math.sin(yaw)
    return x + mount.x_m * c - mount.y_m * s, y + mount.x_m * s + mount.y_m * c


def _landmark_offsets(state: FloatArray, landmark_xy_m: FloatArray, mount: LidarMount
                      ) -> tuple[FloatArray, FloatArray]:
    """(xa - xL, ya - yL) of each landmark: what h and H are made of."""
    xl, yl = sensor_position(state, mount)
    landmarks = np.asarray(landmark_xy_m, dtype=np.float64)
    return landmarks[..., 0] - xl, landmarks[..., 1] - yl


def _h(state: FloatArray, dx: FloatArray, dy: FloatArray, mount: LidarMount,
       bearing_zero_rad: float) -> FloatArray:
    bearing = np.arctan2(dy, dx) - state[YAW] - mount.yaw_rad + bearing_zero_rad
    return np.stack([np.hypot(dx, dy), wrap_angle(bearing)], axis=-1)


def _H(state: FloatArray, dx: FloatArray, dy: FloatArray, mount: LidarMount) -> FloatArray:
    c, s = math.cos(state[YAW]), math.sin(state[YAW])
    # d(xL)/d(yaw) and d(yL)/d(yaw): the sensor swings around the reference point.
    dxl_dyaw = -mount.x_m * s - mount.y_m * c
    dyl_dyaw = mount.x_m * c - mount.y_m * s
    r2 = dx * dx + dy * dy
    r = np.sqrt(r2)
    H = np.zeros(np.shape(dx) + (2, np.size(state)))
    H[..., RANGE, X] = -dx / r
    H[..., RANGE, Y] = -dy / r
    H[..., RANGE, YAW] = -(dx * dxl_dyaw + dy * dyl_dyaw) / r
    H[..., BEARING, X] = dy / r2
    H[..., BEARING, Y] = -dx / r2
    H[..., BEARING, YAW] = (dy * dxl_dyaw - dx * dyl_dyaw) / r2 - 1.0
    return H


def observe(state: FloatArray, landmark_xy_m: FloatArray, mount: LidarMount = _NO_MOUNT,
            bearing_zero_rad: float = 0.0) -> FloatArray:
    """h: predicted [range m, bearing rad] of landmarks, (2,) for one, (k, 2) for (k, 2)."""
    dx, dy = _landmark_offsets(state, landmark_xy_m, mount)
    return _h(state, dx, dy, mount, bearing_zero_rad)


def observation_jacobian(state: FloatArray, landmark_xy_m: FloatArray,
                         mount: LidarMount = _NO_MOUNT) -> FloatArray:
    """H = dh/dx, shape (2, n) for one landmark or (k, 2, n) for (k, 2) landmarks."""
    dx, dy = _landmark_offsets(state, landmark_xy_m, mount)
    return _H(state, dx, dy, mount)


def observe_with_jacobian(state: FloatArray, landmark_xy_m: FloatArray,
                          mount: LidarMount = _NO_MOUNT) -> tuple[FloatArray, FloatArray]:
    """Predict h and H together from one geometry (association needs both per landmark).

    Returns:
        h: [range m, bearing rad (0 = sensor forward)], shape (..., 2).
        H: dh/dx, shape (..., 2, n).
    """
    dx, dy = _landmark_offsets(state, landmark_xy_m, mount)
    return _h(state, dx, dy, mount, 0.0), _H(state, dx, dy, mount)


def observation_noise(range_m: float | FloatArray, sensor_noise: FloatArray,
                      landmark_var_m2: float) -> FloatArray:
    """R of landmarks at predicted ranges: sensor noise plus the map's, (..., 2, 2).

    A landmark's map position off by sigma along any axis moves its range by sigma and its
    bearing by sigma / range, so the map adds diag(sigma^2, sigma^2 / range^2) to the
    sensor's R = diag(sigma_r^2, sigma_b^2).
    """
    range_m = np.asarray(range_m, dtype=np.float64)
    R = np.zeros(range_m.shape + (2, 2)) + sensor_noise
    R[..., RANGE, RANGE] += landmark_var_m2
    # A landmark at the sensor (range 0) has no bearing; its H is NaN already.
    with np.errstate(divide='ignore', invalid='ignore'):
        R[..., BEARING, BEARING] += landmark_var_m2 / (range_m * range_m)
    return R


def observe_bias(state: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Predict a gyro sample taken standing still: h = [b + c], H = [[0, 0, 0, 1, 1]], (1, n)."""
    H = np.zeros((1, np.size(state)))
    H[0, BIAS] = 1.0
    h = state[BIAS]
    if _has_wander(state):
        H[0, WANDER] = 1.0
        h += state[WANDER]
    return np.array([h], dtype=np.float64), H


def sensor_to_map(state: FloatArray, points_sensor_m: FloatArray,
                  mount: LidarMount = _NO_MOUNT) -> FloatArray:
    """Points (k, 2) in the sensor frame to the map frame at the given platform pose."""
    xl, yl = sensor_position(state, mount)
    heading = state[YAW] + mount.yaw_rad
    c, s = math.cos(heading), math.sin(heading)
    points = np.asarray(points_sensor_m, dtype=np.float64).reshape(-1, 2)
    return np.column_stack([xl + c * points[:, 0] - s * points[:, 1],
                            yl + s * points[:, 0] + c * points[:, 1]])


def sensor_point_to_map(state: list[float] | FloatArray, x_m: float, y_m: float,
                        mount: LidarMount = _NO_MOUNT) -> tuple[float, float]:
    """One sensor-frame point to the map frame in plain floats (sensor_to_map for one)."""
    return sensor_points_to_map(state, [(x_m, y_m)], mount)[0]


def sensor_points_to_map(state: list[float] | FloatArray, points_m: list,
                         mount: LidarMount = _NO_MOUNT) -> list[tuple[float, float]]:
    """Sensor-frame points [(x, y), ...] to the map frame in plain floats (sensor_to_map)."""
    # Plain floats (a numpy state gives numpy scalars), the sensor's place once per scan:
    # this runs at every update of a run (its update log).
    xl, yl = sensor_position(state, mount)
    xl, yl = float(xl), float(yl)
    heading = float(state[YAW]) + mount.yaw_rad
    ch, sh = math.cos(heading), math.sin(heading)
    return [(xl + ch * x_m - sh * y_m, yl + sh * x_m + ch * y_m) for x_m, y_m in points_m]


def points_less_range(points_sensor_m: FloatArray, offset_m: float) -> FloatArray:
    """Points (k, 2) in the sensor frame moved offset_m toward the sensor along their rays.

    The poles a LiDAR whose ranges read offset_m long saw, where they stand
    (``lidar.<topic>.range_offset_m``): a range offset moves every return of a pole along
    its own beam, so the centre moves along the ray to it by as much. Points nearer than
    the offset are left where they are (no pole is detected that near).
    """
    points = np.asarray(points_sensor_m, dtype=np.float64).reshape(-1, 2)
    if not offset_m or not len(points):
        return points
    ranges = np.hypot(points[:, 0], points[:, 1])
    scale = np.where(ranges > abs(offset_m), 1.0 - offset_m / np.maximum(ranges, 1e-300), 1.0)
    return points * scale[:, None]


def points_upright(points_sensor_m: FloatArray) -> FloatArray:
    """Points (k, 2) of a LiDAR mounted upside down, in the frame of one mounted upright.

    Upside down is turned half a turn about its x axis (roll pi, ``lidar.<topic>
    .upside_down``): x still points where its mount's yaw says, but its bearings run
    clockwise seen from above, so y is negated. (Half a turn about y instead is this and
    a yaw of 180 deg more.)
    """
    points = np.asarray(points_sensor_m, dtype=np.float64).reshape(-1, 2)
    return points * np.array([1.0, -1.0])


def points_to_range_bearing(points_sensor_m: FloatArray) -> FloatArray:
    """Points (k, 2) in the sensor frame to observations (k, 2): range m, bearing rad."""
    points = np.asarray(points_sensor_m, dtype=np.float64).reshape(-1, 2)
    # Filled in place, not column_stack'ed: this runs for every scan, with a few points.
    observations = np.empty_like(points)
    observations[:, 0] = np.hypot(points[:, 0], points[:, 1])
    observations[:, 1] = np.arctan2(points[:, 1], points[:, 0])
    return observations
