"""Offline LiDAR mount calibration against the map, given a reference trajectory.

A LiDAR whose stated mount is wrong puts every detection in the wrong place on the map.
With the platform's path known from another source (the EKF run on the first LiDAR alone),
the mount that lays that LiDAR's detections onto the map poles is found by robust least
squares. A detection d (sensor frame) seen at platform pose (x, y, phi) with mount
(a, mx, my) lies at

    p = (x, y) + R(phi) (m + R(a) d)

and its residual is p minus the nearest map pole. The fit:

1. **Coarse yaw search** over the stated yaw +-``search_rad`` with the stated x, y: the yaw
   whose detections fall closest to poles (a truncated quadratic, so detections of
   reflectors that are not in the map or the other half of a wrong association do not
   decide) wins. Gauss-Newton alone would lock onto the wrong pole for errors of a few
   degrees, where detections sit tens of centimetres off.
2. **Gauss-Newton** on (a, mx, my, e) with Huber weights, re-associating each detection to
   its nearest pole every iteration; detections farther than ``gate_m`` from every pole are
   left out. e is the LiDAR's range offset: each detection is taken e nearer along its ray
   (d (1 - e / |d|)), since a LiDAR that reads long moves every return of a pole along its
   beam; poles seen at many bearings tell it from an offset of the mount (a LiDAR 3 cm long
   fitted without it moved the mount 2 cm instead). Where e is not observable (sigma above
   ``max_offset_sigma_m``) the fit keeps e = 0; where the x, y offset is not either (e.g. few
   poles seen from one side), the stated x, y too, and solves the yaw alone. A range offset
   is proposed only beyond ``min_range_offset_m`` and 3 of its sigmas.

Sigmas are from the normal equations scaled by the weighted residual variance. Detections
of successive scans share the reference trajectory's errors, so they are not independent:
the sigmas are a lower bound, good for comparing mounts, not for a chi-square test. On
the 2023 course log, whose mounts are exact, the fit lands 0.048 deg and 4 mm off them (the
reference path's own heading errors; against the true path it lands within 0.005 deg),
ten times its sigma, and such a change costs the filter's consistency (NEES share 0.914 ->
0.859). So a fit is only proposed in place of the stated mount when it lays the detections
clearly closer to the poles (``min_improvement``); a mount off by 0.15 deg or more is.
"""

from __future__ import annotations

from dataclasses import dataclass
import math

import numpy as np

from gyro_ekf.core.angles import wrap_scalar
from gyro_ekf.core.config import DetectorConfig
from gyro_ekf.core.detection import detect_poles_in_scans
from gyro_ekf.core.errors import CoreError
from gyro_ekf.core.types import FloatArray, LidarMount, ScanSeries, Trip

MIN_DETECTIONS = 20
"""Fewest matched detections a mount is estimated from."""
MIN_FIT_SHARE = 0.5
"""Least share of a LiDAR's detections the fitted mount must lay on map poles.

A LiDAR beyond the yaw search (30 deg off with a search of +-15) has no mount in reach that
lays its poles on the map: the best candidate lays a few per cent of them there, by
chance, with a sigma of a tenth of a degree, and was written as if it were right (185.2 deg
for a LiDAR at 210, 'upside down', 102 of 2958 detections). Right mounts lay most of them
(the course logs and simulated trips: the ones left out are reflectors the map lacks)."""


@dataclass(frozen=True, slots=True)
class MountSettings:
    """How the fit searches and weighs.

    Attributes:
        search_rad: half width of the coarse yaw search around the stated yaw, rad.
        search_step_rad: step of the coarse search, rad.
        coarse_gate_m: residuals beyond this count as this in the coarse search, m.
        gate_m: detections farther than this from every pole are left out of the fit, m.
        huber_m: Huber threshold on the residual norm, m.
        max_offset_sigma_m: above this sigma the x, y offset (or the range offset) is
            called unobservable, m.
        min_range_offset_m: a fitted range offset nearer 0 than this is taken as 0, m (the
            verdict's 0.5 cm: a quarter of the configured range noise, health.py).
        iterations: most Gauss-Newton iterations.
        rest_distance_m, rest_yaw_rad: a scan is used only when the reference pose moved
            this far or turned this much since the last scan used (a stop counts once).
        min_improvement: the fit replaces the stated mount only when the stated mount's RMS
            residual exceeds the fit's by more than this share (0: always).
    """

    search_rad: float = math.radians(15.0)
    search_step_rad: float = math.radians(0.25)
    coarse_gate_m: float = 0.5
    gate_m: float = 0.25
    huber_m: float = 0.02
    max_offset_sigma_m: float = 0.02
    min_range_offset_m: float = 0.005
    iterations: int = 30
    rest_distance_m: float = 0.05
    rest_yaw_rad: float = math.radians(1.0)
    min_improvement: float = 0.1


@dataclass(frozen=True, slots=True)
class MountEstimate:
    """A LiDAR's estimated mount.

    Attributes:
        topic: scan topic (no slash).
        frame_id: the sensor's TF frame.
        stated: the mount the log states.
        mount: the estimated mount (x, y as stated when not offset_observable).
        sigma: 1-sigma of yaw (rad), x (m) and y (m); x, y are NaN when not estimated.
        offset_observable: whether x, y were estimated.
        range_offset_m: how much its ranges read long, m (0 when not estimated or not
            clearly off 0: see MountSettings.min_range_offset_m).
        range_offset_sigma_m: its 1-sigma, m (NaN when not estimated).
        upside_down: its detections lie on the map mirrored (half a turn about its x axis):
            mount and range offset are those of the LiDAR so taken.
        rms_residual_m: RMS distance of the used detections to their poles, m.
        rms_residual_stated_m: the same under the stated mount (same gate), m.
        detections: detections used in the final fit.
        detections_total: detections of this LiDAR in the scans used (where the reference
            is defined and the platform moved, see MountSettings.rest_distance_m).
        significant: whether the fit explains the detections clearly better than the
            stated mount (see MountSettings.min_improvement); else the stated one stays.
    """

    topic: str
    frame_id: str
    stated: LidarMount
    mount: LidarMount
    sigma: tuple[float, float, float]
    offset_observable: bool
    rms_residual_m: float
    rms_residual_stated_m: float
    detections: int
    detections_total: int
    significant: bool = True
    range_offset_m: float = 0.0
    range_offset_sigma_m: float = math.nan
    upside_down: bool = False

    @property
    def proposed(self) -> LidarMount:
        """The mount to use: the fit when significant, else the stated one."""
        return self.mount if self.significant else self.stated

    @property
    def yaw_error_rad(self) -> float:
        """Estimated minus stated yaw, rad, in [-pi, pi)."""
        return wrap_scalar(self.mount.yaw_rad - self.stated.yaw_rad)


@dataclass(frozen=True, slots=True)
class _Detections:
    """One LiDAR's detections with the reference pose at their scan."""

    points: FloatArray       # (n, 2) sensor frame, m
    pose: FloatArray         # (n, 3) platform pose, m, m, rad

    @property
    def ranges(self) -> FloatArray:
        """Range of each detection, (n,), m."""
        return np.hypot(self.points[:, 0], self.points[:, 1])


def _reference_pose(stamp_s: FloatArray, ref_stamp_s: FloatArray, ref_pose: FloatArray
                    ) -> FloatArray:
    """Interpolate the reference pose at stamp_s (inside the reference's span), linearly."""
    yaw = np.unwrap(ref_pose[:, 2])
    return np.column_stack([np.interp(stamp_s, ref_stamp_s, ref_pose[:, 0]),
                            np.interp(stamp_s, ref_stamp_s, ref_pose[:, 1]),
                            np.interp(stamp_s, ref_stamp_s, yaw)])


def _moved_scans(pose: FloatArray, settings: MountSettings) -> FloatArray:
    """Select the scans taken after the platform moved since the last one selected.

    Standing still, every scan sees the same poles from the same pose with the same errors
    (the same beams hit them): an 8 s stop at 10 Hz would outweigh a minute of driving and
    pull the yaw 0.02-0.05 deg towards that one view. Returns the selected indices.
    """
    keep = []
    last = None
    for row, (x, y, yaw) in enumerate(pose):
        if (last is None or math.hypot(x - last[0], y - last[1]) >= settings.rest_distance_m
                or abs(yaw - last[2]) >= settings.rest_yaw_rad):
            keep.append(row)
            last = (x, y, yaw)
    return np.array(keep, dtype=np.int64)


def _detections(scans: ScanSeries, ref_stamp_s: FloatArray, ref_pose: FloatArray,
                detector: DetectorConfig | None, settings: MountSettings) -> _Detections:
    inside = np.flatnonzero((scans.stamp_s >= ref_stamp_s[0])
                            & (scans.stamp_s <= ref_stamp_s[-1]))
    index = inside[_moved_scans(_reference_pose(scans.stamp_s[inside], ref_stamp_s, ref_pose),
                                settings)] if len(inside) else inside
    points: list[FloatArray] = []
    stamps: list[FloatArray] = []
    block = 512
    for first in range(0, len(index), block):
        rows = index[first:first + block]
        found = detect_poles_in_scans(
            scans.ranges_m[rows], scans.angles_rad,
            None if scans.intensities is None else scans.intensities[rows], detector)
        for row, detections in zip(rows, found):
            if len(detections.points_sensor_m):
                points.append(detections.points_sensor_m)
                stamps.append(np.full(len(detections.points_sensor_m), scans.stamp_s[row]))
    if not points:
        return _Detections(np.zeros((0, 2)), np.zeros((0, 3)))
    stamp = np.concatenate(stamps)
    return _Detections(np.concatenate(points), _reference_pose(stamp, ref_stamp_s, ref_pose))


def _to_map(found: _Detections, yaw: float, x: float, y: float, offset: float = 0.0
            ) -> FloatArray:
    """Put the detections in the map frame under mount (yaw, x, y), shape (n, 2).

    offset: the LiDAR's range offset, m (each detection taken that much nearer on its ray).
    """
    phi = found.pose[:, 2]
    c, s = np.cos(phi), np.sin(phi)
    ca, sa = math.cos(yaw), math.sin(yaw)
    points = found.points * (1.0 - offset / found.ranges)[:, None] if offset else found.points
    px = x + ca * points[:, 0] - sa * points[:, 1]
    py = y + sa * points[:, 0] + ca * points[:, 1]
    return np.column_stack([found.pose[:, 0] + c * px - s * py,
                            found.pose[:, 1] + s * px + c * py])


def _nearest(points: FloatArray, poles: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Residual to the nearest pole (n, 2) and its norm (n,)."""
    # (n, k) distances: a trip has thousands of detections and tens of poles.
    diff = points[:, None, :] - poles[None, :, :]
    nearest = np.argmin(np.einsum('nkj,nkj->nk', diff, diff), axis=1)
    residual = points - poles[nearest]
    return residual, np.hypot(residual[:, 0], residual[:, 1])


def _coarse_yaw(found: _Detections, poles: FloatArray, stated: LidarMount,
                settings: MountSettings) -> float:
    steps = int(round(settings.search_rad / settings.search_step_rad))
    candidates = stated.yaw_rad + settings.search_step_rad * np.arange(-steps, steps + 1)
    costs = [np.minimum(_nearest(_to_map(found, yaw, stated.x_m, stated.y_m), poles)[1],
                        settings.coarse_gate_m) ** 2 for yaw in candidates]
    totals = np.array([cost.sum() for cost in costs])
    return float(candidates[int(np.argmin(totals))])


def _jacobian(found: _Detections, yaw: float, offset: float = 0.0) -> FloatArray:
    """d(map point)/d(yaw, x, y, range offset), shape (n, 2, 4)."""
    phi = found.pose[:, 2]
    heading = phi + yaw
    c, s = np.cos(heading), np.sin(heading)
    ux, uy = found.points[:, 0] / found.ranges, found.points[:, 1] / found.ranges
    px, py = found.points[:, 0] - offset * ux, found.points[:, 1] - offset * uy
    jac = np.empty((len(phi), 2, 4))
    # d/d offset: the point moves back along its ray, R(phi + yaw) (-u).
    jac[:, 0, 3] = -(c * ux - s * uy)
    jac[:, 1, 3] = -(s * ux + c * uy)
    # d/d yaw of R(phi) R(yaw) d = R(phi + yaw) [-dy, dx].
    jac[:, 0, 0] = -c * py - s * px
    jac[:, 1, 0] = -s * py + c * px
    jac[:, 0, 1], jac[:, 1, 1] = np.cos(phi), np.sin(phi)
    jac[:, 0, 2], jac[:, 1, 2] = -np.sin(phi), np.cos(phi)
    return jac


def _offset(theta: FloatArray) -> float:
    """Return the range offset of a parameter vector (yaw, x, y[, offset]), m."""
    return float(theta[3]) if len(theta) > 3 else 0.0


def _gauss_newton(found: _Detections, poles: FloatArray, start: FloatArray,
                  free: list[int], settings: MountSettings
                  ) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Robust fit of the `free` parameters of (yaw, x, y[, range offset]) from `start`.

    Returns the parameters, their covariance (NaN where not free; as many rows as `start`
    has parameters: without a range offset, it is 0) and the mask of detections inside the
    gate at the end.
    """
    theta = start.copy()
    used = np.zeros(len(found.points), dtype=bool)
    for _ in range(settings.iterations):
        residual, distance = _nearest(_to_map(found, *theta), poles)
        used = distance <= settings.gate_m
        if used.sum() < MIN_DETECTIONS:
            break
        jac = _jacobian(found, theta[0], _offset(theta))[used][:, :, free]
        weight = np.minimum(1.0, settings.huber_m / np.maximum(distance[used], 1e-12))
        normal = np.einsum('n,nij,nik->jk', weight, jac, jac)
        gradient = np.einsum('n,nij,ni->j', weight, jac, residual[used])
        step = -np.linalg.solve(normal, gradient)
        theta[free] += step
        if np.max(np.abs(step)) < 1e-9:
            break
    residual, distance = _nearest(_to_map(found, *theta), poles)
    used = distance <= settings.gate_m
    covariance = np.full((len(theta), len(theta)), math.nan)
    count = int(used.sum())
    if count > len(free):
        jac = _jacobian(found, theta[0], _offset(theta))[used][:, :, free]
        weight = np.minimum(1.0, settings.huber_m / np.maximum(distance[used], 1e-12))
        normal = np.einsum('n,nij,nik->jk', weight, jac, jac)
        variance = float(np.sum(weight * distance[used] ** 2)) / (2 * count - len(free))
        try:
            covariance[np.ix_(free, free)] = variance * np.linalg.inv(normal)
        except np.linalg.LinAlgError:
            pass
    return theta, covariance, used


def calibrate_mount(scans: ScanSeries, landmarks_xy_m: FloatArray, ref_stamp_s: FloatArray,
                    ref_pose: FloatArray, detector: DetectorConfig | None = None,
                    settings: MountSettings | None = None, source: str = 'trip'
                    ) -> MountEstimate:
    """Estimate one LiDAR's mount from its detections against the map.

    Args:
        scans: the LiDAR's scans; its mount is the stated one the search starts from.
        landmarks_xy_m: map pole centres, shape (k, 2), m.
        ref_stamp_s: reference trajectory stamps, shape (n,), s, increasing.
        ref_pose: reference platform poses, shape (n, 3): x m, y m, yaw rad.
        detector: pole detector settings (as the run uses); defaults when None.
        settings: the fit's settings; defaults when None.
        source: the bag or trip named in errors.

    Raises:
        CoreError: no map, no reference, no scans, or too few detections near poles.
    """
    settings = settings or MountSettings()
    poles = np.asarray(landmarks_xy_m, dtype=np.float64).reshape(-1, 2)
    where = f"{source}: topic '{scans.topic}'"
    if not len(poles):
        raise CoreError(f'{source}: no landmark map: a mount is calibrated against the map')
    if len(scans.stamp_s) == 0:
        raise CoreError(f'{where}: no scans to calibrate the mount from')
    ref_stamp_s = np.asarray(ref_stamp_s, dtype=np.float64)
    ref_pose = np.asarray(ref_pose, dtype=np.float64)
    if len(ref_stamp_s) < 2 or ref_pose.shape != (len(ref_stamp_s), 3):
        raise CoreError(f'{where}: the reference trajectory needs at least 2 poses (n, 3)')
    found = _detections(scans, ref_stamp_s, ref_pose, detector, settings)
    if len(found.points) < MIN_DETECTIONS:
        raise CoreError(f'{where}: only {len(found.points)} pole detections; at least '
                        f'{MIN_DETECTIONS} are needed to calibrate the mount')
    stated = scans.mount
    theta, covariance, used, xy_observable = _fit(found, poles, stated, settings)
    # Upside down (half a turn about x), a LiDAR's poles are its upright twin's mirrored:
    # no mount lays them on the map, and the fit that lays the most (a few per cent of
    # them, at a yaw and offset off by degrees and decimetres) would be written as if it
    # did. Both ways up are fitted; the one that lays more detections on poles is the
    # LiDAR's.
    raw = found
    flipped = _Detections(raw.points * np.array([1.0, -1.0]), raw.pose)
    fit_flipped = _fit(flipped, poles, stated, settings)
    upside_down = bool(fit_flipped[2].sum() > used.sum())
    if upside_down:
        found = flipped
        theta, covariance, used, xy_observable = fit_flipped
    count = int(used.sum())
    if count < MIN_DETECTIONS:
        raise CoreError(f'{where}: only {count} of {len(found.points)} detections lie within '
                        f'{settings.gate_m:g} m of a map pole under any mount within '
                        f'+-{math.degrees(settings.search_rad):g} deg; at least '
                        f'{MIN_DETECTIONS} are needed (is the map or the reference right?)')
    if count < MIN_FIT_SHARE * len(found.points):
        way = ', upside down' if upside_down else ''
        raise CoreError(f'{where}: no mount within +-{math.degrees(settings.search_rad):g} '
                        f'deg of the stated yaw lays its poles on the map: the best '
                        f'({math.degrees(float(theta[0])):.1f} deg{way}) lays only {count} of '
                        f'{len(found.points)} detections ({count / len(found.points):.0%}) '
                        f'within {settings.gate_m:g} m of a map pole, under '
                        f'{MIN_FIT_SHARE:.0%}; nothing is written for it (state its yaw '
                        f'to within {math.degrees(settings.search_rad):g} deg, or check the '
                        f'map and the first LiDAR)')
    # A range offset within its noise is no offset: the fit of an exact LiDAR lands a few
    # millimetres off 0, and moving its poles by that costs more than it gains.
    range_sigma = float(np.sqrt(abs(covariance[3, 3])))
    if not (abs(theta[3]) > max(settings.min_range_offset_m, 3.0 * range_sigma)):
        theta[3] = 0.0
    distance = _nearest(_to_map(found, *theta), poles)[1][used]
    as_stated = flipped if scans.upside_down else raw
    stated_distance = _nearest(_to_map(as_stated, stated.yaw_rad, stated.x_m, stated.y_m),
                               poles)[1]
    stated_used = stated_distance[stated_distance <= settings.gate_m]
    # Kept next to the stated yaw (185 deg, not -175 deg), as a person compares them.
    yaw = stated.yaw_rad + wrap_scalar(float(theta[0]) - stated.yaw_rad)
    sigma = np.sqrt(np.abs(np.diag(covariance)[:3]))
    rms = float(np.sqrt(np.mean(distance ** 2)))
    rms_stated = float(np.sqrt(np.mean(stated_used ** 2))) if len(stated_used) else math.nan
    # A stated mount that lays fewer detections inside the gate also counts as worse, and
    # a LiDAR found upside down differs from one stated upright whatever its mount.
    significant = bool(not len(stated_used) or len(stated_used) < 0.95 * count
                       or rms_stated > (1.0 + settings.min_improvement) * rms
                       or upside_down != scans.upside_down)
    return MountEstimate(
        topic=scans.topic, frame_id=scans.frame_id, stated=stated,
        mount=LidarMount(float(theta[1]), float(theta[2]), yaw),
        sigma=(float(sigma[0]), float(sigma[1]), float(sigma[2])),
        offset_observable=xy_observable,
        rms_residual_m=rms, rms_residual_stated_m=rms_stated,
        detections=count, detections_total=len(found.points), significant=significant,
        range_offset_m=float(theta[3]), range_offset_sigma_m=range_sigma,
        upside_down=upside_down)


def _fit(found: _Detections, poles: FloatArray, stated: LidarMount, settings: MountSettings
         ) -> tuple[FloatArray, FloatArray, FloatArray, bool]:
    """Fit (yaw, x, y, range offset) from the coarse yaw search: what is observable.

    Returns the parameters, their covariance, the detections used and whether x, y were
    fitted.
    """
    start = np.array([_coarse_yaw(found, poles, stated, settings), stated.x_m, stated.y_m,
                      0.0])

    def observable(covariance: FloatArray, used: FloatArray, axes: list[int]) -> bool:
        sigmas = np.sqrt(np.abs(np.diag(covariance)[axes]))
        return bool(used.sum() >= MIN_DETECTIONS and np.all(np.isfinite(sigmas))
                    and np.all(sigmas <= settings.max_offset_sigma_m))

    theta, covariance, used = _gauss_newton(found, poles, start, [0, 1, 2, 3], settings)
    if not observable(covariance, used, [1, 2, 3]):
        theta, covariance, used = _gauss_newton(found, poles, start, [0, 1, 2], settings)
    xy_observable = observable(covariance, used, [1, 2])
    if not xy_observable:
        theta, covariance, used = _gauss_newton(found, poles, start, [0], settings)
    return theta, covariance, used, xy_observable


def calibrate_mounts(trip: Trip, ref_stamp_s: FloatArray, ref_pose: FloatArray,
                     detector: DetectorConfig | None = None,
                     settings: MountSettings | None = None, source: str | None = None
                     ) -> list[MountEstimate]:
    """Estimate the mount of every LiDAR but the first, which the reference stands on.

    Raises:
        CoreError: no map, no second LiDAR, or a LiDAR that cannot be calibrated.
    """
    source = source or trip.name
    if not len(trip.landmarks):
        raise CoreError(f'{source}: no landmark map: a mount is calibrated against the map')
    if len(trip.scans) < 2:
        topics = ', '.join(repr(s.topic) for s in trip.scans) or 'none'
        raise CoreError(f'{source}: no LiDAR to calibrate: the first LiDAR is the reference '
                        f'and the trip has no other (scan topics: {topics})')
    return [calibrate_mount(scans, trip.landmarks.xy_m, ref_stamp_s, ref_pose, detector,
                            settings, source) for scans in trip.scans[1:]]
