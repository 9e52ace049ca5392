"""`gyro-ekf reindex`: make a bag whose recorder was killed readable again (to stdout).

Rebuilds the MCAP summary of a .mcap cut short and the bag's metadata.yaml, keeping every
complete chunk; a bag that needs nothing is left untouched, and one with no message to
recover (an empty .mcap) is refused with nothing written (see `gyro_ekf.io.reindex`).
"""

from __future__ import annotations

import argparse
from pathlib import Path

HELP = ('rebuild the metadata.yaml and MCAP summary of a bag cut short (e.g. its recorder '
        'was killed), keeping every complete chunk')


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add this command's arguments."""
    parser.add_argument('bag', type=Path, metavar='BAG', help='rosbag2 folder with one .mcap')


def run(args: argparse.Namespace) -> int:
    """Run the command; returns the exit code."""
    from gyro_ekf.io.reindex import reindex

    result = reindex(args.bag)
    if not result.wrote_metadata:
        print(f'{args.bag}: nothing to do (metadata.yaml and the .mcap footer are in place)')
        return 0
    written = 'a new .mcap and metadata.yaml' if result.rewrote_mcap else 'metadata.yaml'
    print(f'{args.bag}: wrote {written}: {result.messages} messages on {result.topics} '
          f'topics; {result.dropped_bytes} bytes of an incomplete tail left out')
    return 0
