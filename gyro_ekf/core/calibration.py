"""Offline gyro bias calibration over a static window.

From the course note on the offline approach (``../shared/course-notes/000_0fea21e8eda0b479.txt``):
a gyro at rest measures ``w_measured = b + eta`` with zero-mean white noise ``eta``, so the
mean of each axis over a window in which the platform is known to be static estimates the
bias ``B``, and ``w_improved = w_measured - B`` afterwards.

The window is only trusted after checking that it really was static: enough samples, no
gap, no speed where a speed stream exists, and no per-axis spread or trend beyond the
configured thresholds. A refused window raises CalibrationError saying why.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from gyro_ekf.core.config import CalibrationConfig
from gyro_ekf.core.errors import CalibrationError
from gyro_ekf.core.types import BiasEstimate, FloatArray

_AXES = 'xyz'


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

    Live use (the calibration node): feed ``add_imu`` and ``add_speed``; ``add_imu``
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
        if stamp_s - self._stamps[0] < self.config.window_length_s:
            return None
        window_config = dataclasses.replace(self.config, window_start_s=0.0)
        try:
            result = estimate_gyro_bias(
                np.array(self._stamps), np.array(self._rates), window_config,
                np.array(self._speed_stamps), np.array(self._speeds), axes_known)
        except CalibrationError:
            self.refusals += 1
            self.restart()
            raise
        self.result = result
        return result
