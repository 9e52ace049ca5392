"""`gyro-ekf simulate`: a seeded simulated trip with ground truth, as a bag or a trip file."""

from __future__ import annotations

import argparse
import dataclasses
import logging
import math
from pathlib import Path

from gyro_ekf.core.config import field_bounds
from gyro_ekf.core.errors import CoreError
from gyro_ekf.core.simulator import SimulationConfig, simulate_trip
from gyro_ekf.errors import GyroEkfError

HELP = 'simulate a course-like trip with ground truth and write it as a bag or .npz file'

log = logging.getLogger(__name__)


def _seed(text: str) -> int:
    """Parse a seed: a non-negative integer (numpy's SeedSequence refuses negatives)."""
    value = int(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f'must be >= 0, got {value}')
    return value


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add this command's arguments."""
    defaults = SimulationConfig()
    parser.add_argument('-o', '--output', type=Path, required=True,
                        help='output: a bag folder, or a trip file when it ends in .npz')
    parser.add_argument('--seed', type=_seed, default=0, help='random seed (>= 0)')
    parser.add_argument('--duration-s', type=float, default=defaults.duration_s,
                        help='trip length, s')
    parser.add_argument('--static-s', type=float, default=None,
                        help='static window at the start (speed exactly 0), s, at most '
                        f'--duration-s (default {defaults.static_s:g} s, or the whole trip '
                        'when that is shorter)')
    parser.add_argument('--second-lidar', action='store_true',
                        help='add a rear-facing second LiDAR on topic scan2, as in the 2023 logs')
    for which, name in (('lidar', 'first'), ('lidar2', 'second')):
        flag = which.replace('_', '-')
        parser.add_argument(f'--{flag}-yaw-error-deg', type=float, default=0.0,
                            help=f'true minus stated yaw of the {name} LiDAR, deg (the bag '
                            'states the nominal mount)')
        parser.add_argument(f'--{flag}-offset-m', type=float, nargs=2, default=(0.0, 0.0),
                            metavar=('X', 'Y'),
                            help=f'true minus stated x and y of the {name} LiDAR, m')
    parser.add_argument('--static-turn-deg-s', type=float, default=0.0,
                        help='turn in place through the static window, deg/s: the odometry '
                        'reads no speed, the gyro and the LiDARs see the turn (a static '
                        'calibration takes it for bias unless the scans refuse the window)')
    parser.add_argument('--storage', choices=('mcap', 'sqlite3'), default='mcap',
                        help='bag storage plugin (ignored for .npz output)')
    parser.add_argument('--force', action='store_true', help='replace an existing output')


def check_options(args: argparse.Namespace) -> None:
    """Refuse options that are not finite, beyond the simulator's bounds or inconsistent.

    Each is checked here, in the option's own name and unit, before the simulator sees it
    (its bounds let NaN pass, and it names its fields in radians).

    Raises:
        GyroEkfError: one line naming the option.
    """
    from gyro_ekf.cli.main import check_number

    check_number('--duration-s', args.duration_s, *field_bounds(SimulationConfig, 'duration_s'),
                 unit='s')
    if args.static_s is None:
        args.static_s = min(SimulationConfig().static_s, args.duration_s)
    check_number('--static-s', args.static_s, *field_bounds(SimulationConfig, 'static_s'),
                 unit='s')
    if args.static_s > args.duration_s:
        raise GyroEkfError(f'--static-s: {args.static_s:g} s is longer than the trip '
                           f'(--duration-s {args.duration_s:g} s)')
    check_number('--static-turn-deg-s', args.static_turn_deg_s,
                 *field_bounds(SimulationConfig, 'static_turn_rad_s', math.radians(1.0)),
                 unit='deg/s')
    if args.static_turn_deg_s and not args.static_s:
        raise GyroEkfError('--static-turn-deg-s: the turn is made through the static window, '
                           'and --static-s is 0')
    for which in ('lidar', 'lidar2'):
        check_number(f'--{which}-yaw-error-deg', getattr(args, f'{which}_yaw_error_deg'),
                     *field_bounds(SimulationConfig, f'{which}_yaw_error_rad',
                                   math.radians(1.0)), unit='deg')
        for axis, value in zip('xy', getattr(args, f'{which}_offset_m')):
            check_number(f'--{which}-offset-m ({axis.upper()})', value,
                         *field_bounds(SimulationConfig, f'{which}_{axis}_error_m'), unit='m')


def run(args: argparse.Namespace) -> int:
    """Simulate and write the trip; returns the exit code."""
    check_options(args)
    second = args.second_lidar
    if not second and (args.lidar2_yaw_error_deg or any(args.lidar2_offset_m)):
        raise CoreError('simulate: --lidar2-* mount errors need --second-lidar')
    config = dataclasses.replace(
        SimulationConfig(), duration_s=args.duration_s, static_s=args.static_s,
        second_lidar=second,
        lidar_yaw_error_rad=math.radians(args.lidar_yaw_error_deg),
        lidar_x_error_m=args.lidar_offset_m[0], lidar_y_error_m=args.lidar_offset_m[1],
        lidar2_yaw_error_rad=math.radians(args.lidar2_yaw_error_deg),
        lidar2_x_error_m=args.lidar2_offset_m[0], lidar2_y_error_m=args.lidar2_offset_m[1],
        static_turn_rad_s=math.radians(args.static_turn_deg_s))
    trip = simulate_trip(config, seed=args.seed)
    output: Path = args.output
    # io pulls in rosbags; import it only once there is something to write.
    if output.suffix == '.npz':
        from gyro_ekf.io.errors import LogFormatError
        from gyro_ekf.io.products import os_reason
        from gyro_ekf.io.trip_file import save_trip

        if output.is_symlink() or (output.exists() and not output.is_file()):
            raise LogFormatError(f'{output}: exists and is not a trip file; --force replaces '
                                 'only a file')
        try:
            written = save_trip(trip, output, force=args.force)
        except OSError as err:
            raise LogFormatError(f'{output}: cannot write the trip file: {os_reason(err)}'
                                 ) from None
    else:
        from gyro_ekf.io.bag_writer import write_trip_bag
        written = write_trip_bag(trip, output, storage=args.storage, force=args.force)
    log.info('%s: %s, %.1f s (%.1f s static), %d scans x %d LiDARs, %d landmarks, '
             'z bias %.3f deg/s', written, trip.name, trip.end_s, trip.static_duration_s,
             len(trip.scans[0].stamp_s), len(trip.scans), len(trip.landmarks),
             math.degrees(trip.true_gyro_bias_rad_s[2]))
    if config.static_turn_rad_s:
        log.info('%s: turning in place at %+g deg/s through the static window (%g deg in '
                 'all), the odometry reading no speed', written,
                 args.static_turn_deg_s, args.static_turn_deg_s * config.static_s)
    for (stated, true), scans in zip(config.lidar_mounts(), trip.scans):
        if true != stated:
            log.info('%s: true mount (%.4f m, %.4f m, %.3f deg), the bag states '
                     '(%.4f m, %.4f m, %.3f deg)', scans.topic, true.x_m, true.y_m,
                     math.degrees(true.yaw_rad), stated.x_m, stated.y_m,
                     math.degrees(stated.yaw_rad))
    return 0
