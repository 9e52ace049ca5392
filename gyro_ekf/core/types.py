"""Plain data that crosses layers: sensor series, maps, trips, estimates.

Everything here is SI (s, m, rad, rad/s) and uses ROS conventions (REP-103): x forward,
y left, angles counter-clockwise, LiDAR bearing 0 = straight ahead of the sensor.
Stamps are float seconds since the trip's time zero; the bag and ROS edges convert to
integer nanoseconds.

Arrays are stored as given (no copies); treat them as read-only.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]

# State vector layout of the EKF: [x, y, yaw, bias, wander]. The gyro's yaw-rate error is
# the bias b (a constant but for its slow walk) plus the wander c, a Gauss-Markov process
# that reverts to 0 over seconds (core/gyro_wander.py); b is the bias the filter reports.
X, Y, YAW, BIAS, WANDER = 0, 1, 2, 3, 4
STATE_SIZE = 5
# What an estimate carries out of the filter: [x, y, yaw, bias] (the wander stays inside).
ESTIMATE_SIZE = 4


@dataclass(frozen=True, slots=True)
class LidarMount:
    """Pose of a LiDAR in the platform frame (base_link).

    Attributes:
        x_m: forward offset of the sensor origin, m.
        y_m: leftward offset of the sensor origin, m.
        yaw_rad: rotation of the sensor about z, rad (pi = rear-facing).
    """

    x_m: float = 0.0
    y_m: float = 0.0
    yaw_rad: float = 0.0
    # The hash, worked out once: a mount keys the per-LiDAR state the filter looks up
    # several times a scan (100 000 look-ups over the 2016 log's run, 2 % of its time when
    # the dataclass hashed a new tuple each time).
    _hash: int = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, '_hash', hash((self.x_m, self.y_m, self.yaw_rad)))

    def __hash__(self) -> int:
        return self._hash


@dataclass(frozen=True, slots=True)
class ImuSeries:
    """Gyro (and optionally accelerometer) samples.

    Attributes:
        stamp_s: sample times, shape (n,), s, non-decreasing.
        angular_velocity_rad_s: shape (n, 3), rad/s, bias included, axes x, y, z of
            imu_link (z = yaw rate, counter-clockwise positive).
        axes_known: which of the three axes the log really measured; unknown axes hold 0.
        linear_acceleration_m_s2: shape (n, 3), m/s^2, or None when the log has none.
        yaw_rate_variance: each message's own variance of the z rate (its
            angular_velocity_covariance[8]), shape (n,), (rad/s)^2, NaN where not given;
            None when no sample gives one (the configured gyro noise applies).
    """

    stamp_s: FloatArray
    angular_velocity_rad_s: FloatArray
    axes_known: tuple[bool, bool, bool] = (True, True, True)
    linear_acceleration_m_s2: FloatArray | None = None
    yaw_rate_variance: FloatArray | None = None

    @property
    def yaw_rate_rad_s(self) -> FloatArray:
        """Z axis, shape (n,), rad/s."""
        return self.angular_velocity_rad_s[:, 2]


@dataclass(frozen=True, slots=True)
class SpeedSeries:
    """Longitudinal speed samples (odometry).

    Attributes:
        stamp_s: shape (n,), s, non-decreasing.
        speed_m_s: shape (n,), m/s, forward positive.
        speed_variance: each message's own speed variance (twist.covariance[0]), shape
            (n,), (m/s)^2, NaN where not given; None when no sample gives one.
    """

    stamp_s: FloatArray
    speed_m_s: FloatArray
    speed_variance: FloatArray | None = None


@dataclass(frozen=True, slots=True)
class ScanSeries:
    """Scans of one 2-D LiDAR, in sensor_msgs/LaserScan conventions.

    Attributes:
        stamp_s: shape (m,), s.
        ranges_m: shape (m, beams), float32, m; no return is +inf (REP-117).
        intensities: shape (m, beams), float32, or None when the sensor gives none.
            Values >= the detector's reflective threshold mark a reflective pole.
        angle_min_rad: bearing of beam 0, rad, 0 = forward, counter-clockwise.
        angle_increment_rad: bearing step between beams, rad.
        range_min_m: smallest valid range, m.
        range_max_m: largest valid range, m.
        mount: where the sensor sits on the platform.
        topic: bag topic name without the leading slash ('scan', 'scan2').
        frame_id: TF frame of the sensor ('laser', 'laser2').
        range_offset_m: how much its ranges read long, m (``lidar.<topic>.range_offset_m``
            of a params file; 0 as recorded): its poles are moved that much toward it
            (models.points_less_range), the ranges themselves left as recorded.
        upside_down: mounted upside down (``lidar.<topic>.upside_down`` of a params file):
            its poles are mirrored into an upright LiDAR's frame (models.points_upright).
        yaw_sigma_rad: how well its mount's yaw is known, rad (``lidar.<topic>.yaw_sigma_rad``
            of a params file, as calibrate-mounts writes a yaw it fitted against the
            odometry; 0 as recorded: the stated yaw is taken as exact). While it defines
            the body frame the reported heading's variance gains it (core/body_frame.py).
    """

    stamp_s: FloatArray
    ranges_m: NDArray[np.float32]
    intensities: NDArray[np.float32] | None
    angle_min_rad: float
    angle_increment_rad: float
    range_min_m: float
    range_max_m: float
    mount: LidarMount = field(default_factory=LidarMount)
    topic: str = 'scan'
    frame_id: str = 'laser'
    range_offset_m: float = 0.0
    upside_down: bool = False
    yaw_sigma_rad: float = 0.0

    @property
    def beam_count(self) -> int:
        """Beams per scan."""
        return int(self.ranges_m.shape[1])

    @property
    def angles_rad(self) -> FloatArray:
        """Bearing of every beam, shape (beams,), rad."""
        return self.angle_min_rad + self.angle_increment_rad * np.arange(
            self.beam_count, dtype=np.float64)


@dataclass(frozen=True, slots=True)
class LandmarkMap:
    """Known landmark (pole centre) positions in the map frame.

    Attributes:
        xy_m: shape (k, 2), m.
    """

    xy_m: FloatArray

    def __len__(self) -> int:
        return int(self.xy_m.shape[0])


@dataclass(frozen=True, slots=True)
class GroundTruth:
    """True platform poses, where a simulated log provides them.

    Attributes:
        stamp_s: shape (g,), s.
        pose: shape (g, 3): x m, y m, yaw rad in the map frame.
    """

    stamp_s: FloatArray
    pose: FloatArray


@dataclass(frozen=True, slots=True)
class NoiseFigures:
    """Sensor noise standard deviations a log states about itself (None = not stated).

    Attributes:
        gyro_rad_s: yaw-rate white noise, rad/s.
        speed_m_s: speed noise, m/s.
        range_m: LiDAR range noise, m.
        bearing_rad: LiDAR bearing noise, rad.
        landmark_m: uncertainty of each landmark's map position, m; 0 for a simulator's
            own map, which is exact.
    """

    gyro_rad_s: float | None = None
    speed_m_s: float | None = None
    range_m: float | None = None
    bearing_rad: float | None = None
    landmark_m: float | None = None


@dataclass(frozen=True, slots=True)
class Trip:
    """One recorded or simulated trip: everything a bag or a course log holds.

    Attributes:
        name: short identifier (file stem).
        imu: gyro samples.
        speed: odometry speed samples.
        scans: one series per LiDAR (possibly none).
        landmarks: known map, or None.
        initial_pose: shape (3,): x m, y m, yaw rad in the map frame.
        ground_truth: true poses, or None.
        true_gyro_bias_rad_s: shape (3,), rad/s, the injected bias when known, else None.
        noise: noise figures the log states about itself.
        walls: shape (w, 2), m, polylines separated by NaN rows, or None.
        static_duration_s: how long the trip is known to start static (0 = moves at once);
            informational, calibration checks the data itself.
    """

    name: str
    imu: ImuSeries
    speed: SpeedSeries
    scans: tuple[ScanSeries, ...] = ()
    landmarks: LandmarkMap | None = None
    initial_pose: FloatArray = field(default_factory=lambda: np.zeros(3))
    ground_truth: GroundTruth | None = None
    true_gyro_bias_rad_s: FloatArray | None = None
    noise: NoiseFigures = field(default_factory=NoiseFigures)
    walls: FloatArray | None = None
    static_duration_s: float = 0.0

    @property
    def start_s(self) -> float:
        """Earliest stamp of any stream, s."""
        starts = [s[0] for s in self._stamp_series() if len(s)]
        return float(min(starts)) if starts else 0.0

    @property
    def end_s(self) -> float:
        """Latest stamp of any stream, s."""
        ends = [s[-1] for s in self._stamp_series() if len(s)]
        return float(max(ends)) if ends else 0.0

    def _stamp_series(self) -> list[FloatArray]:
        # Each stream on its own: any of them may be empty (a bag with /odom declared
        # but no message on it).
        return [self.imu.stamp_s, self.speed.stamp_s] + [s.stamp_s for s in self.scans]


@dataclass(frozen=True, slots=True)
class BiasEstimate:
    """Result of an offline static-window calibration.

    Attributes:
        bias_rad_s: per-axis mean over the window, shape (3,), rad/s.
        sigma_rad_s: per-axis white-noise standard deviation, shape (3,), rad/s.
        n_samples: samples in the window.
        window_start_s: first stamp of the window, s.
        window_end_s: last stamp of the window, s.
        max_abs_rate_rad_s: largest |rate| seen per axis, shape (3,), rad/s.
        scan_turns: how fast each LiDAR that followed poles through the window saw the
            platform turn (calibration.ScanTurn; calibration.confirm_still), none when
            no scan was looked at.
    """

    bias_rad_s: FloatArray
    sigma_rad_s: FloatArray
    n_samples: int
    window_start_s: float
    window_end_s: float
    max_abs_rate_rad_s: FloatArray
    scan_turns: tuple = ()

    @property
    def bias_standard_error_rad_s(self) -> FloatArray:
        """Standard error of the mean per axis, shape (3,), rad/s."""
        return self.sigma_rad_s / np.sqrt(max(self.n_samples, 1))

    def correct(self, angular_velocity_rad_s: FloatArray) -> FloatArray:
        """Remove the bias: w_improved = w_measured - B. Shape (..., 3), rad/s."""
        return np.asarray(angular_velocity_rad_s) - self.bias_rad_s
