"""The event driver: feeds speed, gyro and LiDAR events to the EKF in time order.

The same ``EventDriver`` runs inside the live EKF node and in the offline ``gyro-ekf run``,
so both produce the same numbers from the same inputs in the same order. What puts the
events in that order lives beside it: ``trip_run`` (offline, a whole trip sorted at once,
and the batch run), ``stream_order.StreamMerger`` and ``lagged.LaggedObservations`` (live).

Inputs are held between samples (zero-order hold): on each event the filter is first
predicted from the previous event's time to this one with the latest speed and yaw rate,
then the event's value replaces the held one (or, for an observation, updates the filter).
Events with equal stamps are ordered speed, observation, IMU, so the estimate emitted on an
IMU sample includes every observation stamped at or before it.

Standing still, each gyro sample measures the bias alone (a zero-rate update): once the
odometry speed has stayed within ``rest_speed_m_s`` for ``zero_rate_min_still_s``, while the
gyro samples of the stop spread at most ``zero_rate_max_spread_rad_s`` and their mean is
no turn (within ``rest_yaw_rate_rad_s`` plus three bias sigmas of the bias: an unknown bias
cannot be told from a slow turn on the spot), every IMU sample updates the bias with the
stop's spread as its sigma (at least ``zero_rate_min_noise_rad_s``) and the prediction holds
the position. The bias is so learned at every stop, as the offline static calibration
learns it from the first seconds. Landmark updates at rest go on as before (their n-th
look during a stop uses n R); the two measure different things, the pose against the map
and the bias against zero rate.

Time going backwards raises TimeWentBackwardsError; the caller decides to reset (a looped
bag) or to drop the event. It is never silently accepted. A gap is predicted in steps of at
most `max_prediction_step_s`, but never in more than MAX_PREDICTION_STEPS steps: a stamp far
ahead (a paused robot, a broken clock) costs bounded time, and is counted in
`DriverStats.long_gaps` (the live node refuses such stamps before they get here unless the
other inputs confirm them).
"""

from __future__ import annotations

from collections.abc import Iterable
import dataclasses
import math

import numpy as np

from gyro_ekf.core.angles import wrap_scalar
from gyro_ekf.core.association import (AssociationOutcome, AssociationResult,
                                       associate_by_distance, associate_packed)
from gyro_ekf.core.bias_rate import BiasRate
from gyro_ekf.core.bias_watch import BiasWatch
from gyro_ekf.core.body_frame import (Offset, Shift, disagreement_spread, mixture_shift,
                                      other_right_share, shift_estimates, with_heading)
from gyro_ekf.core.config import DetectorConfig, EkfConfig
from gyro_ekf.core.ekf import GyroBiasEkf
from gyro_ekf.core.errors import CoreError, TimeWentBackwardsError
from gyro_ekf.core.gate_starved import GateStarvation
from gyro_ekf.core.gyro_scale import GyroScaleWatch
from gyro_ekf.core.gyro_wander import GyroWander, block_allowed
from gyro_ekf.core.input_loss import InputLoss
from gyro_ekf.core.input_frozen import FrozenWatch
from gyro_ekf.core.rest_turn import RestTurnWatch
from gyro_ekf.core.input_spikes import SpikeGate
from gyro_ekf.core.map_poles import MapPoleWatch
from gyro_ekf.core.turn_sign import TurnSignCheck
from gyro_ekf.core.stamp_jitter import StampJitterWatch
from gyro_ekf.core.event_records import DriverStats, Estimate, ObservationReport
from gyro_ekf.core.health import HealthMonitor, Transition, chi_square_upper, dead_reckoned
from gyro_ekf.core.held_rate import MIN_AGE_S, HeldRate
from gyro_ekf.core.held_start import HeldStart
from gyro_ekf.core.models import observe_bias, points_to_range_bearing, sensor_point_to_map
from gyro_ekf.core.mount_online import CONFIRMED, OnlineMounts, OnlineMountSettings
from gyro_ekf.core.noise_online import NoiseMatch
from gyro_ekf.core.odometry_online import (Moved, OdometrySettings, OdometryTracker,
                                           midpoint_yaw)
from gyro_ekf.core.stop_wander import StopBlocks
from gyro_ekf.core.time_offset import MIN_UPDATES as OFFSET_MIN_UPDATES, TimeOffsetWatch
from gyro_ekf.core.types import (BIAS, ESTIMATE_SIZE, YAW, FloatArray, LandmarkMap,
                                 LidarMount)


_NO_NIS = np.zeros(0)
_MATCHED, _UNMATCHED = AssociationOutcome.MATCHED, AssociationOutcome.UNMATCHED
_NO_NIS.flags.writeable = False
_OUTCOME_KEYS = {outcome: outcome.name.lower() for outcome in AssociationOutcome}

SPEED_NOISE_FACTOR = 2.0
"""The odometry's own spread is taken as its noise once its variance is this many times the
stated one (EkfConfig.learn_speed_noise)."""

MAX_PREDICTION_STEPS = 1000
"""Most prediction steps for one gap (100 s at the default 0.1 s step): a longer gap is split
into this many equal steps, so a stamp 1e6 s ahead costs what 100 s costs, not 52 s of CPU."""

HOLD_WITHOUT_ODOMETRY_S = 1.0
"""Longest a start pose is held on gyro samples alone, before any odometry message (s): the
zero-rate logic needs 0.5 s of zero speed to call the platform still, and without odometry
nothing says it is."""

BIAS_LEARNT_FACTOR = 2.0
"""A bias watch block is no evidence of a wander when the bias's variance fell by more than
this factor over it (core/gyro_wander.py): the bias was being learnt, its corrections the
learning. Ordinary blocks while driving change it by a few per cent."""

STOP_NOISE_SIGNIFICANCE = 1e-4
"""Chance that a stop's gyro spread, on a gyro as noisy as stated, reads as noisier
(``EventDriver._judge_stop_noise``)."""

STOP_NOISE_MIN_SAMPLES = 100
"""Fewest gyro samples of a stop whose spread is judged (0.5 s at 200 Hz): the chi-square
quantile's approximation holds from 10 dof, and a shorter stop says little."""


class EventDriver:
    """Holds the inputs and drives a GyroBiasEkf event by event.

    Attributes:
        ekf: the filter.
        stamp_s: stamp of the last processed event, or None before the first.
        speed_m_s: held speed, m/s.
        rate_rad_s: held measured yaw rate (bias included), rad/s, or None before the first.
        landmarks: the map used for association, or None.
        stats: running counts.
        health: per-LiDAR consistency figures; excludes a LiDAR that disagrees
            (core/health.py).
        last_transition: the last exclusion or readmission on_detections caused, or None.
        sensor_names: display name per mount for health reports (kept across resets).
        mount_yaw_sigmas: how well each stated mount's yaw is known, rad, by stated mount
            (``lidar.<topic>.yaw_sigma_rad``; 0 when not given). The reported heading's
            variance gains that of the LiDAR that defines the body frame
            (``core/body_frame.py``, ``heading_spread``); kept across resets.
        zero_rate: whether zero-rate updates are being applied now (standing still).
        mounts: the online mount estimators of the LiDARs given to ``track_mounts``
            (core/mount_online.py); a LiDAR's observations are taken with its mount in use.
    """

    def __init__(self, config: EkfConfig | None = None, landmarks: LandmarkMap | None = None,
                 pose: FloatArray | None = None, bias_rad_s: float | None = None,
                 detector_config: DetectorConfig | None = None):
        """Create a filter at a pose with the configured priors."""
        self.config = config or EkfConfig()
        # Settings read at every sample, looked up once (the config is frozen).
        self._max_step_s = self.config.max_prediction_step_s
        self._recovery_after_s = self.config.recovery_after_s
        self._rest_speed_m_s = self.config.rest_speed_m_s
        self._gyro_scale = 1.0 + self.config.gyro_scale_error
        # The gyro's scale, measured against the heading the LiDARs hold (core/gyro_scale.py)
        # from the integral of its raw readings.
        self.gyro_scale = GyroScaleWatch(self.config.gyro_scale_error,
                                         self.config.learn_gyro_scale)
        self._turned = 0.0
        # Each LiDAR's stamps against the gyro's, from its own headings (core/time_offset.py).
        self.time_offsets: dict[LidarMount, TimeOffsetWatch] = {}
        # What the gyro and the odometry read against each LiDAR's scans: a sensor upside
        # down, in the wrong units or sign (core/turn_sign.py).
        self.turn_signs = TurnSignCheck()
        # Each LiDAR's stamps' scatter about when its scans were taken (core/stamp_jitter.py),
        # and the range and bearing variances a LiDAR without measured ones is weighed by.
        self.stamp_jitter: dict[LidarMount, StampJitterWatch] = {}
        self._stated_variances = (self.config.range_noise_m ** 2,
                                  self.config.bearing_noise_rad ** 2)
        # Samples each input lost, by its own stamps (core/input_loss.py).
        self._gyro_loss, self._speed_loss = InputLoss(), InputLoss()
        self.input_loss = {'gyro': self._gyro_loss, 'odometry': self._speed_loss}
        # Scans each LiDAR's detections lost on the way, by its name (the node's landmarks
        # topic is reliable but keeps 10: a node behind loses the oldest).
        self.scan_loss: dict[str, InputLoss] = {}
        self._new_spike_gates()
        self.detector_config = detector_config or DetectorConfig()
        self.ekf = GyroBiasEkf(self.config, pose, bias_rad_s)
        self.landmarks = landmarks
        self.stats = DriverStats()
        self.health = HealthMonitor(self.config)
        self.bias_watch = BiasWatch()
        self.bias_rate = BiasRate(self.config.bias_rate_window_s)
        self.gyro_wander = GyroWander(self.config.gyro_wander_tau_s)
        self.ekf.assume_wander(self.config.initial_wander_rad_s)
        # Each LiDAR's range and bearing noise, measured online (core/noise_online.py).
        self.noise: dict[LidarMount, NoiseMatch] = {}
        # The filter's bias and its variance where the bias watch's open block began.
        self._block_bias = self._block_bias_variance = 0.0
        self.held_rate = HeldRate()
        self.mounts = OnlineMounts(OnlineMountSettings(
            converged_yaw_sigma_rad=self.config.mount_online_yaw_sigma_rad))
        # The odometry's speed scale, estimated online (core/odometry_online.py).
        self.odometry = OdometryTracker(OdometrySettings(
            min_change=self.config.odometry_online_min_change,
            prior_scale_sigma=self.config.odometry_scale_sigma,
            scale_time_s=self.config.odometry_scale_time_s))
        self.odometry.start_at(self._trusted(pose))
        self.held_start = HeldStart(self.config.hold_exact_start
                                    and self._trusted(pose) is not None)
        self._forget_body_frame()
        self._measured_speed_m_s = 0.0
        # Stamp up to which the odometry path's distance is summed, the distance not yet
        # laid along the heading, and the heading at the last scan (_integrate_path).
        self._path_s: float | None = None
        self._path_m = 0.0
        self._path_yaw = 0.0
        self.last_transition: Transition | None = None
        self.sensor_names: dict[LidarMount, str] = {}
        self.mount_yaw_sigmas: dict[LidarMount, float] = {}
        self.stamp_s: float | None = None
        self.speed_m_s = 0.0
        self.rate_rad_s: float | None = None
        # The held inputs' own variances (None: the configured noise).
        self.speed_variance: float | None = None
        self.rate_variance: float | None = None
        # Stamp of the held yaw rate's sample: its age is what a gap may have changed.
        self._rate_stamp_s: float | None = None
        self._heading_dt2 = 0.0
        # Integral of the modelled wander over the watch's open block (rad): what the
        # wander took out of the predictions, for the blocks' bias error against b alone;
        # and when a stale rate was last held (an IMU gap), s.
        self._wander_dt = 0.0
        self._rate_held_s = -math.inf
        self._first_scan_s: float | None = None
        # Detections matched and left beside their poles, over the recovery delay: a
        # filter its own gate starves is re-associated by distance (core/gate_starved.py).
        self._gate = GateStarvation(self.config.recovery_after_s)
        # What the LiDARs saw of each stop with zero-rate updates (core/rest_turn.py).
        self.rest_turns = RestTurnWatch()
        self._end_stop()

    def _end_stop(self) -> None:
        """Forget the stop (moving, or not known to stand still), once its scans are judged."""
        self.rest_turns.close(self.stamp_s)
        # Stamp of the speed sample the stop began with, and the running mean and sum of
        # squared deviations (Welford) of the stop's gyro samples.
        self._stop_since_s: float | None = None
        self._stop_n, self._stop_mean, self._stop_m2 = 0, 0.0, 0.0
        self._stop_blocks = StopBlocks()
        self.zero_rate = False
        self.bias_rate.end_rest()

    @property
    def landmarks(self) -> LandmarkMap | None:
        """The map used for association, or None."""
        return self._landmarks

    @landmarks.setter
    def landmarks(self, landmarks: LandmarkMap | None) -> None:
        self._landmarks = landmarks
        self._landmark_xy = [] if landmarks is None else landmarks.xy_m.tolist()
        # The rest counts and the looks at poles that stand elsewhere (core/map_poles.py)
        # are per landmark index: a new map starts them again.
        self._rest_updates: dict[tuple[int, LidarMount], int] = {}
        self.map_poles = MapPoleWatch(len(self._landmark_xy))

    def reset(self, pose: FloatArray | None = None, bias_rad_s: float | None = None) -> None:
        """Start over (a looped bag, a ~/reset call): new filter, held inputs and counts."""
        self.ekf.reset(pose, bias_rad_s)
        self.stats = DriverStats()
        self.health = HealthMonitor(self.config)
        self._restart_bias_evidence()
        self.gyro_scale = GyroScaleWatch(self.config.gyro_scale_error,
                                         self.config.learn_gyro_scale)
        self._gyro_scale = 1.0 + self.config.gyro_scale_error
        self._turned = 0.0
        self.time_offsets = {}
        self.stamp_jitter = {}
        self.map_poles = MapPoleWatch(len(self._landmark_xy))
        self.turn_signs = TurnSignCheck()
        self._gyro_loss, self._speed_loss = InputLoss(), InputLoss()
        self.input_loss = {'gyro': self._gyro_loss, 'odometry': self._speed_loss}
        self.scan_loss = {}
        self._new_spike_gates()
        # A wander found before the reset is forgotten with it; the prior holds again.
        self.ekf.assume_wander(self.config.initial_wander_rad_s)
        self.noise = {}
        self._block_bias = self._block_bias_variance = 0.0
        self.ekf.odometry_walk = 0.0
        self.held_rate = HeldRate()
        self._rate_stamp_s = None
        self._rate_held_s = -math.inf
        self.mounts.reset()
        self.odometry.reset()
        self.odometry.start_at(self._trusted(pose))
        self.held_start = HeldStart(self.config.hold_exact_start
                                    and self._trusted(pose) is not None)
        self._forget_body_frame()
        self._measured_speed_m_s = 0.0
        self._path_s, self._path_m, self._path_yaw = None, 0.0, 0.0
        self.stamp_s = None
        self.speed_m_s = 0.0
        self.rate_rad_s = None
        self.speed_variance = self.rate_variance = None
        self._first_scan_s = None
        self._gate.clear()
        self._rest_updates = {}
        self.rest_turns = RestTurnWatch()
        self._end_stop()

    def _new_spike_gates(self) -> None:
        """Lone bad samples of each input, held back and dropped (core/input_spikes.py)."""
        config = self.config
        self._gyro_spikes = SpikeGate(config.gyro_noise_rad_s,
                                      config.max_angular_acceleration_rad_s2)
        self._speed_spikes = SpikeGate(config.speed_noise_m_s, config.max_acceleration_m_s2)
        self.input_spikes = {'gyro': self._gyro_spikes, 'odometry': self._speed_spikes}
        self._speed_var = config.speed_noise_m_s ** 2  # stated where a message states none
        # A gyro repeating one value: its repeats left out (core/input_frozen.py).
        self.gyro_frozen = FrozenWatch()

    def _forget_body_frame(self) -> None:
        """Start the two LiDARs' word on the body frame afresh (core/body_frame.py)."""
        # Where each LiDAR's scans at the trusted start pose place it (by stated mount),
        # the LiDAR that defines the body frame now, and the mixture reported.
        self._start_offsets: dict[LidarMount, Offset] = {}
        self._body_key: LidarMount | None = None
        self.frame_shift: Shift | None = None

    def _trusted(self, pose: FloatArray | None) -> FloatArray | None:
        """Return the start pose when the filter trusts it exactly (P0 of the pose 0)."""
        config = self.config
        if pose is None or config.initial_position_sigma_m or config.initial_yaw_sigma_rad:
            return None
        return pose

    def mount_in_use(self, stated: LidarMount) -> LidarMount:
        """Return the mount a LiDAR stated as `stated` is taken with now.

        Estimated online (core/mount_online.py), or, for the LiDAR that defines the body
        frame, moved by the odometry's fits (core/odometry_online.py).
        """
        if stated in self.mounts.trackers:
            return self.mounts.used(stated)
        return self.odometry.first_mount(stated)

    def track_mounts(self, mounts: Iterable[tuple[LidarMount, str]]) -> None:
        """Estimate these LiDARs' mounts online, (stated mount, name) each.

        Every LiDAR but the first, which defines the body frame with the odometry (until
        it disagrees with the map and another takes over, OnlineMounts.hand_over); off when
        ``mount_online_yaw_sigma_rad`` is 0.
        """
        if self.config.mount_online_yaw_sigma_rad > 0.0:
            self.mounts.track(mounts)

    def save(self) -> tuple:
        """Return everything ``restore`` needs to put the driver back as it is now."""
        stats = dataclasses.replace(self.stats, outcomes=dict(self.stats.outcomes))
        return (self.ekf.save(), stats, self.stamp_s, self.speed_m_s, self.rate_rad_s,
                self.speed_variance, self.rate_variance, self._first_scan_s,
                dict(self._rest_updates), self.health.save(),
                (self._stop_since_s, self._stop_n, self._stop_mean, self._stop_m2,
                 self._stop_blocks.copy(), self.zero_rate, self.held_start.copy(),
                 self.rest_turns.save()),
                self.mounts.save(),
                (self.bias_watch.copy(), self.bias_rate.copy(),
                 (self._block_bias, self._block_bias_variance),
                 self.gyro_wander.copy(), self._wander_dt, self._rate_held_s),
                self.held_rate.save(), self._rate_stamp_s, self._heading_dt2,
                (self.odometry.save(), self._measured_speed_m_s, self._path_s,
                 self._path_m, self._path_yaw),
                {key: noise.save() for key, noise in self.noise.items()},
                (self.gyro_scale.save(), self._turned,
                 {key: watch.save() for key, watch in self.time_offsets.items()}),
                ({name: loss.save() for name, loss in self.input_loss.items()},
                 {name: gate.save() for name, gate in self.input_spikes.items()},
                 {key: watch.save() for key, watch in self.stamp_jitter.items()},
                 self.map_poles.save(), self.turn_signs.save(), self.gyro_frozen.save(),
                 {name: loss.save() for name, loss in self.scan_loss.items()}),
                (dict(self._start_offsets), self._body_key, self.frame_shift),
                self._gate.copy())

    def restore(self, saved: tuple) -> None:
        """Put the driver back into a state returned by ``save`` (the map is kept)."""
        (ekf, stats, self.stamp_s, self.speed_m_s, self.rate_rad_s, self.speed_variance,
         self.rate_variance, self._first_scan_s, rest_updates, health, stop, mounts,
         watch, held, self._rate_stamp_s, self._heading_dt2,
         (odometry, self._measured_speed_m_s, self._path_s, self._path_m,
          self._path_yaw), noise, (gyro_scale, self._turned, offsets),
         (input_loss, spikes, jitter, map_poles, turn_signs, frozen, scan_loss),
         (start_offsets, self._body_key, self.frame_shift), gate) = saved
        self._gate = gate.copy()
        self.map_poles.restore(map_poles)
        self.gyro_frozen.restore(frozen)
        self.turn_signs.restore(turn_signs)
        self._start_offsets = dict(start_offsets)
        for name, saved_loss in input_loss.items():
            self.input_loss[name].restore(saved_loss)
        # The same counts, less those of LiDARs first seen since.
        self.scan_loss = {name: loss for name, loss in self.scan_loss.items()
                          if name in scan_loss}
        for name, loss in self.scan_loss.items():
            loss.restore(scan_loss[name])
        for name, saved_gate in spikes.items():
            self.input_spikes[name].restore(saved_gate)
        self.stamp_jitter = {key: stamps for key, stamps in self.stamp_jitter.items()
                             if key in jitter}
        for key, stamps in self.stamp_jitter.items():
            stamps.restore(jitter[key])
        self.gyro_scale.restore(gyro_scale)
        # The same watches (their rows are kept for this), less those begun since.
        self.time_offsets = {key: offset for key, offset in self.time_offsets.items()
                             if key in offsets}
        for key, offset in self.time_offsets.items():
            offset.restore(offsets[key])
        self._gyro_scale = 1.0 + self.gyro_scale.in_use
        self.noise = {}
        for key, saved_noise in noise.items():
            self.lidar_noise(key).restore(saved_noise)
        self.held_rate.restore(held)
        self.odometry.restore(odometry)
        (watch, rate, (self._block_bias, self._block_bias_variance), wander,
         self._wander_dt, self._rate_held_s) = watch
        self.bias_watch, self.bias_rate = watch.copy(), rate.copy()
        self.gyro_wander = wander.copy()
        self._model_wander()
        self.ekf.bias_walk_found = self.bias_watch.walk + self.bias_rate.walk
        self.ekf.bias_rate_found = self.bias_rate.rate_rad_s2
        self.ekf.rate_noise_scale = self.bias_watch.noise_scale
        self.ekf.odometry_walk = self.odometry.walk_density(self.speed_m_s)
        self.mounts.restore(mounts)
        (self._stop_since_s, self._stop_n, self._stop_mean, self._stop_m2, stop_blocks,
         self.zero_rate, held_start, rest_turns) = stop
        self.rest_turns.restore(rest_turns)
        self._stop_blocks = stop_blocks.copy()
        self.held_start = held_start.copy()
        self._rest_updates = dict(rest_updates)
        self.health.restore(health)
        self.ekf.restore(ekf)
        self.stats = dataclasses.replace(stats, outcomes=dict(stats.outcomes))

    def _advance(self, stamp_s: float, what: str) -> None:
        # Runs twice per sample pair (89 000 times over the 2016 log): the filter and the
        # held inputs are read into locals once.
        before_s = self.stamp_s
        if not math.isfinite(stamp_s):
            raise CoreError(f'{what} stamp {stamp_s} is not finite')
        if before_s is None:
            self.stamp_s = stamp_s
            return
        dt_s = stamp_s - before_s
        if dt_s < 0.0:
            raise TimeWentBackwardsError(
                f'{what} stamp {stamp_s:.4f} s went back {-dt_s:.4f} s behind the filter')
        if dt_s == 0.0:
            return  # nothing to predict (the 2016 log's gyro and odometry share stamps)
        ekf = self.ekf
        rate = self.rate_rad_s
        if rate is not None:
            self._turned += rate * dt_s  # the gyro's raw integral, bias included
        else:
            # Before the first gyro sample the heading is held: the yaw rate is the bias.
            rate = ekf.bias_rad_s
        if self._gyro_scale != 1.0:
            # A gyro that reads (1 + e) times the turn (gyro_scale_error): the filter turns
            # by (w - b) / (1 + e), and its bias stays the gyro's own.
            bias = ekf.bias_rad_s
            rate = bias + (rate - bias) / self._gyro_scale
        step = self._max_step_s
        if dt_s > step * MAX_PREDICTION_STEPS:
            # Over a gap this long the held inputs are a guess anyway; fine steps would
            # only cost time in proportion to the gap (hours for a stamp 4e8 s ahead).
            step = dt_s / MAX_PREDICTION_STEPS
            self.stats.long_gaps += 1
        if self.held_start.held:
            ekf.hold_still(dt_s)
            self.stamp_s = stamp_s
            return
        speed, speed_variance, rate_variance = (self.speed_m_s, self.speed_variance,
                                                self.rate_variance)
        hold = self.zero_rate
        # The position walk covers the detection errors' change between landmark updates;
        # in a gap (no update for recovery_after_s, or none yet) the pose's uncertainty
        # grows by the odometry and the gyro alone. Kept, it tripled the position sigma
        # over a 5-s LiDAR dropout while the error stayed at 3 mm (NEES below its band).
        last = self.stats.last_association_s
        ekf.position_walk_paused = last is None or before_s - last > self._recovery_after_s
        while dt_s > step:
            self._wander_dt += step * ekf.wander_rad_s
            ekf.predict(speed, rate, step, speed_variance, rate_variance, hold)
            # Sum of T^2 over the predictions: times sigma_w^2, the heading noise they added
            # (the bias watch weighs a slow drift against it).
            self._heading_dt2 += step * step
            dt_s -= step
        self._wander_dt += dt_s * ekf.wander_rad_s
        ekf.predict(speed, rate, dt_s, speed_variance, rate_variance, hold)
        self._heading_dt2 += dt_s * dt_s
        rate_stamp = self._rate_stamp_s
        if rate_stamp is not None and stamp_s - rate_stamp > MIN_AGE_S:
            # The held rate grows stale: what the platform may have turned meanwhile.
            ekf.add_heading_variance(self.held_rate.heading_variance(
                before_s - rate_stamp, stamp_s - rate_stamp))
            self._rate_held_s = stamp_s
        self.stamp_s = stamp_s

    def _integrate_path(self, scan: bool) -> None:
        """Bring the odometry path up to the filter's stamp: the held speed along the heading.

        The distance is summed at every speed sample (the speed held since the last one);
        it is laid along the heading at scans only (the midpoint of the headings at the two
        scans: the heading moves little between scans, and the fits use the path at scans).
        """
        stamp = self.stamp_s
        if self._path_s is not None and self._measured_speed_m_s and not self.zero_rate:
            self._path_m += self._measured_speed_m_s * (stamp - self._path_s)
        self._path_s = stamp
        if scan:
            yaw = self.ekf.yaw_rad
            if self._path_m:
                self.odometry.advance(self._path_m, midpoint_yaw(self._path_yaw, yaw))
                self._path_m = 0.0
            self._path_yaw = yaw

    def on_speed(self, stamp_s: float, speed_m_s: float, variance: float | None = None
                 ) -> None:
        """Predict to stamp_s, then hold the new speed (m/s).

        variance: the message's own speed variance ((m/s)^2), held with the speed; None
        means the configured speed noise.
        """
        self._advance(stamp_s, 'speed')
        self._speed_loss.add(stamp_s)
        self._integrate_path(False)
        spikes = self._speed_spikes
        taken = spikes.admit(stamp_s, speed_m_s)
        if taken is None:
            self.stats.speed += 1
            return  # held back: a lone spike is dropped at the next sample
        speed_m_s = taken
        # One comparison per sample in the common case (the 2016 log's speed is a goal).
        stated = self._speed_var if variance is None else variance
        if spikes.white_variance > SPEED_NOISE_FACTOR * stated and \
                self.config.learn_speed_noise:
            variance = self._speed_noise(stated)
        # Divided by the speed scale estimated online (1 until one is applied).
        self._measured_speed_m_s = speed_m_s
        odometry = self.odometry
        self.speed_m_s, self.speed_variance = odometry.correct(speed_m_s, variance,
                                                               self._speed_var)
        # The scale not yet known, as a position random walk (core/odometry_online.py).
        self.ekf.odometry_walk = odometry.walk_density(self.speed_m_s)
        self.stats.speed += 1
        if self._rest_updates and not self._still():
            self._rest_updates.clear()
        speed_abs, rest = abs(speed_m_s), self._rest_speed_m_s
        if self.held_start.held and speed_abs > rest:
            self.held_start.release(stamp_s, 'the odometry read a speed')
        if speed_abs <= rest:
            if self._stop_since_s is None and self.config.zero_rate_max_spread_rad_s > 0.0:
                self._stop_since_s = stamp_s
        elif self._stop_since_s is not None:
            stats = self.stats
            if self.zero_rate:
                self._judge_stop_noise()
                self._judge_stop_wander(stamp_s)
            if self.zero_rate and stats.first_stop_end_s is None:
                # The bias the first stop's zero-rate updates learnt: a bias that stays put
                # ends the run where this places it, within their sigmas (health.verdict).
                stats.first_stop_end_s = stamp_s
                stats.first_stop_bias_rad_s = self.ekf.bias_rad_s
                stats.first_stop_bias_sigma_rad_s = math.sqrt(max(self.ekf.bias_var, 0.0))
            self._end_stop()

    def _speed_noise(self, stated: float) -> float:
        """Return the odometry's own spread as its variance, counted: beyond the stated one.

        The stated variance is the message's own or speed_noise_m_s squared. The spread is
        the odometry's scatter from sample to sample (SpikeGate.white_sigma), taken (on_speed)
        once its square exceeds ``SPEED_NOISE_FACTOR`` times the stated variance: a
        platform's own changes add to it, so it is taken only well beyond.
        """
        variance = self._speed_spikes.white_variance
        stats = self.stats
        stats.speed_noise_widened += 1
        stats.speed_noise_m_s = max(stats.speed_noise_m_s, math.sqrt(variance))
        stats.speed_noise_stated_m_s = math.sqrt(stated)
        return variance

    def on_imu(self, stamp_s: float, yaw_rate_rad_s: float, variance: float | None = None
               ) -> Estimate:
        """Predict to stamp_s, then hold the new measured yaw rate (rad/s, bias included).

        variance: the message's own yaw-rate variance ((rad/s)^2), held with the rate; None
        means the configured gyro noise.
        """
        self.step_imu(stamp_s, yaw_rate_rad_s, variance)
        return self.estimate()

    def step_imu(self, stamp_s: float, yaw_rate_rad_s: float, variance: float | None = None
                 ) -> None:
        """Do what on_imu does without building the Estimate (for callers that batch)."""
        if stamp_s != self.stamp_s:
            # (At the filter's stamp _advance has nothing to do: a call saved per sample
            # where the odometry shares the gyro's stamps, as in the 2016 log.)
            self._advance(stamp_s, 'imu')
        self._gyro_loss.add(stamp_s)
        if self.gyro_frozen.left_out(stamp_s, yaw_rate_rad_s):
            self.stats.imu += 1
            return  # a repeat of a frozen value: the held rate ages as in a gap
        taken = self._gyro_spikes.admit(stamp_s, yaw_rate_rad_s)
        if taken is None:
            self.stats.imu += 1
            return  # held back: a lone spike is dropped at the next sample
        yaw_rate_rad_s = taken
        self.rate_rad_s = yaw_rate_rad_s
        self.rate_variance = variance
        self._rate_stamp_s = stamp_s
        held = self.held_rate
        if stamp_s >= held.next_check_s:
            held.sample(stamp_s, yaw_rate_rad_s)
        self.stats.imu += 1
        if self.held_start.held:
            self._judge_held_rate(stamp_s, yaw_rate_rad_s, variance)
        if self._rest_updates and not self._still():
            self._rest_updates.clear()
        if self._stop_since_s is not None:
            self._zero_rate_update(stamp_s, yaw_rate_rad_s)

    def _judge_held_rate(self, stamp_s: float, rate_rad_s: float, variance: float | None
                         ) -> None:
        """End the held start on a gyro sample that is a turn, or with no odometry to tell.

        The zero-rate logic judges a stop by its mean over 0.5 s and more, and only once the
        odometry says the speed is 0; a turn on the spot faster than a sample's noise and
        the bias's uncertainty allow is seen at once, and a platform with no odometry
        message yet is not known to stand still.
        """
        held, config = self.held_start, self.config
        if held.first_input_s is None:
            held.first_input_s = stamp_s
        if self.stats.speed == 0:
            if stamp_s - held.first_input_s > HOLD_WITHOUT_ODOMETRY_S:
                held.release(stamp_s, 'no odometry message to tell that the platform stands '
                             'still')
            return
        sigma_w = math.sqrt(variance) if variance else config.gyro_noise_rad_s
        ekf = self.ekf
        if abs(rate_rad_s - ekf.bias_rad_s) > (config.rest_yaw_rate_rad_s + 4.0 * sigma_w
                                               + 3.0 * math.sqrt(max(ekf.bias_var, 0.0))):
            held.release(stamp_s, 'the gyro showed a turn')

    def _judge_stop_noise(self) -> None:
        """At a still stop: a gyro noisier than stated is measured, not guessed.

        Standing still the gyro reads its bias plus white noise, so the spread of the
        stop's samples is the noise itself, known to a chi-square of n - 1 dof. Beyond
        chance (``STOP_NOISE_SIGNIFICANCE``) above the stated variance (the held
        message's own, else ``gyro_noise_rad_s``), the stated figure is wrong: from then
        on (judged every ``STOP_NOISE_MIN_SAMPLES`` samples of the stop and at its end) the
        prediction's yaw-rate noise is scaled up to the spread (the bias watch's noise
        factor never falls below it). The figure is the stop with the most samples at its
        latest look: the largest of many looks would read high (the first, on 100
        samples, is known to 14 % of the variance). A spread below the stated
        figure changes nothing: driving adds vibration a stop does not show. Before, a gyro
        three times noisier than it said was left to the LiDARs' blocks, which read it as
        a wander or widened the noise late: NEES shares of 0.85-0.89 (docs/stress.md).
        """
        n = self._stop_n
        stats = self.stats
        if n < STOP_NOISE_MIN_SAMPLES or n < stats.gyro_rest_noise_samples:
            return  # a longer stop measured it better
        stated = self.ekf.gyro_variance if self.rate_variance is None else self.rate_variance
        if not 0.0 < stated < math.inf:
            return  # a message stating no usable variance: nothing to judge against
        spread = self._stop_m2 / (n - 1)
        beyond = spread > stated * chi_square_upper(STOP_NOISE_SIGNIFICANCE, n - 1) / (n - 1)
        stats.gyro_rest_noise_samples = n
        stats.gyro_rest_noise_scale = spread / stated if beyond else 1.0
        stats.gyro_rest_noise_rad_s = math.sqrt(spread) if beyond else 0.0
        self.bias_watch.set_noise_floor(stats.gyro_rest_noise_scale)
        self.ekf.rate_noise_scale = stats.gyro_noise_scale = self.bias_watch.noise_scale

    def _judge_stop_wander(self, stamp_s: float) -> None:
        """At a still stop's end: a wander its gyro samples show is modelled as a prior.

        See core/stop_wander.py. Not while a bias rate is in use: a ramp's blocks scatter
        as a wander's do.
        """
        n = self._stop_n
        if not self.config.learn_gyro_wander or n < 2 or self.bias_rate.rate_rad_s2 != 0.0:
            return
        sigma = self._stop_blocks.wander(self._stop_m2 / (n - 1))
        if sigma is not None:
            self.gyro_wander.seen_at_stop(stamp_s, sigma)
            self._model_wander()

    def _zero_rate_update(self, stamp_s: float, rate_rad_s: float) -> None:
        """Add a gyro sample to the stop; apply it as a zero-rate update once still."""
        n = self._stop_n + 1
        delta = rate_rad_s - self._stop_mean
        self._stop_mean += delta / n
        self._stop_m2 += delta * (rate_rad_s - self._stop_mean)
        self._stop_n = n
        self._stop_blocks.add(stamp_s, rate_rad_s)
        config = self.config
        if n < 2 or stamp_s - self._stop_since_s < config.zero_rate_min_still_s:
            return
        variance = self._stop_m2 / (n - 1)
        ekf = self.ekf
        turn_limit = config.rest_yaw_rate_rad_s + 3.0 * math.sqrt(max(ekf.bias_var, 0.0))
        if (variance > config.zero_rate_max_spread_rad_s ** 2
                or abs(self._stop_mean - ekf.bias_rad_s) > turn_limit):
            # Vibration, a push or a turn on the spot: not still after all. The spread is
            # of the whole stop, so a shaken stop stays shaken.
            self.zero_rate = False
            self.held_start.release(stamp_s, 'the gyro showed a turn or a shake')
            self.bias_rate.end_rest()
            return
        if not self.zero_rate:
            self.zero_rate = True
            self.stats.stops += 1
        ekf.update_zero_rate(rate_rad_s, max(variance, config.zero_rate_min_noise_rad_s ** 2))
        self.stats.zero_rate_updates += 1
        if n % STOP_NOISE_MIN_SAMPLES == 0:
            # While the stop lasts too: its heading integrates the noise the stop shows.
            self._judge_stop_noise()
        # The samples of the stop measure the bias itself: a ramp shows in their line
        # (core/bias_rate.py, a ramp at rest).
        lag = self.bias_rate.add_rest(stamp_s, rate_rad_s, ekf.bias_rad_s)
        if lag is not None or self.bias_rate.rate_rad_s2 != ekf.bias_rate_found:
            self._rate_followed(lag)

    def estimate(self) -> Estimate:
        """Return a snapshot of the filter (state and covariance are copies)."""
        x, P = self.ekf.x, self.ekf.P
        # The gyro's rate error, as a sample at rest measures it (b + c).
        h, H = observe_bias(x)
        error = float(h[0])
        rate = 0.0 if self.rate_rad_s is None else (self.rate_rad_s - error) / self._gyro_scale
        state, covariance = x[:ESTIMATE_SIZE], P[:ESTIMATE_SIZE, :ESTIMATE_SIZE]
        if self.frame_shift is not None:
            # The two LiDARs' mixture (core/body_frame.py), as drive_trip reports it.
            shift_estimates(state[None], covariance[None], self.frame_shift)
        return Estimate(stamp_s=self.stamp_s if self.stamp_s is not None else 0.0,
                        state=state, covariance=covariance,
                        speed_m_s=self.speed_m_s, yaw_rate_rad_s=rate,
                        gyro_error_rad_s=error,
                        gyro_error_variance=float((H @ P @ H.T)[0, 0]))

    def on_detections(self, stamp_s: float, points_sensor_m: FloatArray,
                      mount: LidarMount, sensor: str | None = None) -> ObservationReport:
        """Predict to stamp_s, associate the detected poles with the map, update.

        Then weigh anew what the LiDARs say of the body frame (``frame_shift``); see
        ``_on_detections``.
        """
        report = self._on_detections(stamp_s, points_sensor_m, mount, sensor)
        # While an exact start pose is held, the heading is that pose's, not the LiDAR's
        # (nor is it reported widened).
        widened = 0.0 if self.held_start.held else self.odometry.heading_variance(
            self.mount_yaw_sigmas.get(self._body_key, 0.0))
        self.frame_shift = with_heading(self._frame_shift(), widened)
        return report

    def _frame_shift(self) -> Shift | None:
        """Return the mixture's move of the reported pose (core/body_frame.py), or None.

        Only while one other LiDAR's mount in use sits off its stated x, y (its yaw within
        the online estimator's smallest change) and the odometry has not moved the mount of
        the LiDAR that defines the body frame. After a hand-over at the start check the two
        swap roles: it rests on the same stop's fits, which may not tell. One made on the
        health monitor's word (a map disagreement another LiDAR vouched against) stands.
        While the other LiDAR's mount in use is its stated one and its last watch fit reads
        the offset off under the change limits (the verdict's disagreement), the pose stays
        and its covariance spans the disagreement (``body_frame.disagreement_spread``).
        """
        trackers = self.mounts.trackers
        for tracker in trackers.values():
            tracker.right_share = tracker.widened_m = None
        if len(trackers) != 1 or self.odometry.offset_applied or self._body_key is None:
            return None
        (key, tracker), = trackers.items()
        used, stated = tracker.used, tracker.stated
        d = (used.x_m - stated.x_m, used.y_m - stated.y_m)
        if d == (0.0, 0.0):
            # Nothing moved, yet the fit may read the two apart under the change limits. A
            # LiDAR handed over was named the one off (by its first looks or the map) and,
            # read off, weighs a ninth: the pose leans on the other, no question is open
            # (widened by the whole disagreement, stress seed 8 mount_offset 6 went from
            # NEES share 0.896 to 0.861 below the band).
            read_off = tracker.watched_read_off_m
            if read_off is None or tracker.handed_over_s is not None:
                return None
            tracker.widened_m = math.hypot(*read_off)
            return disagreement_spread(read_off)
        # A yaw change too small to be made alone comes along with an offset's fit.
        if abs(wrap_scalar(used.yaw_rad - stated.yaw_rad)) >= (
                tracker.settings.min_yaw_change_rad):
            return None
        offsets = self._start_offsets
        if self.mounts.handovers and not (self._body_key in offsets and key in offsets):
            # Handed over on the health monitor's word (the LiDAR disagreed with the map
            # while this one vouched): that decided. Only a hand-over at the start check,
            # resting on the stop's fits of both, is weighed again.
            return None
        fit = self.odometry.clean_fit()
        path = None if fit is None else (*fit.offset_m, *fit.offset_sigma_m)
        tracker.right_share = other_right_share(d, offsets.get(self._body_key),
                                                offsets.get(key), path)
        return mixture_shift(d, tracker.right_share)

    def _on_detections(self, stamp_s: float, points_sensor_m: FloatArray,
                       mount: LidarMount, sensor: str | None = None) -> ObservationReport:
        """Predict to stamp_s, associate the detected poles with the map, update.

        A LiDAR the health monitor has excluded is associated but not applied (its report
        has no NIS); ``last_transition`` tells when this scan excluded or readmitted one.
        A LiDAR whose mount is estimated online (``track_mounts``) feeds its estimator
        first and is taken with its mount in use (the report's mount); when that mount
        changes, its health window starts again, and when it is excluded, its estimator.

        Args:
            stamp_s: scan stamp, s.
            points_sensor_m: pole centres in the sensor frame, shape (k, 2), m.
            mount: pose of the sensor on the platform (its health is kept per mount).
            sensor: its name in health reports (topic or frame) on first use; by default
                sensor_names[mount].
        """
        self.last_transition = None
        if sensor is None:
            # Unnamed (a node with no sidecar): by its mount, never the dataclass's repr.
            sensor = self.sensor_names.get(mount) or (
                f'mounted at ({mount.x_m:g} m, {mount.y_m:g} m, '
                f'{math.degrees(mount.yaw_rad):g} deg)')
        self._advance(stamp_s, 'observation')
        self.stats.scans += 1
        lost = self.scan_loss.get(sensor)
        if lost is None:
            lost = self.scan_loss[sensor] = InputLoss()
        lost.add(stamp_s)
        if self._first_scan_s is None:
            self._first_scan_s = stamp_s
        points = np.asarray(points_sensor_m, dtype=np.float64).reshape(-1, 2)
        detected = points.shape[0]
        self.stats.detections += detected
        ekf = self.ekf
        prior = ekf.x
        # The same prior as plain floats, for the scalar maths of this scan.
        prior_values = ekf.x_values
        prior_yaw_variance = ekf.yaw_var
        self._integrate_path(scan=True)
        key = mount  # the LiDAR (its stated mount): the key of its health and rest counts
        tracker = self.mounts.trackers.get(key)
        if tracker is not None:
            mount = tracker.used
        else:
            # Where the odometry places the LiDARs that define the body frame.
            mount = self.odometry.first_mount(mount)
            self._body_key = key
            if self._landmarks is not None and detected:
                # Moving by the odometry (the bias is not known yet to judge the gyro).
                checking = self.odometry.checked_at is None
                moved = self.odometry.observe_start(
                    stamp_s, points, mount, self._landmarks.xy_m,
                    abs(self._measured_speed_m_s) > self.config.rest_speed_m_s)
                if checking and self.odometry.checked_at is not None:
                    # Where each LiDAR's scans at the start pose place it: this one's
                    # from the check, the others' from their own scans there.
                    if self.odometry.start_offset is not None:
                        self._start_offsets[key] = self.odometry.start_offset
                    for other, other_tracker in self.mounts.trackers.items():
                        offset = other_tracker.start_offset(self.odometry.checked_at,
                                                            self._landmarks.xy_m)
                        if offset is not None:
                            self._start_offsets[other] = offset
                # The start check's fit takes the scans of a stop as one (their errors
                # repeat), so a first LiDAR 2-3 cm off can stay within its 3 sigmas, where
                # its first look at each pole from the held start pose may already show it.
                # When those disagree with the pose and another LiDAR's agree, it is this
                # one's mount (a wrong pose would shift both): the check closing acts on it.
                off_alone = (moved is None and checking and self.odometry.checked_at
                             is not None and self.held_start.disagrees_alone(key))
                if moved is not None or off_alone:
                    if self._hand_over(key, stamp_s, self.odometry.checked_at):
                        # Off its mount at the trusted start pose, and another LiDAR agrees
                        # with the map there: that one defines the body frame, this one's
                        # mount is estimated online, and the pose it dragged goes back.
                        still_at = self.odometry.still_at
                        if still_at is not None:
                            self.ekf.reset(np.array(still_at), self.ekf.bias_rad_s, self.ekf.P)
                            self._restart_heading_windows()
                        return ObservationReport(stamp_s, points, prior, mount, None, _NO_NIS)
                    # No other LiDAR corroborates it: only what the check proves alone.
                    moved = self.odometry.start_alone
                if moved is not None:
                    self.odometry.apply(moved)
                    self._first_lidar_moved(key, moved)
                    still_at = self.odometry.still_at
                    if still_at is not None:
                        # Still at the trusted start pose: the pose a LiDAR off its mount
                        # dragged goes back there, heading included (at rest the looks drag
                        # it only part of the way, so moving it back by the whole offset or
                        # yaw would overshoot; an offset drags the heading too).
                        self.ekf.reset(np.array(still_at), self.ekf.bias_rad_s, self.ekf.P)
                        self._restart_heading_windows()
                    mount = self.odometry.first_mount(key)
        if self.rate_rad_s is not None:
            # Scan to scan, without the map: a gyro or LiDAR upside down, or a gyro or
            # odometry in the wrong units or sign, shows here first.
            # The bias the first stop learnt, not the filter's: a filter the flipped
            # sensor misled takes the turn for a bias of tens of deg/s.
            self.turn_signs.scan(key, sensor, stamp_s, points, mount, self._turned,
                                 self.stats.first_stop_bias_rad_s or 0.0,
                                 self._measured_speed_m_s)
        if self.zero_rate and detected:
            # The gyro's rate taken for bias: what the poles say of a turn (rest_turn.py).
            self.rest_turns.add(sensor, stamp_s, points, mount)
        if not self._landmark_xy or not detected:  # no map, an empty one, or no poles
            return ObservationReport(stamp_s, points, prior, mount, None, _NO_NIS)
        # Plain floats from here: a scan has a handful of poles, and numpy's per-call cost
        # would outweigh the arithmetic (this runs ~40 times a second on the real trip).
        z = points_to_range_bearing(points).tolist()
        excluded = self.health.excluded(key)
        held = False
        if tracker is not None:
            if self.odometry.at_start(abs(self._measured_speed_m_s)
                                      > self.config.rest_speed_m_s) is not None:
                tracker.observe_start(points)
            # The pose does not depend on a LiDAR held out or excluded.
            if self.mounts.observe(key, stamp_s, list(prior_values), points,
                                   self._landmarks.xy_m,
                                   excluded or tracker.holds, prior_yaw_variance,
                                   self.odometry.pose_offset):
                self.health.mount_changed(key, stamp_s)
            mount, held = tracker.used, tracker.holds
        noise = self.lidar_noise(key) if self.config.lidar_noise_window else None
        variances = None if noise is None else noise.variances
        R = self.ekf.R if noise is None else noise.R
        after_gap = self._recovering(stamp_s)
        starved = (not after_gap and not self.held_start.held
                   and self._gate.starved(stamp_s))
        if after_gap or starved:
            self.stats.recoveries += 1
            self.stats.gate_starved += starved
            self._gate.clear()
            result = associate_by_distance(
                z, prior, self.ekf.P, R, self._landmarks.xy_m, mount,
                self.config.recovery_max_distance_m, self.config.recovery_ratio,
                self.ekf.landmark_var_m2)
        else:
            # The filter's own plain floats: no array per scan (core/association.py).
            result = associate_packed(z, self.ekf.packed_row(), R, self._landmark_xy, mount,
                                      self.config.gate_probability, self.ekf.landmark_var_m2)
        if excluded or held:
            # Held out while its mount is estimated online; not readmitted while a mount
            # estimated online is being verified.
            return self._recheck(stamp_s, points, z, prior, key, mount, result, sensor,
                                 tracker is None or not tracker.holds, excluded)
        nis = []
        bearing_sum = 0.0
        outcomes = self.stats.outcomes
        landmark_xy = self._landmark_xy
        # Standing still, the same beams hit the same pole scan after scan, so its error
        # repeats (the simulator's bearings at rest repeat to 0.001 deg): averaging N such
        # scans would shrink P N times and the error not at all. The n-th update of a
        # landmark by one LiDAR during a stop uses n R, so a stop adds about ln N scans'
        # worth, and the yaw drift is still tracked (that is how the bias is found at rest).
        at_rest = self._still()
        self._close_bias_block(stamp_s, at_rest)
        if self.bias_watch.idle:
            # This scan's updates may start a block: the bias it begins with, and how well
            # it is known then.
            self._block_bias = self.ekf.bias_rad_s
            self._block_bias_variance = self.ekf.bias_var
        # A mount estimated online weighs less (core/mount_online.py, its item 6).
        base = self.mounts.body_noise_scale if tracker is None else tracker.noise_scale
        jitter = (None if at_rest or self.held_start.held else
                  self._jitter_frame(key, prior_values, mount, len(result.associations),
                                     variances))
        if jitter is not None:
            points_list = points.tolist()
        near_poles = None
        pole_matches = self.map_poles.matched
        held_start, health, bias_watch = self.held_start, self.health, self.bias_watch
        landmark_var = ekf.landmark_var_m2
        for match in result.associations:
            outcome = match.outcome
            outcomes[_OUTCOME_KEYS[outcome]] += 1
            if outcome is _UNMATCHED:
                near = self._count_unmapped(prior, points[match.detection_index], mount)
                if near is not None:
                    if near_poles is None:
                        near_poles = []
                    near_poles.append(near)
                    if held_start.held:
                        # Outside the gate of the pole it lies near: the strongest
                        # disagreement.
                        held_start.look(key, near[0], match.mahalanobis_sq, stamp_s)
            elif outcome is _MATCHED:
                detection, landmark = match.detection_index, match.landmark_index
                pole_matches[landmark] += 1
                scale = base
                if at_rest:
                    look = (landmark, key)
                    n = self._rest_updates.get(look, 0) + 1
                    self._rest_updates[look] = n
                    scale = base * n
                zi = z[detection]
                nis.append(ekf.update(zi, landmark_xy[landmark], mount, float(scale),
                                      variances))
                # Plain floats: this runs at every update.
                y, S = ekf.y_values, ekf.S_packed
                bearing_sum += y[1]
                if noise is not None and scale == 1.0:
                    # At the LiDAR's plain R: not a repeated look at rest, nor a mount on
                    # probation (their R is scaled; the first's error repeats).
                    noise.add(y, S, variances)
                if held_start.held:
                    # Judging the held start pose (and, with P of the pose 0, moving
                    # nothing): no test of the innovations' whiteness, as for repeated looks.
                    if scale == base:
                        held_start.look(key, landmark, nis[-1], stamp_s,
                                        y[1] / math.sqrt(S[2]))
                elif scale == base:  # not a repeated look at rest
                    health.innovation(key, stamp_s, y, S, zi)
                    if jitter is not None:
                        _stamp_look(jitter, points_list[detection], landmark_xy[landmark])
                    if not at_rest:
                        r = zi[0]
                        bias_watch.add(stamp_s, y[1], S[2], landmark,
                                       landmark_var / (r * r) * scale)
        if jitter is not None:
            jitter[0].close_scan(jitter[12])
        if near_poles is not None:
            # Detections near a pole this scan matched to none: looks at where it may
            # stand (core/map_poles.py); near one it matched, something besides it.
            matched = {match.landmark_index for match in result.associations
                       if match.outcome is AssociationOutcome.MATCHED}
            for pole, dx, dy in near_poles:
                if pole not in matched:
                    self.map_poles.look(pole, dx, dy)
        if nis and not at_rest:
            self.bias_watch.corrected(wrap_scalar(ekf.yaw_rad - prior_values[YAW]))
            if len(nis) >= OFFSET_MIN_UPDATES:
                self._look_in_time(key, stamp_s, prior_values[YAW] - bearing_sum / len(nis),
                                   prior_yaw_variance)
            if self.gyro_scale.add(stamp_s, self.ekf.yaw_rad, self._turned):
                self._gyro_scale_applied()
            if tracker is None:
                # The poses the first LiDAR holds (a second one's could carry its own
                # mount error, which would be taken for the first's).
                moved = self.odometry.observe(stamp_s, self.ekf.x_values, self.ekf.yaw_var,
                                              self._vouching_lidar)
                if moved is not None:
                    self._first_lidar_moved(key, moved)
        self._gate.add(stamp_s, key, len(nis),
                       0 if near_poles is None else len(near_poles))
        self.held_start.judge(stamp_s, 1 + len(self.mounts.trackers))
        self.turn_signs.associated(key, detected, len(nis))
        nis_sum = float(sum(nis))
        self._judged(key, self.health.record(key, stamp_s, detected, len(nis),
                                             nis_sum, float(bearing_sum), sensor))
        if nis:
            self.stats.updates += len(nis)
            self.stats.nis_sum += nis_sum
            if self.stats.last_association_s is not None:
                gap = stamp_s - self.stats.last_association_s
                self.stats.longest_gap_s = max(self.stats.longest_gap_s, gap)
                self.stats.dead_reckoned_s += dead_reckoned(gap)
            else:
                self.stats.first_association_s = stamp_s
            self.stats.last_association_s = stamp_s
        return ObservationReport(stamp_s, points, prior, mount, result, np.array(nis))

    def lidar_noise(self, key: LidarMount) -> NoiseMatch:
        """Return the noise estimate of the LiDAR at stated mount `key` (made on first use)."""
        noise = self.noise.get(key)
        if noise is None:
            config = self.config
            noise = self.noise[key] = NoiseMatch(
                config.range_noise_m ** 2, config.bearing_noise_rad ** 2,
                config.lidar_noise_window, config.lidar_noise_min_updates,
                config.lidar_noise_limit)
        return noise

    def held_start_report(self) -> dict:
        """Return the held start's figures (``HeldStart.report``), LiDARs by name."""
        return self.held_start.report({key: self.health.sensor(key).name
                                       for key in self.held_start.looks})

    def noise_report(self) -> list[dict]:
        """Return each LiDAR's measured noise (``NoiseMatch.report``) with its name."""
        return [{'name': self.health.sensor(key).name, **noise.report()}
                for key, noise in self.noise.items()]

    def _vouching_lidar(self) -> str | None:
        """Return another LiDAR that vouches for the first one's yaw, or None.

        One in the filter (not held, not excluded) whose stated mount its estimator
        confirmed and still reads right in yaw (no noise scaled, never moved, never handed
        over): it agrees with the first LiDAR on the heading (core/odometry_online.py).
        """
        for key, tracker in self.mounts.trackers.items():
            if (tracker.state == CONFIRMED and not tracker.applied and not tracker.holds
                    and tracker.handed_over_s is None and tracker.noise_scale_reason is None
                    and not self.health.excluded(key)):
                return tracker.name
        return None

    def _first_lidar_moved(self, key: LidarMount, moved: Moved) -> None:
        """Move the pose back: the first LiDAR's mount in use moved by `moved`.

        `moved` is (x, y, sigma, yaw, yaw sigma). The pose followed the LiDAR: move it back
        by as much (turn the heading back by the yaw), with that uncertainty; every other
        LiDAR's mount, estimated against the old pose, is estimated again, and the LiDAR's
        health is judged on new figures (core/odometry_online.py).
        """
        dx, dy, sigma, dyaw, yaw_sigma = moved
        x = self.ekf.x
        c, s = math.cos(x[YAW]), math.sin(x[YAW])
        P = self.ekf.P
        P[0, 0] += sigma * sigma
        P[1, 1] += sigma * sigma
        P[YAW, YAW] += yaw_sigma * yaw_sigma
        self.ekf.reset(np.array([x[0] - c * dx + s * dy, x[1] - s * dx - c * dy,
                                 x[YAW] - dyaw]), float(x[3]), P)
        self._restart_heading_windows()
        for other in self.mounts.trackers:
            self.mounts.restart(other)
        self.health.mount_changed(key, self.stamp_s)

    def _restart_heading_windows(self) -> None:
        """Start the heading watches' windows again (the filter's heading was reset)."""
        self.gyro_scale.restart_window()
        for watch in self.time_offsets.values():
            watch.restart_window()

    def time_offset_report(self) -> list[dict]:
        """Return each LiDAR's time offset figures (``TimeOffsetWatch.report``) with its name."""
        return [{'name': self.health.sensor(key).name, **watch.report()}
                for key, watch in self.time_offsets.items()]

    def rest_turn_report(self) -> list[dict]:
        """Return the stops whose poles turned while zero-rate updates held them still.

        Those ended and the one under way (core/rest_turn.py).
        """
        return self.rest_turns.report(self.stamp_s)

    def turn_sign_report(self) -> list[dict]:
        """Return per LiDAR what the gyro and odometry read against it (core/turn_sign.py)."""
        return self.turn_signs.report()

    def map_poles_report(self) -> list[dict]:
        """Return the mapped poles found to stand elsewhere (core/map_poles.py)."""
        return self.map_poles.report(self._landmark_xy)

    def stamp_jitter_report(self) -> list[dict]:
        """Return each LiDAR's stamp scatter figures (``StampJitterWatch.report``) by name."""
        return [{'name': self.health.sensor(key).name, **watch.report()}
                for key, watch in self.stamp_jitter.items()]

    def _jitter_frame(self, key: LidarMount, prior: tuple[float, ...], mount: LidarMount,
                      updates: int, variances: tuple[float, float] | None) -> tuple | None:
        """Return what each update of a moving scan gives its stamp estimate, or None.

        The sensor's pose before the scan, its velocity in its own frame, the noise its
        poles are weighed by and the pose's covariance before the scan
        (core/stamp_jitter.py); None when the gyro has not spoken yet or the scan is too
        slow to tell its stamp. Call before the scan's first update.
        """
        rate = self.rate_rad_s
        if rate is None:
            return None
        range_var, bearing_var = variances or self._stated_variances
        omega, speed = rate - self.ekf.bias_rad_s, self.speed_m_s
        if not StampJitterWatch.scan_is_informative(updates, omega, speed, range_var,
                                                    bearing_var):
            return None
        watch = self.stamp_jitter.get(key)
        if watch is None:
            watch = self.stamp_jitter[key] = StampJitterWatch()
        x, y, yaw = prior[:3]  # the state before the scan, plain floats
        c, s = math.cos(yaw), math.sin(yaw)
        sensor_x = x + mount.x_m * c - mount.y_m * s
        sensor_y = y + mount.x_m * s + mount.y_m * c
        cm, sm = math.cos(mount.yaw_rad), math.sin(mount.yaw_rad)
        # The sensor's velocity in the body frame, then in its own frame.
        ux, uy = speed - omega * mount.y_m, omega * mount.x_m
        theta = yaw + mount.yaw_rad
        landmark_var = self.ekf.landmark_var_m2
        p = self.ekf.packed_row()
        # The pose block of P before the scan: xx, xy, x yaw, yy, y yaw, yaw yaw.
        pose_covariance = (p[5], p[6], p[7], p[10], p[11], p[14])
        # d(sensor position)/d(yaw): the sensor swings about the reference point.
        swing = (-mount.x_m * s - mount.y_m * c, mount.x_m * c - mount.y_m * s)
        return (watch, math.cos(theta), math.sin(theta), sensor_x, sensor_y,
                cm * ux + sm * uy, -sm * ux + cm * uy, omega, range_var + landmark_var,
                bearing_var, landmark_var, swing, pose_covariance)

    def _close_bias_block(self, stamp_s: float, at_rest: bool) -> None:
        """Before a scan's updates: judge the bias watch's block; re-open the bias on a drift."""
        watch = self.bias_watch
        if at_rest:
            # Zero-rate updates learn the bias at rest; repeated looks are not a drift.
            watch.pause()
            self._heading_dt2 = self._wander_dt = 0.0
            return
        if not watch.due(stamp_s):
            return
        ekf = self.ekf
        P = ekf.P
        rate_variance = ekf.gyro_variance if self.rate_variance is None else self.rate_variance
        bias_variance = float(P[BIAS, BIAS])
        heading_noise = self._heading_dt2 * rate_variance * ekf.rate_noise_scale
        start_yaw_variance = watch.start_yaw_variance  # close() moves it to the next block
        yaw_variance = float(P[YAW, YAW])
        variance = watch.close(stamp_s, bias_variance, yaw_variance, heading_noise)
        wander_dt = self._wander_dt
        self._heading_dt2 = self._wander_dt = 0.0
        self.ekf.rate_noise_scale = self.stats.gyro_noise_scale = watch.noise_scale
        self.stats.gyro_noise_scale_max = max(self.stats.gyro_noise_scale_max, watch.noise_scale)
        if (variance is None and watch.block is not None and watch.walk == 0.0
                and self.config.learn_gyro_wander):
            # A block of a bias that stayed: its error against b alone is the wander's
            # evidence (core/gyro_wander.py). Not over an IMU gap or in the block after
            # one (its error is taken back over the next scans): there the heading error
            # is the held rate's, not the gyro's.
            # Nor while the bias is being learnt (its variance more than halved over the
            # block: a trip that starts moving, its bias known to degrees per second): the
            # corrections then take back the heading the bias's first error ran up, which
            # is the learning, not a wander.
            start, length, error = watch.block
            if (self._rate_held_s < start - length
                    and self._block_bias_variance <= BIAS_LEARNT_FACTOR * bias_variance):
                self.gyro_wander.add_block(stamp_s, length, error + wander_dt / length,
                                           block_allowed(length, bias_variance, heading_noise,
                                                         start_yaw_variance, yaw_variance))
                self.gyro_wander.rule_out(stamp_s, self.config.wander_prior_rad_s)
                self._model_wander()
        if variance is not None:
            self.gyro_wander.clear_held()
        elif watch.block is not None and self.ekf.wander_sigma_rad_s > 0.0:
            # The modelled wander holding one sign for 20 s is a bias that moved
            # (core/gyro_wander.py).
            held = self.gyro_wander.held(watch.block[1], wander_dt / watch.block[1],
                                         bias_variance)
            if held is not None:
                # A drift as the watch's own: its walk and a ramp's line count it.
                variance = watch.found(stamp_s, held)
                self.stats.bias_wander_held += 1
                # The blocks that found the wander were that move too: taken back, as a
                # ramp's line takes them back. Kept, a step's wander stayed modelled and
                # took the step in again (stress bias_step seed 27 #5).
                self.gyro_wander.retract(stamp_s)
                self._model_wander()
        if variance is not None:
            self.ekf.open_bias(variance)
            self.stats.bias_openings += 1
            self.stats.bias_largest_opening_rad_s = max(
                self.stats.bias_largest_opening_rad_s, math.sqrt(variance))
        if watch.block is not None:
            # The block's true-bias estimate (the bias used plus the error its corrections
            # imply) for the ramp's line (core/bias_rate.py).
            start, length, error = watch.block
            bias = ekf.bias_rad_s
            self._rate_followed(self.bias_rate.add(
                start + 0.5 * length, 0.5 * (self._block_bias + bias), error,
                watch.drift_sign(), bias))
        else:
            self._rate_followed(None)

    def _model_wander(self) -> None:
        """Give the filter the wander found (never less than the one configured).

        The prior wander is modelled as well until the blocks rule it out
        (core/gyro_wander.py).
        """
        found, config, stats = self.gyro_wander, self.config, self.stats
        self.ekf.wander_sigma_rad_s = max(config.gyro_wander_rad_s, found.sigma_rad_s,
                                          found.prior_rad_s(config.initial_wander_rad_s))
        stats.gyro_wander_rad_s = found.sigma_rad_s
        stats.gyro_wander_found_s = found.found_at_s
        stats.gyro_wander_prior_ruled_out_s = found.prior_ruled_out_s
        stats.gyro_wander_stop_rad_s = found.stop_sigma_rad_s
        stats.gyro_wander_stop_s = found.stop_seen_s
        stats.gyro_wander_stop_ruled_out_s = found.stop_ruled_out_s

    def _restart_bias_evidence(self) -> None:
        """Start the bias watch, the ramp's line and the wander's blocks again, walks none."""
        self.bias_watch = BiasWatch()
        # What a stop measured of the gyro's noise stays measured.
        self.bias_watch.set_noise_floor(self.stats.gyro_rest_noise_scale)
        self.bias_rate = BiasRate(self.config.bias_rate_window_s)
        self.gyro_wander = GyroWander(self.config.gyro_wander_tau_s)
        # So does a wander a stop showed, and whether it was ruled out: at rest the gyro's
        # scale draws on nothing.
        stats, wander = self.stats, self.gyro_wander
        wander.stop_sigma_rad_s, wander.stop_seen_s, wander.stop_ruled_out_s = (
            stats.gyro_wander_stop_rad_s, stats.gyro_wander_stop_s,
            stats.gyro_wander_stop_ruled_out_s)
        self.ekf.bias_walk_found = self.ekf.bias_rate_found = 0.0
        self._heading_dt2 = self._wander_dt = 0.0

    def _gyro_scale_applied(self) -> None:
        """Turn by the scale the LiDARs' heading measured; what its error drew on starts again.

        Until now the prediction ran (e - e_old) times each turn ahead of the heading and
        the LiDARs took it back: the bias took that in (by up to (e - e_old) times the turn
        rate), the bias watch read it as drifts, a ramp or a noisier gyro, and the wander's
        blocks as wander (core/gyro_scale.py). Those findings were the scale's: the watch,
        the ramp's line and the wander's evidence start again (the prior wander with them),
        and the bias is opened by the error the old scale put into it at the last window's
        RMS turn rate. The run's counts keep what happened before (re-openings, the largest
        noise widening): the verdict still names them, as the estimates carried them.
        """
        watch = self.gyro_scale
        change = watch.in_use - (self._gyro_scale - 1.0)
        self._gyro_scale = 1.0 + watch.in_use
        self._restart_bias_evidence()
        self._model_wander()
        self.ekf.rate_noise_scale = self.stats.gyro_noise_scale = self.bias_watch.noise_scale
        self.stats.bias_rate_rad_s2 = 0.0
        self.ekf.open_bias(change * change * watch.mean_square_rate)

    def _rate_followed(self, lag: float | None) -> None:
        """Open the bias by a new rate's lag; hand the rate and the walks to the filter."""
        rate = self.bias_rate
        if lag is not None:
            self.ekf.open_bias(lag)
            # A ramp found: the blocks before it leaned its way, a bias that moved and not a
            # wander (core/gyro_wander.py).
            self.gyro_wander.retract(self.stamp_s)
            self._model_wander()
        self.stats.bias_rate_rad_s2 = rate.rate_rad_s2
        self.stats.bias_rate_found = rate.found
        self.stats.bias_largest_rate_rad_s2 = rate.largest_rad_s2
        self.ekf.bias_walk_found = self.bias_watch.walk + rate.walk
        self.ekf.bias_rate_found = rate.rate_rad_s2

    def _judged(self, key: LidarMount, transition: Transition | None) -> None:
        """Keep the health monitor's decision; re-estimate a newly excluded LiDAR's mount.

        When the excluded LiDAR is the one that defines the body frame, a tracked LiDAR
        that agrees with the map at its stated mount takes over (OnlineMounts.hand_over).
        """
        self.last_transition = transition
        if transition is None or transition.change != 'excluded':
            return
        if key not in self.mounts.trackers:
            self._hand_over(key, transition.stamp_s)
        self.mounts.restart(key)

    def _hand_over(self, key: LidarMount, stamp_s: float,
                   start: tuple[float, float, float] | None = None) -> bool:
        """Let another LiDAR define the body frame instead of `key`; return whether one did.

        A tracked LiDAR that agrees with the map takes over from `key`, which disagrees
        (OnlineMounts.hand_over). It agrees when the health monitor says so, or, at the
        start check (`start`: the trusted start pose), when its own scans there keep its
        mount in use: the pose the health monitor judges by was dragged by `key` meanwhile.
        """
        if start is None:
            candidates = self.health.vouching_peers(key, stamp_s)
        else:
            candidates = [other for other, tracker in self.mounts.trackers.items()
                          if tracker.agrees_at_start(start, self.landmarks.xy_m)]
        for other in candidates:
            tracker = self.mounts.trackers.get(other)
            # Not one whose mount was estimated against the pose the other one held.
            if tracker is not None and not tracker.applied:
                self.mounts.hand_over(key, self.health.sensor(key).name, other, stamp_s)
                self.odometry.new_reference(stamp_s)
                if start is not None:
                    # Excluded against the pose `key` dragged, it agreed at the start pose.
                    self.health.vouched(other, stamp_s, 'its scans at the trusted start '
                                        'pose agree with its stated mount')
                return True
        return False

    def _recheck(self, stamp_s: float, points: FloatArray, z: list, prior: FloatArray,
                 key: LidarMount, mount: LidarMount, result: AssociationResult,
                 sensor: str | None, readmit: bool, excluded: bool) -> ObservationReport:
        """Judge a held-out LiDAR's scan against the map at the current pose; apply nothing.

        key: the LiDAR's stated mount (its health key); mount: the mount in use; readmit:
        whether agreeing re-checks may readmit it now; excluded: by the health monitor
        (else only held while its mount is estimated online: its association outcomes
        count as any LiDAR's do).
        """
        if excluded:
            self.stats.excluded += points.shape[0]
        outcomes = self.stats.outcomes
        matched, nis_sum, bearing_sum = 0, 0.0, 0.0
        for match in result.associations:
            if not excluded:
                outcomes[_OUTCOME_KEYS[match.outcome]] += 1
            if match.outcome is AssociationOutcome.MATCHED:
                y, S, _ = self.ekf.innovation(z[match.detection_index],
                                              self.landmarks.xy_m[match.landmark_index], mount)
                matched += 1
                nis_sum += match.mahalanobis_sq
                bearing_sum += float(y[1])
                self.held_start.look(key, match.landmark_index, match.mahalanobis_sq, stamp_s,
                                     float(y[1]) / math.sqrt(float(S[1, 1])))
            elif match.outcome is AssociationOutcome.UNMATCHED and self.held_start.held:
                near = self._nearest_landmark(prior, points[match.detection_index], mount)
                if near is not None:
                    self.held_start.look(key, near[0], match.mahalanobis_sq, stamp_s)
        self.held_start.judge(stamp_s, 1 + len(self.mounts.trackers))
        if matched >= OFFSET_MIN_UPDATES and not self._still():
            # Held out, its headings against a pose the other LiDARs hold: its stamps'
            # offset shows as well as (better than) while it takes part.
            self._look_in_time(key, stamp_s, float(prior[YAW]) - bearing_sum / matched,
                               self.ekf.yaw_var)
        self._judged(key, self.health.record(key, stamp_s, points.shape[0], matched,
                                             nis_sum, bearing_sum, sensor, readmit))
        return ObservationReport(stamp_s, points, prior, mount, None, _NO_NIS)

    def _look_in_time(self, key: LidarMount, stamp_s: float, heading_rad: float,
                      heading_variance: float) -> None:
        """Give a LiDAR's own heading at a scan, while driving, to its time offset watch.

        heading_rad: the filter's heading before the scan less the LiDAR's mean bearing
        innovation; against the gyro's integral and rate it shows the stamps' offset
        (core/time_offset.py).
        """
        if self.rate_rad_s is None:
            return
        watch = self.time_offsets.get(key)
        if watch is None:
            watch = self.time_offsets[key] = TimeOffsetWatch()
        watch.add(stamp_s, heading_rad, self._turned, self.rate_rad_s - self.ekf.bias_rad_s,
                  heading_variance)

    def _count_unmapped(self, prior: FloatArray, point: FloatArray, mount: LidarMount
                        ) -> tuple[int, float, float] | None:
        """Count an unmatched detection that lies far from every landmark of the map.

        Returns the nearest landmark's index and the detection's offset from it in the map
        frame (m) when one lies within the recovery distance.
        """
        nearest = self._nearest_landmark(prior, point, mount)
        if nearest is None:
            self.stats.unmapped += 1
        return nearest

    def _nearest_landmark(self, prior: FloatArray, point: FloatArray, mount: LidarMount
                          ) -> tuple[int, float, float] | None:
        """Return the landmark nearest a detection, if within the recovery distance.

        As (index, dx, dy): the detection's offset from it in the map frame, m.
        """
        x, y = sensor_point_to_map(prior, float(point[0]), float(point[1]), mount)
        nearest, best = None, self.config.recovery_max_distance_m ** 2
        for k, (lx, ly) in enumerate(self._landmark_xy):
            d2 = (lx - x) ** 2 + (ly - y) ** 2
            if d2 <= best:
                nearest, best = (k, x - lx, y - ly), d2
        return nearest

    def _still(self) -> bool:
        """Whether the platform is known to stand still (speed and turn rate near zero)."""
        # Without a speed or gyro message yet, it is not known to.
        return (self.stats.speed > 0 and self.rate_rad_s is not None
                and abs(self.speed_m_s) <= self._rest_speed_m_s
                and abs(self.rate_rad_s - self.ekf.bias_rad_s)
                <= self.config.rest_yaw_rate_rad_s)

    def _recovering(self, stamp_s: float) -> bool:
        """Whether no update has been applied for longer than the recovery delay."""
        last = self.stats.last_association_s
        if last is None:
            last = self._first_scan_s
        return stamp_s - last > self.config.recovery_after_s


def _stamp_look(frame: tuple, point: list[float], landmark: list[float]) -> None:
    """Give one update's pole to its scan's stamp estimate (core/stamp_jitter.py).

    e: the pole as measured less where the pose before the scan puts it (q); j: its
    velocity in the sensor frame (-u - omega x p). k = W j weighs j's radial part by the
    range variance and its tangential part by r^2 times the bearing variance (each plus
    the map's); the scan sums k.e, k.j and, for the pose's error that all its poles share,
    (dq/dpose)^T k.
    """
    (watch, c, s, sensor_x, sensor_y, ux, uy, omega, radial_var, bearing_var, map_var,
     (swing_x, swing_y), _) = frame
    px, py = point
    dx, dy = landmark[0] - sensor_x, landmark[1] - sensor_y
    qx, qy = c * dx + s * dy, c * dy - s * dx
    jx, jy = omega * py - ux, -omega * px - uy
    r2 = px * px + py * py
    # k = W j: (j.p) p / (r^2 radial_var) + (p x j) p_perp / (r^2 (r^2 bearing_var + map)).
    radial = (jx * px + jy * py) / (r2 * radial_var)
    tangential = (px * jy - py * jx) / (r2 * (r2 * bearing_var + map_var))
    kx, ky = radial * px - tangential * py, radial * py + tangential * px
    # dq/dx = (-c, s), dq/dy = (-s, -c); dq/dyaw = (qy, -qx) less R(-theta) times the swing.
    watch.add(kx * (px - qx) + ky * (py - qy), kx * jx + ky * jy,
              -c * kx + s * ky, -s * kx - c * ky,
              kx * (qy - c * swing_x - s * swing_y) + ky * (-qx + s * swing_x - c * swing_y))
