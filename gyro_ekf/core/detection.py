"""Pole detection in one 2-D LiDAR scan.

A scan is cut into clusters of neighbouring valid beams; a range step larger than
``DetectorConfig.range_jump_m`` or an invalid beam (inf, NaN, <= 0 or beyond
``max_range_m``) ends a cluster. Which clusters are poles depends on the sensor:

* **Intensity mode** (the sensor gives intensities): a cluster holding at least one
  reflective return (intensity >= ``reflective_intensity``) is a pole, and only its
  reflective returns are used, so a pole standing close to a wall (same cluster) is still
  placed on the tape and not dragged towards the wall. The chord of the reflective part
  must not exceed ``max_width_m`` (a reflective wall is not a pole).
* **Width mode** (no intensities): a cluster is a pole when its apparent width lies in
  ``[min_width_m, max_width_m]`` and it stands in front of its neighbours.

Cut poles. A pole whose returns reach the first or last beam of the scan may extend past
the field of view, and the centre of its visible part lies inward of the real one (by up to
2 deg at 1-3 m on the 2023 log). Its inner edge is still seen: the pole's tangent ray lies
half a beam beyond its last return there, so the centre is placed asin(R / d) past that
ray, at the distance d that puts the returns on the circle (``cut_pole_centre``). A pole
hidden on its inner side by something closer, or reaching both ends of the scan, is not
reported.

Apparent width. The chord between the first and last return underestimates an object's
width by about one beam footprint: a 10 cm pole at 6 m under 0.5 deg beams is hit by one
beam, chord 0. Each edge return stands for half a beam spacing beyond it, so the apparent
width is ``chord + r * dtheta`` (r = range of the cluster centroid, dtheta = beam spacing).

Centre. The returns lie on the pole's front surface. A return at lateral offset u from
the ray through the cluster centroid lies ``sqrt(R^2 - u^2)`` in front of the centre
(R = ``pole_radius_m``), so the centroid is pushed back along its ray by the mean of that
depth. For a densely sampled pole that mean is pi/4 R, which removes the 1 cm bias a plain
push by R (the course's "about 5 cm behind the mean of its returns") would leave. A single
return says nothing about where across the pole it struck, so it is pushed back by the
depth expected given that its neighbours missed (``single_return_depth``), not by R.
"""

from __future__ import annotations

from dataclasses import dataclass
import math

import numpy as np
from numpy.typing import NDArray

from gyro_ekf.core.config import DetectorConfig
from gyro_ekf.core.errors import CoreError
from gyro_ekf.core.types import FloatArray

IntArray = NDArray[np.int64]


@dataclass(frozen=True, slots=True)
class PoleDetections:
    """Poles found in one scan, in beam order.

    Attributes:
        points_sensor_m: pole centres in the sensor frame (x forward, y left), shape (k, 2), m.
        widths_m: apparent width (chord + one beam footprint) of the pole's returns,
            shape (k,), m.
        beam_counts: returns used for each pole, shape (k,).
        first_beams: index of the first beam of each pole's cluster, shape (k,).
        last_beams: index of the last beam of each pole's cluster, shape (k,).
        cluster_count: clusters of valid beams in the scan (poles and everything else).
        used_intensities: True in intensity mode, False in width mode.
    """

    points_sensor_m: FloatArray
    widths_m: FloatArray
    beam_counts: IntArray
    first_beams: IntArray
    last_beams: IntArray
    cluster_count: int
    used_intensities: bool

    def __len__(self) -> int:
        return int(self.points_sensor_m.shape[0])

    @property
    def ranges_m(self) -> FloatArray:
        """Range of each pole centre, shape (k,), m."""
        return np.hypot(self.points_sensor_m[:, 0], self.points_sensor_m[:, 1])

    @property
    def bearings_rad(self) -> FloatArray:
        """Bearing of each pole centre (0 = forward, counter-clockwise), shape (k,), rad."""
        return np.arctan2(self.points_sensor_m[:, 1], self.points_sensor_m[:, 0])


def single_return_depth(radius_m: float, beam_gap_m: FloatArray) -> FloatArray:
    """Return how far behind a pole's only return its centre lies, on average, m.

    The return lies on its own ray, so its lateral offset u from the centre is unknown;
    pushing it back by R (a dead-centre hit) puts far poles about 1 cm too far. With beams
    beam_gap_m apart at the pole (range times beam spacing), one beam alone hits the pole
    when |u| < a = min(R, gap - R) (the neighbours miss it), so u is uniform on [0, a]
    and the mean of sqrt(R^2 - u^2) over it is
    (a sqrt(R^2 - a^2) + R^2 asin(a / R)) / (2 a): pi R / 4 when beams are wider apart
    than the pole, R when its neighbours barely miss it.

    Args:
        radius_m: pole radius R, m.
        beam_gap_m: lateral distance between neighbouring beams at the pole, m (array).
    """
    gap = np.asarray(beam_gap_m, dtype=np.float64)
    if radius_m <= 0.0:
        return np.zeros_like(gap)
    a = np.clip(gap - radius_m, 1e-9 * radius_m, radius_m)
    root = np.sqrt(np.maximum(radius_m * radius_m - a * a, 0.0))
    return (a * root + radius_m * radius_m * np.arcsin(a / radius_m)) / (2.0 * a)


def cut_pole_centre(edge_rad: float, toward: float, bearings_rad: FloatArray,
                    ranges_m: FloatArray, radius_m: float) -> tuple[float, float]:
    """Return the centre (x, y, m, sensor frame) of a pole cut off by the field of view.

    Args:
        edge_rad: bearing of the pole's visible tangent ray (half a beam beyond its last
            return on the inner side), rad.
        toward: +1 when the centre lies at larger bearings than that ray, -1 otherwise.
        bearings_rad, ranges_m: the pole's returns, shape (n,).
        radius_m: pole radius R, m.
    """
    bearings = np.asarray(bearings_rad, dtype=np.float64)
    ranges = np.asarray(ranges_m, dtype=np.float64)
    distance = float(ranges.min()) + radius_m
    for _ in range(4):
        # The centre's bearing given its distance, then the distance that puts each return
        # on the circle, |p_i - c| = R (the far root), averaged.
        bearing = edge_rad + toward * math.asin(min(radius_m / distance, 1.0))
        offset = bearings - bearing
        across = ranges * np.sin(offset)
        distance = float(np.mean(ranges * np.cos(offset)
                                 + np.sqrt(np.maximum(radius_m * radius_m - across * across,
                                                      0.0))))
    bearing = edge_rad + toward * math.asin(min(radius_m / distance, 1.0))
    return distance * math.cos(bearing), distance * math.sin(bearing)


def _empty(cluster_count: int, used_intensities: bool) -> PoleDetections:
    return PoleDetections(
        points_sensor_m=np.zeros((0, 2)), widths_m=np.zeros(0),
        beam_counts=np.zeros(0, dtype=np.int64), first_beams=np.zeros(0, dtype=np.int64),
        last_beams=np.zeros(0, dtype=np.int64),
        cluster_count=cluster_count, used_intensities=used_intensities)


def detect_poles(ranges_m: FloatArray, angles_rad: FloatArray,
                 intensities: FloatArray | None, config: DetectorConfig | None = None, *,
                 require_foreground: bool = True) -> PoleDetections:
    """Find poles in one scan.

    Args:
        ranges_m: range of every beam, shape (b,), m; inf, NaN, <= 0 or beyond
            ``config.max_range_m`` mean no return.
        angles_rad: bearing of every beam, shape (b,), rad, 0 = forward, counter-clockwise,
            evenly spaced in beam order.
        intensities: intensity of every beam, shape (b,), or None when the sensor gives
            none (then poles are found by width).
        config: detector settings; defaults when None.
        require_foreground: width mode only: refuse a cluster whose neighbour beam on
            either side is valid and closer (a cut-off object, or one beam of a wall seen
            at a grazing angle, whose beams all split at range jumps). Scan edges and
            missing returns count as background.

    Returns:
        The poles, in beam order.

    Raises:
        CoreError: the arrays do not have matching 1-D shapes.
    """
    ranges = np.asarray(ranges_m)
    angles = np.asarray(angles_rad)
    if ranges.ndim != 1 or angles.shape != ranges.shape:
        raise CoreError(f'detect_poles: ranges {ranges.shape} and angles {angles.shape} must '
                        'be 1-D arrays of the same length')
    if intensities is not None and np.shape(intensities) != ranges.shape:
        raise CoreError(f'detect_poles: intensities {np.shape(intensities)} do not match '
                        f'ranges {ranges.shape}')
    return detect_poles_in_scans(
        ranges[None, :], angles, None if intensities is None else np.asarray(intensities)[None],
        config, require_foreground=require_foreground)[0]


def detect_poles_in_scans(ranges_m: FloatArray, angles_rad: FloatArray,
                          intensities: FloatArray | None, config: DetectorConfig | None = None,
                          *, require_foreground: bool = True) -> list[PoleDetections]:
    """Find poles in several scans of one sensor at once (same results as one by one).

    The scans are laid end to end and processed as one long scan with a forced cluster
    break at the start of every scan, so numpy's per-call cost is paid once per batch
    rather than once per scan (the offline run detects thousands of scans).

    Args:
        ranges_m: shape (m, b), m; see detect_poles.
        angles_rad: bearing of every beam, shape (b,), rad.
        intensities: shape (m, b), or None.
        config: detector settings; defaults when None.
        require_foreground: see detect_poles.

    Returns:
        One PoleDetections per scan, in scan order.

    Raises:
        CoreError: the arrays do not have matching shapes.
    """
    if config is None:
        config = DetectorConfig()
    ranges2 = np.asarray(ranges_m, dtype=np.float64)
    angles = np.asarray(angles_rad, dtype=np.float64)
    use_intensity = intensities is not None
    if ranges2.ndim != 2 or angles.shape != ranges2.shape[1:]:
        raise CoreError(f'detect_poles: ranges {ranges2.shape} must be (scans, beams) with '
                        f'{angles.shape} angles')
    if use_intensity:
        inten2 = np.asarray(intensities, dtype=np.float64)
        if inten2.shape != ranges2.shape:
            raise CoreError(f'detect_poles: intensities {inten2.shape} do not match ranges '
                            f'{ranges2.shape}')
    scans, beams = ranges2.shape
    ranges = ranges2.ravel()
    with np.errstate(invalid='ignore'):
        valid = np.isfinite(ranges) & (ranges > 0.0) & (ranges <= config.max_range_m)
    idx = np.flatnonzero(valid)
    n = idx.size
    if n == 0:
        return [_empty(0, use_intensity) for _ in range(scans)]

    r = ranges[idx]
    # The beam of each valid return, picked from a broadcast row of beam numbers: idx % beams
    # (an integer division per return) cost more than the rest of these lines.
    beam_of = np.broadcast_to(np.arange(beams), (scans, beams))[valid.reshape(scans, beams)]
    # A new cluster starts at the first valid beam of every scan, after any invalid beam
    # and at a jump.
    new = np.empty(n, dtype=bool)
    new[0] = True
    new[1:] = (np.diff(idx) != 1) | (beam_of[1:] == 0) | (np.abs(np.diff(r)) > config.range_jump_m)
    starts = np.flatnonzero(new)
    cluster_counts = np.bincount(idx[starts] // beams, minlength=scans)
    if use_intensity:
        used = inten2.ravel()[idx] >= config.reflective_intensity
        # Only clusters with a reflective return can be poles: keep their beams alone for
        # the rest (walls are most of a scan's returns; the results do not change).
        candidate = np.logical_or.reduceat(used, starts)[np.cumsum(new) - 1]
        if not candidate.all():
            idx, r, beam_of, new, used = (idx[candidate], r[candidate], beam_of[candidate],
                                          new[candidate], used[candidate])
            n = idx.size
            if n == 0:
                return [_empty(int(c), use_intensity) for c in cluster_counts]
            starts = np.flatnonzero(new)
    else:
        used = np.ones(n, dtype=bool)
    ends = np.append(starts[1:], n) - 1
    cluster_of = np.cumsum(new) - 1
    a = angles[beam_of]
    x = r * np.cos(a)
    y = r * np.sin(a)
    w = used.astype(np.float64)
    counts = np.add.reduceat(w, starts)
    sum_x = np.add.reduceat(x * w, starts)
    sum_y = np.add.reduceat(y * w, starts)
    pos = np.arange(n)
    first_used = np.minimum.reduceat(np.where(used, pos, n), starts)
    last_used = np.maximum.reduceat(np.where(used, pos, -1), starts)

    keep = counts > 0
    # Clusters without used returns get dummy indices; they are dropped below.
    first_used = np.where(keep, first_used, starts)
    last_used = np.where(keep, last_used, starts)
    safe_counts = np.maximum(counts, 1.0)
    mean_x = sum_x / safe_counts
    mean_y = sum_y / safe_counts
    mean_r = np.hypot(mean_x, mean_y)
    chord = np.hypot(x[last_used] - x[first_used], y[last_used] - y[first_used])
    spacing = float(np.abs(angles[-1] - angles[0]) / (beams - 1)) if beams > 1 else 0.0
    width = chord + mean_r * spacing

    # Poles cut by the field of view are placed from their inner edge, further below.
    cut_low = beam_of[first_used] == 0
    cut_high = beam_of[last_used] == beams - 1
    keep &= ~(cut_low & cut_high)
    if use_intensity:
        keep &= chord <= config.max_width_m
    else:
        keep &= (width >= config.min_width_m) & (width <= config.max_width_m)
        if require_foreground:
            first_beam = idx[starts]
            last_beam = idx[ends]
            has_left = first_beam % beams > 0
            has_right = last_beam % beams < beams - 1
            left = np.where(has_left, first_beam - 1, first_beam)
            right = np.where(has_right, last_beam + 1, last_beam)
            # valid[...] covers inf/NaN/out-of-range neighbours; a valid neighbour in
            # another cluster differs by more than range_jump_m, so '<' means in front.
            left_closer = has_left & valid[left] & (ranges[left] < r[starts])
            right_closer = has_right & valid[right] & (ranges[right] < r[ends])
            keep &= ~(left_closer | right_closer)
    sel = np.flatnonzero(keep)
    if sel.size == 0:
        return [_empty(int(c), use_intensity) for c in cluster_counts]

    # Push each centroid back along its ray by the mean depth of the pole centre behind
    # the returns, sqrt(R^2 - u^2), u = lateral offset of a return from that ray.
    ux = mean_x / np.maximum(mean_r, 1e-12)
    uy = mean_y / np.maximum(mean_r, 1e-12)
    lateral = x * uy[cluster_of] - y * ux[cluster_of]
    radius = config.pole_radius_m
    depth = np.sqrt(np.maximum(radius * radius - lateral * lateral, 0.0)) * w
    push = np.add.reduceat(depth, starts) / safe_counts
    push = np.where(counts == 1, single_return_depth(radius, mean_r * spacing), push)
    centre = np.column_stack([mean_x + push * ux, mean_y + push * uy])[sel]
    cut = np.flatnonzero((cut_low | cut_high)[sel])
    if cut.size:
        step = float(angles[1] - angles[0])
        hidden = []
        for row in cut.tolist():
            cluster = sel[row]
            low = bool(cut_low[cluster])
            edge = int(last_used[cluster] if low else first_used[cluster])
            beyond = idx[edge] + (1 if low else -1)
            if valid[beyond] and ranges[beyond] < r[edge]:
                hidden.append(row)
                continue
            members = np.arange(starts[cluster], ends[cluster] + 1)
            members = members[used[members]]
            centre[row] = cut_pole_centre(
                a[edge] + (0.5 if low else -0.5) * step, -math.copysign(1.0, step) if low
                else math.copysign(1.0, step), a[members], r[members], radius)
        if hidden:
            sel = np.delete(sel, hidden)
            centre = np.delete(centre, hidden, axis=0)
            if sel.size == 0:
                return [_empty(int(c), use_intensity) for c in cluster_counts]

    first_flat = idx[starts[sel]]
    scan_of = first_flat // beams
    first_beams = (first_flat % beams).astype(np.int64)
    last_beams = (idx[ends[sel]] % beams).astype(np.int64)
    widths = width[sel]
    beam_counts = counts[sel].astype(np.int64)
    # Plain ints for the loop: a numpy scalar per scan and bound costs more than the slices.
    bounds = np.searchsorted(scan_of, np.arange(scans + 1)).tolist()
    found = []
    for k, clusters in enumerate(cluster_counts.tolist()):
        lo, hi = bounds[k], bounds[k + 1]
        if lo == hi:
            found.append(_empty(clusters, use_intensity))
            continue
        found.append(PoleDetections(
            points_sensor_m=centre[lo:hi], widths_m=widths[lo:hi],
            beam_counts=beam_counts[lo:hi], first_beams=first_beams[lo:hi],
            last_beams=last_beams[lo:hi],
            cluster_count=clusters, used_intensities=use_intensity))
    return found
