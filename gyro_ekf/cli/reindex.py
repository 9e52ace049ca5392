"""`gyro-ekf reindex`: make a bag whose recorder was killed readable again (to stdout).

Rebuilds the MCAP summary of a .mcap cut short and the bag's metadata.yaml, keeping every
complete chunk (a damaged one, whose CRC fails, is left out and named by its offset, the
chunks after it kept); a bag that needs nothing is left untouched, and one with no message to
recover (an empty .mcap) is refused with nothing written (see `gyro_ekf.io.reindex`).
The messages it keeps are the bag's own, so the fingerprint its params file records
(`trip.bag`) still holds; when it had to leave an incomplete tail out, the bag is no longer
the one the params file was written with, and it says so (every reader refuses the pair).
"""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

log = logging.getLogger(__name__)

HELP = ('rebuild the metadata.yaml and MCAP summary of a bag cut short (e.g. its recorder '
        'was killed), keeping every complete chunk')


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add this command's arguments."""
    parser.add_argument('bag', type=Path, metavar='BAG', help='rosbag2 folder with one .mcap')
    parser.add_argument('--drop-damaged', action='store_true',
                        help='rebuild a bag whose footer is in place but a chunk of which is '
                        'damaged (a CRC mismatch), leaving that chunk and its messages out')


def run(args: argparse.Namespace) -> int:
    """Run the command; returns the exit code."""
    from gyro_ekf.io.reindex import reindex

    from gyro_ekf.io.bag_info import verify_bag
    from gyro_ekf.io.errors import BagError

    result = reindex(args.bag)
    if not result.wrote_metadata:
        # In place is not whole: a chunk damaged inside a bag with its footer (a flipped
        # byte) was "nothing to do" here while `info` and `run` refused the bag.
        try:
            verify_bag(args.bag)
        except BagError as err:
            if not args.drop_damaged:
                raise BagError(f'{err}; the bag\'s footer and metadata.yaml are in place, '
                               'so reindex leaves it as it is: `gyro-ekf reindex --drop-'
                               'damaged` rebuilds it without the damaged chunk (its messages '
                               'are lost, the others kept)') from None
            result = reindex(args.bag, drop_damaged=True)
        else:
            print(f'{args.bag}: nothing to do (metadata.yaml and the .mcap footer are in '
                  'place, and every chunk reads whole)')
            return 0
    written = 'a new .mcap and metadata.yaml' if result.rewrote_mcap else 'metadata.yaml'
    left = [f'the damaged chunk at offset {chunk.offset} ({chunk.size} bytes: '
            f'{chunk.reason})' for chunk in result.damaged]
    if result.dropped_bytes or not left:
        left.append(f'{result.dropped_bytes} bytes of an incomplete tail')
    print(f'{args.bag}: wrote {written}: {result.messages} messages on {result.topics} '
          f'topics; left out: ' + '; '.join(left))
    note = sidecar_note(args.bag)
    if note:
        log.warning('%s', note)
    return 0


def sidecar_note(bag: Path) -> str:
    """Say whether the bag's params file still fingerprints it after a reindex ('' if so).

    Never an error: the bag is readable again either way, and each reader refuses a params
    file that is not the bag's with its own one line.
    """
    from gyro_ekf.io.bag_open import metadata
    from gyro_ekf.io.errors import BagError
    from gyro_ekf.io.sidecar import fingerprint_of, read_sidecar, sidecar_path

    try:
        params = read_sidecar(bag, check=False)
        found = fingerprint_of(metadata(bag), bag)
    except BagError as err:
        return str(err)
    if params is None or params.bag is None or params.bag == found:
        return ''
    return (f'{sidecar_path(bag)}: written with a bag of {params.bag.describe()}; {bag} now '
            f'has {found.describe()}: run, info and replay refuse the pair. If the file is '
            "this trip's (the bag lost some of its messages), delete its trip.bag entries to "
            'use it unchecked')
