"""Offline gyro bias calibration over a static window.

From the course note on the offline approach (``../shared/course-notes/000_0fea21e8eda0b479.txt``):
a gyro at rest measures ``w_measured = b + eta`` with zero-mean white noise ``eta``, so the
mean of each axis over a window in which the platform is known to be static estimates the
bias ``B``, and ``w_improved = w_measured - B`` afterwards.

The window is only trusted after checking that it really was static: enough samples, no
gap, no speed where a speed stream exists, and no per-axis spread or trend beyond the
configured thresholds. A refused window raises CalibrationError saying why.

None of those sees a platform turning in place slowly and steadily: the odometry reads no
speed, the gyro a constant rate with its usual spread, and the mean takes the turn for
bias (a simulated 0.1 deg/s turn gave a bias 0.098 deg/s off, accepted). The LiDARs do see
it: every pole they follow through the window turns about the platform at minus its rate
(``scan_turn``), so where scans exist a turn beyond ``MAX_SCAN_TURN_RAD_S`` refuses the
window too.
"""

from __future__ import annotations

import bisect
from collections.abc import Iterable, Iterator, Sequence
import dataclasses
from dataclasses import dataclass
import math

import numpy as np

from gyro_ekf.core.config import CalibrationConfig, DEG, DetectorConfig
from gyro_ekf.core.detection import detect_poles_in_scans
from gyro_ekf.core.errors import CalibrationError
from gyro_ekf.core.models import points_upright, sensor_to_map
from gyro_ekf.core.types import BiasEstimate, FloatArray, ScanSeries, Trip

_AXES = 'xyz'

MAX_SCAN_TURN_RAD_S = 0.02 * DEG
"""The largest turn a LiDAR may see in a static window (beyond it, and beyond 3 sigmas of
the fit, the window is refused): the project's bound on a final bias error, all of which a
turn the gyro's mean takes for bias would use up. The real 2016 log's static start reads
-0.0003 deg/s."""

LIVE_BEAM_STEP_RAD = 0.5 * DEG
"""Live: the beam step the poles' turn is taken as quantised by (a PoseArray of poles carries
none): the course LiDARs' 0.5 deg; a finer LiDAR is judged a little more cautiously."""

POLE_LAG_S = 0.25
"""Live: a LiDAR whose last scan is older than this at the window's end lags the gyro."""

POLE_WAIT_S = 1.0
"""Live: how long (gyro time) a full window waits for a lagging LiDAR's last scans."""

TRACK_GATE_M = 0.3
"""Farthest a pole may move between two scans and still be the same pole (body frame): a
turn of 17 deg/s at 10 m between scans 0.1 s apart."""

_BODY = np.zeros(3)
"""The platform's own pose: sensor_to_map at it places points in the body frame."""


@dataclass(frozen=True, slots=True)
class ScanTurn:
    """How fast a LiDAR saw the platform turn in a window in which it stood still.

    Attributes:
        rate_rad_s: the platform's mean yaw rate over the window (counter-clockwise
            positive): its net turn over the time between the window's ends, rad/s.
        sigma_rad_s: its standard error from the bearings' scatter at those ends, rad/s.
        poles: poles followed through at least half the window's scans.
        scans: scans in the window.
        topic: the LiDAR's scan topic.
    """

    rate_rad_s: float
    sigma_rad_s: float
    poles: int
    scans: int
    topic: str = ''

    @property
    def turning(self) -> bool:
        """Beyond MAX_SCAN_TURN_RAD_S and beyond 3 sigmas: the platform turned."""
        return abs(self.rate_rad_s) > max(MAX_SCAN_TURN_RAD_S, 3.0 * self.sigma_rad_s)

    @property
    def ruled_out_rad_s(self) -> float:
        """The least turn rate this look rules out (3 sigmas beyond what it saw), rad/s.

        A window the LiDAR passes may still hold a turn up to this, which its bias would
        carry: a short window or a coarse LiDAR rules out less.
        """
        return abs(self.rate_rad_s) + 3.0 * self.sigma_rad_s


def pole_turn(stamp_s: Sequence[float], points_body_m: Sequence[FloatArray],
              beam_step_rad: float = 0.0) -> ScanTurn | None:
    """Return the platform's mean turn rate from poles followed through scans at a stop.

    Seen from a platform turning in place, every pole's bearing in the body frame (about
    the platform's reference point, wherever the LiDAR sits) turns back by as much. Each
    pole is followed scan to scan (the nearest detection within TRACK_GATE_M of where it
    was last); of every pole followed through at least half the scans, the bearings of its
    first and last fifth are averaged, and the rate is the turn between those ends over
    the time between them (one rate for all poles, least squares). The net turn, not a
    line's slope: what the gyro's mean takes for bias is the window's net turn over its
    length, and a turn that stops part way through the window counts for what it turned.

    A pole's centre moves in steps of about half a beam (a beam joins or leaves its
    returns), and at rest the same beams hit it scan after scan: averaging an end does not
    take that step out, so each end's mean is taken as uncertain by at least a uniform half
    step (a 0.5 deg beam and a 5-s window: about 0.01 deg/s of turn from five poles).

    Args:
        stamp_s: the scans' stamps, s.
        points_body_m: each scan's pole centres in the body frame, shape (k, 2), m.
        beam_step_rad: the LiDAR's angle between beams (0: only the scatter counts).

    Returns:
        The turn, or None when no pole was followed through half the scans (nothing seen).
    """
    tracks: list[tuple[list[float], list[float], list[float]]] = []  # last xy, stamps, bearings
    for stamp, points in zip(stamp_s, points_body_m):
        taken: set[int] = set()
        for x, y in np.asarray(points, dtype=np.float64).reshape(-1, 2).tolist():
            nearest, distance = None, TRACK_GATE_M
            for k, (last, _, _) in enumerate(tracks):
                gap = math.hypot(x - last[0], y - last[1])
                if k not in taken and gap < distance:
                    nearest, distance = k, gap
            if nearest is None:
                tracks.append(([x, y], [], []))
                nearest = len(tracks) - 1
            last, stamps, bearings = tracks[nearest]
            last[:] = (x, y)
            stamps.append(float(stamp))
            bearings.append(math.atan2(y, x))
            taken.add(nearest)
    enough = max(5, len(stamp_s) // 2)
    spans, turns, counts, scatter, free = [], [], [], 0.0, 0
    for _, stamps, bearings in tracks:
        if len(stamps) < enough:
            continue
        t, b = np.asarray(stamps), np.unwrap(np.asarray(bearings))
        k = max(1, len(t) // 5)
        ends = (slice(None, k), slice(-k, None))
        spans.append(t[ends[1]].mean() - t[ends[0]].mean())
        turns.append(b[ends[1]].mean() - b[ends[0]].mean())
        counts.append(k)
        for end in ends:
            scatter += float(np.sum((b[end] - b[end].mean()) ** 2))
            free += k - 1
    span, turn = np.asarray(spans), np.asarray(turns)
    sxx = float(span @ span)
    if not spans or sxx <= 0.0:
        return None
    rate = -float(span @ turn) / sxx
    # Each end's mean: its bearings' scatter over k, or the half-beam step's uniform
    # variance where that is more; a pole's turn has twice it.
    variance = scatter / max(free, 1)
    step_variance = (0.5 * beam_step_rad) ** 2 / 12.0
    turn_variance = 2.0 * np.maximum(variance / np.asarray(counts), step_variance)
    sigma = math.sqrt(float(turn_variance @ (span * span))) / sxx
    return ScanTurn(rate, sigma, len(spans), len(stamp_s))


def scan_turn(scan: ScanSeries, start_s: float, end_s: float,
              detector: DetectorConfig | None = None) -> ScanTurn | None:
    """Return pole_turn of a LiDAR's scans stamped in [start_s, end_s].

    The poles are found as the run finds them and placed in the body frame by the LiDAR's
    mount (the turn does not depend on it: a mount a few degrees off turns every bearing
    alike).
    """
    inside = np.flatnonzero((scan.stamp_s >= start_s) & (scan.stamp_s <= end_s))
    if inside.size < 3:
        return None
    found = detect_poles_in_scans(
        scan.ranges_m[inside], scan.angles_rad,
        None if scan.intensities is None else scan.intensities[inside], detector)
    points = [points_upright(p.points_sensor_m) if scan.upside_down else p.points_sensor_m
              for p in found]
    turn = pole_turn(scan.stamp_s[inside].tolist(),
                     [sensor_to_map(_BODY, p, scan.mount) for p in points],
                     abs(scan.angle_increment_rad))
    return None if turn is None else dataclasses.replace(turn, topic=scan.topic)


def estimate_gyro_bias(stamp_s: FloatArray, angular_velocity_rad_s: FloatArray,
                       config: CalibrationConfig | None = None,
                       speed_stamp_s: FloatArray | None = None,
                       speed_m_s: FloatArray | None = None,
                       axes_known: tuple[bool, bool, bool] = (True, True, True),
                       ) -> BiasEstimate:
    """Mean and spread of each gyro axis over the static window, after checking it.

    The window starts ``config.window_start_s`` after the first sample and lasts
    ``config.window_length_s``.

    Args:
        stamp_s: sample times, shape (n,), s, non-decreasing.
        angular_velocity_rad_s: rates, shape (n, 3) (x, y, z) or (n,) for yaw only, rad/s,
            bias included.
        config: window and thresholds; CalibrationConfig() when None.
        speed_stamp_s: speed sample times, shape (m,), s; optional.
        speed_m_s: speeds, shape (m,), m/s; any |speed| above the threshold in the window
            refuses it.
        axes_known: axes that were really measured; the others are not checked and report 0.

    Returns:
        The per-axis bias and white-noise sigma with the window used.

    Raises:
        CalibrationError: too few samples, a gap, data ending before the window does, or
            motion (speed, spread or trend), with the reason and the numbers; its stream
            says which input ('imu' or 'speed') refused the window.
    """
    config = config or CalibrationConfig()
    stamps = np.asarray(stamp_s, dtype=np.float64)
    rates = np.asarray(angular_velocity_rad_s, dtype=np.float64)
    if rates.ndim == 1:
        rates = np.column_stack([np.zeros_like(rates), np.zeros_like(rates), rates])
        axes_known = (False, False, True)
    if rates.shape != (stamps.shape[0], 3):
        raise CalibrationError(f'gyro rates have shape {rates.shape}, expected '
                               f'({stamps.shape[0]}, 3) to match the stamps')
    if stamps.size == 0:
        raise CalibrationError('no gyro samples to calibrate from')
    start = stamps[0] + config.window_start_s
    end = start + config.window_length_s
    if stamps[-1] < end - config.max_gap_s:
        raise CalibrationError(
            f'the static window {start - stamps[0]:.2f}-{end - stamps[0]:.2f} s needs data '
            f'until {end - stamps[0]:.2f} s, but the gyro stream ends at '
            f'{stamps[-1] - stamps[0]:.2f} s')
    inside = (stamps >= start) & (stamps <= end)
    window_stamps = stamps[inside]
    window_rates = rates[inside]
    count = int(window_stamps.size)
    if count < config.min_samples:
        raise CalibrationError(f'the static window has {count} gyro samples, at least '
                               f'{config.min_samples} are needed')
    edges = np.concatenate([[start], window_stamps, [end]])
    gaps = np.diff(edges)
    worst = int(np.argmax(gaps))
    if gaps[worst] > config.max_gap_s:
        raise CalibrationError(
            f'gap of {gaps[worst]:.3f} s in the gyro stream at '
            f'{edges[worst] - stamps[0]:.2f} s (at most {config.max_gap_s} s allowed)')
    if speed_m_s is not None and speed_stamp_s is not None:
        _check_speed(np.asarray(speed_stamp_s, dtype=np.float64),
                     np.asarray(speed_m_s, dtype=np.float64), start, end, stamps[0], config)

    known = np.array(axes_known, dtype=bool)
    # NaN passes every `>` threshold below, so a non-finite sample must be refused here or
    # it becomes a NaN bias.
    bad = ~np.isfinite(window_rates[:, known]).all(axis=1)
    if bad.any():
        i = int(np.argmax(bad))
        raise CalibrationError(
            f'the static window holds a non-finite gyro sample at '
            f'{window_stamps[i] - stamps[0]:.3f} s ({window_rates[i].tolist()} rad/s)')
    bias = np.where(known, window_rates.mean(axis=0), 0.0)
    sigma = np.where(known, window_rates.std(axis=0, ddof=1), 0.0)
    half = count // 2
    drift = np.abs(window_rates[:half].mean(axis=0) - window_rates[half:].mean(axis=0))
    for axis in np.flatnonzero(known):
        if sigma[axis] > config.max_sigma_rad_s:
            raise CalibrationError(
                f'platform not static: gyro {_AXES[axis]} spread {np.rad2deg(sigma[axis]):.3f} '
                f'deg/s exceeds {np.rad2deg(config.max_sigma_rad_s):.3f} deg/s')
        if drift[axis] > config.max_drift_rad_s:
            raise CalibrationError(
                f'platform not static: gyro {_AXES[axis]} mean changed by '
                f'{np.rad2deg(drift[axis]):.3f} deg/s between the window halves (at most '
                f'{np.rad2deg(config.max_drift_rad_s):.3f} deg/s)')
    return BiasEstimate(
        bias_rad_s=bias, sigma_rad_s=sigma, n_samples=count,
        window_start_s=float(window_stamps[0]), window_end_s=float(window_stamps[-1]),
        max_abs_rate_rad_s=np.where(known, np.abs(window_rates).max(axis=0), 0.0))


def confirm_still(estimate: BiasEstimate, turns: Iterable[ScanTurn | None]) -> BiasEstimate:
    """Refuse a window in which a LiDAR saw the platform turn; else record what they saw.

    Args:
        estimate: the window the gyro and speed checks accepted.
        turns: each LiDAR's scan_turn (or pole_turn) over that window; None where it
            followed no pole.

    Returns:
        The estimate with ``scan_turns`` (the LiDARs that followed poles).

    Raises:
        CalibrationError: a LiDAR saw a turn (ScanTurn.turning), naming it and the rate.
    """
    seen = tuple(turn for turn in turns if turn is not None)
    for turn in seen:
        if turn.turning:
            raise CalibrationError(
                f"platform not static: its LiDAR '{turn.topic}' saw it turn "
                f'{math.degrees(turn.rate_rad_s):+.3f} deg/s (+-'
                f'{math.degrees(turn.sigma_rad_s):.3f}, {turn.poles} poles through '
                f'{turn.scans} scans), which the gyro\'s mean would take for bias (at most '
                f'{math.degrees(MAX_SCAN_TURN_RAD_S):.3f} deg/s)', stream=f'lidar:{turn.topic}')
    return dataclasses.replace(estimate, scan_turns=seen)


def calibrate_trip(trip: Trip, config: CalibrationConfig | None = None,
                   detector: DetectorConfig | None = None, use_speed: bool = True,
                   use_scans: bool = True) -> BiasEstimate:
    """Calibrate a trip's gyro on its static window, checked by its speed and its scans.

    Raises:
        CalibrationError: the window refused (estimate_gyro_bias, confirm_still).
    """
    speed = trip.speed if use_speed and len(trip.speed.stamp_s) else None
    estimate = estimate_gyro_bias(
        trip.imu.stamp_s, trip.imu.angular_velocity_rad_s, config,
        speed_stamp_s=None if speed is None else speed.stamp_s,
        speed_m_s=None if speed is None else speed.speed_m_s,
        axes_known=trip.imu.axes_known)
    if not use_scans:
        return estimate
    return confirm_still(estimate, (
        scan_turn(scan, estimate.window_start_s, estimate.window_end_s, detector)
        for scan in trip.scans))


def measured_axes(values: FloatArray, axes_known: tuple[bool, bool, bool]
                  ) -> list[float | None]:
    """Return per-axis values as a JSON-ready list, None (null) for an axis not measured.

    estimate_gyro_bias reports 0 for such an axis (x and y of a yaw-rate-only gyro), which
    in a report would read as a bias or a noise known to be exactly zero.
    """
    return [float(v) if known else None for v, known in zip(values, axes_known)]


def _check_speed(speed_stamps: FloatArray, speeds: FloatArray, start: float, end: float,
                 origin: float, config: CalibrationConfig) -> None:
    inside = (speed_stamps >= start) & (speed_stamps <= end)
    if not inside.any():
        return
    # `not <=` so that a NaN speed cannot pass as standing still.
    moving = np.flatnonzero(~(np.abs(speeds[inside]) <= config.max_speed_m_s))
    if moving.size:
        first = moving[0]
        raise CalibrationError(
            f'platform moved: speed {speeds[inside][first]:.4g} m/s at '
            f'{speed_stamps[inside][first] - origin:.2f} s inside the static window '
            f'(at most {config.max_speed_m_s} m/s allowed)', stream='speed')


class StaticWindowCalibrator:
    """Collects samples as they arrive and calibrates once a window is complete.

    Live use (the calibration node): feed ``add_imu``, ``add_speed`` and ``add_poles`` (the
    LiDARs' poles, which refuse a window they saw turn, ``confirm_still``); ``add_imu``
    returns a BiasEstimate once the window is full and passes the checks. A refused window
    raises CalibrationError and the calibrator starts a new window at the next sample.
    ``restart`` starts a new window on demand.

    Attributes:
        result: the last accepted BiasEstimate, or None.
        refusals: how many windows were refused.
    """

    def __init__(self, config: CalibrationConfig | None = None):
        """Start collecting a first window."""
        self.config = config or CalibrationConfig()
        self.result: BiasEstimate | None = None
        self.refusals = 0
        # Per LiDAR: its scans' stamps and poles. Kept over a restart (a refused window's
        # successor may already have scans), dropped once older than a window's start.
        self._poles: dict[str, tuple[list[float], list[FloatArray]]] = {}
        self.restart()

    def restart(self) -> None:
        """Drop the collected samples (and the result) and start a new window."""
        self._stamps: list[float] = []
        self._rates: list[tuple[float, float, float]] = []
        self._speed_stamps: list[float] = []
        self._speeds: list[float] = []
        self.result = None

    @property
    def collecting(self) -> bool:
        """True until a window has been accepted."""
        return self.result is None

    def add_speed(self, stamp_s: float, speed_m_s: float) -> None:
        """Record a speed sample (used to confirm the platform is still)."""
        if self.collecting:
            self._speed_stamps.append(stamp_s)
            self._speeds.append(speed_m_s)

    def add_poles(self, sensor: str, stamp_s: float, points_m: FloatArray) -> None:
        """Record the poles one LiDAR saw in a scan (used to confirm the platform does not turn).

        points_m: pole centres, shape (k, 2), m, in the body frame or the LiDAR's own (a
        LiDAR d from the platform's reference point reads a turn in place to within d / r
        for poles at range r: enough to tell a turn from none).
        """
        if self.collecting:
            stamps, points = self._poles.setdefault(sensor, ([], []))
            stamps.append(stamp_s)
            points.append(np.asarray(points_m, dtype=np.float64).reshape(-1, 2))
            # Bounded with no gyro to start a window: none is older than a window and its wait.
            old = bisect.bisect_left(stamps, stamp_s - self.config.window_length_s
                                     - 2.0 * POLE_WAIT_S)
            del stamps[:old], points[:old]

    def _drop_poles_before(self, stamp_s: float) -> None:
        for stamps, points in self._poles.values():
            first = next((k for k, stamp in enumerate(stamps) if stamp >= stamp_s), len(stamps))
            del stamps[:first], points[:first]

    def _pole_turns(self, start_s: float, end_s: float) -> Iterator[ScanTurn | None]:
        """pole_turn of each LiDAR's scans stamped in [start_s, end_s]."""
        for sensor, (stamps, points) in self._poles.items():
            chosen = [k for k, stamp in enumerate(stamps) if start_s <= stamp <= end_s]
            turn = pole_turn([stamps[k] for k in chosen], [points[k] for k in chosen],
                             LIVE_BEAM_STEP_RAD)
            yield None if turn is None else dataclasses.replace(turn, topic=sensor)

    def add_imu(self, stamp_s: float, rate_xyz_rad_s: tuple[float, float, float],
                axes_known: tuple[bool, bool, bool] = (True, True, True),
                ) -> BiasEstimate | None:
        """Record a gyro sample; returns the estimate when this sample completes the window.

        Raises:
            CalibrationError: the completed window was refused (collection restarts).
        """
        if not self.collecting:
            return None
        if self._stamps and stamp_s < self._stamps[-1]:
            step_back_s = self._stamps[-1] - stamp_s
            self.restart()
            raise CalibrationError(
                f'gyro stamp went back {step_back_s:.3f} s; starting a new window')
        self._stamps.append(stamp_s)
        self._rates.append(tuple(rate_xyz_rad_s))
        if len(self._stamps) == 1:
            self._drop_poles_before(stamp_s)
        end_s = self._stamps[0] + self.config.window_length_s
        if stamp_s < end_s:
            return None
        if stamp_s < end_s + POLE_WAIT_S and any(
                stamps and stamps[-1] < end_s - POLE_LAG_S
                for stamps, _ in self._poles.values()):
            # A LiDAR's scans lag the gyro (detection, transport): its last ones decide
            # whether the window ended turning. Waited for up to POLE_WAIT_S.
            return None
        window_config = dataclasses.replace(self.config, window_start_s=0.0)
        try:
            result = estimate_gyro_bias(
                np.array(self._stamps), np.array(self._rates), window_config,
                np.array(self._speed_stamps), np.array(self._speeds), axes_known)
            result = confirm_still(result, self._pole_turns(result.window_start_s,
                                                            result.window_end_s))
        except CalibrationError:
            self.refusals += 1
            self.restart()
            raise
        self.result = result
        return result
