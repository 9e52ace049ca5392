"""`gyro-ekf calibrate-mounts BAG [-o PARAMS.yaml]`: LiDAR mounts from the data and the map.

The first LiDAR is the reference: the offline pipeline runs on it alone (the bag's other
LiDARs left out; a bag may have that one alone) and its estimated path is the reference
trajectory against which every other LiDAR's detections are fitted to the map
(`core.mount_calibration`). Prints each
mount (degrees, metres) with its sigma and residual; with -o writes a params file in the
bag sidecar's `lidar.*` layout that `gyro-ekf run --params-file` and the EKF node take. A
LiDAR whose fit is not clearly better than its stated mount (`--min-improvement`) keeps the
stated mount in the file: fits of exact mounts land a few hundredths of a degree off, and
that costs the filter more than it gains.

Each LiDAR's stamps against the gyro's are measured too, on a run of that LiDAR alone with
the mount the file gets (`core/time_offset.py`, as `run` measures them): one found late or
early beyond its sigmas is written as `lidar.<topic>.time_offset_s`, which `run` and the EKF
node take each scan's stamp less.

And each LiDAR's ranges against the map: one that reads long or short is written with
`lidar.<topic>.range_offset_m`, which `run` and the EKF node move its poles by. Every LiDAR
but the first fits it with its mount (`core.mount_calibration`). The first, the reference,
reads it in its range innovations (their mean beyond the verdict's limits,
core/health.py): it runs alone again with that offset added, until what is left is within
them (the filter takes part of an offset into the pose, so a first run reads about nine
tenths of it), and that run is the reference the others are fitted along.

The first LiDAR's own mount is not fitted to the map (it is the reference), but its run
alone holds it against the odometry (core/odometry_online.py) and moves it when the path
it holds lies off the odometry's: the mount it ends on is written (`first_mount_moved`). So
a bag with one LiDAR gets a file too.
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
import math
from pathlib import Path

from gyro_ekf.cli.convert import add_skip_bad_argument, warn_dropped

HELP = ('estimate the mounts of every LiDAR but the first against the map (the first\'s '
        "against the odometry), and every LiDAR's time and range offsets, and write them as "
        'a params file')

log = logging.getLogger(__name__)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add this command's arguments."""
    parser.add_argument('bag', type=Path, help='input bag folder (from convert or simulate)')
    parser.add_argument('-o', '--output', type=Path, default=None,
                        help='params YAML to write the mounts to (lidar.* parameters)')
    parser.add_argument('--force', action='store_true', help='replace an existing output')
    parser.add_argument('--min-improvement', type=_share, default=0.1, metavar='SHARE',
                        help='write a LiDAR\'s fitted mount only when the stated mount\'s RMS '
                        'residual exceeds the fit\'s by more than this share; 0 writes every '
                        'fit')
    add_skip_bad_argument(parser)


def _share(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not 0.0 <= value <= 10.0:
        raise argparse.ArgumentTypeError(f'{text!r}: must be a number from 0 to 10')
    return value


def params_yaml(estimates: list, reference: object,
                offsets: dict[str, dict] | None = None,
                first_range: dict | None = None) -> str:
    """Return the mounts as params-file text, the reference LiDAR's as the bag states it.

    offsets: per topic, its time offset figures (estimate_time_offsets); those found are
    written as `time_offset_s`. first_range: the reference LiDAR's range offset figures
    (first_range_offset), written as its `range_offset_m` when found; the others' come
    with their fitted mounts.
    """
    import yaml

    lidar: dict = {'topics': [reference.topic] + [e.topic for e in estimates]}
    lidar[reference.topic] = {'frame_id': reference.frame_id,
                              'x_m': float(reference.mount.x_m),
                              'y_m': float(reference.mount.y_m),
                              'yaw_rad': float(reference.mount.yaw_rad)}
    if reference.yaw_sigma_rad:
        lidar[reference.topic]['yaw_sigma_rad'] = float(reference.yaw_sigma_rad)
    for e in estimates:
        mount = e.proposed
        lidar[e.topic] = {'frame_id': e.frame_id, 'x_m': float(mount.x_m),
                          'y_m': float(mount.y_m), 'yaw_rad': float(mount.yaw_rad)}
        if e.significant and e.range_offset_m:
            lidar[e.topic]['range_offset_m'] = round(float(e.range_offset_m), 5)
        if e.significant and e.upside_down:
            lidar[e.topic]['upside_down'] = True
    if first_range and first_range['found']:
        lidar[reference.topic]['range_offset_m'] = round(float(first_range['offset_m']), 5)
    if reference.upside_down:
        lidar[reference.topic]['upside_down'] = True
    from gyro_ekf.core.validation import time_offset_problem
    for topic, figures in (offsets or {}).items():
        if (figures['found'] and topic in lidar
                and time_offset_problem(figures['offset_s']) is None):
            lidar[topic]['time_offset_s'] = round(float(figures['offset_s']), 6)
    header = ('# gyro_ekf LiDAR mounts (SI) from calibrate-mounts; the first LiDAR is the '
              'reference.\n# Give it to `gyro-ekf run --params-file` or a node\'s '
              '--ros-args --params-file.\n')
    return header + yaml.safe_dump({'/**': {'ros__parameters': {'lidar': lidar}}},
                                   sort_keys=False, default_flow_style=False)


def _table(estimates: list, reference: object, stated: object = None) -> str:
    """Return the mounts' table; stated: the first LiDAR's mount as the bag states it."""
    rows = [('topic', 'yaw (deg)', 'x (m)', 'y (m)', 'stated yaw/x/y', 'residual (m)',
             'detections', 'written')]
    moved = stated is not None and stated != reference.mount
    written = 'moved against the odometry' if moved else 'stated'
    sigma = (f' +- {math.degrees(reference.yaw_sigma_rad):.3f}' if reference.yaw_sigma_rad
             else '')
    rows.append((reference.topic, f'{math.degrees(reference.mount.yaw_rad):.3f}{sigma}',
                 f'{reference.mount.x_m:.4f}', f'{reference.mount.y_m:.4f}',
                 (f'{math.degrees(stated.yaw_rad):.3f} / {stated.x_m:.4f} / {stated.y_m:.4f}'
                  if moved else 'reference'), '', '',
                 f'{written}, upside down' if reference.upside_down else written))
    for e in estimates:
        sy, sx, sxy = e.sigma
        xy = ((f'{e.mount.x_m:.4f} +- {sx:.4f}', f'{e.mount.y_m:.4f} +- {sxy:.4f}')
              if e.offset_observable else (f'{e.mount.x_m:.4f} (stated)',
                                           f'{e.mount.y_m:.4f} (stated)'))
        rows.append((e.topic, f'{math.degrees(e.mount.yaw_rad):.3f} +- {math.degrees(sy):.3f}',
                     *xy, f'{math.degrees(e.stated.yaw_rad):.3f} / {e.stated.x_m:.4f} / '
                     f'{e.stated.y_m:.4f}',
                     f'{e.rms_residual_m:.4f} (stated {e.rms_residual_stated_m:.4f})',
                     f'{e.detections}/{e.detections_total}',
                     ('fit, upside down' if e.upside_down else 'fit') if e.significant
                     else 'stated (fit not clearly better)'))
    widths = [max(len(row[i]) for row in rows) for i in range(len(rows[0]))]
    return '\n'.join('  '.join(f'{cell:<{w}}' for cell, w in zip(row, widths)).rstrip()
                     for row in rows)


def run(args: argparse.Namespace) -> int:
    """Run the command; returns the exit code."""
    from gyro_ekf.io.output_dir import check_output_file, staged_file
    from gyro_ekf.core.mount_calibration import MountSettings
    from gyro_ekf.io.bag_reader import read_bag, validate_bag

    output: Path | None = args.output
    if output is not None:
        check_output_file(output, args.force, 'a params')
    bag = read_bag(args.bag, acceleration=False)
    source = str(args.bag)
    trip, report = validate_bag(bag, Path(args.bag).name, skip_bad=args.skip_bad)
    warn_dropped(report)
    # One run on the first LiDAR alone (again upside down, if its scans turn against the
    # gyro's; on the mount the odometry moved it to, if it did; and with its range offset,
    # if it reads long or short): the mounts' reference path and its time offset.
    stated = trip.scans[0].mount if trip.scans else None
    trip, first = first_upside_down(trip, reference_run(trip, source))
    trip, first = first_mount_moved(trip, first)
    first_range, first = first_range_offset(trip, first)
    _judge_reference(first, trip.scans[0].topic, source)
    found = estimate_mounts(trip, source, MountSettings(min_improvement=args.min_improvement),
                            first)
    reference = trip.scans[0]
    offsets = estimate_time_offsets(trip, found, first,
                                    first_range['offset_m'] if first_range['found'] else 0.0)
    print(_table(found, reference, stated))
    if len(trip.scans) < 2:
        print(f'no other LiDAR: {reference.topic!r} is the reference; its mount against the '
              'odometry, its time and range offsets, and which way up it is, measured alone')
    print(_offsets_table(offsets))
    print(_ranges_table(reference.topic, first_range, found))
    if output is not None:
        with staged_file(output) as staging:
            staging.write_text(params_yaml(found, reference, offsets, first_range),
                               encoding='utf-8')
        log.info('%s: wrote the mounts of %d LiDARs', output, len(found) + 1)
    return 0


def _offsets_table(offsets: dict[str, dict]) -> str:
    """Return the time offsets' lines: each LiDAR's stamps late against the gyro's, ms."""
    from gyro_ekf.core.time_offset import MIN_WINDOWS
    from gyro_ekf.core.validation import time_offset_problem
    lines = ['time offset, each LiDAR alone (ms late against the gyro):']
    for topic, figures in offsets.items():
        if figures['offset_s'] is None:
            lines.append(f"  {topic}: not measured ({figures['windows']} of the {MIN_WINDOWS} "
                         'windows with turns it needs)')
        else:
            problem = time_offset_problem(figures['offset_s'])
            left = (f"; alone, {figures['runs']} runs, {1000.0 * figures['left_s']:+.1f} +- "
                    f"{1000.0 * figures['left_sigma_s']:.1f} left"
                    if figures.get('runs', 1) > 1 and figures['left_s'] is not None else '')
            lines.append(f"  {topic}: {1000.0 * figures['offset_s']:+.1f} +- "
                         f"{1000.0 * figures['offset_sigma_s']:.1f} "
                         + (f'(not written: {problem})' if figures['found'] and problem
                            else f'(written{left})' if figures['found']
                            else '(not found: within its sigmas, or too small to matter; not '
                            'written)'))
    return '\n'.join(lines)


def _ranges_table(topic: str, first: dict, estimates: list) -> str:
    """Return the range offsets' lines: how much each LiDAR's ranges read long, cm."""
    lines = ['range offset (cm long against the map):']
    if first['offset_m'] is None:
        lines.append(f'  {topic}: not measured (too few blocks of updates)')
    elif first['found']:
        lines.append(f"  {topic}: {100.0 * first['offset_m']:+.2f} (written; alone, "
                     f"{first['runs']} runs, {100.0 * (first['left_m'] or 0.0):+.2f} left)")
    else:
        lines.append(f"  {topic}: {100.0 * first['left_m']:+.2f} at t {first['left_t']:.1f} "
                     "alone (within the verdict's limits: not written)")
    for e in estimates:
        if e.range_offset_m and e.significant:
            lines.append(f'  {e.topic}: {100.0 * e.range_offset_m:+.2f} +- '
                         f'{100.0 * e.range_offset_sigma_m:.2f} (written, with its mount)')
        else:
            lines.append(f'  {e.topic}: within its sigmas and 0.5 cm, or not observable: not '
                         'written')
    return '\n'.join(lines)


def first_upside_down(trip: object, first: object) -> tuple[object, object]:
    """Return the trip and the first LiDAR's run alone, upside down if it is.

    Its run alone (``first``) says so: its scans turn against the gyro's
    (core/turn_sign.py), and before the first turn its detections matched the map under
    half as often as an upright LiDAR's would (health.VERDICT_UPRIGHT_ASSOCIATION_SHARE:
    a gyro upside down leaves them matched). It runs again mirrored
    (ScanSeries.upside_down); kept so when that run associates more of its detections.
    """
    from gyro_ekf.analysis.offline import run_trip
    from gyro_ekf.core.health import VERDICT_UPRIGHT_ASSOCIATION_SHARE

    series = trip.scans[0]
    signs = [lidar for lidar in first.result.turn_signs or () if lidar['name'] == series.topic]
    share = signs[0]['associated_before_turns'] if signs else None
    if not (signs and signs[0]['opposite_found'] and share is not None
            and share < VERDICT_UPRIGHT_ASSOCIATION_SHARE):
        return trip, first
    flipped = dataclasses.replace(series, upside_down=not series.upside_down)
    run = run_trip(dataclasses.replace(trip, scans=(flipped,)))

    def associated(run: object) -> float:
        stats = run.result.stats
        return stats.updates / stats.detections if stats.detections else 0.0

    if associated(run) <= associated(first):
        return trip, first
    log.info("LiDAR '%s' is upside down: its scans turn against the gyro's and match the map "
             'mirrored (%.0f %% of its detections associated, %.0f %% as stated)',
             series.topic, 100.0 * associated(run), 100.0 * associated(first))
    return dataclasses.replace(trip, scans=(flipped,) + tuple(trip.scans[1:])), run


def first_mount_moved(trip: object, first: object) -> tuple[object, object]:
    """Return the trip and the first LiDAR's run alone, on its mount against the odometry.

    The first LiDAR is the reference of the other mounts, but against the odometry its own
    mount is measured too: the run alone moves it when the path it holds lies off the
    odometry's beyond the limits (core/odometry_online.py: a 1 cm offset, a 0.1 deg yaw,
    each beyond 3 sigmas), and its verdict says by how much. Until that move the run held a
    pose off by as much (a lone LiDAR 0.3 deg off: NEES share 0.61, moved by 0.29 deg after
    40 s). The trip then takes the mount in use as the stated one (ScanSeries.mount, which
    the params file gets) and runs alone again, up to ``MOUNT_RUNS`` runs in all, until
    the odometry moves it no more. An offset the run's last path fit reads beyond
    ``OFFSET_SAID_M`` under the move limit (its verdict says it) is taken too: the run
    followed it, and every other mount, fitted along that path, would take it on (two
    LiDARs, the first 9.3 mm off: the second was written 1 cm off with it, the file's run
    NEES share 0.06).
    """
    from gyro_ekf.analysis.offline import run_trip
    from gyro_ekf.core.types import LidarMount

    series, run = trip.scans[0], first
    for _ in range(MOUNT_RUNS - 1):
        odometry = run.result.odometry
        read = None if odometry is None else _offset_said(odometry)
        if odometry is None or not (odometry.offset_applied or read):
            break
        mount = odometry.first_mount(series.mount)
        if read:
            mount = LidarMount(mount.x_m + read[0], mount.y_m + read[1], mount.yaw_rad)
        series = dataclasses.replace(series, mount=mount,
                                     yaw_sigma_rad=_yaw_sigma(odometry, series))
        run = run_trip(dataclasses.replace(trip, scans=(series,)))
    if series is trip.scans[0]:
        return trip, first
    if series.mount.yaw_rad != trip.scans[0].mount.yaw_rad:
        series = dataclasses.replace(series, yaw_sigma_rad=_yaw_sigma(run.result.odometry,
                                                                      series, taken=False))
    else:
        series = dataclasses.replace(series, yaw_sigma_rad=trip.scans[0].yaw_sigma_rad)
    stated = trip.scans[0].mount
    log.info("LiDAR '%s' sits off its stated mount against the odometry: x %+.1f cm, y %+.1f "
             'cm, yaw %+.3f deg%s, written', series.topic,
             100.0 * (series.mount.x_m - stated.x_m), 100.0 * (series.mount.y_m - stated.y_m),
             math.degrees(series.mount.yaw_rad - stated.yaw_rad),
             f' +- {math.degrees(series.yaw_sigma_rad):.3f}' if series.yaw_sigma_rad else '')
    return dataclasses.replace(trip, scans=(series,) + tuple(trip.scans[1:])), run


def _offset_said(odometry: object) -> tuple[float, float] | None:
    """Return the first LiDAR's offset the run's verdict says under the move limit, m.

    Its last path fit of the mount in use over 20 m driven (``pose_offset``) read beyond
    ``OFFSET_SAID_M`` and 3 sigmas (``odometry_online.verdict_reasons``); None otherwise.
    """
    from gyro_ekf.core.odometry_online import OFFSET_SAID_M

    read = odometry.pose_offset()
    if read is None or odometry.offset_found():
        return None
    x, y, sigma = read
    size = math.hypot(x, y)
    if size > OFFSET_SAID_M and size > odometry.settings.offset_sigmas * sigma:
        return x, y
    return None


def _yaw_sigma(odometry: object, series: object, taken: bool = True) -> float:
    """Return how well the yaw a run of the first LiDAR alone ends on is known, rad.

    The odometry's path fits (core/odometry_online.py) are all that place it. The run's
    last clean fit of its mount in use reads it ``e`` off with sigma ``s``: ``hypot(e,
    s)``, its sigma when the two agree and their disagreement when not (as the scale's
    sigma is taken, ``OdometryTracker.walk_density``). ``s`` is the fit's own: the
    filter's heading error over the window is in ``e`` already, and with it in ``s`` too
    (``OdometryFit.yaw_sigma_with_heading``) the written yaws of 71 simulated trips lay
    within 1.1 sigmas of the truth, 90 % within one: too wide, and a trip whose yaw came
    out right had its NEES share fall below the band (0.883 and 0.895 on two of them; 0.907
    and 0.916 with the fit's own, errors of 0.4-1.6 of it on 7 trips). With no such fit,
    the sigma of the run's last turn, or of the yaw it started on (``series``).
    A turn the run made that is not ``taken`` into the yaw written leaves it that much
    further off. Written with the yaw (``lidar.<topic>.yaw_sigma_rad``): the heading a run
    reports is known no better (a 2-deg mount of a trip with no static start, written
    1.974 deg: the heading held 0.03 deg off with a sigma of 0.012, NEES share 0.69, until
    its sigma said so).
    """
    if odometry is None:
        return series.yaw_sigma_rad
    turn = 0.0 if taken else odometry.yaw_rad
    fit = odometry.window_fit()
    if fit is not None:
        return math.hypot(turn + fit.yaw_rad, fit.yaw_sigma_rad)
    sigma = odometry.yaw_sigma_rad if odometry.yaw_rad else series.yaw_sigma_rad
    return math.hypot(turn, sigma)


MOUNT_RUNS = 3
"""Runs of the first LiDAR alone at most, the first included, on its mount in use."""


def first_range_offset(trip: object, first: object) -> tuple[dict, object]:
    """Return the first LiDAR's range offset figures, and its run alone with it applied.

    The first LiDAR is the reference the others' mounts (and range offsets) are fitted
    against, so its own range offset comes from its range innovations against the map:
    from its run alone (``first``, reference_run's), then again with the offset their mean
    gives added, up to ``RANGE_RUNS`` runs in all, until that mean is within the verdict's
    limits (health.range_offset_found). Figures: offset_m (the sum applied; None: not
    measured), found, runs, left_m and left_t (the mean and its t in the last run).
    """
    from gyro_ekf.analysis.offline import run_trip
    from gyro_ekf.core.health import range_offset_found

    series, run = trip.scans[0], first
    applied, count = 0.0, 1
    while True:
        lidars = run.result.health.report() if run.result.health is not None else []
        whiteness = (lidars[0].get('whiteness') if lidars else None) or {}
        mean, t = whiteness.get('range_mean_m'), whiteness.get('range_mean_t')
        if mean is None or not range_offset_found(whiteness) or count == RANGE_RUNS:
            break
        applied += mean
        count += 1
        alone = dataclasses.replace(series, range_offset_m=applied)
        run = run_trip(dataclasses.replace(trip, scans=(alone,)))
    figures = {'offset_m': applied if applied or mean is not None else None,
               'found': bool(applied), 'runs': count, 'left_m': mean, 'left_t': t}
    return figures, run


RANGE_RUNS = 4
"""Runs of the first LiDAR alone at most, the first included, to measure its range offset."""


def estimate_time_offsets(trip: object, estimates: list, first: object = None,
                          first_range_m: float = 0.0) -> dict[str, dict]:
    """Return each LiDAR's time offset figures (TimeOffsetWatch.report), by topic.

    From the offline pipeline on that LiDAR alone with the mount (and range offset) the
    params file gets: its own stamps against the gyro's integral, a mount's yaw free in each
    window. first: reference_run's, which is the first LiDAR's (None: run again);
    first_range_m: the first LiDAR's range offset (first_range_offset).

    A LiDAR whose offset is found runs alone again with its stamps less the offset, and
    what that run reads is added, up to ``TIME_RUNS`` runs in all, until what is left lies
    within ``TIME_LEFT_SIGMAS`` of its standard errors: the bias takes part of an offset in
    and the windows' standard error is wide before it is applied (a trip 30 ms late read
    33.9 +- 1.8 ms; written, its run read -2.7 +- 0.5 ms left, NEES share 0.62, below the
    limits that say an offset). Figures: offset_s (the sum applied), offset_sigma_s and
    windows (the first run's), found, runs, left_s and left_sigma_s (the last run's).
    """
    from gyro_ekf.analysis.offline import run_trip
    from gyro_ekf.core.time_offset import TimeOffsetWatch
    from gyro_ekf.io.params_file import stamps_less

    mounts = {e.topic: e.proposed for e in estimates}
    ranges = {e.topic: e.range_offset_m for e in estimates if e.significant}
    flipped = {e.topic for e in estimates if e.significant and e.upside_down}

    def measured(run: object) -> dict:
        reports = run.result.time_offsets
        return reports[0] if reports else TimeOffsetWatch().report()

    offsets = {}
    for k, series in enumerate(trip.scans):
        alone = dataclasses.replace(
            series, mount=mounts.get(series.topic, series.mount),
            range_offset_m=first_range_m if k == 0 else ranges.get(series.topic, 0.0),
            upside_down=series.upside_down or series.topic in flipped)
        figures = measured(first if k == 0 and first is not None
                           else run_trip(dataclasses.replace(trip, scans=(alone,))))
        figures = dict(figures, runs=1, left_s=figures['offset_s'],
                       left_sigma_s=figures['offset_sigma_s'])
        if figures['found']:
            applied = figures['offset_s']
            while True:
                again = dataclasses.replace(alone, stamp_s=stamps_less(series.stamp_s, applied))
                left = measured(run_trip(dataclasses.replace(trip, scans=(again,))))
                figures.update(runs=figures['runs'] + 1, left_s=left['offset_s'],
                               left_sigma_s=left['offset_sigma_s'])
                if (left['offset_s'] is None or figures['runs'] == TIME_RUNS
                        or abs(left['offset_s']) <= TIME_LEFT_SIGMAS * left['offset_sigma_s']):
                    break
                applied += left['offset_s']
            figures['offset_s'] = applied
        offsets[series.topic] = figures
    return offsets


TIME_RUNS = 4
"""Runs of a LiDAR alone at most, the first included, to measure its time offset."""

TIME_LEFT_SIGMAS = 2.0
"""What a run with the offset applied still reads is added while beyond this many of its
standard errors."""


def reference_run(trip: object, source: str) -> object:
    """Return the offline pipeline's run on the first LiDAR alone: the reference path.

    A bag with that LiDAR alone is run too: no other mount is fitted, but its own mount
    against the odometry (first_mount_moved), its time and range offsets, and which way up
    it is are measured.

    Raises:
        BagError: no map, or no scan topic.
    """
    from gyro_ekf.analysis.offline import run_trip
    from gyro_ekf.io.errors import BagError

    if not len(trip.landmarks):
        raise BagError(f'{source}: no landmark map (/landmark_map): a mount is calibrated '
                       'against the map')
    if not trip.scans:
        raise BagError(f'{source}: no LiDAR to calibrate: the bag has no scan topic '
                       '(scan topics: none)')
    reference = trip.scans[0]
    ref = run_trip(dataclasses.replace(trip, scans=(reference,)))
    stats = ref.result.stats
    log.info("%s: reference path from LiDAR '%s' alone (%d of %d detections associated)",
             source, reference.topic, stats.updates, stats.detections)
    return ref


def _judge_reference(first: object, topic: str, source: str) -> None:
    """Say what the reference run's health verdict says; refuse a failed one.

    Every mount is fitted along the first LiDAR's path, and its own mount is only checked
    against the odometry: a first LiDAR 10 deg off its stated yaw, 75 % of its detections
    associated, was printed as 'stated' with nothing said (the run it gives is degraded).

    Raises:
        BagError: the reference run failed: its path is no reference.
    """
    from gyro_ekf.analysis.summary import summarize
    from gyro_ekf.io.errors import BagError

    health = summarize(first)['health']
    if health['verdict'] == 'ok':
        return
    reasons = '; '.join(health['reasons'])
    if health['verdict'] == 'failed':
        raise BagError(f"{source}: the run on LiDAR '{topic}' alone, the reference every "
                       f"mount is fitted along, failed: {reasons}; no mount is estimated")
    log.warning("%s: the run on LiDAR '%s' alone, the reference every mount is fitted "
                "along, is degraded: %s; the mounts below are only as good as it", source,
                topic, reasons)


def estimate_mounts(trip: object, source: str, settings: object = None,
                    first: object = None) -> list:
    """Estimate every LiDAR's mount but the first's, along the first LiDAR's own path.

    first: reference_run's (None: run it here).

    Raises:
        BagError: no map, no scan topic, or a LiDAR whose mount cannot be estimated.
    """
    from gyro_ekf.core.errors import CoreError
    from gyro_ekf.core.mount_calibration import calibrate_mounts
    from gyro_ekf.io.errors import BagError

    if len(trip.scans) < 2:
        return []  # the reference alone: no other mount to fit along its path
    # The reference path: the whole offline pipeline on the first LiDAR alone.
    estimates = (first or reference_run(trip, source)).result.estimates
    try:
        return calibrate_mounts(trip, estimates.stamp_s, estimates.state[:, :3],
                                settings=settings, source=source)
    except CoreError as err:
        raise BagError(str(err)) from None
