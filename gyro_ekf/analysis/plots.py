"""Figures of an offline run (matplotlib, imported lazily, Agg backend).

`write_plots` writes, into the output folder:

- `trajectory.png`: EKF path, dead reckoning with the raw gyro and with the offline bias,
  ground truth where present, the landmarks and the associated detections (map frame).
- `bias.png`: bias state with its +-2 sigma band and the offline value (deg/s).
- `errors.png` (only with ground truth): position and heading errors with +-2 sigma bands.
- `nis.png`: NIS of every update over time with the 2-dof 95 % band.
"""

from __future__ import annotations

import logging
import math
from pathlib import Path
from typing import Any

import numpy as np

from gyro_ekf.analysis import metrics
from gyro_ekf.analysis.offline import OfflineRun
from gyro_ekf.io.output_dir import staged_file
from gyro_ekf.core.types import BIAS, FloatArray

log = logging.getLogger(__name__)

_DPI = 110
_COLOURS = {'ekf': 'tab:blue', 'raw': 'tab:red', 'offline': 'tab:orange', 'truth': 'black',
            'landmark': 'tab:green', 'detection': 'tab:purple'}


def _pyplot() -> Any:
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    return plt


def _save(figure: Any, path: Path) -> Path:
    with staged_file(path) as staged:
        figure.savefig(staged, dpi=_DPI, format='png', bbox_inches='tight')
    _pyplot().close(figure)
    return path


def _decimate(count: int, limit: int = 20_000) -> slice:
    """Return a slice that keeps at most about `limit` of `count` points (plots stay light)."""
    return slice(None, None, max(1, count // limit))


def associated_detections(run: OfflineRun) -> FloatArray:
    """Map-frame positions (at the prior pose) of every MATCHED detection, shape (k, 2), m."""
    return run.result.updates.point_map_m


def plot_trajectory(run: OfflineRun, path: Path) -> Path:
    """Write the map-frame trajectory figure."""
    plt = _pyplot()
    trip = run.trip
    est = run.result.estimates
    figure, axes = plt.subplots(figsize=(8, 7))
    raw = metrics.dead_reckon(trip.imu.stamp_s, trip.imu.yaw_rate_rad_s, trip.speed.stamp_s,
                              trip.speed.speed_m_s, trip.initial_pose, 0.0)
    keep = _decimate(len(raw))
    axes.plot(raw[keep, 0], raw[keep, 1], color=_COLOURS['raw'], lw=1.0, alpha=0.8,
              label='dead reckoning, raw gyro')
    if run.calibration is not None:
        fixed = metrics.dead_reckon(trip.imu.stamp_s, trip.imu.yaw_rate_rad_s,
                                    trip.speed.stamp_s, trip.speed.speed_m_s, trip.initial_pose,
                                    float(run.calibration.bias_rad_s[2]))
        axes.plot(fixed[keep, 0], fixed[keep, 1], color=_COLOURS['offline'], lw=1.0,
                  alpha=0.8, label='dead reckoning, offline bias')
    if trip.ground_truth is not None:
        axes.plot(trip.ground_truth.pose[:, 0], trip.ground_truth.pose[:, 1],
                  color=_COLOURS['truth'], lw=2.0, alpha=0.5, label='ground truth')
    axes.plot(est.state[keep, 0], est.state[keep, 1], color=_COLOURS['ekf'], lw=1.2,
              label='EKF')
    detections = associated_detections(run)
    if len(detections):
        axes.scatter(detections[_decimate(len(detections)), 0],
                     detections[_decimate(len(detections)), 1], s=2,
                     color=_COLOURS['detection'], alpha=0.3, label='associated detections')
    if trip.landmarks is not None and len(trip.landmarks):
        axes.scatter(trip.landmarks.xy_m[:, 0], trip.landmarks.xy_m[:, 1], marker='*', s=120,
                     color=_COLOURS['landmark'], edgecolor='black', zorder=5,
                     label='landmarks (map)')
    # Keep the view on the EKF path and the map; a diverging dead reckoning may leave it.
    focus = [est.state[:, :2]]
    if trip.landmarks is not None and len(trip.landmarks):
        focus.append(trip.landmarks.xy_m)
    if trip.ground_truth is not None:
        focus.append(trip.ground_truth.pose[:, :2])
    _map_axes(axes, focus, f'{trip.name}: trajectory')
    return _save(figure, path)


def _map_axes(axes: Any, focus: list[FloatArray], title: str) -> None:
    """Limits around the focus points, equal aspect, map-frame labels, grid and legend."""
    span = np.concatenate(focus)
    low, high = np.nanmin(span, axis=0), np.nanmax(span, axis=0)
    margin = 0.1 * max(float(np.max(high - low)), 1.0)
    axes.set_xlim(low[0] - margin, high[0] + margin)
    axes.set_ylim(low[1] - margin, high[1] + margin)
    axes.set_aspect('equal', adjustable='box')
    axes.set_xlabel('x (m, map frame)')
    axes.set_ylabel('y (m, map frame)')
    axes.set_title(title)
    axes.grid(True, alpha=0.3)
    axes.legend(loc='best', fontsize='small')


def plot_live_trajectory(trip: Any, pose_xy_m: FloatArray, path: Path, title: str) -> Path:
    """Write the map-frame path the live ekf_node published, with truth and landmarks.

    Args:
        trip: the replayed Trip (ground truth and landmarks, when it has them).
        pose_xy_m: shape (n, 2), the recorded /ekf/pose positions, m.
        path: the PNG to write.
        title: figure title.
    """
    plt = _pyplot()
    figure, axes = plt.subplots(figsize=(8, 7))
    pose_xy_m = np.asarray(pose_xy_m, dtype=np.float64).reshape(-1, 2)
    focus = [pose_xy_m]
    if trip.ground_truth is not None:
        axes.plot(trip.ground_truth.pose[:, 0], trip.ground_truth.pose[:, 1],
                  color=_COLOURS['truth'], lw=2.0, alpha=0.5, label='ground truth')
        focus.append(trip.ground_truth.pose[:, :2])
    keep = _decimate(len(pose_xy_m))
    axes.plot(pose_xy_m[keep, 0], pose_xy_m[keep, 1], color=_COLOURS['ekf'], lw=1.2,
              label='ekf_node (live, recorded /ekf/pose)')
    if trip.landmarks is not None and len(trip.landmarks):
        axes.scatter(trip.landmarks.xy_m[:, 0], trip.landmarks.xy_m[:, 1], marker='*', s=120,
                     color=_COLOURS['landmark'], edgecolor='black', zorder=5,
                     label='landmarks (map)')
        focus.append(trip.landmarks.xy_m)
    _map_axes(axes, focus, title)
    return _save(figure, path)


def plot_bias(run: OfflineRun, path: Path) -> Path:
    """Write the bias-versus-time figure (deg/s)."""
    plt = _pyplot()
    est = run.result.estimates
    keep = _decimate(len(est.stamp_s))
    t = est.stamp_s[keep]
    bias = np.degrees(est.state[keep, BIAS])
    sigma = np.degrees(np.sqrt(np.maximum(est.covariance[keep, BIAS, BIAS], 0.0)))
    figure, axes = plt.subplots(figsize=(9, 4.5))
    axes.fill_between(t, bias - 2 * sigma, bias + 2 * sigma, color=_COLOURS['ekf'], alpha=0.2,
                      label='EKF +-2 sigma')
    axes.plot(t, bias, color=_COLOURS['ekf'], lw=1.2, label='EKF bias')
    if run.calibration is not None:
        axes.axhline(math.degrees(run.calibration.bias_rad_s[2]), color=_COLOURS['offline'],
                     ls='--', label='offline (static window)')
    if run.trip.true_gyro_bias_rad_s is not None:
        axes.axhline(math.degrees(run.trip.true_gyro_bias_rad_s[2]), color=_COLOURS['truth'],
                     ls=':', label='injected (true)')
    # Zoom on the converged part; the prior's +-2 sigma would flatten everything else.
    settled = bias[len(bias) // 10:] if len(bias) > 10 else bias
    centre = float(np.median(settled))
    spread = max(float(np.percentile(np.abs(settled - centre), 99)) * 3.0, 0.2)
    axes.set_ylim(centre - spread, centre + spread)
    axes.set_xlabel('time (s since bag start)')
    axes.set_ylabel('yaw-rate bias (deg/s)')
    axes.set_title(f'{run.trip.name}: gyro bias')
    axes.grid(True, alpha=0.3)
    axes.legend(loc='best', fontsize='small')
    return _save(figure, path)


def plot_errors(run: OfflineRun, path: Path) -> Path | None:
    """Write position/heading errors with +-2 sigma bands; None without ground truth."""
    truth = run.trip.ground_truth
    if truth is None:
        return None
    plt = _pyplot()
    est = run.result.estimates
    cmp = metrics.compare_with_truth(est.stamp_s, est.state, est.covariance, truth.stamp_s,
                                     truth.pose)
    keep = _decimate(len(cmp.stamp_s))
    t = cmp.stamp_s[keep]
    figure, axes = plt.subplots(3, 1, figsize=(9, 8), sharex=True)
    labels = [('x error (cm)', 100.0), ('y error (cm)', 100.0),
              ('heading error (deg)', math.degrees(1.0))]
    for k, (label, scale) in enumerate(labels):
        error = cmp.errors[keep, k] * scale
        sigma = cmp.sigmas[keep, k] * scale
        axes[k].fill_between(t, -2 * sigma, 2 * sigma, color=_COLOURS['ekf'], alpha=0.2,
                             label='+-2 sigma (EKF)')
        axes[k].plot(t, error, color=_COLOURS['ekf'], lw=1.0, label='EKF - truth')
        limit = max(float(np.percentile(np.abs(error), 99.5)) * 1.5, 1e-3)
        axes[k].set_ylim(-limit, limit)
        axes[k].set_ylabel(label)
        axes[k].grid(True, alpha=0.3)
    axes[0].legend(loc='upper right', fontsize='small')
    axes[-1].set_xlabel('time (s since bag start)')
    axes[0].set_title(f'{run.trip.name}: errors against ground truth')
    return _save(figure, path)


def plot_nis(run: OfflineRun, path: Path) -> Path:
    """Write the NIS-over-time figure with the 2-dof two-sided 95 % band."""
    plt = _pyplot()
    t, nis = run.result.updates.stamp_s, run.result.updates.nis
    figure, axes = plt.subplots(figsize=(9, 4.5))
    low, high = metrics.chi_square_band(2)
    if nis.size:
        keep = _decimate(len(nis))
        axes.scatter(t[keep], nis[keep], s=3, color=_COLOURS['ekf'], alpha=0.5,
                     label='NIS per update')
        axes.set_yscale('log')
    else:
        axes.text(0.5, 0.5, 'no landmark updates', transform=axes.transAxes, ha='center')
    axes.axhline(low, color='black', ls='--', lw=1.0, label=f'95 % band ({low:.3f}, {high:.2f})')
    axes.axhline(high, color='black', ls='--', lw=1.0)
    axes.axhline(2.0, color='grey', ls=':', lw=1.0, label='expected mean (2)')
    axes.set_xlabel('time (s since bag start)')
    axes.set_ylabel('NIS (2 dof, log scale)')
    axes.set_title(f'{run.trip.name}: normalised innovation squared')
    axes.grid(True, alpha=0.3)
    axes.legend(loc='best', fontsize='small')
    return _save(figure, path)


def write_plots(run: OfflineRun, folder: Path | str) -> list[Path]:
    """Write every figure of a run into folder; returns the files written."""
    folder = Path(folder)
    written = [plot_trajectory(run, folder / 'trajectory.png'),
               plot_bias(run, folder / 'bias.png')]
    errors = plot_errors(run, folder / 'errors.png')
    if errors is not None:
        written.append(errors)
    written.append(plot_nis(run, folder / 'nis.png'))
    return written
