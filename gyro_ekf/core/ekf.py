"""Extended Kalman filter for pose and gyro bias: state [x, y, yaw, b, c].

The models are those of the MTRN4010 Project 3 report
(``../shared/course-notes/003_3aeb4dcf00f2eae3.txt``), written out once in ``models.py``:
f, J, Ju, Q, h, H and R. The filter is the textbook EKF (filterpy's ``EKF.py``), written
out in ``Textbook`` for a state of any size.

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
(``models.observation_noise``): a real map is surveyed to about a centimetre, a
simulator's map is exact.

Because the bias enters yaw through ``-T`` in J, landmark updates that correct yaw also
correct the bias: that is how the filter finds the bias online.

A bias found to ramp (``bias_rate.py``) is a known input of the prediction: b += T r, with
r's uncertainty added to Q2's bias random walk (``bias_rate_found``, ``bias_walk_found``).
The odometry's speed scale, while not yet known, adds to q^2 of x and y
(``odometry_walk``, ``odometry_online.walk_density``).

Standing still (the driver decides when, ``events.py``), a gyro sample w measures the bias
alone: z = w, h(x) = b + c, H = [0, 0, 0, 1, 1] (a zero-rate update, ``update_zero_rate``),
and the prediction holds the position (no translation, no speed noise).

The fifth state c is the gyro's wander (``models.py``): a Gauss-Markov process of
correlation time ``gyro_wander_tau_s`` and stationary sigma ``wander_sigma_rad_s``, the
stated one (0 by default) until the data show one (``core/gyro_wander.py``; the driver also
assumes a prior wander from the start until the data rule it out, ``assume_wander``).
While it is 0, c and its covariance stay 0 and the first four states are the report's
filter exactly; b is the bias reported.

``GyroBiasEkf`` runs these lines through the private kernel ``_ekf_kernel.py``: the same
arithmetic unrolled on plain floats for these five states, since at this size
numpy's per-call overhead costs several times the arithmetic (`make bench` compares it with
filterpy). Tests check the kernel against ``Textbook`` to 1e-12; ``textbook=True`` runs
the filter on ``Textbook`` itself, as does a state the kernel does not cover.
"""

from __future__ import annotations

import math

import numpy as np

from gyro_ekf.core import _ekf_kernel, models
from gyro_ekf.core.angles import wrap_angle, wrap_scalar
from gyro_ekf.core.config import EkfConfig
from gyro_ekf.core.errors import CoreError
from gyro_ekf.core.models import BEARING, RANGE
from gyro_ekf.core.types import BIAS, STATE_SIZE, WANDER, X, Y, YAW, FloatArray, LidarMount

_NO_MOUNT = LidarMount()

_POSE = [X, Y, YAW]

# The covariance is stored as its upper triangle, row by row: _UPPER[k] = (i, j) is the
# entry P[i, j] at position k (the kernel's p_x_x, p_x_y, ..., p_b_b).
_UPPER = [(i, j) for i in range(STATE_SIZE) for j in range(i, STATE_SIZE)]
_UPPER_ROWS, _UPPER_COLUMNS = (np.array(axis) for axis in zip(*_UPPER))


def _packed_positions() -> np.ndarray:
    # Position in the packed triangle of P[i, j], for every i, j.
    index = np.empty((STATE_SIZE, STATE_SIZE), dtype=np.int64)
    for k, (i, j) in enumerate(_UPPER):
        index[i, j] = index[j, i] = k
    return index


_PACKED = _packed_positions()
# The positions the hot paths read, as plain ints: indexing _PACKED is a numpy call.
_YAW_YAW, _BIAS_BIAS = int(_PACKED[YAW, YAW]), int(_PACKED[BIAS, BIAS])

PACKED_ROW_SIZE = STATE_SIZE + len(_UPPER)
"""Length of ``GyroBiasEkf.packed_row``: the state, then P's upper triangle."""


def _packed(P: FloatArray) -> list[float]:
    return np.asarray(P, dtype=np.float64)[_UPPER_ROWS, _UPPER_COLUMNS].tolist()


def _full(packed: list[float]) -> FloatArray:
    return np.array(packed)[_PACKED]


def unpack_rows(rows: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Split ``GyroBiasEkf.packed_row`` rows (n, 20) into states (n, 5) and P (n, 5, 5)."""
    rows = np.asarray(rows, dtype=np.float64).reshape(-1, PACKED_ROW_SIZE)
    return rows[:, :STATE_SIZE], rows[:, STATE_SIZE + _PACKED]


def initial_covariance(config: EkfConfig) -> FloatArray:
    """P0 = diag(sigma_pos^2, sigma_pos^2, sigma_yaw^2, sigma_b^2, sigma_c^2), shape (5, 5).

    sigma_c is the stated wander's stationary sigma (0 unless configured).
    """
    P0 = np.zeros((STATE_SIZE, STATE_SIZE))
    P0[X, X] = P0[Y, Y] = config.initial_position_sigma_m ** 2
    P0[YAW, YAW] = config.initial_yaw_sigma_rad ** 2
    P0[BIAS, BIAS] = config.initial_bias_sigma_rad_s ** 2
    P0[WANDER, WANDER] = config.gyro_wander_rad_s ** 2
    return P0


def innovation(z: FloatArray, z_hat: FloatArray) -> FloatArray:
    """Return y = z - h(x) with the bearing wrapped to [-pi, pi), shape (..., 2)."""
    y = np.asarray(z, dtype=np.float64) - z_hat
    y[..., BEARING] = wrap_angle(y[..., BEARING])
    return y


def innovation_covariance(H: FloatArray, P: FloatArray, R: FloatArray) -> FloatArray:
    """Return S = H P H^T + R (H (..., m, n), R (..., m, m): one S per leading index)."""
    return H @ P @ np.swapaxes(H, -1, -2) + R


def normalised_innovation_sq(y: FloatArray, S: FloatArray) -> FloatArray:
    """Return y^T S^-1 y (the NIS; a squared Mahalanobis distance), over leading axes."""
    return np.einsum('...i,...i->...', y, np.linalg.solve(S, y[..., None])[..., 0])


def _check_positive_definite(S: FloatArray) -> None:
    if not (np.isfinite(S).all() and np.all(np.linalg.eigvalsh(S) > 0.0)):
        raise CoreError(f'innovation covariance is not positive definite: {S.tolist()}')


class Textbook:
    """The filter's predict and update as the textbook writes them, numpy, any state size.

    The same interface as the private kernel (``_ekf_kernel``): the stored state as a
    list and P as its packed upper triangle, in and out.
    """

    @staticmethod
    def predict(s: list[float], p: list[float], speed_m_s: float, rate_rad_s: float,
                dt_s: float, speed_var: float, rate_var: float, position_walk_var: float,
                bias_walk_var: float, hold_position: bool, wander_sigma_rad_s: float,
                wander_tau_s: float) -> tuple[list[float], list[float]]:
        """Predict: x = f(x, u); P = J P J^T + Q.

        Held (standing still) the speed and its noise are zero: the odometry's zero is
        exact, while the position random walk of Q2 stays.
        """
        x, P = np.array(s), _full(p)
        if hold_position:
            speed_m_s, speed_var = 0.0, 0.0
        J = models.process_jacobian(x, speed_m_s, dt_s, wander_tau_s)
        Q = models.process_noise(x, dt_s, math.sqrt(speed_var), math.sqrt(rate_var),
                                 math.sqrt(position_walk_var), math.sqrt(bias_walk_var),
                                 wander_sigma_rad_s, wander_tau_s)
        x = models.predict_state(x, speed_m_s, rate_rad_s, dt_s, wander_tau_s)
        P = J @ P @ J.T + Q
        return x.tolist(), _packed(P)

    @staticmethod
    def update(s: list[float], p: list[float], z_range: float, z_bearing: float,
               landmark_x_m: float, landmark_y_m: float, mount: LidarMount, range_var: float,
               bearing_var: float, landmark_var_m2: float, noise_scale: float) -> tuple:
        """Landmark update: y = z - h(x) with R = sensor + map noise (times noise_scale).

        The NIS is taken against the unscaled R.

        Returns:
            s, p, y (2), S (s00, s01, s11), K (row by row), NIS.
        """
        x, P = np.array(s), _full(p)
        z_hat, H = models.observe_with_jacobian(x, [landmark_x_m, landmark_y_m], mount)
        R = models.observation_noise(z_hat[RANGE], np.diag([range_var, bearing_var]),
                                     landmark_var_m2)
        y = innovation([z_range, z_bearing], z_hat)
        nis = float(normalised_innovation_sq(y, innovation_covariance(H, P, R)))
        x, P, S, K = _correct(x, P, y, H, noise_scale * R)
        return (x.tolist(), _packed(P), tuple(y.tolist()), (S[0, 0], S[0, 1], S[1, 1]),
                tuple(K.ravel().tolist()), nis)

    @staticmethod
    def update_bias(s: list[float], p: list[float], rate_rad_s: float, variance: float
                    ) -> tuple[list[float], list[float], float]:
        """Zero-rate update: y = w - h(x) with h = b + c, H = [0, 0, 0, 1, 1], R = [[variance]].

        Returns:
            s, p, NIS.
        """
        x, P = np.array(s), _full(p)
        h, H = models.observe_bias(x)
        y = np.array([rate_rad_s]) - h
        x, P, S, _ = _correct(x, P, y, H, np.array([[variance]]))
        return x.tolist(), _packed(P), float(normalised_innovation_sq(y, S))


def _correct(x: FloatArray, P: FloatArray, y: FloatArray, H: FloatArray, R: FloatArray
             ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """Kalman update with innovation y: returns x, P (Joseph form), S and K."""
    S = innovation_covariance(H, P, R)
    _check_positive_definite(S)
    K = P @ H.T @ np.linalg.inv(S)
    x = x + K @ y
    x[YAW] = wrap_scalar(x[YAW])
    A = np.eye(x.size) - K @ H
    return x, A @ P @ A.T + K @ R @ K.T, S, K


class GyroBiasEkf:
    """EKF over [x, y, yaw, bias, wander] with speed/yaw-rate inputs and landmark updates.

    Attributes (arrays are fresh copies; change the filter through its methods):
        x: state estimate, shape (5,): m, m, rad, rad/s, rad/s.
        P: state covariance, shape (5, 5), symmetric.
        x_prior, P_prior: state and covariance before the last update.
        y: last innovation, shape (2,): m, rad.
        S: last innovation covariance, shape (2, 2).
        K: last Kalman gain, shape (5, 2).
        nis: last normalised innovation squared y^T S^-1 y.
        R: sensor noise covariance, shape (2, 2) (``observation_noise`` adds the map's).
        landmark_var_m2: variance of a landmark's map position along any axis, m^2.
    """

    def __init__(self, config: EkfConfig | None = None, pose: FloatArray | None = None,
                 bias_rad_s: float | None = None, covariance: FloatArray | None = None,
                 textbook: bool = False):
        """Start at a pose (x m, y m, yaw rad) with the configured priors.

        Args:
            config: noise model and priors; defaults to EkfConfig().
            pose: initial pose, shape (3,); zeros when None.
            bias_rad_s: initial bias; config.initial_bias_rad_s when None.
            covariance: initial P, shape (5, 5); initial_covariance(config) when None.
            textbook: compute with ``Textbook`` (numpy, any state size) instead of the
                private kernel: slower, the same numbers to rounding.
        """
        self.config = config or EkfConfig()
        # The kernel covers these five states only; any other state is textbook.
        self._maths = (_ekf_kernel if not textbook and STATE_SIZE == _ekf_kernel.STATE_SIZE
                       else Textbook)
        self._r_range = self.config.range_noise_m ** 2
        self._r_bearing = self.config.bearing_noise_rad ** 2
        self.landmark_var_m2 = self.config.landmark_sigma_m ** 2
        self.R = np.diag([self._r_range, self._r_bearing])
        self._sigma_v2 = self.config.speed_noise_m_s ** 2
        self._sigma_w2 = self.config.gyro_noise_rad_s ** 2
        self._q_pos2 = self.config.position_random_walk_m_sqrt_s ** 2
        self._q_b2 = self.config.bias_random_walk_rad_s2 ** 2
        # A random walk of the bias found in the data ((rad/s)^2 per s, core/bias_watch.py):
        # Q2 adds it times T to the bias, on top of the configured (q_b T)^2.
        self.bias_walk_found = 0.0
        # The odometry's speed scale not yet known, as a random walk of x and y (m^2 per s,
        # core/odometry_online.py walk_density): Q2 adds it times T, beside q_pos^2 T.
        self.odometry_walk = 0.0
        # q_pos stands for the LiDARs' detection errors changing slowly from scan to scan
        # (config.py): with no landmark update for a while (a gap, core/events.py) there is
        # nothing for it to cover, and the driver pauses it.
        self.position_walk_paused = False
        # A rate of the bias found in the data (rad/s^2, core/bias_rate.py): each prediction
        # moves b by T times it, a known input (its uncertainty comes in bias_walk_found).
        self.bias_rate_found = 0.0
        # A factor on the gyro's noise variance found in the data (core/bias_watch.py).
        self.rate_noise_scale = 1.0
        # The wander's stationary sigma (rad/s): the stated one until the data show a
        # larger one (core/gyro_wander.py); its correlation time is configured.
        self.wander_sigma_rad_s = self.config.gyro_wander_rad_s
        self._wander_tau_s = self.config.gyro_wander_tau_s
        self.reset(pose, bias_rad_s, covariance)

    # State: _s, a list of plain floats; covariance: _p, P's upper triangle (see _UPPER).
    # Plain floats: numpy scalars would spread into the state and slow every step.

    @property
    def x(self) -> FloatArray:
        """State estimate, shape (5,)."""
        return np.array(self._s)

    @property
    def P(self) -> FloatArray:
        """State covariance, shape (5, 5)."""
        return _full(self._p)

    @property
    def x_values(self) -> tuple[float, ...]:
        """State estimate as plain floats (no array): x, y m; yaw rad; bias, wander rad/s."""
        return tuple(self._s)

    @property
    def yaw_rad(self) -> float:
        """Heading estimate, rad (a plain float, no array)."""
        return self._s[YAW]

    @property
    def bias_rad_s(self) -> float:
        """Bias estimate, rad/s (its constant part: the wander is apart)."""
        return self._s[BIAS]

    @property
    def wander_rad_s(self) -> float:
        """The wander's estimate now, rad/s: the gyro reads b + c (+ noise) at rest."""
        return self._s[WANDER]

    @property
    def yaw_var(self) -> float:
        """Variance of the heading estimate, rad^2."""
        return self._p[_YAW_YAW]

    @property
    def bias_var(self) -> float:
        """Variance of the bias estimate, (rad/s)^2."""
        return self._p[_BIAS_BIAS]

    @property
    def x_prior(self) -> FloatArray:
        """State before the last update, shape (5,)."""
        return np.array(self._s_prior)

    @property
    def P_prior(self) -> FloatArray:
        """Covariance before the last update, shape (5, 5)."""
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
    def S_packed(self) -> tuple[float, float, float]:
        """Last innovation covariance as (s00, s01, s11), plain floats."""
        return tuple(self._S)

    @property
    def y_values(self) -> tuple[float, float]:
        """Last innovation as plain floats (range m, bearing rad): the per-update path."""
        return tuple(self._y)

    @property
    def K(self) -> FloatArray:
        """Last Kalman gain, shape (5, 2)."""
        return np.array(self._K).reshape(STATE_SIZE, 2)

    def reset(self, pose: FloatArray | None = None, bias_rad_s: float | None = None,
              covariance: FloatArray | None = None) -> None:
        """Restart from a pose and bias with the given (or configured) covariance."""
        pose = np.zeros(3) if pose is None else np.asarray(pose, dtype=np.float64)
        bias = self.config.initial_bias_rad_s if bias_rad_s is None else float(bias_rad_s)
        P = (initial_covariance(self.config) if covariance is None
             else np.asarray(covariance, dtype=np.float64))
        if P.shape != (STATE_SIZE, STATE_SIZE):
            raise CoreError(f'initial covariance has shape {P.shape}, '
                            f'expected ({STATE_SIZE}, {STATE_SIZE})')
        # A NaN here would surface much later as "SVD did not converge" in an update.
        if pose.shape != (3,) or not np.isfinite(pose).all() or not math.isfinite(bias):
            raise CoreError(f'initial state {pose.tolist()} with bias {bias} is not finite')
        if not np.isfinite(P).all():
            raise CoreError('initial covariance is not finite')
        state = [0.0] * STATE_SIZE
        state[X], state[Y], state[YAW] = float(pose[0]), float(pose[1]), wrap_scalar(
            float(pose[2]))
        state[BIAS] = bias
        self._s = state
        self._p = _packed(0.5 * (P + P.T))
        self._s_prior = list(self._s)
        self._p_prior = list(self._p)
        self._y = (0.0, 0.0)
        self._S = (0.0, 0.0, 0.0)
        self._K = (0.0,) * (2 * STATE_SIZE)
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
        """Return the state and the covariance's upper triangle as 20 plain floats.

        Order: x, y, yaw, b, c, then P row by row (p00, p01, p02, p03, p04, p11, ..., p33,
        p34, p44); ``unpack_rows`` turns a stack of them back into states and covariances.
        For callers that keep every estimate: building two arrays per step would cost more
        than the step.
        """
        return self._s + self._p

    def set_pose(self, pose: FloatArray, pose_covariance: FloatArray) -> None:
        """Replace the pose and its 3x3 covariance; keep bias and wander, drop their coupling."""
        bias, wander = self._s[BIAS], self._s[WANDER]
        P = self.P
        covariance = np.zeros((STATE_SIZE, STATE_SIZE))
        covariance[np.ix_(_POSE, _POSE)] = pose_covariance
        gyro = [BIAS, WANDER]
        covariance[np.ix_(gyro, gyro)] = P[np.ix_(gyro, gyro)]
        self.reset(pose, bias, covariance)
        self._s[WANDER] = wander

    def set_bias(self, bias_rad_s: float, sigma_rad_s: float) -> None:
        """Seed the bias state and its variance (e.g. from a static calibration)."""
        self._s[BIAS] = float(bias_rad_s)
        for i in range(STATE_SIZE):
            self._p[_PACKED[i, BIAS]] = 0.0
        self._p[_PACKED[BIAS, BIAS]] = float(sigma_rad_s) ** 2

    @property
    def gyro_variance(self) -> float:
        """The configured gyro noise variance sigma_w^2, (rad/s)^2."""
        return self._sigma_w2

    def add_heading_variance(self, variance: float) -> None:
        """Add ``variance`` (rad^2) to the heading's: an error the prediction did not model."""
        self._p[_YAW_YAW] += float(variance)

    def assume_wander(self, sigma_rad_s: float) -> None:
        """Model a wander of stationary sigma ``sigma_rad_s`` from now, as if it had run.

        A prior at the start (``EkfConfig.gyro_wander_prior_rad_s``, the driver's): c's
        variance is at once the stationary sigma^2, not grown to it over tau.
        """
        self.wander_sigma_rad_s = float(sigma_rad_s)
        k = _PACKED[WANDER, WANDER]
        self._p[k] = max(self._p[k], self.wander_sigma_rad_s * self.wander_sigma_rad_s)

    def open_bias(self, variance: float) -> None:
        """Add ``variance`` ((rad/s)^2) to the bias variance: the bias is less known than P says.

        Only P_bb grows (P stays positive definite); the next updates move the bias again.
        """
        self._p[_BIAS_BIAS] += float(variance)

    def hold_still(self, dt_s: float) -> None:
        """Propagate over dt_s seconds standing still at a pose known exactly: only b, c move.

        The platform has not left a start pose given with no uncertainty
        (``core/held_start.py``): x, y and yaw neither move nor grow uncertain (a gyro at
        rest shows its bias and noise, not a turn), and with P of the pose 0 a landmark
        update moves nothing but judges the pose. The bias keeps its random walk and rate,
        the wander its decay; the zero-rate updates learn them.
        """
        if dt_s <= 0.0:
            return
        bias_walk = self._q_b2
        if self.bias_walk_found:
            bias_walk += self.bias_walk_found / dt_s
        # As predict's Q for b (T^2 times the walk density), with J = I.
        self._p[_BIAS_BIAS] += dt_s * dt_s * bias_walk
        if self.bias_rate_found:
            self._s[BIAS] += dt_s * self.bias_rate_found
        # J = I but J[WANDER, WANDER] = phi (as predict's), Q adds s^2 (1 - phi^2) to c.
        phi = models.wander_decay(dt_s, self._wander_tau_s)
        self._s[WANDER] *= phi
        for i in range(WANDER):
            self._p[_PACKED[i, WANDER]] *= phi
        sigma2 = self.wander_sigma_rad_s * self.wander_sigma_rad_s
        k = _PACKED[WANDER, WANDER]
        self._p[k] = phi * phi * self._p[k] + sigma2 * (1.0 - phi * phi)

    def predict(self, speed_m_s: float, rate_rad_s: float, dt_s: float,
                speed_variance: float | None = None, rate_variance: float | None = None,
                hold_position: bool = False) -> None:
        """Propagate over dt_s seconds with constant speed (m/s) and measured yaw rate (rad/s).

        speed_variance ((m/s)^2) and rate_variance ((rad/s)^2), when given, replace the
        configured sigma_v^2 and sigma_w^2 of Pu for this step (the inputs' own message
        covariances). ``hold_position`` (standing still): x and y do not move and gain no
        speed noise; the position random walk still applies (landmark looks at rest repeat
        their errors and move the estimate by millimetres, which a frozen position
        covariance would not cover); yaw still integrates the rate minus the bias.
        """
        if dt_s <= 0.0:
            return
        rate_var = self._sigma_w2 if rate_variance is None else rate_variance
        if self.rate_noise_scale != 1.0:
            rate_var *= self.rate_noise_scale
        bias_walk = self._q_b2
        if self.bias_walk_found:
            bias_walk += self.bias_walk_found / dt_s
        self._s, self._p = self._maths.predict(
            self._s, self._p, float(speed_m_s), float(rate_rad_s), float(dt_s),
            self._sigma_v2 if speed_variance is None else speed_variance, rate_var,
            (0.0 if self.position_walk_paused else self._q_pos2) + self.odometry_walk,
            bias_walk, hold_position,
            self.wander_sigma_rad_s, self._wander_tau_s)
        if self.bias_rate_found:
            # b += T b' (the bias ramps; core/bias_rate.py): J's bias row is still [0 0 0 1].
            self._s[BIAS] += dt_s * self.bias_rate_found

    def update_zero_rate(self, rate_rad_s: float, variance: float) -> float:
        """Correct with a gyro sample taken standing still: z = w = b + noise.

        h(x) = b and H = [0, 0, 0, 1]; the innovation, gain and prior of the last landmark
        update are kept.

        Args:
            rate_rad_s: the measured yaw rate, bias included, rad/s.
            variance: R, the sample's noise variance, (rad/s)^2.

        Returns:
            The NIS (w - b)^2 / S.

        Raises:
            CoreError: S is not positive.
        """
        self._s, self._p, nis = self._maths.update_bias(self._s, self._p, float(rate_rad_s),
                                                        variance)
        return nis

    def innovation(self, z: FloatArray, landmark_xy_m: FloatArray,
                   mount: LidarMount = _NO_MOUNT) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Innovation y (2,), its covariance S (2, 2) and H (2, 4) of one observation.

        Nothing is applied (for a LiDAR that is being judged, not used).
        """
        z_hat, H = models.observe_with_jacobian(self.x, landmark_xy_m, mount)
        S = innovation_covariance(H, self.P, self.observation_noise(float(z_hat[RANGE])))
        return innovation(z, z_hat), S, H

    def observation_noise(self, range_m: float) -> FloatArray:
        """R of one landmark at a predicted range (m): sensor noise plus map uncertainty."""
        return models.observation_noise(range_m, self.R, self.landmark_var_m2)

    def update(self, z: FloatArray, landmark_xy_m: FloatArray,
               mount: LidarMount = _NO_MOUNT, noise_scale: float = 1.0,
               sensor_variance: tuple[float, float] | None = None) -> float:
        """Correct with z = [range m, bearing rad] (0 = sensor forward) of a known landmark.

        ``noise_scale`` multiplies R (sensor and map) for this observation only; the NIS
        is still taken against the unscaled R, so it keeps measuring the sensor.
        ``sensor_variance`` (range m^2, bearing rad^2), when given, replaces the configured
        sensor noise of R for this observation (a LiDAR's measured noise,
        core/noise_online.py).

        Returns:
            The normalised innovation squared (NIS) of this observation.

        Raises:
            CoreError: the innovation covariance is not positive definite.
        """
        # One conversion each: indexing numpy scalars one by one costs more than the maths.
        z_range, z_bearing = z.tolist() if isinstance(z, np.ndarray) else z
        lx, ly = (landmark_xy_m.tolist() if isinstance(landmark_xy_m, np.ndarray)
                  else landmark_xy_m)
        r_range, r_bearing = ((self._r_range, self._r_bearing) if sensor_variance is None
                              else sensor_variance)
        prior = self._s, self._p
        self._s, self._p, self._y, self._S, self._K, self.nis = self._maths.update(
            self._s, self._p, z_range, z_bearing, lx, ly, mount, r_range, r_bearing,
            self.landmark_var_m2, noise_scale)
        self._s_prior, self._p_prior = prior
        return self.nis
