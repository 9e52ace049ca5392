"""`gyro-ekf info`: topics, types, counts, duration and start time of a bag (to stdout).

It also reads the bag's storage files through and checks them as `run` does (CRCs,
lengths, log times; `io.bag_info.verify_bag`): a damaged bag is a one-line error naming the
file and the chunk, exit 1, and nothing is printed. The counts, start and duration
metadata.yaml states must be what that read found (`io.bag_info.check_metadata`), or it is
a one-line error naming each field with both values. `--no-verify` reads the metadata only.
A params file beside the bag that was written with another bag (its `trip.bag` fingerprint
differs from the bag's) is a one-line error naming both (`io.bag_info.check_sidecar`); one
without a fingerprint (older versions) is shown as not fingerprinted.
"""

from __future__ import annotations

import argparse
from datetime import datetime, timezone
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from gyro_ekf.io.bag_info import BagSummary, FileCheck

HELP = ('print the topics, types, message counts, duration and start time of a bag, after '
        'checking its bytes (CRCs) as run does')


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add this command's arguments."""
    parser.add_argument('bag', type=Path, metavar='BAG', help='rosbag2 folder')
    parser.add_argument('--no-verify', action='store_true',
                        help='read the metadata only; by default every storage file is read '
                        'through and its CRCs, lengths and log times are checked (about 1-2 s '
                        'per hour of bag)')


def iso_time(stamp_ns: int) -> str:
    """UTC ISO 8601 text of ns since the epoch, to the nanosecond."""
    from gyro_ekf.core.stamps import split_ns

    seconds, nanoseconds = split_ns(stamp_ns)
    moment = datetime.fromtimestamp(seconds, tz=timezone.utc)
    return moment.strftime('%Y-%m-%dT%H:%M:%S') + f'.{nanoseconds:09d}Z'


def format_check(check: FileCheck) -> str:
    """Say what was checked in one storage file."""
    verified = check.verified
    if verified is None:
        return f'{check.name}: not checked ({check.why_not})'
    crcs = []
    if verified.data_crc:
        crcs.append('data section (covers every chunk)')
    elif verified.chunk_crcs:
        crcs.append(f'{verified.chunk_crcs} of {verified.chunks} chunks')
    if verified.summary_crc:
        crcs.append('summary')
    said = (f'CRCs match: {", ".join(crcs)}' if crcs else
            'the file carries no CRCs, so only lengths and log times were checked')
    chunks = f'{verified.chunks} chunk' + ('' if verified.chunks == 1 else 's')
    return f'{check.name}: {chunks} read; {said}'


def _params_line(summary: BagSummary) -> str:
    """Name the sidecar and say whether it was checked against the bag."""
    if summary.sidecar is None:
        return '(none)'
    if summary.params is None or summary.params.bag is None:
        return (f'{summary.sidecar} (sidecar: not fingerprinted, written before gyro_ekf '
                'recorded its bag or by hand; not checked against this bag)')
    return f'{summary.sidecar} (fingerprint matches this bag)'


def format_summary(summary: BagSummary, checks: list[FileCheck] | None = None) -> str:
    """Render the text `info` prints; checks None: the files were not read (--no-verify)."""
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
        f'params:    {_params_line(summary)}',
    ]
    converted = summary.converted
    if converted is not None and converted.total_dropped:
        lines.append(f'dropped:   when {converted.source} was converted, --skip-bad '
                     f'{converted.dropped_text(indexes=True)}; indexes count in the log, '
                     'these samples are not in the bag')
    if checks is None:
        lines.append('checked:   not checked (--no-verify)')
    for k, check in enumerate(checks or ()):
        lines.append(('checked:   ' if k == 0 else ' ' * 11) + format_check(check))
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
    from gyro_ekf.io.bag_info import bag_summary, check_metadata, check_sidecar, verify_bag
    from gyro_ekf.io.errors import BagError
    from gyro_ekf.io.reindex import needs_reindex

    reason = needs_reindex(args.bag)
    if reason is not None:
        raise BagError(f'{args.bag}: {reason}; run `gyro-ekf reindex {args.bag}`')
    summary = bag_summary(args.bag, check=False)
    # Checked before anything is printed: a damaged bag gets its one line only.
    checks = None if args.no_verify else verify_bag(args.bag)
    if checks is not None:
        check_metadata(summary, checks)
    # After the metadata is held to the data: the bag's fingerprint is what it states.
    check_sidecar(summary)
    print(format_summary(summary, checks))
    return 0
