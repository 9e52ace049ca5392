"""Pole detection ahead of the run (analysis.detect_ahead): the same blocks, whatever happens."""

from __future__ import annotations

import os

import numpy as np
import pytest

from gyro_ekf.analysis import detect_ahead
from gyro_ekf.analysis.detect_ahead import DetectionsAhead
from gyro_ekf.analysis.offline import run_trip
from gyro_ekf.core.config import DetectorConfig
from gyro_ekf.core.errors import CoreError
from gyro_ekf.core.simulator import SimulationConfig, simulate_trip
from gyro_ekf.core.trip_run import ScanDetector, iter_trip_events
from gyro_ekf.core.types import FloatArray

PARENT = os.getpid()


@pytest.fixture(scope='module')
def two_lidar_trip():
    """A 40 s trip with two LiDARs: blocks of both, interleaved in time."""
    return simulate_trip(SimulationConfig(duration_s=40.0, second_lidar=True), seed=3)


def _same(a: list[FloatArray], b: list[FloatArray]) -> bool:
    return len(a) == len(b) and all(
        x.dtype == y.dtype and x.shape == y.shape and np.array_equal(x, y)
        for x, y in zip(a, b))


def test_order_is_the_order_the_run_first_needs_each_block(two_lidar_trip):
    detector = ScanDetector(two_lidar_trip, DetectorConfig())
    needed, seen = [], {}
    for _, kind, series, index in iter_trip_events(two_lidar_trip):
        if kind.name == 'OBSERVATION' and index >= seen.get(series, 0):
            needed.append((series, index))
            seen[series] = index + detector.block_sizes[series]
    assert detector.order() == needed
    assert len({series for series, _ in needed}) == 2


def test_the_child_hands_over_the_same_blocks_to_the_bit(two_lidar_trip):
    detector = ScanDetector(two_lidar_trip, DetectorConfig())
    order = detector.order()
    assert len(order) >= detect_ahead.MIN_BLOCKS
    with DetectionsAhead(detector) as ahead:
        assert ahead.ahead  # a child runs (two cores here)
        for series, begin in order:
            assert _same(ahead(series, begin), detector.block(series, begin))
        assert ahead.ahead  # never fell back
    assert not ahead.ahead  # reaped


def test_run_trip_gives_the_same_numbers_with_the_child(two_lidar_trip):
    plain = run_trip(two_lidar_trip)
    ahead = run_trip(two_lidar_trip, detect_ahead=True)
    for a, b in ((plain.result.estimates.state, ahead.result.estimates.state),
                 (plain.result.estimates.covariance, ahead.result.estimates.covariance),
                 (plain.result.updates.nis, ahead.result.updates.nis)):
        assert np.array_equal(a, b)
    assert plain.result.stats == ahead.result.stats


class _DiesInChild(ScanDetector):
    """Fails at one block in the child only (as a child killed there would stop)."""

    def block(self, series, begin):
        if os.getpid() != PARENT and (series, begin) == self.order()[2]:
            os._exit(3)
        return super().block(series, begin)


def test_a_child_that_stops_is_replaced_by_detection_here(two_lidar_trip):
    detector = _DiesInChild(two_lidar_trip, DetectorConfig())
    reference = ScanDetector(two_lidar_trip, DetectorConfig())
    with DetectionsAhead(detector) as ahead:
        for n, (series, begin) in enumerate(detector.order()):
            assert _same(ahead(series, begin), reference.block(series, begin))
            assert ahead.ahead == (n < 2)


def test_a_block_asked_out_of_order_is_found_here(two_lidar_trip):
    detector = ScanDetector(two_lidar_trip, DetectorConfig())
    series, begin = detector.order()[1]
    with DetectionsAhead(detector) as ahead:
        assert _same(ahead(series, begin), detector.block(series, begin))
        assert not ahead.ahead


class _FailsAt(ScanDetector):
    def block(self, series, begin):
        if (series, begin) == self.order()[-1]:
            raise CoreError('detector failed here')
        return super().block(series, begin)


def test_a_detection_error_is_raised_by_the_run_itself(two_lidar_trip, monkeypatch):
    monkeypatch.setattr('gyro_ekf.analysis.offline.ScanDetector', _FailsAt)
    with pytest.raises(CoreError, match='detector failed here'):
        run_trip(two_lidar_trip, detect_ahead=True)


def test_no_child_without_a_spare_core_or_for_a_short_trip(two_lidar_trip, monkeypatch):
    detector = ScanDetector(two_lidar_trip, DetectorConfig())
    monkeypatch.setattr(detect_ahead, 'spare_core', lambda: False)
    with DetectionsAhead(detector) as ahead:
        assert not ahead.ahead
        series, begin = detector.order()[0]
        assert _same(ahead(series, begin), detector.block(series, begin))
    monkeypatch.setattr(detect_ahead, 'spare_core', lambda: True)
    monkeypatch.setattr(detect_ahead, 'MIN_BLOCKS', len(detector.order()) + 1)
    with DetectionsAhead(detector) as ahead:
        assert not ahead.ahead
