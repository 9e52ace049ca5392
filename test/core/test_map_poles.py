"""Mapped poles that stand elsewhere (core/map_poles.py), and the verdict that names them."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from gyro_ekf.analysis.offline import run_trip
from gyro_ekf.analysis.summary import summarize
from gyro_ekf.core.map_poles import MIN_LOOKS, MapPoleWatch
from gyro_ekf.core.simulator import SimulationConfig, simulate_trip

POLES = [[0.0, 0.0], [5.0, 1.0], [-3.0, 4.0]]


def _looked(looks, matched=(0, 0, 0)) -> MapPoleWatch:
    watch = MapPoleWatch(len(POLES))
    watch.matched[:] = matched
    for pole, dx, dy in looks:
        watch.look(pole, dx, dy)
    return watch


def test_looks_that_cluster_off_a_pole_find_where_it_stands():
    rng = np.random.default_rng(0)
    looks = [(1, 0.2 + e, -0.1 + f) for e, f in rng.normal(0.0, 0.01, (40, 2))]
    [found] = _looked(looks).report(POLES)
    assert found['index'] == 1 and found['looks'] == 40
    assert found['seen_xy_m'] == pytest.approx([5.2, 0.9], abs=0.01)
    assert found['offset_m'] == pytest.approx(np.hypot(0.2, 0.1), abs=0.01)
    assert found['spread_m'] == pytest.approx(0.01 * np.sqrt(2.0), rel=0.3)


def test_misses_on_every_side_of_a_pole_and_a_few_looks_find_nothing():
    rng = np.random.default_rng(1)
    # The gate's misses of a pole where the map has it: about as far, on every side.
    angles = rng.uniform(0.0, 2.0 * np.pi, 200)
    around = [(0, 0.08 * np.cos(a), 0.08 * np.sin(a)) for a in angles]
    # A lost pose: offsets that scatter as much as they lie off.
    scattered = [(2, 0.3 + e, f) for e, f in rng.normal(0.0, 0.4, (200, 2))]
    few = [(1, 0.3, 0.0)] * (MIN_LOOKS - 1)
    assert _looked(around + scattered + few).report(POLES) == []
    assert len(_looked(few + [(1, 0.3, 0.0)]).report(POLES)) == 1
    # Another object near a pole, seen while the pole is hidden: the pole itself was
    # matched more often where the map has it.
    assert _looked(few * 2, matched=(0, 2 * MIN_LOOKS, 0)).report(POLES) == []


def test_restore_takes_looks_back_and_the_report_follows():
    watch = _looked([(1, 0.3, 0.0)] * 30)
    assert len(watch.report(POLES)) == 1  # summed up to here
    saved = watch.save()
    for _ in range(40):
        watch.look(2, 0.0, 0.5)
    watch.matched[1] += 100
    assert [p['index'] for p in watch.report(POLES)] == [2]
    watch.restore(saved)
    assert [p['index'] for p in watch.report(POLES)] == [1]
    watch.restore((10, (0, 0, 0)))
    assert watch.looks == 10 and watch.report(POLES) == []


def _moved(trip, index: int, dx: float, dy: float):
    xy = trip.landmarks.xy_m.copy()
    xy[index] += (dx, dy)
    return dataclasses.replace(trip, landmarks=dataclasses.replace(trip.landmarks, xy_m=xy))


def test_a_trip_whose_map_has_a_pole_off_names_it_and_where_it_stands():
    # The map has one pole 0.25 m from where it stands (moved after the survey): its
    # detections fall outside the gate, the run used to say only that fewer were
    # associated. The estimates stay within the bounds.
    trip = simulate_trip(SimulationConfig(duration_s=60.0), 3)
    seen = summarize(run_trip(trip))
    # The pole the trip passes nearest: seen on every lap.
    path = trip.ground_truth.pose[:, :2]
    busiest = int(np.argmin([np.min(np.hypot(*(path - xy).T)) for xy in trip.landmarks.xy_m]))
    wrong = _moved(trip, busiest, 0.25, 0.0)
    summary = summarize(run_trip(wrong))
    [pole] = summary['map_poles_elsewhere']
    assert pole['index'] == busiest
    assert pole['seen_xy_m'] == pytest.approx(trip.landmarks.xy_m[busiest].tolist(), abs=0.02)
    said = [r for r in summary['health']['reasons'] if r.startswith('mapped pole ')]
    assert len(said) == 1 and summary['health']['verdict'] == 'degraded'
    assert summary['ground_truth']['position_rmse_m'] < 0.02
    # The map as surveyed: nothing found, nothing said.
    assert seen['map_poles_elsewhere'] == []
    assert not [r for r in seen['health']['reasons'] if r.startswith('mapped pole ')]
