"""`gyro-ekf convert`: a course log or simulator trip -> ROS 2 bag plus params sidecar.

The bag layer (scipy, rosbags) is imported when the command runs, so `gyro-ekf --help` and
the other commands do not pay for it.
"""

from __future__ import annotations

import argparse
from datetime import datetime, timezone
from decimal import Decimal, InvalidOperation
import logging
from pathlib import Path
import sys
import time

from typing import Any, Callable

from gyro_ekf.core.stamps import NS_PER_S
from gyro_ekf.io.defaults import DEFAULT_EPOCH_NS, STORAGE_NAMES
from gyro_ekf.io.errors import BagError

HELP = ('convert a course log (2016 trio, 2021 event table + map, 2022/2023 simulation) or '
        'a simulator trip (.npz) into a ROS 2 bag')

log = logging.getLogger(__name__)

LAST_STAMP_NS = 2**31 * NS_PER_S
"""Message stamps (builtin_interfaces/Time) hold int32 seconds: none reaches this time."""
LAST_STAMP_TEXT = '2038-01-19T03:14:08Z'
"""LAST_STAMP_NS in words."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add this command's arguments."""
    parser.add_argument('sources', nargs='+', type=Path, metavar='SRC',
                        help='the log: its .mat files or their folder, or one trip .npz')
    parser.add_argument('-o', '--output', type=Path, required=True, metavar='OUT_BAG',
                        help='bag folder to create; OUT_BAG.params.yaml is written beside it')
    parser.add_argument('--storage', choices=STORAGE_NAMES, default=STORAGE_NAMES[0],
                        help='rosbag2 storage plugin')
    parser.add_argument('--map', type=Path, metavar='MAP.mat',
                        help='landmark map (MapMTRN4010.mat) for the 2016/2021 logs, if it '
                        'is not beside them')
    parser.add_argument('--start-time', default=None, metavar='T',
                        help='bag time of the log\'s time zero: seconds since 1970 (e.g. '
                        '1700000000.25) or an ISO 8601 time (e.g. 2024-03-01T09:00:00Z); '
                        f'default {DEFAULT_EPOCH_NS // NS_PER_S} s = 2023-11-14T22:13:20Z')
    parser.add_argument('--force', action='store_true',
                        help='replace an existing OUT_BAG and its params file')
    add_skip_bad_argument(parser)


def add_skip_bad_argument(parser: argparse.ArgumentParser) -> None:
    """Add the --skip-bad option of the commands that read logs or bags."""
    parser.add_argument('--skip-bad', action='store_true',
                        help='drop samples that fail the input checks (not finite, beyond '
                        'the limits, stamps going back or a lone stamp far ahead) and count '
                        'them, instead of stopping at the first')


def warn_dropped(report: Any) -> None:
    """Log the one warning line of an InputReport that dropped or flagged anything."""
    line = report.warning()
    if line:
        log.warning('%s', line)


def parse_start_time(text: str) -> int:
    """Parse a start time (seconds since 1970 or ISO 8601) into integer ns since the epoch.

    Raises:
        BagError: unparsable, or not after the epoch (0 means "unset" in ROS).
    """
    try:
        value = Decimal(text)
        if not value.is_finite():
            raise BagError(f'--start-time {text!r}: not a finite number of seconds')
        ns = int(value * NS_PER_S)
    except InvalidOperation:
        try:
            moment = datetime.fromisoformat(text)
        except ValueError:
            raise BagError(f'--start-time {text!r}: expected seconds since 1970 or an ISO 8601 '
                           'time such as 2024-03-01T09:00:00Z') from None
        if moment.tzinfo is None:
            moment = moment.replace(tzinfo=timezone.utc)
        delta = moment - datetime(1970, 1, 1, tzinfo=timezone.utc)
        ns = (delta.days * 86_400 + delta.seconds) * NS_PER_S + delta.microseconds * 1000
    if ns <= 0:
        raise BagError(f'--start-time {text!r}: must be after 1970-01-01 (0 reads as "unset")')
    if ns >= LAST_STAMP_NS:
        raise BagError(f'--start-time {text!r}: not before {LAST_STAMP_TEXT}, the last time '
                       'a message stamp can hold (int32 seconds)')
    return ns


def _progress_bar() -> tuple[Callable[[int, int], None] | None, Any]:
    if not sys.stderr.isatty():
        return None, None
    try:
        from tqdm import tqdm
    except ImportError:  # tqdm is an install requirement; degrade quietly without it
        return None, None
    bar = tqdm(total=0, unit='msg', unit_scale=True, desc='writing', file=sys.stderr,
               leave=False)

    def update(done: int, total: int) -> None:
        bar.total = total
        bar.n = done
        bar.refresh()
    return update, bar


def run(args: argparse.Namespace) -> int:
    """Run the command; returns the exit code."""
    from gyro_ekf.io.bag_writer import write_trip_bag
    from gyro_ekf.io.sidecar import sidecar_path
    from gyro_ekf.io.sources import load_checked_log

    start_ns = DEFAULT_EPOCH_NS if args.start_time is None else parse_start_time(
        str(args.start_time))
    output = Path(args.output)
    if not args.force:
        for existing in (output, sidecar_path(output)):
            if existing.exists():
                raise BagError(f'{existing}: exists already; use --force to replace it')
    began = time.monotonic()
    trip, report = load_checked_log(args.sources, args.map, skip_bad=args.skip_bad)
    warn_dropped(report)
    if start_ns + trip.end_s * NS_PER_S >= LAST_STAMP_NS:
        raise BagError(f'--start-time {args.start_time!r}: the {trip.end_s:g} s log would end '
                       f'after {LAST_STAMP_TEXT}, the last time a message stamp can hold')
    progress, bar = _progress_bar()
    try:
        # What --skip-bad dropped goes into the sidecar: a run on the bag counts it too.
        write_trip_bag(trip, output, storage=args.storage, start_time_ns=start_ns,
                       force=args.force, progress=progress, converted=report)
    finally:
        if bar is not None:
            bar.close()
    log.info('wrote %s and %s in %.1f s', output, sidecar_path(output).name,
             time.monotonic() - began)
    return 0
