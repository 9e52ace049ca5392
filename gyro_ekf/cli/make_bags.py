"""`gyro-ekf make-bags`: rebuild the bundled sample bags from the simulator, bit for bit."""

from __future__ import annotations

import argparse
import dataclasses
import logging
from pathlib import Path
from typing import Any, NamedTuple

HELP = 'rebuild the bundled sample bags (deterministic simulator trips)'

log = logging.getLogger(__name__)


class BundledBag(NamedTuple):
    """One sample bag: simulator seed and settings, and what it is for."""

    name: str
    seed: int
    settings: dict[str, Any]
    description: str


BUNDLED_BAGS = (
    # Without the accelerometer (nothing here uses it, and its noise does not compress) the
    # two bags stay under 5 MB together.
    BundledBag('sim_static_start', 1,
               {'duration_s': 90.0, 'static_s': 8.0, 'with_accelerometer': False},
               '90 s trip, static for the first 8 s (calibration works), then a '
               'figure-eight among 14 poles; 3-axis gyro bias (0.35, -0.55, -0.90) deg/s; '
               'ground truth. The default input of `make demo`.'),
    BundledBag('sim_moving_start', 2,
               {'duration_s': 45.0, 'static_s': 0.0, 'with_accelerometer': False},
               '45 s trip that moves from t = 0 like the 2022/2023 course logs: calibration '
               'must refuse it and the EKF must find the bias on its own; ground truth.'),
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add this command's arguments."""
    parser.add_argument('directory', type=Path, help='where the bags go (bags/ in the repo)')
    parser.add_argument('--force', action='store_true', help='replace existing bags')


def build_bundled_bags(directory: Path, force: bool = False) -> list[Path]:
    """Simulate and write every bundled bag (with its params sidecar) into directory."""
    from gyro_ekf.core.simulator import SimulationConfig, simulate_trip
    from gyro_ekf.io.bag_writer import write_trip_bag
    from gyro_ekf.io.errors import BagError
    from gyro_ekf.io.products import os_reason

    try:
        directory.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise BagError(f'{directory}: cannot write the bags: {os_reason(err)}') from None
    written = []
    for bag in BUNDLED_BAGS:
        config = dataclasses.replace(SimulationConfig(), **bag.settings)
        trip = dataclasses.replace(simulate_trip(config, seed=bag.seed), name=bag.name)
        path = directory / bag.name
        write_trip_bag(trip, path, storage='mcap', force=force, compress=True)
        log.info('wrote %s', path)
        written.append(path)
    return written


def run(args: argparse.Namespace) -> int:
    """Write the bundled bags and list them."""
    for path in build_bundled_bags(args.directory, args.force):
        size = sum(f.stat().st_size for f in path.rglob('*') if f.is_file())
        print(f'{path}  {size / 1e6:.2f} MB')
    return 0
