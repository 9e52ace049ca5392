"""`python -m benchmarks -o results/bench.json`: the benchmarks of `make bench` (never a test)."""

from __future__ import annotations

import argparse
import logging
from pathlib import Path
import sys

DESCRIPTION = ('benchmark the core against filterpy, `run` speed, peak memory, the live nodes '
               'and a 10x replay; write JSON')

log = logging.getLogger(__name__)

DEFAULT_DATA = Path(__file__).resolve().parents[1].parent / 'shared' / 'data' / 'mtrn4010'


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
    from benchmarks.bench import run_all, table
    from gyro_ekf.io.results import write_summary_json

    results = run_all(args.data, args.long_trip_s, args.core_steps, live_s=args.live_s)
    args.output.parent.mkdir(parents=True, exist_ok=True)
    write_summary_json(args.output, results)
    log.info('wrote %s', args.output)
    print(table(results))
    return 0


def main(argv: list[str] | None = None) -> int:
    """Parse the arguments, run the benchmarks, write the JSON; returns the exit code."""
    parser = argparse.ArgumentParser(prog='python -m benchmarks', description=DESCRIPTION)
    add_arguments(parser)
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format='%(levelname)s %(name)s: %(message)s')
    from gyro_ekf.errors import GyroEkfError
    try:
        return run(args)
    except GyroEkfError as error:  # one line, no traceback (as the gyro-ekf commands do)
        print(f'error: {error}', file=sys.stderr)
        return 1


if __name__ == '__main__':
    sys.exit(main())
