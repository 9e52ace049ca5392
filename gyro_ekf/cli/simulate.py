"""`gyro-ekf simulate`: a seeded simulated trip with ground truth, as a bag or a trip file."""

from __future__ import annotations

import argparse
import dataclasses
import logging
import math
from pathlib import Path

from gyro_ekf.core.simulator import SimulationConfig, simulate_trip

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
    parser.add_argument('--static-s', type=float, default=defaults.static_s,
                        help='static window at the start (speed exactly 0), s')
    parser.add_argument('--storage', choices=('mcap', 'sqlite3'), default='mcap',
                        help='bag storage plugin (ignored for .npz output)')
    parser.add_argument('--force', action='store_true', help='replace an existing output')


def run(args: argparse.Namespace) -> int:
    """Simulate and write the trip; returns the exit code."""
    config = dataclasses.replace(SimulationConfig(), duration_s=args.duration_s,
                                 static_s=args.static_s)
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
    log.info('%s: %s, %.1f s (%.1f s static), %d scans, %d landmarks, z bias %.3f deg/s',
             written, trip.name, trip.end_s, trip.static_duration_s,
             len(trip.scans[0].stamp_s), len(trip.landmarks),
             math.degrees(trip.true_gyro_bias_rad_s[2]))
    return 0
