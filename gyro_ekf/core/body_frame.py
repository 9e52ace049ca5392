"""Two LiDARs that disagree on where they sit: the pose between them until one is shown right.

The first LiDAR (with the odometry) defines the body frame; every other LiDAR's mount is
estimated against it (``core/mount_online.py``). When that estimate moves the other
LiDAR's mount by ``d`` (x, y in the body frame, its yaw as stated), the two disagree, and
the LiDARs alone cannot say which one is off: a shift of the whole body frame moves both
alike. Either

- **A**: the other LiDAR sits ``d`` off its stated mount, and the pose is right; or
- **B**: the first one sits ``-d`` off its own. The pose, drawn along with it, is then off
  too, and the true position is ``p + R(yaw) d``.

Before, the filter took A for granted. When B held, the pose stayed 0.4-2 cm off with a
covariance of 2 mm until the odometry's path fit had driven the 20 m it needs
(``core/odometry_online.py``), if ever (stress class mount_offset: 23 of 25 at seed 0, 94 %
over seeds 0 and 40-45; 7 of its 10 misses a first LiDAR 0.4-2.3 cm off beside an exact
second).

Now what the filter reports is the mixture of the two, weighted by the evidence for each
(Bayes, an even prior): its mean ``p + w_B R d`` and its covariance ``P + w_A w_B R d d^T
R^T`` (the position block; the filter's own state and P are untouched: the LiDARs can never
shrink this term, so it must not enter their updates). When the evidence is even the pose
lies halfway and its covariance spans the disagreement; when it is clear, the mixture is
the hypothesis it points at.

The evidence:

- **The start check.** Standing at the trusted start pose, each LiDAR's scans fit an offset
  of its own mount (``stop_offset``): near 0 and ``d`` under A, ``-d`` and 0 under B, each
  a Gaussian with the fit's covariance. On 473 starts of exact LiDARs (stress seeds 0 and
  40-45, classes second_lidar and mount_offset) the offset's squared distance under that
  covariance averaged 1.05, 4.2 % beyond 2 sigmas and 0.85 % beyond 3 (a 2-D Gaussian:
  2, 13.5 % and 1.1 %): not too narrow. A Student t on the stop's few poles (2 P - 3
  degrees of freedom, as the start check's F test) was tried first, in a run that carried
  a bug since mended, so its figures say nothing of the t (docs/stress.md).
- **The odometry's path fit** of the first LiDAR's offset (its last clean fit): near 0
  under A, ``-d`` under B, Gaussian with the fit's sigma.

**The heading.** Every LiDAR update holds the heading to the yaw of the LiDAR that defines
the body frame, so the heading is known no better than that yaw: the reported heading's
variance gains what is known of it (``heading_spread``, ``with_heading``: the params
file's ``lidar.<topic>.yaw_sigma_rad``, the sigma of a turn the odometry made, or what its
path fit reads beyond its noise), outside the filter's P like the mixture's terms.

The odometry's move of the first LiDAR's mount ends the mixture (it decided), as does a
yaw change of the other LiDAR (another error than an offset) or a third LiDAR (not
modelled). A hand-over of the body frame at the start check swaps the two roles: it rests
on the same stop's fits, which may not tell (stress seed 40, mount_offset 24: an exact first
LiDAR read 3.2 sigmas off beside a second 1.8 cm off read 2.8, and the body frame went to
the wrong one; NEES share 0.67 -> 0.90 with the mixture). A hand-over on the health
monitor's word (the first LiDAR disagreed with the map while the other vouched) stands:
weighed again with no start fits, the pose sat halfway across a 6-cm disagreement until the
path fit decided (seed 0 mount_offset 3: RMSE 2.2 mm -> 9.0 mm).
"""

from __future__ import annotations

import math

import numpy as np

from gyro_ekf.core.types import FloatArray, LidarMount

Offset = tuple[float, float, float, float, float, float]
"""A LiDAR's offset off a mount, fitted at a stop: x m, y m, covariance xx, xy, yy m^2, dof."""

Shift = tuple[float, float, float, float, float, float]
"""The reported pose's move: x m, y m (body frame), covariance xx, xy, yy m^2, yaw rad^2."""


def stop_offset(theta: FloatArray, covariance: FloatArray, used: int, scans: int,
                mount: LidarMount) -> Offset:
    """Return a stop's fit (``mount_online.fit_window``: yaw, x, y) as an offset off `mount`.

    Every scan of a stop sees the same poles with the same beams: its errors repeat, so
    the scans are worth one scan, not many (the covariance is multiplied by their count),
    and the residuals rest on the poles a scan sees, ``2 P - 3`` degrees of freedom.
    """
    xy = np.asarray(covariance, dtype=np.float64)[1:3, 1:3] * scans
    dof = max(2.0 * used / scans - 3.0, 1.0)
    return (float(theta[1]) - mount.x_m, float(theta[2]) - mount.y_m,
            float(xy[0, 0]), float(xy[0, 1]), float(xy[1, 1]), dof)


def _usable(offset: Offset | None) -> bool:
    """Whether a stop's offset can weigh: finite, its covariance positive definite."""
    if offset is None or not all(math.isfinite(v) for v in offset):
        return False
    _, _, xx, xy, yy, _ = offset
    return xx > 0.0 and xx * yy - xy * xy > 0.0


def _log_likelihood(offset: Offset, ex: float, ey: float) -> float:
    """Log-likelihood, up to a constant, that the true offset is (ex, ey): a 2-D Gaussian."""
    x, y, xx, xy, yy, _ = offset
    u, v = x - ex, y - ey
    return -0.5 * (yy * u * u - 2.0 * xy * u * v + xx * v * v) / (xx * yy - xy * xy)


def other_right_share(d: tuple[float, float], start_first: Offset | None,
                      start_other: Offset | None,
                      path_offset: tuple[float, float, float, float] | None) -> float:
    """Return w_B, the weight of B (the other LiDAR right, the first one -d off its mount).

    Args:
        d: where the other LiDAR's mount in use sits off its stated one (x, y), m.
        start_first, start_other: each LiDAR's offset off its stated mount fitted at the
            trusted start pose (``stop_offset``), or None.
        path_offset: the odometry's last clean path fit of the first LiDAR's offset
            (x, y, sigma x, sigma y), m, or None.
    """
    dx, dy = d
    log_ratio = 0.0  # log L_B - log L_A
    # A fit with no usable covariance (singular, or not finite) says nothing: counted as
    # evidence it would make either side certain.
    if _usable(start_first):
        log_ratio += (_log_likelihood(start_first, -dx, -dy)
                      - _log_likelihood(start_first, 0.0, 0.0))
    if _usable(start_other):
        log_ratio += (_log_likelihood(start_other, 0.0, 0.0)
                      - _log_likelihood(start_other, dx, dy))
    if path_offset is not None and all(math.isfinite(v) for v in path_offset):
        x, y, sx, sy = path_offset
        if sx > 0.0 and sy > 0.0:
            log_ratio += 0.5 * (((x / sx) ** 2 + (y / sy) ** 2)
                                - ((x + dx) / sx) ** 2 - ((y + dy) / sy) ** 2)
    if math.isnan(log_ratio):  # d not finite: nothing to weigh
        return 0.5
    # exp overflows past 709: the weight is 0 or 1 to double precision long before.
    return 1.0 / (1.0 + math.exp(min(-log_ratio, 700.0)))


def mixture_shift(d: tuple[float, float], other_right: float) -> Shift:
    """Return the mixture's move of the pose (body frame) and its covariance term."""
    dx, dy = d
    spread = other_right * (1.0 - other_right)
    return (other_right * dx, other_right * dy,
            spread * dx * dx, spread * dx * dy, spread * dy * dy, 0.0)


def disagreement_spread(d: tuple[float, float]) -> Shift:
    """Return the covariance term of a disagreement under the change limits (no move).

    ``d`` is the other LiDAR's fit off its mount in use, read beyond the fit's noise but
    under the limits a mount is changed by, so both LiDARs keep their stated mounts and
    both weigh in the filter. Either the other LiDAR sits ``a`` off (A) or the first one
    ``b`` off (B). With the other LiDAR holding a share ``s`` of the pose's information,
    the pose leans ``s a`` towards A's error and the fit reads ``(1 - s) a``; under B the
    pose follows the first LiDAR by ``(1 - s) b`` and the fit reads ``-(1 - s) b``. So
    the pose is off by ``s / (1 - s) d`` under A and ``-d`` under B: by about ``d`` either
    way at even weights (``s`` = 1/2), less under A when the other LiDAR weighs less.
    Which one holds the LiDARs cannot say, so the pose stays and the covariance gains
    ``d d^T``, the larger of the two: what the verdict's "the pose may be off by as much"
    says, in the figures a user reads (a second LiDAR 4.7 mm off, read 2.7 mm: NEES share
    0.882 with the filter's covariance alone, 0.912 with this; stress seed 15,
    mount_offset 8). Only a watch fit's ``d`` counts (``MountTracker.watched_read_off_m``:
    fits of a few seconds read exact mounts 4 mm off), and not for a LiDAR handed over
    (named the one off, it weighs a ninth; the driver, ``core/events.py``). Like the
    mixture's term it stays out of the filter's P.
    """
    dx, dy = d
    return (0.0, 0.0, dx * dx, dx * dy, dy * dy, 0.0)


def heading_spread(yaw_rad: float, sigma_rad: float) -> float:
    """Return the heading variance a body-frame LiDAR's yaw read off leaves, rad^2.

    The odometry's path fit reads how far the LiDAR that defines the body frame turns the
    heading off the direction the odometry moves in (``core/odometry_online.py``: ``e``,
    with ``sigma``, the fit's and the heading's own). Under the change limits (a 0.05 deg
    turn, beyond 3 sigmas) the mount stays, and every LiDAR update holds the heading ``e``
    off, however small its variance: the map agrees with the LiDAR, whatever its mount.
    Such a mount is not rare: ``calibrate-mounts`` on a trip with no static start writes
    the first LiDAR's yaw from such fits, a few hundredths of a degree off (simulated seed
    6, a LiDAR 2 deg off: written 1.974 deg, and `run` with the file held the heading
    0.02-0.06 deg off with a sigma of 0.012: NEES share 0.69, verdict ok). The driver takes
    the larger of this and the mount's own sigma (``OdometryTracker.heading_variance``).

    ``E[e^2] = delta^2 + sigma^2`` for a mount ``delta`` off, so ``e^2 - sigma^2`` is what
    the covariance lacks. Only a fit read beyond ``READ_OFF_SIGMAS`` of its sigma counts
    (as a disagreement of two LiDARs does): a third of the fits of an exact mount read
    beyond one sigma, and each widened a heading the filter already holds loosely (a
    second LiDAR 0.5 deg off beside an exact first, 60 s moving: NEES share 0.911 -> 0.897,
    its share below the band 8.5 -> 9.9 %). Like the mixture's terms it stays out of the
    filter's P (the LiDARs can never shrink it).
    """
    if not abs(yaw_rad) > READ_OFF_SIGMAS * sigma_rad:
        return 0.0
    return yaw_rad * yaw_rad - sigma_rad * sigma_rad


READ_OFF_SIGMAS = 2.0
"""How many of its sigmas a path fit must read a body-frame yaw off to widen the heading."""


def with_heading(shift: Shift | None, variance: float) -> Shift | None:
    """Return ``shift`` with ``variance`` (rad^2) added to its heading's; None if nothing."""
    if not variance > 0.0:
        return shift
    x, y, xx, xy, yy, yaw = shift if shift is not None else (0.0,) * 6
    return (x, y, xx, xy, yy, yaw + variance)


def shift_estimates(states: FloatArray, covariances: FloatArray, shift: Shift) -> None:
    """Move estimate rows by the shift, in place: states (n, >=3), covariances (n, k, k).

    The position moves by ``R(yaw) s`` and its covariance gains ``R(yaw) C R(yaw)^T``; the
    heading's variance gains the shift's.
    """
    sx, sy, cxx, cxy, cyy, cyaw = shift
    yaw = states[:, 2]
    c, s = np.cos(yaw), np.sin(yaw)
    states[:, 0] += c * sx - s * sy
    states[:, 1] += s * sx + c * sy
    # R C R^T, element by element.
    a = c * cxx - s * cxy
    b = c * cxy - s * cyy
    e = s * cxx + c * cxy
    f = s * cxy + c * cyy
    covariances[:, 0, 0] += a * c - b * s
    covariances[:, 0, 1] += a * s + b * c
    covariances[:, 1, 0] += a * s + b * c
    covariances[:, 1, 1] += e * s + f * c
    covariances[:, 2, 2] += cyaw
