"""A seeded, deterministic simulator of a course-like trip, with ground truth.

The platform stands still for ``static_s`` (speed exactly 0), then drives a figure-eight
(so it turns both ways) among reflective poles inside a walled arena with a doorway:

* **Path.** In the path frame the reference point follows ``c(u) = (a sin u, b sin 2u)``
  from the end of one lobe; ``a`` and ``b`` vary a little with the seed. The scene is
  rotated and shifted so the trip starts at the course's pose (0, 0, pi/2).
* **Speed.** Zero, then a quintic ramp over ``ramp_s`` to a cruise speed that is a sum of
  three slow random sinusoids inside ``[min_speed_m_s, max_speed_m_s]``.
* **Truth.** The speed is integrated on a fine grid (``integration_rate_hz``) into arc
  length s(t); the pose is the curve at that arc length (a table inverts the arc length),
  so the pose never drifts from the path, however long the trip.
* **Inputs.** A sample stamped t_k is the mean of the true quantity over
  [t_k, t_k + T): speed = (s(t_k + T) - s(t_k)) / T, yaw rate = (yaw(t_k + T) - yaw(t_k)) / T.
  Zero-order-hold integration of noise-free inputs (what ``events.EventDriver`` does)
  therefore reproduces the true heading exactly at every sample.
* **Gyro.** Three axes, each with its own constant bias and white noise; the true x and y
  rates are 0 (planar motion). Accelerometer (optional): specific force
  [dv/dt, v w, g] plus white noise.
* **Speed encoder.** The mean speed plus white noise while moving, exactly 0 at rest.
* **LiDAR.** One planar scanner on ``LidarMount(lidar_x_m, lidar_y_m, lidar_yaw_rad)``,
  ray-cast (vectorised over scans, beams and objects) against poles (circles, intensity
  1.0) and wall segments (intensity 0.0); per-beam Gaussian range noise; no return (+inf)
  beyond ``lidar_max_range_m``. A whole scan is taken at its stamp (no sweep motion).
* **Second LiDAR** (``second_lidar``, off by default): like the 2023 course logs, a
  second scanner (topic ``scan2``, frame ``laser2``) with the same beams, stated at
  ``LidarMount(lidar2_x_m, lidar2_y_m, lidar2_yaw_rad)`` (default rear-facing at the first
  LiDAR's origin), scanned at the same stamps with its own noise stream.
* **Mount errors** (all 0 by default): the log states each LiDAR's nominal mount, while
  the world is scanned from the true one, the nominal plus ``*_yaw_error_rad``,
  ``*_x_error_m`` and ``*_y_error_m`` (``lidar_*`` for the first LiDAR, ``lidar2_*`` for the
  second). They are given, not drawn, so a stress suite picks them from its own seeds.

The other perturbations (docs/stress.md lists them with the stress suite's ranges). Sizes
and counts are given; where and when they happen is drawn from a random stream of the
seed's own for each kind, so switching one on changes nothing else of the trip:

* **Speed-scale error** (``speed_scale_error``): the encoder reads ``1 + e`` times the
  true mean speed (plus its white noise), as a wrong wheel radius does.
* **Gyro scale error** (``gyro_scale_error``): the yaw axis reads ``1 + e`` times the
  true yaw rate (plus its bias and noise), as a MEMS gyro's scale factor is off by up to a
  few per cent. Not a stress class; ``test/core/test_health.py`` checks that it is said.
* **Bias step** (``gyro_bias_step_rad_s`` at ``gyro_bias_step_at_s``) and **bias ramp**
  (``gyro_bias_ramp_rad_s2`` from t = 0): the yaw-axis bias is then
  ``b(t) = gyro_bias_z + ramp t + step [t >= at]`` (``SimulationConfig.gyro_bias_z_at``);
  ``Trip.true_gyro_bias_rad_s`` states the bias at the end of the trip, the one a final
  bias error is measured against.
* **Coloured gyro noise** (``gyro_colored_noise_rad_s``, ``gyro_colored_noise_tau_s``): a
  first-order Gauss-Markov process (stationary sigma, correlation time) added to the yaw
  axis on top of its white noise; it starts in its stationary distribution.
* **Reflectors not in the map** (``extra_reflectors``): poles in the world, placed by the
  same rules as the map's (clear of the path, spaced from each other and the map's poles),
  that the map does not list.
* **Map poles missing in the world** (``missing_poles``): that many of the map's poles,
  picked at random, are not there to be scanned; the map still lists them.
* **LiDAR dropouts** (``lidar_dropouts`` of ``lidar_dropout_s`` each): spans in which no
  LiDAR gives a scan (the scans are removed, as a stalled driver's are).
* **IMU gaps** (``imu_gaps`` of ``imu_gap_s`` each): spans without IMU samples.

Dropouts and gaps fall after the static window: the time from ``static_s`` to the end is
cut into equal slots, one per span, and each span starts at a uniform time in its slot
(so they never overlap; a config whose spans do not fit is refused).

Every perturbation is off by default, and then the trip is bit-identical to one simulated
before they existed (each perturbation that draws has a random stream of its own).

``Trip.noise`` states the gyro (z) and speed white-noise sigmas the simulator used and an
exact map (landmark_m = 0). It states no range or bearing figure: the EKF's are the noise
of a detected pole centre, which averages several beams and so lies below the per-beam
range noise and the beam quantisation (increment / sqrt(12));
``test/core/test_simulator.py`` checks that detected poles stay within those.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

# The private helper is imported on purpose: the same field metadata (unit, description,
# bounds) as the other configs lets `info --params` and the nodes list this one too.
from gyro_ekf.core.angles import wrap_angle
from gyro_ekf.core.config import DEG
from gyro_ekf.core.config import config_field as _param
from gyro_ekf.core.errors import CoreError
from gyro_ekf.core.types import (FloatArray, GroundTruth, ImuSeries, LandmarkMap, LidarMount,
                                 NoiseFigures, ScanSeries, SpeedSeries, Trip)
# Plain strings, no ROS: the topic and frame names the 2023 logs' two LiDARs get.
from gyro_ekf.topics import LASER2_FRAME, LASER_FRAME, SCAN, SCAN2

GRAVITY_M_S2 = 9.80665
POLE_INTENSITY = 1.0
WALL_INTENSITY = 0.0
# Scans ray-cast per vectorised block: bounds the (scans, beams, objects) temporaries.
_SCAN_BLOCK = 64
# Arc-length table resolution per lap of the figure-eight (about 1 mm per entry).
_TABLE_SIZE = 40_000


@dataclass(frozen=True, slots=True)
class SimulationConfig:
    """Everything the simulator can be told; defaults resemble the real 2016 log."""

    duration_s: float = _param(120.0, 's', 'Trip length.', 1.0, 1e5)
    static_s: float = _param(8.0, 's', 'Static window at the start (speed exactly 0).',
                             0.0, 1e5)
    ramp_s: float = _param(3.0, 's', 'Time to reach cruise speed after the static window.',
                           0.1, 60.0)
    min_speed_m_s: float = _param(0.3, 'm/s', 'Lowest cruise speed.', 0.0, 5.0)
    max_speed_m_s: float = _param(1.0, 'm/s', 'Highest cruise speed.', 0.01, 5.0)
    path_half_length_m: float = _param(
        6.0, 'm', 'Nominal half length a of the figure-eight (varies +-10 % by seed).',
        2.0, 100.0)
    path_half_width_m: float = _param(
        2.5, 'm', 'Nominal half width b of the figure-eight (varies +-10 % by seed).',
        1.0, 100.0)
    wall_margin_m: float = _param(3.5, 'm', 'Distance from the path extent to the walls.',
                                  1.0, 100.0)
    doorway_m: float = _param(1.5, 'm', 'Width of the gap in one long wall (inf returns).',
                              0.0, 20.0)
    pole_count: int = _param(14, '1', 'Poles (landmarks) in the arena.', 0, 200)
    pole_radius_m: float = _param(0.05, 'm', 'Pole radius.', 0.005, 1.0)
    pole_clearance_m: float = _param(
        1.2, 'm', 'Least distance from a pole to the path of the reference point.', 0.6, 10.0)
    pole_spacing_m: float = _param(2.0, 'm', 'Least distance between two poles.', 0.2, 20.0)
    integration_rate_hz: float = _param(1000.0, 'Hz', 'Grid the true speed is integrated on.',
                                        100.0, 100_000.0)
    imu_rate_hz: float = _param(200.0, 'Hz', 'Gyro/accelerometer sample rate.', 1.0, 10_000.0)
    speed_rate_hz: float = _param(100.0, 'Hz', 'Speed encoder sample rate.', 1.0, 10_000.0)
    lidar_rate_hz: float = _param(10.0, 'Hz', 'LiDAR scan rate.', 0.1, 1000.0)
    truth_rate_hz: float = _param(50.0, 'Hz', 'Ground-truth pose rate.', 0.1, 10_000.0)
    gyro_bias_x_rad_s: float = _param(0.35 * DEG, 'rad/s', 'Constant gyro bias, x axis.',
                                      -1.0, 1.0)
    gyro_bias_y_rad_s: float = _param(-0.55 * DEG, 'rad/s', 'Constant gyro bias, y axis.',
                                      -1.0, 1.0)
    gyro_bias_z_rad_s: float = _param(-0.9 * DEG, 'rad/s',
                                      'Constant gyro bias, z (yaw) axis.', -1.0, 1.0)
    gyro_noise_x_rad_s: float = _param(0.20 * DEG, 'rad/s', 'Gyro white noise sigma, x axis.',
                                       0.0, 1.0)
    gyro_noise_y_rad_s: float = _param(0.30 * DEG, 'rad/s', 'Gyro white noise sigma, y axis.',
                                       0.0, 1.0)
    gyro_noise_z_rad_s: float = _param(0.25 * DEG, 'rad/s', 'Gyro white noise sigma, z axis.',
                                       0.0, 1.0)
    with_accelerometer: bool = _param(True, '', 'Simulate the accelerometer too.')
    accel_noise_m_s2: float = _param(0.03, 'm/s^2', 'Accelerometer white noise sigma.',
                                     0.0, 10.0)
    speed_noise_m_s: float = _param(0.01, 'm/s', 'Speed encoder white noise sigma (moving).',
                                    0.0, 1.0)
    lidar_x_m: float = _param(0.46, 'm', 'LiDAR forward offset on the platform.', -5.0, 5.0)
    lidar_y_m: float = _param(0.0, 'm', 'LiDAR leftward offset on the platform.', -5.0, 5.0)
    lidar_yaw_rad: float = _param(0.0, 'rad', 'LiDAR yaw on the platform.', -math.pi,
                                  math.pi)
    lidar_beams: int = _param(361, '1', 'Beams per scan.', 2, 100_000)
    lidar_angle_min_rad: float = _param(-90.0 * DEG, 'rad', 'Bearing of the first beam.',
                                        -math.pi, math.pi)
    lidar_increment_rad: float = _param(0.5 * DEG, 'rad', 'Bearing step between beams.',
                                        1e-5, 1.0)
    lidar_max_range_m: float = _param(30.0, 'm', 'No return (+inf) beyond this range.',
                                      1.0, 1000.0)
    range_noise_m: float = _param(0.015, 'm', 'Per-beam range noise sigma.', 0.0, 1.0)
    lidar_yaw_error_rad: float = _param(
        0.0, 'rad', 'True minus stated yaw of the first LiDAR.', -math.pi, math.pi)
    lidar_x_error_m: float = _param(0.0, 'm', 'True minus stated x of the first LiDAR.',
                                    -1.0, 1.0)
    lidar_y_error_m: float = _param(0.0, 'm', 'True minus stated y of the first LiDAR.',
                                    -1.0, 1.0)
    second_lidar: bool = _param(False, '', 'Simulate a second LiDAR (topic scan2).')
    lidar2_x_m: float = _param(0.46, 'm', 'Stated forward offset of the second LiDAR.',
                               -5.0, 5.0)
    lidar2_y_m: float = _param(0.0, 'm', 'Stated leftward offset of the second LiDAR.',
                               -5.0, 5.0)
    lidar2_yaw_rad: float = _param(math.pi, 'rad', 'Stated yaw of the second LiDAR '
                                   '(pi = rear-facing).', -math.pi, math.pi)
    lidar2_yaw_error_rad: float = _param(
        0.0, 'rad', 'True minus stated yaw of the second LiDAR.', -math.pi, math.pi)
    lidar2_x_error_m: float = _param(0.0, 'm', 'True minus stated x of the second LiDAR.',
                                     -1.0, 1.0)
    lidar2_y_error_m: float = _param(0.0, 'm', 'True minus stated y of the second LiDAR.',
                                     -1.0, 1.0)
    speed_scale_error: float = _param(
        0.0, '1', 'Speed-scale error e: the encoder reads (1 + e) times the true speed.',
        -0.5, 0.5)
    gyro_scale_error: float = _param(
        0.0, '1', 'Gyro scale error e: the yaw axis reads (1 + e) times the true yaw rate.',
        -0.5, 0.5)
    static_turn_rad_s: float = _param(
        0.0, 'rad/s', 'Turn in place through the static window (speed 0, the gyro and '
        'LiDARs see it): the platform starts it turned back by this times static_s.',
        -0.5, 0.5)
    gyro_bias_step_rad_s: float = _param(
        0.0, 'rad/s', 'Step added to the yaw-axis bias at gyro_bias_step_at_s.', -1.0, 1.0)
    gyro_bias_step_at_s: float = _param(0.0, 's', 'When the yaw-axis bias step happens.',
                                        0.0, 1e5)
    gyro_bias_ramp_rad_s2: float = _param(
        0.0, 'rad/s^2', 'Rate of change of the yaw-axis bias from t = 0.', -0.01, 0.01)
    gyro_colored_noise_rad_s: float = _param(
        0.0, 'rad/s', 'Stationary sigma of first-order Gauss-Markov noise on the yaw axis.',
        0.0, 1.0)
    gyro_colored_noise_tau_s: float = _param(
        1.0, 's', 'Correlation time of the coloured yaw-axis noise.', 1e-3, 1e4)
    extra_reflectors: int = _param(0, '1', 'Reflective poles in the world but not in the map.',
                                   0, 100)
    missing_poles: int = _param(0, '1', 'Map poles absent from the world.', 0, 200)
    lidar_dropouts: int = _param(0, '1', 'Spans without any LiDAR scan.', 0, 100)
    lidar_dropout_s: float = _param(5.0, 's', 'Length of each LiDAR dropout.', 0.01, 1e4)
    imu_gaps: int = _param(0, '1', 'Spans without IMU samples.', 0, 100)
    imu_gap_s: float = _param(0.5, 's', 'Length of each IMU gap.', 0.001, 1e4)

    def lidar_mounts(self) -> tuple[tuple[LidarMount, LidarMount], ...]:
        """(stated, true) mount of every simulated LiDAR, the first LiDAR first."""
        mounts = [(LidarMount(self.lidar_x_m, self.lidar_y_m, self.lidar_yaw_rad),
                   self.lidar_yaw_error_rad, self.lidar_x_error_m, self.lidar_y_error_m)]
        if self.second_lidar:
            mounts.append((LidarMount(self.lidar2_x_m, self.lidar2_y_m, self.lidar2_yaw_rad),
                           self.lidar2_yaw_error_rad, self.lidar2_x_error_m,
                           self.lidar2_y_error_m))
        return tuple((stated, _offset(stated, yaw, x, y)) for stated, yaw, x, y in mounts)

    def gyro_bias_drift_z(self, t_s: FloatArray) -> FloatArray:
        """Return the yaw-axis bias change since t = 0 at times t_s (n,): ramp plus step, rad/s."""
        t_s = np.asarray(t_s, dtype=np.float64)
        return (self.gyro_bias_ramp_rad_s2 * t_s
                + np.where(t_s >= self.gyro_bias_step_at_s, self.gyro_bias_step_rad_s, 0.0))

    def gyro_bias_z_at(self, t_s: FloatArray) -> FloatArray:
        """Return the true yaw-axis gyro bias at times t_s (n,), rad/s."""
        return self.gyro_bias_z_rad_s + self.gyro_bias_drift_z(t_s)

    @property
    def bias_drifts(self) -> bool:
        """Whether the yaw-axis bias changes during the trip (a step or a ramp)."""
        return self.gyro_bias_step_rad_s != 0.0 or self.gyro_bias_ramp_rad_s2 != 0.0


def _offset(stated: LidarMount, yaw_rad: float, x_m: float, y_m: float) -> LidarMount:
    """Move the stated mount by the given errors.

    The stated mount itself is returned when they are 0, so a trip without mount errors
    computes exactly what it did before they existed.
    """
    if yaw_rad == 0.0 and x_m == 0.0 and y_m == 0.0:
        return stated
    return LidarMount(stated.x_m + x_m, stated.y_m + y_m, stated.yaw_rad + yaw_rad)


def _check(config: SimulationConfig) -> None:
    """Bounds from the field metadata, then the relations between fields."""
    for spec in dataclasses.fields(config):
        value = getattr(config, spec.name)
        low, high = spec.metadata.get('min'), spec.metadata.get('max')
        if (low is not None and value < low) or (high is not None and value > high):
            raise CoreError(f'simulation: {spec.name} = {value} is outside [{low}, {high}] '
                            f'{spec.metadata["unit"]}')
    if config.min_speed_m_s > config.max_speed_m_s:
        raise CoreError(f'simulation: min_speed_m_s {config.min_speed_m_s} exceeds '
                        f'max_speed_m_s {config.max_speed_m_s}')
    if config.missing_poles > config.pole_count:
        raise CoreError(f'simulation: missing_poles {config.missing_poles} exceeds '
                        f'pole_count {config.pole_count}')
    for count, length, name in ((config.lidar_dropouts, config.lidar_dropout_s, 'lidar_dropout'),
                                (config.imu_gaps, config.imu_gap_s, 'imu_gap')):
        if count and (config.duration_s - config.static_s) / count < length:
            raise CoreError(f'simulation: {count} x {name}_s {length} s do not fit in the '
                            f'{config.duration_s - config.static_s:g} s after the static window')


@dataclass(frozen=True, slots=True)
class _Path:
    """Figure-eight c(u) = (a sin u, b sin 2u), traversed from u0 in direction sign."""

    a: float
    b: float
    u0: float
    sign: float
    rotation_rad: float          # path frame -> map frame
    offset_xy: FloatArray        # c(u0), removed before rotating
    table_s: FloatArray          # arc length at table_u, shape (N + 1,)
    table_u: FloatArray

    @property
    def lap_m(self) -> float:
        return float(self.table_s[-1])

    def path_frame(self, s_m: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Position and heading in the path frame at arc lengths s_m, shape (n,) each."""
        u = np.interp(np.mod(s_m, self.lap_m), self.table_s, self.table_u)
        x = self.a * np.sin(u)
        y = self.b * np.sin(2.0 * u)
        heading = np.arctan2(self.sign * 2.0 * self.b * np.cos(2.0 * u),
                             self.sign * self.a * np.cos(u))
        return x, y, heading

    def to_map(self, xy: FloatArray) -> FloatArray:
        """Path-frame points (n, 2) to the map frame."""
        c, s = math.cos(self.rotation_rad), math.sin(self.rotation_rad)
        d = np.asarray(xy, dtype=np.float64) - self.offset_xy
        return np.column_stack([c * d[:, 0] - s * d[:, 1], s * d[:, 0] + c * d[:, 1]])

    def pose(self, s_m: FloatArray) -> FloatArray:
        """Map-frame poses (n, 3): x m, y m, yaw rad in [-pi, pi)."""
        x, y, heading = self.path_frame(s_m)
        xy = self.to_map(np.column_stack([x, y]))
        yaw = wrap_angle(heading + self.rotation_rad)
        return np.column_stack([xy, yaw])


def _make_path(config: SimulationConfig, rng: np.random.Generator) -> _Path:
    a = config.path_half_length_m * rng.uniform(0.9, 1.1)
    b = config.path_half_width_m * rng.uniform(0.9, 1.1)
    sign = 1.0 if rng.random() < 0.5 else -1.0
    u0 = 0.5 * math.pi            # end of the right lobe: x = a, heading -+pi/2
    table_u = u0 + sign * np.linspace(0.0, 2.0 * math.pi, _TABLE_SIZE + 1)
    pts = np.column_stack([a * np.sin(table_u), b * np.sin(2.0 * table_u)])
    table_s = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(pts, axis=0).T))])
    heading0 = math.atan2(sign * 2.0 * b * math.cos(2.0 * u0), sign * a * math.cos(u0))
    # Rotate so the trip starts facing +y at the origin (the course's initial pose).
    return _Path(a=a, b=b, u0=u0, sign=sign, rotation_rad=0.5 * math.pi - heading0,
                 offset_xy=pts[0].copy(), table_s=table_s, table_u=table_u)


def _make_walls(config: SimulationConfig, path: _Path) -> FloatArray:
    """Arena walls in the map frame: one polyline with a doorway, shape (w, 2)."""
    hx = path.a + config.wall_margin_m
    hy = path.b + config.wall_margin_m
    gap = 0.5 * config.doorway_m
    # Start and end at the doorway in the middle of the +y wall (path frame).
    corners = np.array([[gap, hy], [hx, hy], [hx, -hy], [-hx, -hy], [-hx, hy], [-gap, hy]])
    return path.to_map(corners)


def _segments(walls: FloatArray) -> tuple[FloatArray, FloatArray]:
    """NaN-separated polylines (w, 2) to segment starts (m, 2) and direction vectors (m, 2)."""
    starts = walls[:-1]
    ends = walls[1:]
    ok = np.all(np.isfinite(starts), axis=1) & np.all(np.isfinite(ends), axis=1)
    return starts[ok], (ends - starts)[ok]


def _place_poles(config: SimulationConfig, path: _Path, rng: np.random.Generator,
                 count: int | None = None, existing: FloatArray | None = None) -> FloatArray:
    """Rejection-sample pole centres (path frame) clear of the path, walls and each other.

    Args:
        count: poles to place (default ``config.pole_count``).
        existing: poles already there (path frame) that new ones keep their spacing from.

    Returns:
        The new poles only, shape (count, 2).
    """
    if count is None:
        count = config.pole_count
    hx = path.a + config.wall_margin_m - 0.8
    hy = path.b + config.wall_margin_m - 0.8
    route = np.column_stack(path.path_frame(np.linspace(0.0, path.lap_m, 2000))[:2])
    before = 0 if existing is None else len(existing)
    poles = np.zeros((0, 2)) if existing is None else np.asarray(existing, dtype=np.float64)
    target = before + count
    stale = 0
    # Give up after a run of batches that add nothing: the arena is full.
    while len(poles) < target and stale < 20:
        candidates = rng.uniform([-hx, -hy], [hx, hy], size=(256, 2))
        gaps = np.min(np.linalg.norm(candidates[:, None, :] - route[None, :, :], axis=2),
                      axis=1)
        stale += 1
        for point in candidates[gaps >= config.pole_clearance_m]:
            if len(poles) and np.min(np.hypot(*(poles - point).T)) < config.pole_spacing_m:
                continue
            poles = np.vstack([poles, point])
            stale = 0
            if len(poles) == target:
                break
    if len(poles) < target:
        raise CoreError(f'simulation: could place only {len(poles)} of {target} poles; lower '
                        'pole_count, extra_reflectors, pole_spacing_m or pole_clearance_m')
    return poles[before:]


@dataclass(frozen=True, slots=True)
class _SpeedLaw:
    """True speed v(t): 0, a quintic ramp, then a cruise of three slow sinusoids."""

    static_s: float
    ramp_s: float
    mid_m_s: float
    amplitudes_m_s: tuple[float, ...]
    frequencies_hz: tuple[float, ...]
    phases_rad: tuple[float, ...]

    @classmethod
    def draw(cls, config: SimulationConfig, rng: np.random.Generator) -> _SpeedLaw:
        half = 0.5 * (config.max_speed_m_s - config.min_speed_m_s)
        weights = rng.uniform(0.5, 1.0, size=3)
        # The amplitudes sum to just under the half range: the cruise stays inside it.
        amplitudes = 0.95 * half * weights / weights.sum()
        frequencies = rng.uniform(1.0 / 45.0, 1.0 / 12.0, size=3)
        phases = rng.uniform(0.0, 2.0 * math.pi, size=3)
        return cls(config.static_s, config.ramp_s,
                   0.5 * (config.min_speed_m_s + config.max_speed_m_s),
                   tuple(amplitudes.tolist()), tuple(frequencies.tolist()),
                   tuple(phases.tolist()))

    def __call__(self, t_s: FloatArray) -> FloatArray:
        """Return the true speed at times t_s (n,), m/s."""
        moving = np.asarray(t_s, dtype=np.float64) - self.static_s
        cruise = np.full(moving.shape, self.mid_m_s)
        for amplitude, frequency, phase in zip(self.amplitudes_m_s, self.frequencies_hz,
                                               self.phases_rad):
            cruise += amplitude * np.sin(2.0 * math.pi * frequency * moving + phase)
        x = np.clip(moving / self.ramp_s, 0.0, 1.0)
        ramp = x * x * x * (10.0 + x * (-15.0 + 6.0 * x))    # quintic: smooth acceleration
        return ramp * cruise


@dataclass(frozen=True, slots=True)
class _ArcLength:
    """Arc length s(t), m, integrated (trapezoid) on a uniform fine grid from t = 0."""

    step_s: float
    grid_m: FloatArray

    @classmethod
    def integrate(cls, speed: _SpeedLaw, end_s: float, step_s: float) -> _ArcLength:
        count = int(math.ceil(end_s / step_s)) + 1
        grid = np.empty(count)
        grid[0] = 0.0
        # In blocks, so a long trip never holds more than one block of grid temporaries.
        block = 1 << 16
        for first in range(0, count - 1, block):
            last = min(first + block, count - 1)
            v = speed(np.arange(first, last + 1) * step_s)
            grid[first + 1:last + 1] = grid[first] + np.cumsum(0.5 * step_s * (v[1:] + v[:-1]))
        return cls(step_s, grid)

    def __call__(self, t_s: FloatArray) -> FloatArray:
        """Return s at times t_s (n,) inside the grid, m, linearly interpolated."""
        position = np.asarray(t_s, dtype=np.float64) / self.step_s
        index = np.clip(np.floor(position).astype(np.int64), 0, self.grid_m.size - 2)
        frac = position - index
        return self.grid_m[index] * (1.0 - frac) + self.grid_m[index + 1] * frac


# Random streams of the perturbations: children of SeedSequence(seed) after the seven the
# trip itself uses (spawn_key (k,) is what SeedSequence(seed).spawn(k + 1)[k] gives).
_COLOURED_STREAM, _REFLECTOR_STREAM, _MISSING_STREAM, _DROPOUT_STREAM, _IMU_GAP_STREAM = (
    7, 8, 9, 10, 11)


def _stream(seed: int, child: int) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(child,)))


def _gauss_markov(count: int, period_s: float, sigma: float, tau_s: float,
                  rng: np.random.Generator) -> FloatArray:
    """First-order Gauss-Markov samples (count,), stationary sigma, correlation time tau_s."""
    decay = math.exp(-period_s / tau_s)
    # Scaled so the stationary variance is sigma^2; the first sample is drawn from it.
    drive = rng.standard_normal(count) * (sigma * math.sqrt(1.0 - decay * decay))
    drive[0] = sigma * rng.standard_normal()
    out = np.empty(count)
    value = 0.0
    for k, kick in enumerate(drive.tolist()):
        value = decay * value + kick
        out[k] = value
    return out


def gyro_wander(config: SimulationConfig, seed: int) -> FloatArray:
    """Return the coloured yaw-rate noise ``simulate_trip`` adds at each IMU sample, rad/s.

    The very samples the trip of this config and seed carries on its yaw axis (the noise
    has a random stream of its own), one per IMU sample before any IMU gap removes some;
    zeros when the config has none. A trip's truth for a stress analysis: what its wander
    averaged to (``analysis/stress.py``).
    """
    count = _sample_times(config.duration_s, config.imu_rate_hz).size
    if config.gyro_colored_noise_rad_s <= 0.0:
        return np.zeros(count)
    return _gauss_markov(count, 1.0 / config.imu_rate_hz, config.gyro_colored_noise_rad_s,
                         config.gyro_colored_noise_tau_s, _stream(seed, _COLOURED_STREAM))


def _spans(count: int, length_s: float, start_s: float, end_s: float,
           rng: np.random.Generator) -> FloatArray:
    """Non-overlapping spans (count, 2) of length_s in [start_s, end_s], one per equal slot."""
    slot = (end_s - start_s) / count
    begin = start_s + slot * np.arange(count) + rng.uniform(0.0, slot - length_s, count)
    return np.column_stack([begin, begin + length_s])


def _outside(stamps: FloatArray, spans: FloatArray) -> FloatArray:
    """Return which stamps lie outside every [begin, end) span, shape (n,) bool."""
    inside = (stamps[:, None] >= spans[None, :, 0]) & (stamps[:, None] < spans[None, :, 1])
    return ~inside.any(axis=1)


def _sample_times(duration_s: float, rate_hz: float) -> FloatArray:
    count = int(math.floor(duration_s * rate_hz + 1e-9)) + 1
    return np.arange(count, dtype=np.float64) / rate_hz


def _ray_cast(origins: FloatArray, headings: FloatArray, angles: FloatArray,
              poles: FloatArray, radius: float, seg_start: FloatArray,
              seg_vec: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Nearest hit per beam.

    Args:
        origins: sensor positions, shape (m, 2), m.
        headings: sensor headings, shape (m,), rad.
        angles: beam bearings in the sensor frame, shape (b,), rad.
        poles: circle centres, shape (p, 2), m.
        radius: circle radius, m.
        seg_start: wall segment starts, shape (w, 2), m.
        seg_vec: wall segment vectors (end - start), shape (w, 2), m.

    Returns:
        Ranges (m, b), m (inf = no hit), and whether the hit is a pole (m, b).
    """
    direction = headings[:, None] + angles[None, :]
    dx = np.cos(direction)[:, :, None]
    dy = np.sin(direction)[:, :, None]
    ox = origins[:, 0, None, None]
    oy = origins[:, 1, None, None]
    # Circles: closest approach along the ray, then back off to the near surface.
    mx = poles[None, None, :, 0] - ox
    my = poles[None, None, :, 1] - oy
    along = mx * dx + my * dy
    miss2 = mx * mx + my * my - along * along
    hit = (miss2 <= radius * radius) & (along > 0.0)
    r_pole = np.where(hit, along - np.sqrt(np.maximum(radius * radius - miss2, 0.0)), np.inf)
    r_pole = r_pole.min(axis=2, initial=np.inf)
    # Segments: o + t d = p + u e, solved with 2-D cross products.
    qx = seg_start[None, None, :, 0] - ox
    qy = seg_start[None, None, :, 1] - oy
    ex = seg_vec[None, None, :, 0]
    ey = seg_vec[None, None, :, 1]
    denom = dx * ey - dy * ex
    with np.errstate(divide='ignore', invalid='ignore'):
        t = (qx * ey - qy * ex) / denom
        u = (qx * dy - qy * dx) / denom
    hit = (np.abs(denom) > 1e-12) & (t > 0.0) & (u >= 0.0) & (u <= 1.0)
    r_wall = np.where(hit, t, np.inf).min(axis=2, initial=np.inf)
    is_pole = r_pole < r_wall
    return np.where(is_pole, r_pole, r_wall), is_pole


def _scan_series(config: SimulationConfig, stated: LidarMount, true: LidarMount,
                 scan_t: FloatArray, scan_pose: FloatArray, landmarks: FloatArray,
                 seg_start: FloatArray, seg_vec: FloatArray, rng: np.random.Generator,
                 topic: str, frame_id: str) -> ScanSeries:
    """Ray-cast one LiDAR's scans from its true mount.

    Block by block to bound memory on long trips; the series states the nominal mount, as
    a log would.
    """
    c, s = np.cos(scan_pose[:, 2]), np.sin(scan_pose[:, 2])
    origins = np.column_stack([scan_pose[:, 0] + true.x_m * c - true.y_m * s,
                               scan_pose[:, 1] + true.x_m * s + true.y_m * c])
    headings = scan_pose[:, 2] + true.yaw_rad
    angles = config.lidar_angle_min_rad + config.lidar_increment_rad * np.arange(
        config.lidar_beams)
    ranges = np.empty((scan_t.size, config.lidar_beams), dtype=np.float32)
    intensities = np.empty_like(ranges)
    for first in range(0, scan_t.size, _SCAN_BLOCK):
        block = slice(first, first + _SCAN_BLOCK)
        r, is_pole = _ray_cast(origins[block], headings[block], angles, landmarks,
                               config.pole_radius_m, seg_start, seg_vec)
        r = r + config.range_noise_m * rng.standard_normal(r.shape)
        r[~(r <= config.lidar_max_range_m)] = np.inf
        ranges[block] = r
        intensities[block] = np.where(is_pole & np.isfinite(r), POLE_INTENSITY,
                                      WALL_INTENSITY)
    return ScanSeries(
        stamp_s=scan_t, ranges_m=ranges, intensities=intensities,
        angle_min_rad=config.lidar_angle_min_rad,
        angle_increment_rad=config.lidar_increment_rad, range_min_m=0.0,
        range_max_m=config.lidar_max_range_m, mount=stated, topic=topic, frame_id=frame_id)


def _static_turn(config: SimulationConfig, t_s: FloatArray) -> FloatArray:
    """Yaw the platform is still to turn in place at t_s (n,) (static_turn_rad_s), rad."""
    if config.static_turn_rad_s == 0.0:
        return np.zeros(np.shape(t_s))
    return config.static_turn_rad_s * np.minimum(np.asarray(t_s) - config.static_s, 0.0)


def _turned(poses: FloatArray, config: SimulationConfig, t_s: FloatArray) -> FloatArray:
    """Poses (n, 3) turned by what the platform is still to turn in place at t_s."""
    if config.static_turn_rad_s != 0.0:
        poses[:, 2] = wrap_angle(poses[:, 2] + _static_turn(config, t_s))
    return poses


def simulate_trip(config: SimulationConfig | None = None, seed: int = 0) -> Trip:
    """Simulate one trip; the same config and seed give the same trip, bit for bit.

    The scene (path shape, poles) depends only on the seed and the scene fields of the
    config, not on the duration or the noise figures: each random stream has its own
    child of ``np.random.SeedSequence(seed)``.

    Args:
        config: what to simulate; defaults when None.
        seed: random seed (>= 0).

    Returns:
        A Trip with ground truth, the map, walls, true gyro bias and noise figures;
        every stamp starts at 0.0 s.

    Raises:
        CoreError: a config value out of bounds, or poles that do not fit the arena.
    """
    if config is None:
        config = SimulationConfig()
    _check(config)
    # The second LiDAR's stream is a seventh child: the first six are what they always were.
    scene_rng, speed_rng, gyro_rng, accel_rng, odo_rng, *lidar_rngs = (
        np.random.default_rng(child) for child in np.random.SeedSequence(seed).spawn(
            7 if config.second_lidar else 6))

    path = _make_path(config, scene_rng)
    poles_path = _place_poles(config, path, scene_rng)
    landmarks = path.to_map(poles_path)
    walls = _make_walls(config, path)

    # True speed on the fine grid, integrated (trapezoid) into arc length; one second of
    # margin covers the [t_k, t_k + T) window of the last samples.
    speed_law = _SpeedLaw.draw(config, speed_rng)
    arc = _ArcLength.integrate(speed_law, config.duration_s + 1.0,
                               1.0 / config.integration_rate_hz)

    # IMU: mean true rate over [t_k, t_k + T) plus bias and noise per axis.
    imu_t = _sample_times(config.duration_s, config.imu_rate_hz)
    period = 1.0 / config.imu_rate_hz
    edges = np.append(imu_t, imu_t[-1] + period)
    edge_s = arc(edges)
    yaw_edges = path.pose(edge_s)[:, 2] + _static_turn(config, edges)
    rate_true = wrap_angle(np.diff(yaw_edges)) / period
    bias = np.array([config.gyro_bias_x_rad_s, config.gyro_bias_y_rad_s,
                     config.gyro_bias_z_rad_s])
    gyro_sigma = np.array([config.gyro_noise_x_rad_s, config.gyro_noise_y_rad_s,
                           config.gyro_noise_z_rad_s])
    gyro = bias + gyro_sigma * gyro_rng.standard_normal((imu_t.size, 3))
    gyro[:, 2] += rate_true if config.gyro_scale_error == 0.0 else (
        (1.0 + config.gyro_scale_error) * rate_true)
    if config.bias_drifts:
        gyro[:, 2] += config.gyro_bias_drift_z(imu_t)
        # The bias a final bias error is measured against: the one at the end.
        bias = bias.copy()
        bias[2] = float(config.gyro_bias_z_at(imu_t[-1]))
    if config.gyro_colored_noise_rad_s > 0.0:
        gyro[:, 2] += gyro_wander(config, seed)
    accel = None
    if config.with_accelerometer:
        speed_mean = np.diff(edge_s) / period
        v_edges = speed_law(edges)
        accel = np.column_stack([np.diff(v_edges) / period, speed_mean * rate_true,
                                 np.full(imu_t.size, GRAVITY_M_S2)])
        accel += config.accel_noise_m_s2 * accel_rng.standard_normal(accel.shape)

    # Speed encoder: mean true speed over [t_k, t_k + T); noise only while moving.
    odo_t = _sample_times(config.duration_s, config.speed_rate_hz)
    odo_period = 1.0 / config.speed_rate_hz
    speed_true = (arc(odo_t + odo_period) - arc(odo_t)) / odo_period
    noise = config.speed_noise_m_s * odo_rng.standard_normal(odo_t.size)
    scale = 1.0 + config.speed_scale_error
    measured = speed_true if config.speed_scale_error == 0.0 else scale * speed_true
    speed = np.where(speed_true > 0.0, measured + noise, 0.0)

    truth_t = _sample_times(config.duration_s, config.truth_rate_hz)
    truth_pose = _turned(path.pose(arc(truth_t)), config, truth_t)

    scan_t = _sample_times(config.duration_s, config.lidar_rate_hz)
    scan_pose = _turned(path.pose(arc(scan_t)), config, scan_t)
    seg_start, seg_vec = _segments(walls)
    # What the LiDARs see: the map's poles but the missing ones, and the extra reflectors.
    world = landmarks
    if config.missing_poles:
        gone = _stream(seed, _MISSING_STREAM).choice(len(landmarks), config.missing_poles,
                                                     replace=False)
        world = np.delete(world, gone, axis=0)
    if config.extra_reflectors:
        extra = _place_poles(config, path, _stream(seed, _REFLECTOR_STREAM),
                             config.extra_reflectors, poles_path)
        world = np.vstack([world, path.to_map(extra)])
    names = ((SCAN, LASER_FRAME), (SCAN2, LASER2_FRAME))
    scans = tuple(
        _scan_series(config, stated, true, scan_t, scan_pose, world, seg_start, seg_vec,
                     rng, topic, frame_id)
        for (stated, true), rng, (topic, frame_id) in zip(config.lidar_mounts(), lidar_rngs,
                                                          names))
    # Dropouts and gaps remove samples after everything is drawn, so the samples kept are
    # the ones the unperturbed trip has.
    if config.lidar_dropouts:
        keep = _outside(scan_t, _spans(config.lidar_dropouts, config.lidar_dropout_s,
                                       config.static_s, config.duration_s,
                                       _stream(seed, _DROPOUT_STREAM)))
        scans = tuple(dataclasses.replace(
            scan, stamp_s=scan.stamp_s[keep], ranges_m=scan.ranges_m[keep],
            intensities=None if scan.intensities is None else scan.intensities[keep])
            for scan in scans)
    if config.imu_gaps:
        keep = _outside(imu_t, _spans(config.imu_gaps, config.imu_gap_s, config.static_s,
                                      config.duration_s, _stream(seed, _IMU_GAP_STREAM)))
        imu_t, gyro = imu_t[keep], gyro[keep]
        accel = None if accel is None else accel[keep]
    return Trip(
        name=f'sim_seed{seed}',
        imu=ImuSeries(stamp_s=imu_t, angular_velocity_rad_s=gyro,
                      linear_acceleration_m_s2=accel),
        speed=SpeedSeries(stamp_s=odo_t, speed_m_s=speed),
        scans=scans,
        landmarks=LandmarkMap(landmarks),
        initial_pose=truth_pose[0].copy(),
        ground_truth=GroundTruth(stamp_s=truth_t, pose=truth_pose),
        true_gyro_bias_rad_s=bias,
        noise=NoiseFigures(gyro_rad_s=config.gyro_noise_z_rad_s,
                           speed_m_s=config.speed_noise_m_s, landmark_m=0.0),
        walls=walls,
        static_duration_s=config.static_s,
    )
