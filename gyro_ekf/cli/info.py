"""`gyro-ekf info`: topics, types, counts, duration and start time of a bag (to stdout)."""

from __future__ import annotations

import argparse
from datetime import datetime, timezone
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from gyro_ekf.io.bag_info import BagSummary

HELP = 'print the topics, types, message counts, duration and start time of a bag'


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add this command's arguments."""
    parser.add_argument('bag', type=Path, metavar='BAG', help='rosbag2 folder')


def iso_time(stamp_ns: int) -> str:
    """UTC ISO 8601 text of ns since the epoch, to the nanosecond."""
    from gyro_ekf.core.stamps import split_ns

    seconds, nanoseconds = split_ns(stamp_ns)
    moment = datetime.fromtimestamp(seconds, tz=timezone.utc)
    return moment.strftime('%Y-%m-%dT%H:%M:%S') + f'.{nanoseconds:09d}Z'


def format_summary(summary: BagSummary) -> str:
    """Render the text `info` prints."""
    from gyro_ekf.core.stamps import seconds_since

    # rosbag2 states the largest int64 as the start of a bag without messages.
    empty = summary.message_count == 0
    lines = [
        f'bag:       {summary.path}',
        f'storage:   {summary.storage} (rosbag2 metadata version {summary.version})',
        'start:     - (the bag has no messages)' if empty else
        f'start:     {iso_time(summary.start_time_ns)} ({summary.start_time_ns} ns)',
        f'duration:  {0.0 if empty else seconds_since(summary.duration_ns, 0):.4f} s',
        f'messages:  {summary.message_count}',
        f'params:    {summary.sidecar if summary.sidecar is not None else "(none)"}',
    ]
    converted = summary.converted
    if converted is not None and converted.total_dropped:
        lines.append(f'dropped:   when {converted.source} was converted, --skip-bad '
                     f'{converted.dropped_text(indexes=True)}; indexes count in the log, '
                     'these samples are not in the bag')
    lines.append('topics:')
    rows = [('topic', 'type', 'count', 'durability')] + [
        (t.name, t.msgtype, str(t.count), t.durability) for t in summary.topics]
    widths = [max(len(row[i]) for row in rows) for i in range(3)]
    for name, msgtype, count, durability in rows:
        lines.append(f'  {name:<{widths[0]}}  {msgtype:<{widths[1]}}  '
                     f'{count:>{widths[2]}}  {durability}')
    return '\n'.join(lines)


def run(args: argparse.Namespace) -> int:
    """Run the command; returns the exit code."""
    from gyro_ekf.io.bag_info import bag_summary
    from gyro_ekf.io.errors import BagError
    from gyro_ekf.io.reindex import needs_reindex

    reason = needs_reindex(args.bag)
    if reason is not None:
        raise BagError(f'{args.bag}: {reason}; run `gyro-ekf reindex {args.bag}`')
    print(format_summary(bag_summary(args.bag)))
    return 0
