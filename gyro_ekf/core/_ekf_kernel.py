"""The filter's one fast path: ``ekf.Textbook``'s lines unrolled on plain floats (private).

Only for the filter's state [x, y, yaw, b, c] (c: the gyro's wander); tests check every
function against the readable definition (``ekf.Textbook`` with ``models.py``) on random
states and covariances to 1e-12. Why it exists: J and H are sparse, and at this size
numpy's per-call overhead costs several times the arithmetic itself (`make bench`: the
core must stay >= 5x filterpy per cycle and `gyro-ekf run` >= 150x real time on the 2016
log).

State ``s = [x, y, yaw, b, c]``; covariance ``p`` = upper triangle of the symmetric P, row
by row, unpacked into names: p_x_yaw is P[X, YAW], p_b_c is P[BIAS, WANDER]. Same interface
as ``ekf.Textbook``.
"""

from __future__ import annotations

import math

from gyro_ekf.core.angles import wrap_scalar
from gyro_ekf.core.errors import CoreError
from gyro_ekf.core.types import LidarMount

_PI, _TWO_PI = math.pi, 2.0 * math.pi

STATE_SIZE = 5


def predict(s: list[float], p: list[float], speed_m_s: float, rate_rad_s: float,
            dt_s: float, speed_var: float, rate_var: float, position_walk_var: float,
            bias_walk_var: float, hold_position: bool, wander_sigma_rad_s: float,
            wander_tau_s: float) -> tuple[list[float], list[float]]:
    """Predict: x = f(x, u); P = J P J^T + Q (see ``ekf.Textbook.predict``)."""
    x, y, yaw, bias, wander = s
    c, sn = math.cos(yaw), math.sin(yaw)
    step = 0.0 if hold_position else dt_s * speed_m_s
    phi = math.exp(-dt_s / wander_tau_s)
    s = [x + step * c, y + step * sn, wrap_scalar(yaw + dt_s * (rate_rad_s - bias - wander)),
         bias, phi * wander]
    # J = I + E with E[X, YAW] = j_x, E[Y, YAW] = j_y, E[YAW, BIAS] = E[YAW, WANDER] = j_yaw,
    # and J[WANDER, WANDER] = phi; first M = J P (the entries J P J^T needs) ...
    j_x, j_y, j_yaw = -step * sn, step * c, -dt_s
    (p_x_x, p_x_y, p_x_yaw, p_x_b, p_x_c, p_y_y, p_y_yaw, p_y_b, p_y_c, p_yaw_yaw, p_yaw_b,
     p_yaw_c, p_b_b, p_b_c, p_c_c) = p
    m_x_x = p_x_x + j_x * p_x_yaw
    m_x_y = p_x_y + j_x * p_y_yaw
    m_x_yaw = p_x_yaw + j_x * p_yaw_yaw
    m_x_b = p_x_b + j_x * p_yaw_b
    m_x_c = p_x_c + j_x * p_yaw_c
    m_y_y = p_y_y + j_y * p_y_yaw
    m_y_yaw = p_y_yaw + j_y * p_yaw_yaw
    m_y_b = p_y_b + j_y * p_yaw_b
    m_y_c = p_y_c + j_y * p_yaw_c
    m_yaw_yaw = p_yaw_yaw + j_yaw * (p_yaw_b + p_yaw_c)
    m_yaw_b = p_yaw_b + j_yaw * (p_b_b + p_b_c)
    m_yaw_c = p_yaw_c + j_yaw * (p_b_c + p_c_c)
    # ... then J P J^T = M J^T, plus Q = Ju Pu Ju^T + Q2 (speed noise lies along the
    # heading; held, the odometry's zero is exact: no speed noise).
    t2 = dt_s * dt_s
    q_v = 0.0 if hold_position else t2 * speed_var
    q_w = t2 * rate_var
    q_p = dt_s * position_walk_var
    return s, [
        m_x_x + j_x * m_x_yaw + q_v * c * c + q_p,
        m_x_y + j_y * m_x_yaw + q_v * c * sn,
        m_x_yaw + j_yaw * (m_x_b + m_x_c),
        m_x_b,
        phi * m_x_c,
        m_y_y + j_y * m_y_yaw + q_v * sn * sn + q_p,
        m_y_yaw + j_yaw * (m_y_b + m_y_c),
        m_y_b,
        phi * m_y_c,
        m_yaw_yaw + j_yaw * (m_yaw_b + m_yaw_c) + q_w,
        m_yaw_b,
        phi * m_yaw_c,
        p_b_b + t2 * bias_walk_var,
        phi * p_b_c,
        phi * phi * p_c_c + wander_sigma_rad_s * wander_sigma_rad_s * (1.0 - phi * phi),
    ]


def innovation_terms(s: list[float], p: list[float], landmark_x_m: float,
                     landmark_y_m: float, mount: LidarMount, range_var: float,
                     cross_var: float, bearing_var: float, landmark_var_m2: float,
                     noise_scale: float, full: bool = True) -> tuple:
    """Compute h, H, R, P H^T and S of one landmark (what an update and the gate share).

    As ``models.observe_with_jacobian``, ``models.observation_noise`` (R = the sensor's
    [[range_var, cross_var], [cross_var, bearing_var]] plus the map's diag(s2, s2 / r^2),
    all times noise_scale) and ``ekf.innovation_covariance``.

    Returns:
        (range, bearing (not wrapped)), H's range row and bearing row over (x, y, yaw)
        (its bias and wander columns are zero), P H^T's range and bearing columns, (R00,
        R11) and S as (s00, s01, s11). Not ``full`` (the gate's): (range, bearing) and S
        alone, the same numbers; P H^T's bias and wander rows are left out (the gate tries
        every landmark on every scan, and S does not need them).

    Raises:
        ZeroDivisionError: the landmark is at the sensor (no bearing).
    """
    x, y, yaw = s[0], s[1], s[2]
    (p_x_x, p_x_y, p_x_yaw, p_x_b, p_x_c, p_y_y, p_y_yaw, p_y_b, p_y_c, p_yaw_yaw, p_yaw_b,
     p_yaw_c, _, _, _) = p
    # h and H.
    c, sn = math.cos(yaw), math.sin(yaw)
    xl = x + mount.x_m * c - mount.y_m * sn
    yl = y + mount.x_m * sn + mount.y_m * c
    # d(xL)/d(yaw) and d(yL)/d(yaw): the sensor swings around the reference point.
    dxl = -mount.x_m * sn - mount.y_m * c
    dyl = mount.x_m * c - mount.y_m * sn
    dx = landmark_x_m - xl
    dy = landmark_y_m - yl
    r2 = dx * dx + dy * dy
    r = math.sqrt(r2)
    hr_x, hr_y, hr_yaw = -dx / r, -dy / r, -(dx * dxl + dy * dyl) / r
    hb_x, hb_y, hb_yaw = dy / r2, -dx / r2, (dy * dxl - dx * dyl) / r2 - 1.0
    # R with the map's share.
    rr = (range_var + landmark_var_m2) * noise_scale
    rb = (bearing_var + landmark_var_m2 / r2) * noise_scale
    # P H^T (columns a: range, b: bearing) and S = H P H^T + R.
    a_x = p_x_x * hr_x + p_x_y * hr_y + p_x_yaw * hr_yaw
    a_y = p_x_y * hr_x + p_y_y * hr_y + p_y_yaw * hr_yaw
    a_yaw = p_x_yaw * hr_x + p_y_yaw * hr_y + p_yaw_yaw * hr_yaw
    b_x = p_x_x * hb_x + p_x_y * hb_y + p_x_yaw * hb_yaw
    b_y = p_x_y * hb_x + p_y_y * hb_y + p_y_yaw * hb_yaw
    b_yaw = p_x_yaw * hb_x + p_y_yaw * hb_y + p_yaw_yaw * hb_yaw
    h = (r, math.atan2(dy, dx) - yaw - mount.yaw_rad)
    S = (hr_x * a_x + hr_y * a_y + hr_yaw * a_yaw + rr,
         hr_x * b_x + hr_y * b_y + hr_yaw * b_yaw + cross_var * noise_scale,
         hb_x * b_x + hb_y * b_y + hb_yaw * b_yaw + rb)
    if not full:
        return h, S
    a_b = p_x_b * hr_x + p_y_b * hr_y + p_yaw_b * hr_yaw
    a_c = p_x_c * hr_x + p_y_c * hr_y + p_yaw_c * hr_yaw
    b_b = p_x_b * hb_x + p_y_b * hb_y + p_yaw_b * hb_yaw
    b_c = p_x_c * hb_x + p_y_c * hb_y + p_yaw_c * hb_yaw
    return (h, (hr_x, hr_y, hr_yaw, hb_x, hb_y, hb_yaw),
            (a_x, a_y, a_yaw, a_b, a_c, b_x, b_y, b_yaw, b_b, b_c), (rr, rb), S)


def inverse(s00: float, s01: float, s11: float) -> tuple[float, float, float]:
    """S^-1 of a symmetric 2x2 S: its entries 00, 01, 11.

    Raises:
        CoreError: S is not positive definite.
    """
    det = s00 * s11 - s01 * s01
    if not (det > 0.0 and s00 > 0.0):
        raise CoreError(f'innovation covariance is not positive definite: '
                        f'[[{s00}, {s01}], [{s01}, {s11}]]')
    return s11 / det, -s01 / det, s00 / det


def mahalanobis_sq(y0: float, y1: float, i00: float, i01: float, i11: float) -> float:
    """Return y^T S^-1 y for S^-1 = [[i00, i01], [i01, i11]]."""
    return y0 * (i00 * y0 + i01 * y1) + y1 * (i01 * y0 + i11 * y1)


def mahalanobis_table(observations: list[list[float]],
                      predictions: list[tuple[float, float, float, float, float]]
                      ) -> list[list[float]]:
    """Return mahalanobis_sq of every observation against every prediction.

    observations: (range, bearing) per detection; predictions: (range, bearing, i00, i01,
    i11) per landmark. The bearing difference is wrapped as angles.wrap_scalar does. The
    same numbers as the two calls per pair, unrolled: association runs it on every scan
    (147 000 pairs over the 2016 log, a third less time; test_ekf_kernel.py).
    """
    rows = []
    for z_range, z_bearing in observations:
        row = []
        for h0, h1, i00, i01, i11 in predictions:
            y0 = z_range - h0
            y1 = (z_bearing - h1 + _PI) % _TWO_PI - _PI
            row.append(y0 * (i00 * y0 + i01 * y1) + y1 * (i01 * y0 + i11 * y1))
        rows.append(row)
    return rows


def update(s: list[float], p: list[float], z_range: float, z_bearing: float,
           landmark_x_m: float, landmark_y_m: float, mount: LidarMount, range_var: float,
           bearing_var: float, landmark_var_m2: float, noise_scale: float) -> tuple:
    """Landmark update, Joseph form (see ``ekf.Textbook.update``).

    Returns:
        s, p, y (2), S (s00, s01, s11), K (row by row, 10), NIS against the unscaled R.
    """
    (r, bearing), (hr_x, hr_y, hr_yaw, hb_x, hb_y, hb_yaw), \
        (a_x, a_y, a_yaw, a_b, a_c, b_x, b_y, b_yaw, b_b, b_c), (rr, rb), (s00, s01, s11) = \
        innovation_terms(s, p, landmark_x_m, landmark_y_m, mount, range_var, 0.0,
                         bearing_var, landmark_var_m2, noise_scale)
    y0 = z_range - r
    y1 = wrap_scalar(z_bearing - bearing)
    i00, i01, i11 = inverse(s00, s01, s11)
    x, y, yaw, bias, wander = s
    (p_x_x, p_x_y, p_x_yaw, p_x_b, p_x_c, p_y_y, p_y_yaw, p_y_b, p_y_c, p_yaw_yaw, p_yaw_b,
     p_yaw_c, p_b_b, p_b_c, p_c_c) = p
    # K = P H^T S^-1, one row per state.
    k_x0, k_x1 = a_x * i00 + b_x * i01, a_x * i01 + b_x * i11
    k_y0, k_y1 = a_y * i00 + b_y * i01, a_y * i01 + b_y * i11
    k_yaw0, k_yaw1 = a_yaw * i00 + b_yaw * i01, a_yaw * i01 + b_yaw * i11
    k_b0, k_b1 = a_b * i00 + b_b * i01, a_b * i01 + b_b * i11
    k_c0, k_c1 = a_c * i00 + b_c * i01, a_c * i01 + b_c * i11
    s = [x + k_x0 * y0 + k_x1 * y1, y + k_y0 * y0 + k_y1 * y1,
         wrap_scalar(yaw + k_yaw0 * y0 + k_yaw1 * y1), bias + k_b0 * y0 + k_b1 * y1,
         wander + k_c0 * y0 + k_c1 * y1]
    # Joseph form P = A P A^T + K R K^T with A = I - K H, evaluated as B = A P (row i:
    # B_ij = P_ij - k_i0 a_j - k_i1 b_j), then A P A^T = B - (B H^T) K^T. H's bias and
    # wander columns are zero, so B H^T needs B's x, y and yaw columns only, and P's
    # upper triangle needs B's entries on and above the diagonal.
    bx_x = p_x_x - k_x0 * a_x - k_x1 * b_x
    bx_y = p_x_y - k_x0 * a_y - k_x1 * b_y
    bx_yaw = p_x_yaw - k_x0 * a_yaw - k_x1 * b_yaw
    bx_b = p_x_b - k_x0 * a_b - k_x1 * b_b
    bx_c = p_x_c - k_x0 * a_c - k_x1 * b_c
    by_x = p_x_y - k_y0 * a_x - k_y1 * b_x
    by_y = p_y_y - k_y0 * a_y - k_y1 * b_y
    by_yaw = p_y_yaw - k_y0 * a_yaw - k_y1 * b_yaw
    by_b = p_y_b - k_y0 * a_b - k_y1 * b_b
    by_c = p_y_c - k_y0 * a_c - k_y1 * b_c
    byaw_x = p_x_yaw - k_yaw0 * a_x - k_yaw1 * b_x
    byaw_y = p_y_yaw - k_yaw0 * a_y - k_yaw1 * b_y
    byaw_yaw = p_yaw_yaw - k_yaw0 * a_yaw - k_yaw1 * b_yaw
    byaw_b = p_yaw_b - k_yaw0 * a_b - k_yaw1 * b_b
    byaw_c = p_yaw_c - k_yaw0 * a_c - k_yaw1 * b_c
    bb_x = p_x_b - k_b0 * a_x - k_b1 * b_x
    bb_y = p_y_b - k_b0 * a_y - k_b1 * b_y
    bb_yaw = p_yaw_b - k_b0 * a_yaw - k_b1 * b_yaw
    bb_b = p_b_b - k_b0 * a_b - k_b1 * b_b
    bb_c = p_b_c - k_b0 * a_c - k_b1 * b_c
    bc_x = p_x_c - k_c0 * a_x - k_c1 * b_x
    bc_y = p_y_c - k_c0 * a_y - k_c1 * b_y
    bc_yaw = p_yaw_c - k_c0 * a_yaw - k_c1 * b_yaw
    bc_c = p_c_c - k_c0 * a_c - k_c1 * b_c
    # C = B H^T; each row minus K R is what multiplies K^T.
    c_x0 = bx_x * hr_x + bx_y * hr_y + bx_yaw * hr_yaw - rr * k_x0
    c_x1 = bx_x * hb_x + bx_y * hb_y + bx_yaw * hb_yaw - rb * k_x1
    c_y0 = by_x * hr_x + by_y * hr_y + by_yaw * hr_yaw - rr * k_y0
    c_y1 = by_x * hb_x + by_y * hb_y + by_yaw * hb_yaw - rb * k_y1
    c_yaw0 = byaw_x * hr_x + byaw_y * hr_y + byaw_yaw * hr_yaw - rr * k_yaw0
    c_yaw1 = byaw_x * hb_x + byaw_y * hb_y + byaw_yaw * hb_yaw - rb * k_yaw1
    c_b0 = bb_x * hr_x + bb_y * hr_y + bb_yaw * hr_yaw - rr * k_b0
    c_b1 = bb_x * hb_x + bb_y * hb_y + bb_yaw * hb_yaw - rb * k_b1
    c_c0 = bc_x * hr_x + bc_y * hr_y + bc_yaw * hr_yaw - rr * k_c0
    c_c1 = bc_x * hb_x + bc_y * hb_y + bc_yaw * hb_yaw - rb * k_c1
    p = [
        bx_x - c_x0 * k_x0 - c_x1 * k_x1, bx_y - c_x0 * k_y0 - c_x1 * k_y1,
        bx_yaw - c_x0 * k_yaw0 - c_x1 * k_yaw1, bx_b - c_x0 * k_b0 - c_x1 * k_b1,
        bx_c - c_x0 * k_c0 - c_x1 * k_c1,
        by_y - c_y0 * k_y0 - c_y1 * k_y1, by_yaw - c_y0 * k_yaw0 - c_y1 * k_yaw1,
        by_b - c_y0 * k_b0 - c_y1 * k_b1, by_c - c_y0 * k_c0 - c_y1 * k_c1,
        byaw_yaw - c_yaw0 * k_yaw0 - c_yaw1 * k_yaw1, byaw_b - c_yaw0 * k_b0 - c_yaw1 * k_b1,
        byaw_c - c_yaw0 * k_c0 - c_yaw1 * k_c1,
        bb_b - c_b0 * k_b0 - c_b1 * k_b1, bb_c - c_b0 * k_c0 - c_b1 * k_c1,
        bc_c - c_c0 * k_c0 - c_c1 * k_c1,
    ]
    if noise_scale != 1.0:
        # The NIS measures the sensor: against S with the unscaled R.
        i00, i01, i11 = inverse(s00 - rr + rr / noise_scale, s01, s11 - rb + rb / noise_scale)
    return (s, p, (y0, y1), (s00, s01, s11),
            (k_x0, k_x1, k_y0, k_y1, k_yaw0, k_yaw1, k_b0, k_b1, k_c0, k_c1),
            mahalanobis_sq(y0, y1, i00, i01, i11))


def update_bias(s: list[float], p: list[float], rate_rad_s: float, variance: float
                ) -> tuple[list[float], list[float], float]:
    """Zero-rate update z = w, h = b + c, H = [0, 0, 0, 1, 1] (``ekf.Textbook.update_bias``).

    With g = P H^T = P[:, BIAS] + P[:, WANDER]: S = g[BIAS] + g[WANDER] + R and
    K = g / S; the Joseph form reduces to P - g g^T / S.

    Returns:
        s, p and the NIS (w - b - c)^2 / S.

    Raises:
        CoreError: S is not positive.
    """
    (p_x_x, p_x_y, p_x_yaw, p_x_b, p_x_c, p_y_y, p_y_yaw, p_y_b, p_y_c, p_yaw_yaw, p_yaw_b,
     p_yaw_c, p_b_b, p_b_c, p_c_c) = p
    x, y, yaw, bias, wander = s
    g_x, g_y, g_yaw = p_x_b + p_x_c, p_y_b + p_y_c, p_yaw_b + p_yaw_c
    g_b, g_c = p_b_b + p_b_c, p_b_c + p_c_c
    s_b = g_b + g_c + variance
    if not s_b > 0.0:
        raise CoreError(f'zero-rate innovation variance {s_b} is not positive')
    innovation = rate_rad_s - bias - wander
    k_x, k_y, k_yaw, k_b, k_c = g_x / s_b, g_y / s_b, g_yaw / s_b, g_b / s_b, g_c / s_b
    s = [x + k_x * innovation, y + k_y * innovation, wrap_scalar(yaw + k_yaw * innovation),
         bias + k_b * innovation, wander + k_c * innovation]
    p = [p_x_x - g_x * k_x, p_x_y - g_x * k_y, p_x_yaw - g_x * k_yaw, p_x_b - g_x * k_b,
         p_x_c - g_x * k_c,
         p_y_y - g_y * k_y, p_y_yaw - g_y * k_yaw, p_y_b - g_y * k_b, p_y_c - g_y * k_c,
         p_yaw_yaw - g_yaw * k_yaw, p_yaw_b - g_yaw * k_b, p_yaw_c - g_yaw * k_c,
         p_b_b - g_b * k_b, p_b_c - g_b * k_c, p_c_c - g_c * k_c]
    return s, p, innovation * innovation / s_b
