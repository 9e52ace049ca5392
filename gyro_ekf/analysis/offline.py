"""Offline run of the pipeline on a Trip: calibration, then the EventDriver over every event.

This is what `gyro-ekf run` does between reading the bag and writing its products, with no
DDS in between: the same `core.events.EventDriver` the live EKF node wraps, fed the trip's
events in stamp order (`core.trip_run.drive_trip`).

Configuration follows the live nodes: the core defaults, then whatever a params file sets
explicitly, then the noise figures the log states, which replace the configured sigmas
(default or params file alike) while `use_stated_noise` holds, as the EKF node's parameter
of that name does; a params file that wants its own sigmas sets `use_stated_noise: false`.
The switches (`use_stated_noise`, `use_message_covariance`, `use_calibration`,
`calibration_bias_sigma_rad_s`) are core.config.RunOptions, whose defaults the node
declares too; a caller's argument overrides the params file's value.
"""

from __future__ import annotations

from collections.abc import Callable
import dataclasses
from dataclasses import dataclass
import logging

import numpy as np

from gyro_ekf.core.calibration import calibrate_trip
from gyro_ekf.core.config import (STATED_NOISE_FIELDS, CalibrationConfig, DetectorConfig,
                                  EkfConfig, with_stated_noise)
from gyro_ekf.core.errors import CalibrationError
from gyro_ekf.core.events import EventDriver
from gyro_ekf.analysis.detect_ahead import DetectionsAhead
from gyro_ekf.core.trip_run import (Estimates, ScanDetector, TripRun, UpdateLog,
                                    corrected_yaw_rate, drive_trip, held_speed)
from gyro_ekf.core.types import BiasEstimate, FloatArray, NoiseFigures, Trip
from gyro_ekf.io.params_file import PipelineParams, with_lidar_mounts

log = logging.getLogger(__name__)


@dataclass(frozen=True, slots=True)
class OfflineRun:
    """Everything a run produced.

    Attributes:
        trip: the inputs.
        config: the EKF configuration used.
        config_sources: EKF field -> 'default', 'log' (stated by the log), 'params-file' or
            'messages' (each message's own variance, ``message_sources``).
        calibration: the accepted static-window estimate, or None.
        calibration_error: why no window was accepted, or None.
        result: estimates (one row per IMU sample), per-scan reports and counts.
        speed_m_s: held speed at each estimate, shape (n,), m/s (computed on access).
        yaw_rate_rad_s: bias-corrected yaw rate at each estimate, shape (n,), rad/s
            (computed on access).
    """

    trip: Trip
    config: EkfConfig
    config_sources: dict[str, str]
    calibration: BiasEstimate | None
    calibration_error: str | None
    result: TripRun

    # What the live node puts in the odometry twist. Computed when asked for (only the
    # estimates bag needs them), so a long run does not carry two more (n,) arrays.
    @property
    def speed_m_s(self) -> FloatArray:
        """Held speed at each estimate, shape (n,), m/s (0 before the first sample)."""
        return held_speed(self.trip.speed, self.result.estimates.stamp_s)

    @property
    def yaw_rate_rad_s(self) -> FloatArray:
        """Bias-corrected yaw rate at each estimate, shape (n,), rad/s.

        The rate the filter's heading moved by: the measured one less the bias and the
        gyro's wander (0 unless one was found), as the live node's twist has it.
        """
        estimates = self.result.estimates
        return corrected_yaw_rate(self.trip.imu.yaw_rate_rad_s[:len(estimates.stamp_s)],
                                  estimates.state, estimates.wander_rad_s)


def effective_config(noise: NoiseFigures, params: PipelineParams | None = None,
                     use_stated_noise: bool | None = None
                     ) -> tuple[EkfConfig, dict[str, str]]:
    """Return the EKF configuration of a run and where each value came from.

    Args:
        noise: the noise figures the log states.
        params: a parsed params file, or None for the defaults.
        use_stated_noise: let the log's stated figures replace the configured sigmas, as
            the EKF node does (core.config.with_stated_noise); None takes the params
            file's option (RunOptions' default: true).

    Returns:
        The config and, per field, 'default', 'log' or 'params-file'.
    """
    params = params or PipelineParams()
    if use_stated_noise is None:
        use_stated_noise = params.options.use_stated_noise
    config = params.ekf
    explicit = set(params.explicit.get('ekf', ()))
    sources = {f.name: ('params-file' if f.name in explicit else 'default')
               for f in dataclasses.fields(EkfConfig)}
    if use_stated_noise:
        config = with_stated_noise(config, noise)
        for key, target in STATED_NOISE_FIELDS.items():
            if getattr(noise, key) is not None:
                sources[target] = 'log'
        # A sigma the user wrote that the log's figure replaces: said, not silently lost.
        replaced = [(target, getattr(params.ekf, target), getattr(config, target))
                    for target, source in sources.items()
                    if source == 'log' and target in explicit
                    and getattr(params.ekf, target) != getattr(config, target)]
        if replaced:
            log.warning('the params file sets %s, but the log states %s, used while '
                        'use_stated_noise is true; to use the file\'s, set '
                        'use_stated_noise: false in it (or run --ignore-stated-noise)',
                        ', '.join(f'{name} = {mine:g}' for name, mine, _ in replaced),
                        ', '.join(f'{name} = {used:g}' for name, _, used in replaced))
    return config, sources


_MESSAGE_NOISE = (('gyro_noise_rad_s', 'IMU', 'angular_velocity_covariance[8]'),
                  ('speed_noise_m_s', 'odometry', 'twist.covariance[0]'))
"""The configured sigmas a message's own variance replaces, with the field it comes in."""


def message_sources(trip: Trip, params: PipelineParams, sources: dict[str, str]) -> None:
    """Mark in sources the noise figures the messages' own variances replace; say a lost one.

    Each IMU and odometry message that states its variance is filtered with it, whatever the
    configuration or the log states (``use_message_covariance``): summary.json once named
    the params file as the source of a gyro noise no message was filtered with. The source
    becomes 'messages' (or 'messages (N of M)' where only some state one); a figure the
    params file sets that they replace is said, with the switch that keeps it.
    """
    explicit = set(params.explicit.get('ekf', ()))
    for name, stream, field_name, variances in (
            (*_MESSAGE_NOISE[0], trip.imu.yaw_rate_variance),
            (*_MESSAGE_NOISE[1], trip.speed.speed_variance)):
        if variances is None:
            continue
        stated = int(np.isfinite(variances).sum())
        if not stated:
            continue
        total = len(variances)
        sources[name] = 'messages' if stated == total else f'messages ({stated} of {total})'
        if name in explicit:
            log.warning('the params file sets %s = %g, but %d of %d %s messages state their '
                        'own variance (%s), used in its place while use_message_covariance '
                        'is true; to use the file\'s, set use_message_covariance: false in '
                        'it (or run --ignore-message-covariance)', name,
                        getattr(params.ekf, name), stated, total, stream, field_name)


def calibrate(trip: Trip, config: CalibrationConfig | None = None,
              detector: DetectorConfig | None = None
              ) -> tuple[BiasEstimate | None, str | None]:
    """Calibrate the trip's gyro on its static window, or say why there is none."""
    try:
        estimate = calibrate_trip(trip, config, detector)
    except CalibrationError as err:
        log.info('%s: no offline bias: %s', trip.name, err)
        return None, str(err)
    log.info('%s: offline yaw-rate bias %.4f deg/s (window %.1f-%.1f s, %d samples)',
             trip.name, np.rad2deg(estimate.bias_rad_s[2]), estimate.window_start_s,
             estimate.window_end_s, estimate.n_samples)
    return estimate, None


def event_count(trip: Trip) -> int:
    """Count the events drive_trip processes (IMU, speed and scans)."""
    return (len(trip.imu.stamp_s) + len(trip.speed.stamp_s)
            + sum(len(s.stamp_s) for s in trip.scans))


def without_message_covariance(trip: Trip) -> Trip:
    """Drop every input message's own variance from a trip (the configured noise applies)."""
    if trip.imu.yaw_rate_variance is None and trip.speed.speed_variance is None:
        return trip
    return dataclasses.replace(
        trip, imu=dataclasses.replace(trip.imu, yaw_rate_variance=None),
        speed=dataclasses.replace(trip.speed, speed_variance=None))


def run_trip(trip: Trip, params: PipelineParams | None = None,
             use_stated_noise: bool | None = None,
             progress: Callable[[int], None] | None = None,
             use_calibration: bool | None = None,
             use_message_covariance: bool | None = None,
             detect_ahead: bool = False,
             on_rows: Callable[[int, Estimates, UpdateLog], None] | None = None,
             into: Estimates | None = None) -> OfflineRun:
    """Calibrate (where the trip starts static) and run the EKF over the whole trip.

    The filter starts at the trip's initial pose with the configured priors, so by default
    its bias is found online, independently of the static window, and the two can be
    compared. With ``use_calibration`` (as the EKF node's parameter) an accepted window
    seeds the bias state with its mean and ``calibration_bias_sigma_rad_s``. Each switch
    left None takes the params file's option (core.config.RunOptions: its default where the
    file sets none).

    Args:
        trip: the inputs (stamps in s since the bag's first message).
        params: a parsed params file, or None for the defaults.
        use_stated_noise: see effective_config.
        progress: called with the number of events processed since the last call.
        use_calibration: seed the bias from the static window.
        use_message_covariance: let each IMU and odometry message's own variance (where
            positive, see core.validation.message_variance) replace the configured gyro or
            speed noise for that message, as the EKF node's parameter of that name does.
        detect_ahead: find the poles in a forked child ahead of the run where a core is
            free (analysis.detect_ahead; the same numbers). For a process that has the
            machine to itself (`gyro-ekf run`), not one of several workers.
        on_rows, into: handed each block of final rows as the run goes, and the arrays
            the rows go into (drive_trip's; io.streamed_products.StreamedProducts gives
            both).
    """
    params = params or PipelineParams()
    options = params.options
    if use_message_covariance is None:
        use_message_covariance = options.use_message_covariance
    if not use_message_covariance:
        trip = without_message_covariance(trip)
    # LiDAR mounts of a params file (e.g. from calibrate-mounts) replace the bag's.
    trip = with_lidar_mounts(trip, params)
    config, sources = effective_config(trip.noise, params, use_stated_noise)
    message_sources(trip, params, sources)
    calibration, reason = calibrate(trip, params.calibration, params.detector)
    driver = EventDriver(config, trip.landmarks, trip.initial_pose,
                         detector_config=params.detector)
    if use_calibration is None:
        use_calibration = options.use_calibration
    if use_calibration and calibration is None:
        # Asked for, not possible: the run goes on as without it, which the user must know.
        log.warning('%s: use_calibration: no static window to seed the bias from (%s); '
                    'the bias starts from its prior and is found online', trip.name, reason)
    if use_calibration and calibration is not None:
        driver.ekf.set_bias(float(calibration.bias_rad_s[2]),
                            options.calibration_bias_sigma_rad_s)
    if not detect_ahead:
        result = drive_trip(trip, driver, progress, on_rows=on_rows, into=into)
    else:
        with DetectionsAhead(ScanDetector(trip, driver.detector_config)) as detections:
            result = drive_trip(trip, driver, progress, detections, on_rows, into)
    return OfflineRun(trip=trip, config=config, config_sources=sources,
                      calibration=calibration, calibration_error=reason, result=result)
