"""Fixtures of the io tests: a synthetic trip and bags of the real logs shared per module."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import pytest
from synthetic_logs import make_trip

from gyro_ekf.core.types import Trip


@pytest.fixture
def synthetic_trip() -> Trip:
    """Build a hand-made trip with every optional part present."""
    return make_trip()


@pytest.fixture(scope='module')
def converted(tmp_path_factory) -> Callable[..., tuple[Trip, Path]]:
    """Return convert(key, paths, storage='mcap') -> (trip, bag), converting each key once.

    Tests pass paths obtained from `shared_data` (which skips or fails when the data is
    missing), so the expensive conversion of a real log runs once per test module.
    """
    from gyro_ekf.io.bag_writer import write_trip_bag
    from gyro_ekf.io.matlab import load_course_log

    cache: dict[str, tuple[Trip, Path]] = {}

    def convert(key: str, paths: list[Path], storage: str = 'mcap') -> tuple[Trip, Path]:
        if key not in cache:
            trip = load_course_log(paths)
            bag = tmp_path_factory.mktemp(key) / key
            write_trip_bag(trip, bag, storage=storage)
            cache[key] = (trip, bag)
        return cache[key]
    return convert
