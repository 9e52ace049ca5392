"""`gyro-ekf stress -o results/stress.json`: the stress suite of `make stress` (never a test).

Seeded simulated trips per perturbation class (analysis.stress, docs/stress.md) through the
offline pipeline of `gyro-ekf run`; prints per class the share within the bounds and the
share that failed silently (a bound missed while the health verdict said ok).
"""

from __future__ import annotations

import argparse
import logging
from pathlib import Path
import sys

HELP = ('run seeded simulated trips per perturbation class offline; print the share within '
        'the bounds and the silent failures; write JSON')

log = logging.getLogger(__name__)


def _at_least(low: int) -> type:
    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            value = low - 1
        if value < low:
            raise argparse.ArgumentTypeError(f'{text!r}: must be a whole number >= {low}')
        return value
    return parse  # type: ignore[return-value]


def _duration(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        value = 0.0
    if not 20.0 <= value <= 3600.0:
        raise argparse.ArgumentTypeError(f'{text!r}: must be a number of seconds in [20, 3600]')
    return value


def _static(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        value = -1.0
    if not 0.0 <= value <= 1800.0:
        raise argparse.ArgumentTypeError(f'{text!r}: must be a number of seconds in [0, 1800]')
    return value


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add this command's arguments."""
    from gyro_ekf.analysis.stress import DEFAULT_DURATION_S
    parser.add_argument('-o', '--output', type=Path, default=Path('results/stress.json'),
                        help='JSON file to write')
    parser.add_argument('--force', action='store_true', help='replace an existing output')
    parser.add_argument('--trips-per-class', type=_at_least(1), default=25,
                        help='seeded trips per perturbation class')
    parser.add_argument('--seed', type=_at_least(0), default=0, help='base seed of the suite')
    parser.add_argument('--workers', type=_at_least(1), default=2,
                        help='worker processes (1: in this process)')
    parser.add_argument('--duration-s', type=_duration, default=DEFAULT_DURATION_S,
                        help='length of each simulated trip, s')
    parser.add_argument('--static-s', type=_static, default=None,
                        help='static start of every trip, s, at most half the trip (default: '
                        "the simulator's 8 s, or a quarter of a trip shorter than 32 s)")


def run(args: argparse.Namespace) -> int:
    """Run the command; returns the exit code."""
    from tqdm import tqdm

    from gyro_ekf.analysis.stress import (CLASSES, MAX_STATIC_SHARE, base_config, run_suite,
                                          table)
    from gyro_ekf.errors import GyroEkfError
    from gyro_ekf.io.output_dir import check_output_file
    from gyro_ekf.io.results import write_summary_json

    try:
        # The suite's own rule, checked before any worker starts.
        base_config(args.duration_s, args.static_s)
    except ValueError:
        raise GyroEkfError(f'--static-s {args.static_s:g}: at most {MAX_STATIC_SHARE:g} of '
                           f'--duration-s {args.duration_s:g} (the rest of each trip is driven)'
                           ) from None
    check_output_file(args.output, args.force, 'a JSON', create_parent=True)
    total = args.trips_per_class * len(CLASSES)
    with tqdm(total=total, unit='trip', desc='stress', leave=False, file=sys.stderr,
              disable=not sys.stderr.isatty()) as bar:
        results = run_suite(args.trips_per_class, args.seed, args.workers, args.duration_s,
                            progress=bar.update, static_s=args.static_s)
    # Staged beside the output and renamed onto it: an earlier file stays whole until then.
    write_summary_json(args.output, results)
    print(table(results), flush=True)
    log.info('wrote %s', args.output)
    return 0
