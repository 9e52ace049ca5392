"""`gyro-ekf run BAG -o OUTDIR`: calibration and EKF straight on a bag, without DDS.

Reads the bag (and its params sidecar), runs the offline calibration where the trip starts
static and the same EventDriver the live EKF node uses, then writes estimates.csv, the
estimates bag, summary.json and the figures into OUTDIR. stdout gets a short summary table.
"""

from __future__ import annotations

import argparse
from collections.abc import Iterator
import contextlib
from dataclasses import replace
import gc
import logging
import math
from pathlib import Path
import sys
import time
from typing import Any

from gyro_ekf.cli.convert import add_skip_bad_argument, warn_dropped

HELP = 'run calibration and the EKF on a bag offline; write CSV, bag, summary and plots'

log = logging.getLogger(__name__)

STRICT_EXIT_CODE = 3
"""Exit code of `run --strict` when the health verdict is not ok."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add this command's arguments."""
    parser.add_argument('bag', type=Path, help='input bag folder (from convert or simulate)')
    parser.add_argument('-o', '--output', type=Path, required=True,
                        help='output folder (created; must be empty unless --force)')
    parser.add_argument('--params-file', type=Path, default=None,
                        help='ROS 2 params YAML with filter parameters (as the nodes take)')
    parser.add_argument('--no-plots', action='store_true', help='skip the PNG figures')
    parser.add_argument('--no-bag', action='store_true', help='skip the estimates bag')
    parser.add_argument('--ignore-stated-noise', action='store_true',
                        help="use the configured noise sigmas even where the log states its own")
    parser.add_argument('--ignore-message-covariance', action='store_true',
                        help='use the configured gyro and speed noise even where a message '
                        'gives its own variance (angular_velocity_covariance[8], '
                        'twist.covariance[0])')
    parser.add_argument('--storage', choices=('mcap', 'sqlite3'), default='mcap',
                        help='storage plugin of the estimates bag')
    parser.add_argument('--force', action='store_true',
                        help='write into a non-empty output folder, replacing its products')
    parser.add_argument('--no-progress', action='store_true', help='no progress bar')
    parser.add_argument('--use-calibration', action='store_true',
                        help='seed the EKF bias from the static window (as the EKF node\'s '
                        'use_calibration); by default the online bias is found independently')
    parser.add_argument('--strict', action='store_true',
                        help='exit 3 unless the health verdict is ok (outputs are still '
                        'written)')
    parser.add_argument('--path-length', type=_path_length, default=None, metavar='POSES',
                        help='most poses per ekf/path message of the estimates bag (>= 1; '
                        'default: the params file\'s path_length, as the EKF node\'s, else '
                        '600, a pose every 0.2 s)')
    add_skip_bad_argument(parser)


def _path_length(text: str) -> int:
    from gyro_ekf.io.errors import OutputError
    from gyro_ekf.io.visual_bag import check_path_length
    try:
        return check_path_length(int(text))
    except (ValueError, OutputError):
        raise argparse.ArgumentTypeError(f'{text!r}: must be a whole number of poses >= 1'
                                         ) from None


def _progress_bar(total: int, enabled: bool) -> Any:
    if not enabled:
        # No bar to show: no tqdm either (its import and its multiprocessing lock cost
        # several milliseconds of the timed run).
        return contextlib.nullcontext()
    from tqdm import tqdm
    return tqdm(total=total, unit='msg', unit_scale=True, desc='run', leave=False,
                file=sys.stderr)


def _wander(online: dict[str, Any]) -> str:
    """Return the gyro wander row: found, or the priors assumed and whether ruled out."""
    if online['gyro_wander_found_s'] is not None:
        row = (f"{online['gyro_wander_deg_s']:.4f} "
               f"(found at {online['gyro_wander_found_s']:.0f} s)")
    else:
        prior = online['gyro_wander_prior_deg_s']
        row = 'none found'
        if prior > 0.0:
            row += f" (the {prior:.3f} assumed {_kept(online['gyro_wander_prior_ruled_out_s'])})"
    stop = online['gyro_wander_stop_s']
    if stop is not None:
        row += (f"; {online['gyro_wander_stop_deg_s']:.3f} shown at the stop ending at "
                f"{stop:.0f} s, {_kept(online['gyro_wander_stop_ruled_out_s'])}")
    return row


def _kept(ruled_out_s: float | None) -> str:
    """Return whether a prior wander was kept or when it was ruled out."""
    return 'kept' if ruled_out_s is None else f'ruled out at {ruled_out_s:.0f} s'


def _scale(scale: dict[str, Any]) -> str:
    """Return the gyro scale row: measured (and whether off the configured one), or not yet."""
    from gyro_ekf.core.gyro_scale import MIN_WINDOWS
    configured = f"{100.0 * scale['configured']:+.2f} configured"
    if scale['scale_error'] is None:
        return (f"not measured ({scale['windows']} of the {MIN_WINDOWS} windows with turns "
                f"it needs; {configured})")
    off = 'off the ' if scale['found'] else ''
    return (f"{100.0 * scale['scale_error']:+.2f} +- {100.0 * scale['scale_error_sigma']:.2f} "
            f"({off}{configured})")


def _dead_reckoned(association: dict) -> str:
    """Return the time in gaps of over a second since the first update, and its share."""
    tracked = association['since_first_update_s']
    if not tracked:
        return 'n/a'
    dead = association['dead_reckoned_s']
    return f'{dead:.1f} s of the {tracked:.1f} s since the first ({100.0 * dead / tracked:.1f} %)'


def _offsets(offsets: dict[str, dict[str, Any]]) -> str:
    """Return the LiDAR time offset row: each LiDAR's stamps against the gyro's, ms late."""
    from gyro_ekf.core.time_offset import MIN_WINDOWS
    if not offsets:
        return 'not measured (no scan with two poles while driving)'
    return '; '.join(
        f"{name}: not measured ({lidar['windows']} of the {MIN_WINDOWS} windows with turns "
        'it needs)' if lidar['offset_s'] is None else
        f"{name}: {1000.0 * lidar['offset_s']:+.1f} +- {1000.0 * lidar['offset_sigma_s']:.1f}"
        + (' (off)' if lidar['found'] else '')
        for name, lidar in offsets.items())


def _scatter(jitter: dict[str, dict[str, Any]]) -> str:
    """Return the LiDAR stamp scatter row: each LiDAR's, ms (core/stamp_jitter.py)."""
    from gyro_ekf.core.stamp_jitter import MIN_SCANS
    if not jitter:
        return 'not measured (no scan of a moving platform that could tell its stamp)'
    return '; '.join(
        f"{name}: not measured ({lidar['scans']} of the {MIN_SCANS} scans it needs)"
        if lidar['jitter_s'] is None else
        f"{name}: {1000.0 * lidar['jitter_s']:.1f}" + (' (found)' if lidar['found'] else '')
        for name, lidar in jitter.items())


def _against_lidars(signs: dict[str, dict[str, Any]]) -> str:
    """Return the row of what the gyro and odometry read against each LiDAR's scans.

    The gyro's reading per radian the scans turn most voted for (votes), and the odometry's
    metres per metre they show (core/turn_sign.py): coarse checks of a sign or a unit, read
    from pairs of scans (the odometry's scale itself is the online odometry row's; a helper
    read `x1.022` for an exact encoder as a 2 % error).
    """
    if not signs:
        return 'not measured (no two scans with two poles while turning)'
    return '; '.join(
        (f"{name}: gyro x{lidar['scale']:.4g} ({lidar['scale_votes']} of {lidar['votes']}), "
         if lidar['votes'] else f"{name}: gyro x0 ({lidar.get('unseen_turns', 0)} turns "
         'unseen), ')
        + ('odometry not measured' if lidar['speed_ratio'] is None
           else f"odometry about x{lidar['speed_ratio']:.2f} (a sign and unit check)")
        for name, lidar in signs.items())


def _spikes(spikes: dict[str, dict[str, Any]] | None) -> str:
    """Return the row of lone input samples left out (core/input_spikes.py)."""
    return ', '.join(f"{name} {figures['spikes']}" for name, figures in (spikes or {}).items())


def _heading_widened(odometry: dict | None) -> str:
    """Return the row of how much the first LiDAR's yaw widens the reported heading.

    The LiDAR that defines the body frame holds the heading to its mount, so the heading is
    known no better than that mount's yaw (core/body_frame.py, heading_spread).
    """
    widened = 0.0 if odometry is None else odometry.get('heading_widened_deg', 0.0)
    if not widened:
        return 'no (its yaw taken as stated)'
    return f'+-{widened:.3f} (its mount\'s yaw known no better)'


def _speed_noise(noise: dict[str, Any]) -> str:
    """Return the row of the odometry's noise taken from its own spread (learn_speed_noise)."""
    if not noise['widened_samples']:
        return 'as stated'
    return (f"up to {noise['measured_m_s']:.3f} m/s over the {noise['stated_m_s']:.3f} stated, "
            f"on {noise['widened_samples']} samples")


def _frozen(frozen: dict[str, Any] | None) -> str:
    """Return the row of a gyro's runs of one repeated value (core/input_frozen.py)."""
    if not frozen or not frozen['runs']:
        return 'no'
    return (f"{frozen['runs']} time(s), the longest {frozen['longest_s']:.2f} s "
            f"({frozen['samples']} samples left out)")


def _table(summary: dict[str, Any]) -> str:
    def number(value: Any, fmt: str) -> str:
        return 'n/a' if value is None or (isinstance(value, float) and math.isnan(value)) \
            else format(value, fmt)

    verdict = summary['health']
    rows = [('verdict', verdict['verdict'] + ''.join(f'\n  - {reason}'
                                                     for reason in verdict['reasons'])),
            ('trip', summary['trip']['name']),
            ('duration (s)', number(summary['trip']['duration_s'], '.1f'))]
    offline = summary['offline_bias']
    rows.append(('offline bias (deg/s)', 'n/a' if offline is None
                 else number(offline['bias_deg_s'][2], '.4f')))
    online = summary['online_bias']
    rows += [('online bias, final (deg/s)', number(online['final_deg_s'], '.4f')),
             ('online bias, last-half mean (deg/s)', number(online['last_half_mean_deg_s'],
                                                            '.4f')),
             ('gyro wander (deg/s)', _wander(online)),
             ('gyro scale error (%)', _scale(summary['gyro_scale'])),
             ('LiDAR stamps late against the gyro (ms)', _offsets(summary['time_offsets'])),
             ('LiDAR stamps\' scatter (ms)', _scatter(summary['stamp_jitter'])),
             ('lone input samples left out', _spikes(summary['input_spikes'])),
             ('gyro frozen (repeats left out)', _frozen(summary['gyro_frozen'])),
             ('odometry noise from its own spread', _speed_noise(summary['speed_noise'])),
             ('gyro and odometry against the LiDARs\' scans',
              _against_lidars(summary['turn_signs'])),
             ('heading widened for the first LiDAR\'s yaw (deg)',
              _heading_widened(summary['online_odometry'])),
             ('mapped poles elsewhere', ', '.join(
                 f"{pole['index']} at ({pole['seen_xy_m'][0]:.3f}, {pole['seen_xy_m'][1]:.3f})"
                 for pole in summary['map_poles_elsewhere']) or 'none'),
             ('poles associated', number(summary['association']['share_associated'], '.2%')),
             ('longest gap without a landmark (s)',
              number(summary['association']['longest_gap_s'], '.2f')),
             ('dead-reckoned (gaps over 1 s)', _dead_reckoned(summary['association'])),
             ('NIS mean / share in 95 % band', number(summary['nis']['mean'], '.2f') + ' / '
              + number(summary['nis']['share_in_band'], '.1%'))]
    truth = summary['ground_truth']
    if truth is not None:
        rows += [('position RMSE / max (m)', number(truth['position_rmse_m'], '.4f') + ' / '
                  + number(truth['position_max_error_m'], '.4f')),
                 ('heading RMSE (deg)', number(truth['heading_rmse_deg'], '.3f')),
                 ('NEES mean / share in 95 % band', number(truth['nees_mean'], '.2f') + ' / '
                  + number(truth['nees_share_in_band'], '.1%'))]
        if 'bias_error_final_deg_s' in truth:
            rows += [('bias error, final (deg/s)', number(truth['bias_error_final_deg_s'],
                                                          '.4f')),
                     ('bias settling time (s)', number(truth['bias_settling_time_s'], '.1f'))]
    width = max(len(name) for name, _ in rows)
    return '\n'.join(f'{name:<{width}}  {value}' for name, value in rows)


@contextlib.contextmanager
def _frozen_heap() -> Iterator[None]:
    """Keep the objects that exist now out of the cyclic collector's passes, for the block.

    They (the modules, their classes and functions) outlive the run, and each full pass
    walked them all: about 20 ms of the 2016 log's run, most of the collector's time there.
    Unfrozen afterwards, for callers that go on (tests run many commands in one process);
    a heap someone else froze is left to them.
    """
    if gc.get_freeze_count():
        yield
        return
    gc.freeze()
    try:
        yield
    finally:
        gc.unfreeze()


SEEN_MAP = 'landmarks_seen.yaml'
"""The map with the poles found elsewhere where they were seen (core/map_poles.py)."""


def _write_seen_map(path: Path, trip: object, elsewhere: list[dict[str, Any]]) -> None:
    """Write the trip's map with each pole found elsewhere where its detections put it.

    In the EKF node's `landmarks_file` layout: a params file's `landmarks_file` gives it to
    `run` and the node alike. The other poles stay as the map has them.
    """
    import yaml

    xy = [[float(x), float(y)] for x, y in trip.landmarks.xy_m]
    for pole in elsewhere:
        xy[pole['index']] = [round(float(v), 4) for v in pole['seen_xy_m']]
    moved = ', '.join(str(pole['index']) for pole in elsewhere)
    path.write_text(f'# {trip.name}: the map with pole(s) {moved} where gyro-ekf run saw them '
                    '(map_poles_elsewhere in summary.json).\n# Give it as landmarks_file in a '
                    'params file (run --params-file, or the EKF node).\n'
                    + yaml.safe_dump({'landmarks': xy}, default_flow_style=None),
                    encoding='utf-8')
    log.warning('pole(s) %s stand elsewhere than the map has them: %s has the map with them '
                'where they were seen (landmarks_file)', moved, SEEN_MAP)


def run(args: argparse.Namespace) -> int:
    """Run the command; returns the exit code."""
    from gyro_ekf.io import output_dir, results
    from gyro_ekf.analysis.offline import event_count, run_trip
    from gyro_ekf.io.params_file import (PipelineParams, read_params_file, with_initial_pose,
                                         with_landmarks_file)
    from gyro_ekf.analysis.summary import summarize
    from gyro_ekf.io.bag_reader import read_bag, validate_bag
    from gyro_ekf.io.streamed_products import StreamedProducts
    # What the run imports on first use, imported with the rest before the clock starts:
    # the real-time factor is processing time (`make bench` also gives it with start-up and
    # imports). numpy.unique (the bag reader) imports numpy.ma; the estimates bag's writer.
    import numpy.ma  # noqa: F401
    from rosbags.rosbag2 import Writer  # noqa: F401
    from gyro_ekf.io import batch_write, messages, visual_bag  # noqa: F401
    from gyro_ekf.io.bag_open import EXPECTED_TYPES
    # rosbags' decoders of the reader's types, which it imports on first use.
    messages.prepare_decoders(sorted(set(EXPECTED_TYPES.values())))

    params = read_params_file(args.params_file) if args.params_file else PipelineParams()
    with _frozen_heap():
        began = time.perf_counter()
        bag = read_bag(args.bag, acceleration=False)  # the EKF does not use it
        bag = replace(bag, trip=with_landmarks_file(
            with_initial_pose(bag.trip, params, bag.pose_from_message), params))
        # Checked before the output folder exists, so refused input leaves nothing behind.
        trip, report = validate_bag(bag, Path(args.bag).name, params.limits,
                                    skip_bad=args.skip_bad)
        warn_dropped(report)
        read_s = time.perf_counter() - began
        folder = output_dir.prepare_output_dir(args.output, force=args.force)
        use_stated = not args.ignore_stated_noise and params.options.use_stated_noise
        use_message_covariance = (not args.ignore_message_covariance
                                  and params.options.use_message_covariance)
        if not use_message_covariance:
            report.covariances_used.clear()  # read, but not used
        show = not args.no_progress and sys.stderr.isatty()
        # Every product is built in a staging folder that replaces the output folder only when
        # complete: a failure (disk full, read-only) leaves any previous output as it was.
        with output_dir.staged_output_dir(folder, force=args.force) as staging:
            # The CSV and the bag are written from the rows as the run makes them (a child
            # process where a core is free, io/streamed_products.py).
            with StreamedProducts(staging / output_dir.ESTIMATES_CSV,
                                  None if args.no_bag else staging / output_dir.ESTIMATES_BAG,
                                  bag.start_time_ns, trip, storage=args.storage,
                                  path_length=(params.path_length if args.path_length is None
                                               else args.path_length)) as products:
                with _progress_bar(event_count(trip), show) as bar:
                    result = run_trip(trip, params, use_stated_noise=use_stated,
                                      progress=None if bar is None else bar.update,
                                      use_message_covariance=use_message_covariance,
                                      use_calibration=True if args.use_calibration else None,
                                      detect_ahead=True, on_rows=products,
                                      into=products.estimates)
                products.finish()
            summary = summarize(result, report)
            if bag.duplicates:
                # Dropped by the reader, with or without --skip-bad (a message recorded twice
                # is no bad sample): counted beside what the validation boundary dropped (by
                # topic; the exact repeats the validation boundary dropped, if any, by
                # stream).
                summary['input']['duplicates_dropped'] = {
                    **bag.duplicates, **summary['input'].get('duplicates_dropped', {})}
            # Stated (by the bag) against used (after a params file's mounts): a calibrated
            # mount shows here.
            summary['mounts'] = {used.topic: {
                'stated': {'x_m': stated.mount.x_m, 'y_m': stated.mount.y_m,
                           'yaw_deg': math.degrees(stated.mount.yaw_rad),
                           'yaw_sigma_deg': math.degrees(stated.yaw_sigma_rad)},
                'used': {'x_m': used.mount.x_m, 'y_m': used.mount.y_m,
                         'yaw_deg': math.degrees(used.mount.yaw_rad),
                         'yaw_sigma_deg': math.degrees(used.yaw_sigma_rad)}}
                for stated, used in zip(trip.scans, result.trip.scans)}
            processed_s = time.perf_counter() - began
            summary['timing'] = {'read_s': read_s, 'run_and_outputs_s': processed_s - read_s,
                                 'real_time_factor': summary['trip']['duration_s'] / processed_s
                                 if processed_s > 0 else None}
            results.write_summary_json(staging / output_dir.SUMMARY_JSON, summary)
            if summary['map_poles_elsewhere']:
                _write_seen_map(staging / SEEN_MAP, trip, summary['map_poles_elsewhere'])
            if not args.no_plots:
                from gyro_ekf.analysis.plots import write_plots
                written = write_plots(result, staging)
                log.info('wrote %d figures', len(written))
    log.info('%s: %.1f s of trip in %.2f s (%.0fx real time, plots excluded)', trip.name,
             summary['trip']['duration_s'], processed_s,
             summary['timing']['real_time_factor'] or math.nan)
    print(_table(summary))
    verdict = summary['health']
    if args.strict and verdict['verdict'] != 'ok':
        print(f'gyro-ekf run: --strict: verdict {verdict["verdict"]}: '
              f'{verdict["reasons"][0]}', file=sys.stderr)
        return STRICT_EXIT_CODE
    return 0
