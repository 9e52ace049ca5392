"""The numbers of summary.json, computed from an OfflineRun.

Definitions (see `metrics` for the band and the interpolation):

- *Offline bias*: the static-window mean per axis, its white-noise sigma, the standard
  error of the mean and the window; null with the reason when no window was accepted. An
  axis the gyro does not measure (x and y of a yaw-rate-only log; ``axes_known``) is null
  in every per-axis list, as in ``gyro-ekf calibrate --json``, never a bias of 0.
- *Online bias*: the bias state at the last estimate with its filter sigma, and the mean
  and standard deviation of the bias state over the second half of the trip's duration;
  the zero-rate updates (gyro samples applied standing still) and stops, and where the
  trip is known to start static, the bias and its sigma at the end of that stretch.
- *Association*: detected poles, how many were MATCHED (and the other outcomes), how many
  unmatched ones lay far from every mapped pole (``unmapped``), the share matched, and
  the longest time without any applied landmark update, counted from the first to the
  last estimate (so a trip that starts with no pole in view counts that stretch).
- *NIS*: of every applied update (2 dof): mean and share inside the two-sided 95 % band.
- *Health*: per LiDAR its association share, NIS mean and mean bearing innovation, when
  it was excluded, and the whiteness test of its innovations (`core/health.py`); the
  verdict ok / degraded / failed with one sentence per reason (thresholds in
  `core/health.py`), which also looks at the longest silence of the gyro and odometry.
- *Online mounts*: per LiDAR but the first, its mount estimated online
  (`core/mount_online.py`): stated, in use at the end, the last fit with its sigmas and
  residual, when it converged and how often it replaced the mount in use.
- *Online odometry*: the odometry's speed scale in use and the first LiDAR's offset in
  use, estimated online (`core/odometry_online.py`), with the start check and the last
  fit of the odometry path against the filter's positions.
- *Input*: what the validation boundary dropped (with --skip-bad): samples per stream,
  counts per field and reason with the first index, and how often a stream's time went back;
  for a bag `convert --skip-bad` wrote, the same figures of what the conversion dropped from
  the log (``dropped_when_converted``, from the bag's sidecar; indexes in the log).
- *Held start*: a start pose given exactly, held until the platform moved
  (`core/held_start.py`): whether it is still held, when and why the hold ended, and
  each LiDAR's NIS sum over its first looks at the poles from it.
- *Ground truth* (only when the trip has it): position RMSE and max error, heading RMSE
  over the estimates inside the truth's span; pose NEES mean and the shares inside, below
  and above the band of each sample's dof (the rank of its covariance: 3, or fewer where
  the filter holds part of the pose exactly; `metrics.nees_band_outcome`); bias error
  (estimate minus the known injected bias) at the end and averaged over the second half;
  settling time: the last time the bias error is outside +-0.05 deg/s.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np

from gyro_ekf.analysis import metrics
from gyro_ekf.analysis.offline import OfflineRun
from gyro_ekf.core import health
from gyro_ekf.core.calibration import measured_axes
from gyro_ekf.core.input_loss import silences
from gyro_ekf.core.types import BIAS, FloatArray
from gyro_ekf.core.validation import InputReport

BIAS_SETTLING_TOLERANCE_RAD_S = math.radians(0.05)
"""Half-width of the band the bias error must stay in to count as settled (0.05 deg/s)."""


def _deg(value: float | None) -> float | None:
    return None if value is None else math.degrees(value)


def nis_values(run: OfflineRun) -> FloatArray:
    """Return the NIS of every applied update in time order, shape (u,)."""
    return run.result.updates.nis


def association_stamps(run: OfflineRun) -> FloatArray:
    """Return the stamps of the scans with at least one applied update, shape (k,), s."""
    return np.unique(run.result.updates.stamp_s)


def summarize(run: OfflineRun, input_report: InputReport | None = None) -> dict[str, Any]:
    """Compute the summary.json numbers as a JSON-ready dict (SI, plus deg/s for biases).

    Args:
        run: the offline run.
        input_report: what the validation boundary dropped from the trip; the `input`
            section is null without it.
    """
    estimates = run.result.estimates
    stamps = estimates.stamp_s
    trip = run.trip
    bias = estimates.state[:, BIAS]
    bias_sigma = np.sqrt(np.maximum(estimates.covariance[:, BIAS, BIAS], 0.0))
    start, end = (float(stamps[0]), float(stamps[-1])) if stamps.size else (0.0, 0.0)
    last_half = stamps >= start + 0.5 * (end - start)

    summary: dict[str, Any] = {
        'trip': {'name': trip.name, 'duration_s': end - start, 'estimates': int(stamps.size),
                 'imu_samples': len(trip.imu.stamp_s), 'speed_samples': len(trip.speed.stamp_s),
                 'scans': {s.topic: len(s.stamp_s) for s in trip.scans},
                 'landmarks': 0 if trip.landmarks is None else len(trip.landmarks),
                 'has_ground_truth': trip.ground_truth is not None},
        'config': {'ekf': dataclasses.asdict(run.config), 'sources': run.config_sources},
    }

    cal = run.calibration
    known = trip.imu.axes_known
    summary['offline_bias'] = None if cal is None else {
        'axes_known': list(known),
        'bias_rad_s': measured_axes(cal.bias_rad_s, known),
        'bias_deg_s': measured_axes(np.degrees(cal.bias_rad_s), known),
        'sigma_rad_s': measured_axes(cal.sigma_rad_s, known),
        'standard_error_rad_s': measured_axes(cal.bias_standard_error_rad_s, known),
        'standard_error_deg_s': measured_axes(np.degrees(cal.bias_standard_error_rad_s), known),
        'window_start_s': cal.window_start_s, 'window_end_s': cal.window_end_s,
        'n_samples': cal.n_samples}
    summary['offline_bias_unavailable_reason'] = run.calibration_error

    final = float(bias[-1]) if bias.size else math.nan
    half_mean = float(bias[last_half].mean()) if last_half.any() else math.nan
    half_std = float(bias[last_half].std()) if last_half.any() else math.nan
    summary['online_bias'] = {
        'final_rad_s': final, 'final_deg_s': _deg(final),
        'final_sigma_rad_s': float(bias_sigma[-1]) if bias.size else math.nan,
        'final_sigma_deg_s': _deg(float(bias_sigma[-1])) if bias.size else math.nan,
        'last_half_mean_rad_s': half_mean, 'last_half_mean_deg_s': _deg(half_mean),
        'last_half_std_rad_s': half_std, 'last_half_std_deg_s': _deg(half_std),
        'last_half_mean_sigma_rad_s': float(bias_sigma[last_half].mean())
        if last_half.any() else math.nan,
        'zero_rate_updates': int(run.result.stats.zero_rate_updates),
        'stops': int(run.result.stats.stops),
        'reopened': int(run.result.stats.bias_openings),
        'largest_reopening_deg_s': _deg(float(run.result.stats.bias_largest_opening_rad_s)),
        'reopened_wander_held': int(run.result.stats.bias_wander_held),
        'gyro_noise_scale': float(run.result.stats.gyro_noise_scale),
        'gyro_noise_scale_max': float(run.result.stats.gyro_noise_scale_max),
        # The gyro's spread standing still, where it lay beyond chance above the stated
        # noise (events.EventDriver._judge_stop_noise; 0 and 1: none did).
        'gyro_rest_noise_deg_s': _deg(float(run.result.stats.gyro_rest_noise_rad_s)),
        'gyro_rest_noise_scale': float(run.result.stats.gyro_rest_noise_scale),
        # The gyro's wander found in the data and modelled (core/gyro_wander.py): its
        # stationary sigma (0: none found) and when it was first found (null: never).
        'gyro_wander_deg_s': _deg(float(run.result.stats.gyro_wander_rad_s)),
        'gyro_wander_found_s': run.result.stats.gyro_wander_found_s,
        # The wander assumed from the start (gyro_wander_prior_rad_s, 0 without
        # learn_gyro_wander) and when the blocks ruled it out (null: never).
        'gyro_wander_prior_deg_s': _deg(run.config.wander_prior_rad_s),
        'gyro_wander_prior_ruled_out_s': run.result.stats.gyro_wander_prior_ruled_out_s,
        # The largest wander a still stop's gyro samples showed (core/stop_wander.py),
        # modelled as a prior from that stop's end (s) until the blocks ruled it out.
        'gyro_wander_stop_deg_s': _deg(float(run.result.stats.gyro_wander_stop_rad_s)),
        'gyro_wander_stop_s': run.result.stats.gyro_wander_stop_s,
        'gyro_wander_stop_ruled_out_s': run.result.stats.gyro_wander_stop_ruled_out_s,
        # A ramping bias followed (core/bias_rate.py): the rate in use at the end, the
        # largest used, and how often one came into use.
        'rate_deg_s_per_min': _deg(float(run.result.stats.bias_rate_rad_s2)) * 60.0,
        'largest_rate_deg_s_per_min': _deg(
            float(run.result.stats.bias_largest_rate_rad_s2)) * 60.0,
        'rate_found': int(run.result.stats.bias_rate_found)}
    # Where the trip is known to start static, the bias the zero-rate updates learned there.
    static_end = trip.start_s + trip.static_duration_s
    at_static_end = int(np.searchsorted(stamps, static_end, side='right')) - 1
    if trip.static_duration_s > 0.0 and at_static_end >= 0:
        summary['online_bias'].update({
            'static_start_end_s': float(stamps[at_static_end]),
            'at_static_start_end_deg_s': _deg(float(bias[at_static_end])),
            'at_static_start_end_sigma_deg_s': _deg(float(bias_sigma[at_static_end]))})
    if cal is not None:
        summary['online_bias']['last_half_mean_minus_offline_deg_s'] = _deg(
            half_mean - float(cal.bias_rad_s[2]))

    stats = run.result.stats
    detections = int(stats.detections)
    matched = int(stats.outcomes.get('matched', 0))
    updated = association_stamps(run)
    gap, gap_start = metrics.longest_gap(updated, start, end)
    # From the first update to the end: the time in gaps the verdict calls dead-reckoned.
    tracked = float(end - updated[0]) if updated.size else 0.0
    dead = sum(health.dead_reckoned(float(g)) for g in np.diff(np.append(updated, end)))
    summary['association'] = {
        'detections': detections, 'outcomes': dict(stats.outcomes),
        'unmapped': int(stats.unmapped),
        'share_associated': matched / detections if detections else math.nan,
        'longest_gap_s': gap, 'longest_gap_start_s': gap_start,
        'dead_reckoned_s': float(dead), 'since_first_update_s': tracked,
        # Scans associated by map distance: after a gap, or with the gate starving the
        # filter (core/gate_starved.py; the verdict says the latter).
        'recoveries': int(stats.recoveries), 'gate_starved': int(stats.gate_starved)}

    nis = nis_values(run)
    nis_band = metrics.chi_square_band(2)
    summary['nis'] = {
        'updates': int(nis.size), 'mean': float(nis.mean()) if nis.size else math.nan,
        'dof': 2, 'band': nis_band, 'share_in_band': metrics.share_inside(nis, *nis_band)}

    summary['input'] = None if input_report is None else input_report.to_dict()
    summary['health'] = _health(run, summary, start, end)
    mounts = run.result.mounts
    summary['online_mounts'] = {} if mounts is None else {
        tracker['name']: tracker for tracker in mounts.report()}
    odometry = run.result.odometry
    summary['online_odometry'] = None if odometry is None else odometry.report()
    summary['online_noise'] = {lidar['name']: lidar for lidar in run.result.noise or ()}
    summary['held_start'] = run.result.held_start
    summary['gyro_scale'] = run.result.gyro_scale
    # Samples each input's stamps say were sent and did not arrive (core/input_loss.py).
    summary['input_loss'] = run.result.input_loss
    # Likewise each LiDAR's scans (offline every scan of the bag arrives; live, the
    # landmarks a node behind lost).
    summary['scan_loss'] = run.result.scan_loss or {}
    # Lone samples far from both neighbours, left out (core/input_spikes.py).
    summary['input_spikes'] = run.result.input_spikes
    # A gyro repeating one value, its repeats left out (core/input_frozen.py).
    summary['gyro_frozen'] = run.result.gyro_frozen
    # The odometry's own sample-to-sample spread, taken as its noise where it was well
    # beyond the stated one (EkfConfig.learn_speed_noise; 0: never).
    stats = run.result.stats
    summary['speed_noise'] = {'widened_samples': int(stats.speed_noise_widened),
                              'measured_m_s': float(stats.speed_noise_m_s),
                              'stated_m_s': float(stats.speed_noise_stated_m_s)}
    # Each LiDAR's stamps against the gyro's, from its own headings (core/time_offset.py).
    summary['time_offsets'] = {lidar['name']: lidar for lidar in run.result.time_offsets or ()}
    # Each LiDAR's stamps' scatter about when its scans were taken (core/stamp_jitter.py).
    summary['stamp_jitter'] = {lidar['name']: lidar for lidar in run.result.stamp_jitter or ()}
    # Mapped poles whose detections lie elsewhere, and where (core/map_poles.py).
    summary['map_poles_elsewhere'] = run.result.map_poles or []
    # Whether each LiDAR's scans turn the way the gyro does (core/turn_sign.py).
    summary['turn_signs'] = {lidar['name']: lidar for lidar in run.result.turn_signs or ()}
    # Stops the odometry called still while a LiDAR's poles turned (core/rest_turn.py).
    summary['rest_turns'] = run.result.rest_turns or []
    summary['ground_truth'] = None
    if trip.ground_truth is not None:
        summary['ground_truth'] = _truth_summary(run, last_half)
    return summary


def _health(run: OfflineRun, summary: dict[str, Any], start: float, end: float
            ) -> dict[str, Any]:
    """Return the verdict with its reasons, and the per-LiDAR figures."""
    stamps = association_stamps(run)
    if stamps.size:
        # The stretch before the first update is judged on its own (2023 starts 10 s
        # with no pole in view); after it, every gap and the stretch to the end count.
        start_gap = float(stamps[0]) - start
        longest = float(np.max(np.diff(np.append(stamps, end)), initial=0.0))
    else:
        start_gap, longest = end - start, 0.0
    monitor = run.result.health
    sensors = [] if monitor is None else monitor.report()
    section = summary['input']
    dropped = {} if section is None else health.samples_dropped_figures(
        section['samples_dropped'])
    converted = None if section is None else section.get('dropped_when_converted')
    dropped_when_converted = {} if converted is None else health.samples_dropped_figures(
        converted['samples_dropped'])
    stats = run.result.stats
    figures = health.RunFigures(
        # Excluded LiDARs' detections have their own reason, not the share's.
        detections=int(stats.detections - stats.excluded), excluded=int(stats.excluded),
        matched=int(stats.outcomes.get('matched', 0)),
        updates=int(stats.updates), nis_mean=summary['nis']['mean'],
        longest_gap_s=longest, start_gap_s=start_gap, sensors=sensors, dropped=dropped,
        dead_reckoned_s=summary['association']['dead_reckoned_s'],
        since_first_update_s=summary['association']['since_first_update_s'],
        dropped_when_converted=dropped_when_converted,
        converted_from='' if converted is None else converted['source'],
        final_bias_rad_s=summary['online_bias']['final_rad_s'],
        unmapped=int(stats.unmapped), scans=int(stats.scans), finished=True,
        # The driver's counters to the trip's last stamp, as the EKF node's verdict has
        # them to its newest one (core/input_loss.py).
        input_gaps_s=silences(run.result.input_loss or {}, run.trip.end_s),
        input_late_s={name: float(series.stamp_s[0]) - run.trip.start_s for name, series in (
            ('gyro', run.trip.imu), ('odometry', run.trip.speed)) if len(series.stamp_s)},
        input_gap_limit_s=run.config.max_prediction_step_s,
        bias_openings=int(stats.bias_openings), gate_starved=int(stats.gate_starved),
        bias_largest_opening_rad_s=float(stats.bias_largest_opening_rad_s),
        bias_wander_held=int(stats.bias_wander_held),
        bias_largest_rate_rad_s2=float(stats.bias_largest_rate_rad_s2),
        gyro_noise_scale_max=float(stats.gyro_noise_scale_max),
        gyro_rest_noise_scale=float(stats.gyro_rest_noise_scale),
        gyro_rest_noise_rad_s=float(stats.gyro_rest_noise_rad_s),
        speed_noise_m_s=float(stats.speed_noise_m_s),
        speed_noise_stated_m_s=float(stats.speed_noise_stated_m_s),
        gyro_wander_rad_s=float(stats.gyro_wander_rad_s),
        gyro_wander_found_s=stats.gyro_wander_found_s,
        gyro_wander_stated_rad_s=run.config.gyro_wander_rad_s,
        gyro_wander_tau_s=run.config.gyro_wander_tau_s,
        mounts=[] if run.result.mounts is None else run.result.mounts.report(),
        odometry=None if run.result.odometry is None else run.result.odometry.report(),
        gyro_scale=run.result.gyro_scale, input_loss=run.result.input_loss or {},
        scan_loss=run.result.scan_loss or {},
        input_spikes=run.result.input_spikes or {},
        gyro_frozen=run.result.gyro_frozen,
        time_offsets=run.result.time_offsets or [],
        stamp_jitter=run.result.stamp_jitter or [],
        map_poles=run.result.map_poles or [],
        turn_signs=run.result.turn_signs or [],
        rest_turns=run.result.rest_turns or [],
        final_bias_sigma_rad_s=summary['online_bias']['final_sigma_rad_s'],
        start_bias=stats.first_stop)
    return {**health.verdict(figures), 'lidars': sensors,
            'transitions': [] if monitor is None else [
                {'stamp_s': t.stamp_s, 'lidar': t.sensor, 'change': t.change,
                 'reason': t.reason} for t in monitor.transitions]}


def _share(flags: np.ndarray) -> float:
    """Share of True among flags (nan when there are none)."""
    return float(np.mean(flags)) if flags.size else math.nan


def _truth_summary(run: OfflineRun, last_half: np.ndarray) -> dict[str, Any]:
    estimates = run.result.estimates
    truth = run.trip.ground_truth
    assert truth is not None
    comparison = metrics.compare_with_truth(estimates.stamp_s, estimates.state,
                                            estimates.covariance, truth.stamp_s, truth.pose)
    band = metrics.chi_square_band(3)
    inside, below, above = metrics.nees_band_outcome(comparison.nees, comparison.dof)
    updates = run.result.updates.stamp_s
    first_update = float(updates[0]) if updates.size else math.inf
    position = comparison.position_error_m
    out: dict[str, Any] = {
        'samples': int(comparison.stamp_s.size),
        'position_rmse_m': metrics.rmse(comparison.errors[:, :2]),
        'position_max_error_m': float(position.max()) if position.size else math.nan,
        'heading_rmse_rad': metrics.rmse(comparison.errors[:, 2]),
        'heading_rmse_deg': _deg(metrics.rmse(comparison.errors[:, 2])),
        # Each sample is judged in the band of its covariance's rank (3, unless the
        # filter holds part of the pose exactly: a held start pose); nees_band is 3 dof's.
        'nees_dof': 3, 'nees_band': band,
        'nees_samples_by_dof': {str(d): int(np.sum(comparison.dof == d)) for d in range(4)},
        'nees_mean': float(np.mean(comparison.nees)) if comparison.nees.size else math.nan,
        'nees_share_in_band': _share(inside),
        # Before any landmark is seen only the priors speak; this share leaves that out.
        'nees_share_in_band_after_first_update': _share(
            inside[comparison.stamp_s >= first_update]),
        'nees_share_below_band': _share(below),
        'nees_share_above_band': _share(above),
    }
    true_bias = run.trip.true_gyro_bias_rad_s
    if true_bias is not None:
        error = estimates.state[:, BIAS] - float(true_bias[2])
        settled = metrics.settling_time(estimates.stamp_s, error, BIAS_SETTLING_TOLERANCE_RAD_S)
        out.update({
            'true_bias_rad_s': float(true_bias[2]),
            'bias_error_final_rad_s': float(error[-1]),
            'bias_error_final_deg_s': _deg(float(error[-1])),
            'bias_error_last_half_mean_deg_s': _deg(float(error[last_half].mean())),
            'bias_settling_tolerance_deg_s': math.degrees(BIAS_SETTLING_TOLERANCE_RAD_S),
            'bias_settling_time_s': settled})
    return out
