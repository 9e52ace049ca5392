"""What the event driver takes and gives: event kinds, estimates, scan reports, counts.

Apart from the driver (`events`), so the modules that order events for it (`trip_run`,
`stream_order`, `lagged`) and the nodes that publish its output need not import it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
import enum
import math
from typing import Any

from gyro_ekf.core.association import AssociationOutcome, AssociationResult
from gyro_ekf.core.models import sensor_to_map
from gyro_ekf.core.types import FloatArray, LidarMount

__all__ = ['DriverStats', 'Estimate', 'EventKind', 'ObservationReport']


class EventKind(enum.IntEnum):
    """Event types; the value orders events that share a stamp."""

    SPEED = 0
    OBSERVATION = 1
    IMU = 2


@dataclass(frozen=True, slots=True)
class Estimate:
    """Filter output after one IMU sample.

    Attributes:
        stamp_s: s.
        state: shape (4,): x m, y m, yaw rad, bias rad/s.
        covariance: shape (4, 4).
        speed_m_s: held speed, m/s.
        yaw_rate_rad_s: bias-corrected yaw rate, rad/s: the measured one less
            ``gyro_error_rad_s``.
        gyro_error_rad_s: the yaw-rate error the filter takes out of the gyro's readings:
            the bias plus the gyro's wander (0 unless one was found, core/gyro_wander.py),
            rad/s.
        gyro_error_variance: its variance, (rad/s)^2 (the bias's when no wander was found).
    """

    stamp_s: float
    state: FloatArray
    covariance: FloatArray
    speed_m_s: float
    yaw_rate_rad_s: float
    gyro_error_rad_s: float
    gyro_error_variance: float


@dataclass(frozen=True, slots=True)
class ObservationReport:
    """What happened to one scan's detections.

    Attributes:
        stamp_s: s.
        points_sensor_m: detections in the sensor frame, shape (k, 2), m.
        prior_state: the filter state before this scan's updates, shape (4,).
        mount: pose of the sensor on the platform.
        association: outcome per detection, or None without a map.
        nis: NIS of every applied update, shape (matched,).
        points_map_m: the detections placed in the map at the prior pose, shape (k, 2), m
            (computed on access: most callers never look).
    """

    stamp_s: float
    points_sensor_m: FloatArray
    prior_state: FloatArray
    mount: LidarMount
    association: AssociationResult | None
    nis: FloatArray

    @property
    def points_map_m(self) -> FloatArray:
        """The detections in the map frame at the prior pose, shape (k, 2), m."""
        return sensor_to_map(self.prior_state, self.points_sensor_m, self.mount)


@dataclass(slots=True)
class DriverStats:
    """Running counts of the driver (mutable; read with ``snapshot``).

    Attributes:
        imu, speed, scans: events processed per kind.
        detections: poles detected.
        outcomes: detections per association outcome name.
        updates: landmark updates applied.
        recoveries: scans associated by map distance after a gap (see EkfConfig), or
            with the filter starved by its own gate (core/gate_starved.py).
        gate_starved: those of the recoveries for a starved filter.
        nis_sum: sum of the NIS of all updates.
        first_association_s: stamp of the first applied update, or None.
        last_association_s: stamp of the last applied update, or None.
        longest_gap_s: longest time between applied updates (from the first one).
        dead_reckoned_s: the time in gaps between applied updates longer than
            ``health.DEAD_RECKONED_GAP_S`` (the gaps closed so far), s.
        long_gaps: gaps longer than events.MAX_PREDICTION_STEPS steps (predicted in
            coarser steps).
        excluded: detections of excluded LiDARs (re-checked, not applied; in no outcome).
        unmapped: UNMATCHED detections farther than ``recovery_max_distance_m`` from every
            landmark (at the pose before the scan): an object the map does not list, not
            a pole the filter failed to match.
        zero_rate_updates: gyro samples applied as zero-rate updates (standing still).
        stops: times zero-rate updates began (once per stop unless the stop was shaken).
        bias_openings: blocks of landmark updates whose heading drift re-opened the bias
            (core/bias_watch.py).
        bias_largest_opening_rad_s: the largest bias error such a drift implied, rad/s.
        bias_wander_held: of those, the openings where the modelled wander's block means
            held one sign for 20 s (a bias that moved taken in by the wander;
            core/gyro_wander.py).
        gyro_noise_scale: the factor on the gyro's noise variance the innovations asked for
            (1: as stated).
        gyro_noise_scale_max: the largest such factor of the run so far.
        gyro_rest_noise_scale: the factor on the stated gyro noise variance a stop's gyro
            samples measured (their spread squared over the stated variance, where it lies
            beyond chance above it; 1: none did). The noise factor never falls below it.
        gyro_rest_noise_rad_s: the spread of that stop's gyro samples, rad/s (0: none).
        gyro_rest_noise_samples: the samples of the stop judged last (the one with the most
            so far; 0: none judged).
        gyro_wander_rad_s: the gyro wander's sigma found in the data (core/gyro_wander.py),
            rad/s (0: none found).
        gyro_wander_found_s: when it was first found, s (None: not found).
        gyro_wander_prior_ruled_out_s: when the blocks ruled the prior wander out
            (``gyro_wander_prior_rad_s``), s (None: not, or no prior).
        gyro_wander_stop_rad_s: the largest wander a still stop's gyro samples showed
            (core/stop_wander.py), modelled as a prior, rad/s (0: none).
        gyro_wander_stop_s: when that stop ended, s (None: none showed one).
        gyro_wander_stop_ruled_out_s: when the blocks ruled it out, s (None: not, or none).
        bias_rate_rad_s2: the rate of the bias in use now (core/bias_rate.py), rad/s^2
            (0: none).
        bias_rate_found: times a bias rate came into use.
        bias_largest_rate_rad_s2: the largest (signed) bias rate used, rad/s^2.
        speed_noise_widened: odometry samples taken with the stream's own spread as their
            noise, larger than the stated (EkfConfig.learn_speed_noise; 0: none).
        speed_noise_m_s: the largest such spread, m/s (0: none).
        speed_noise_stated_m_s: the stated noise it was taken over last, m/s (0: none).
        first_stop_end_s: when the first stop whose zero-rate updates learnt the bias
            ended (the static start, on a trip that has one), s (None: none yet).
        first_stop_bias_rad_s: the bias then, rad/s ...
        first_stop_bias_sigma_rad_s: ... and its sigma, rad/s: ``health.verdict`` judges
            the bias now against it.
    """

    imu: int = 0
    speed: int = 0
    scans: int = 0
    detections: int = 0
    outcomes: dict[str, int] = field(
        default_factory=lambda: {o.name.lower(): 0 for o in AssociationOutcome})
    updates: int = 0
    recoveries: int = 0
    gate_starved: int = 0
    nis_sum: float = 0.0
    first_association_s: float | None = None
    last_association_s: float | None = None
    longest_gap_s: float = 0.0
    dead_reckoned_s: float = 0.0
    long_gaps: int = 0
    excluded: int = 0
    unmapped: int = 0
    zero_rate_updates: int = 0
    stops: int = 0
    bias_openings: int = 0
    bias_largest_opening_rad_s: float = 0.0
    bias_wander_held: int = 0
    gyro_noise_scale: float = 1.0
    gyro_noise_scale_max: float = 1.0
    gyro_rest_noise_scale: float = 1.0
    gyro_rest_noise_rad_s: float = 0.0
    gyro_rest_noise_samples: int = 0
    gyro_wander_rad_s: float = 0.0
    gyro_wander_found_s: float | None = None
    gyro_wander_prior_ruled_out_s: float | None = None
    gyro_wander_stop_rad_s: float = 0.0
    gyro_wander_stop_s: float | None = None
    gyro_wander_stop_ruled_out_s: float | None = None
    bias_rate_rad_s2: float = 0.0
    bias_rate_found: int = 0
    bias_largest_rate_rad_s2: float = 0.0
    speed_noise_widened: int = 0
    speed_noise_m_s: float = 0.0
    speed_noise_stated_m_s: float = 0.0
    first_stop_end_s: float | None = None
    first_stop_bias_rad_s: float | None = None
    first_stop_bias_sigma_rad_s: float | None = None

    @property
    def first_stop(self) -> tuple[float, float, float] | None:
        """(end s, bias rad/s, sigma rad/s) of the first stop that learnt the bias, or None."""
        if self.first_stop_end_s is None:
            return None
        return (self.first_stop_end_s, self.first_stop_bias_rad_s,
                self.first_stop_bias_sigma_rad_s)

    @property
    def mean_nis(self) -> float:
        """Mean NIS of all updates (nan before the first)."""
        return self.nis_sum / self.updates if self.updates else math.nan

    def snapshot(self) -> dict[str, Any]:
        """Return a plain copy for reports."""
        return {'imu': self.imu, 'speed': self.speed, 'scans': self.scans,
                'detections': self.detections, 'outcomes': dict(self.outcomes),
                'updates': self.updates, 'recoveries': self.recoveries,
                'gate_starved': self.gate_starved,
                'mean_nis': self.mean_nis,
                'first_association_s': self.first_association_s,
                'last_association_s': self.last_association_s,
                'longest_gap_s': self.longest_gap_s,
                'dead_reckoned_s': self.dead_reckoned_s, 'long_gaps': self.long_gaps,
                'excluded': self.excluded, 'unmapped': self.unmapped,
                'zero_rate_updates': self.zero_rate_updates,
                'stops': self.stops, 'bias_openings': self.bias_openings,
                'bias_largest_opening_rad_s': self.bias_largest_opening_rad_s,
                'bias_wander_held': self.bias_wander_held,
                'gyro_noise_scale': self.gyro_noise_scale,
                'gyro_noise_scale_max': self.gyro_noise_scale_max,
                'gyro_rest_noise_scale': self.gyro_rest_noise_scale,
                'gyro_rest_noise_rad_s': self.gyro_rest_noise_rad_s,
                'gyro_rest_noise_samples': self.gyro_rest_noise_samples,
                'gyro_wander_rad_s': self.gyro_wander_rad_s,
                'gyro_wander_found_s': self.gyro_wander_found_s,
                'gyro_wander_prior_ruled_out_s': self.gyro_wander_prior_ruled_out_s,
                'gyro_wander_stop_rad_s': self.gyro_wander_stop_rad_s,
                'gyro_wander_stop_s': self.gyro_wander_stop_s,
                'gyro_wander_stop_ruled_out_s': self.gyro_wander_stop_ruled_out_s,
                'speed_noise_widened': self.speed_noise_widened,
                'speed_noise_m_s': self.speed_noise_m_s,
                'speed_noise_stated_m_s': self.speed_noise_stated_m_s,
                'bias_rate_rad_s2': self.bias_rate_rad_s2,
                'bias_rate_found': self.bias_rate_found,
                'bias_largest_rate_rad_s2': self.bias_largest_rate_rad_s2,
                'first_stop_end_s': self.first_stop_end_s,
                'first_stop_bias_rad_s': self.first_stop_bias_rad_s,
                'first_stop_bias_sigma_rad_s': self.first_stop_bias_sigma_rad_s}
