"""`gyro-ekf bench -o results/bench.json`: the benchmarks of `make bench` (never a test)."""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

HELP = ('benchmark the core against filterpy, `run` speed, peak memory and live ekf_node '
        'latency; write JSON')

log = logging.getLogger(__name__)

DEFAULT_DATA = Path(__file__).resolve().parents[2].parent / 'shared' / 'data' / 'mtrn4010'


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add this command's arguments."""
    parser.add_argument('-o', '--output', type=Path, default=Path('results/bench.json'),
                        help='JSON file to write')
    parser.add_argument('--data', type=Path, default=DEFAULT_DATA,
                        help='folder of the course logs (for the 2016 real-time factor)')
    parser.add_argument('--long-trip-s', type=float, default=3600.0,
                        help='length of the simulated trip of the memory benchmark, s')
    parser.add_argument('--core-steps', type=int, default=20_000,
                        help='predict+update cycles of the core benchmark')
    parser.add_argument('--live-s', type=float, default=10.0,
                        help='measured length of each live ekf_node case (200 Hz, 1 kHz, ...), '
                             's; 0 skips the live benchmark')


def run(args: argparse.Namespace) -> int:
    """Run the command; returns the exit code."""
    from gyro_ekf.analysis.bench import run_all, table
    from gyro_ekf.io.results import write_summary_json

    results = run_all(args.data, args.long_trip_s, args.core_steps, live_s=args.live_s)
    args.output.parent.mkdir(parents=True, exist_ok=True)
    write_summary_json(args.output, results)
    log.info('wrote %s', args.output)
    print(table(results))
    return 0
