"""A pole found elsewhere: `run` writes the map with it where seen, and takes that map back.

A map is surveyed once; a pole moved later is found from the detections near it
(core/map_poles.py). `run` writes `landmarks_seen.yaml` (the EKF node's `landmarks_file`
layout) and a params file's `landmarks_file` gives a run (and the node) that map instead of
the bag's.
"""

from __future__ import annotations

import dataclasses
import json

import pytest
import yaml

from gyro_ekf.cli.main import main
from gyro_ekf.core.simulator import SimulationConfig, simulate_trip
from gyro_ekf.core.types import LandmarkMap
from gyro_ekf.io.bag_writer import write_trip_bag


def _run(bag, out, *extra):
    assert main(['-q', 'run', str(bag), '-o', str(out), '--no-plots', '--no-bag',
                 '--no-progress', *extra]) == 0
    return json.loads((out / 'summary.json').read_text())


def test_a_pole_moved_after_the_survey_is_written_where_seen_and_that_map_taken(tmp_path):
    trip = simulate_trip(SimulationConfig(duration_s=120.0), seed=1)
    xy = trip.landmarks.xy_m.copy()
    true_xy = xy[3].copy()
    xy[3] += (0.3, 0.0)  # the map has pole 3 where it stood before it was moved
    bag = write_trip_bag(dataclasses.replace(trip, landmarks=LandmarkMap(xy)), tmp_path / 'bag')
    before = _run(bag, tmp_path / 'before')
    (pole,) = before['map_poles_elsewhere']
    assert pole['index'] == 3
    seen = yaml.safe_load((tmp_path / 'before' / 'landmarks_seen.yaml').read_text())
    assert len(seen['landmarks']) == len(xy)
    assert seen['landmarks'][3] == pytest.approx(true_xy.tolist(), abs=0.02)
    assert seen['landmarks'][0] == pytest.approx(xy[0].tolist())

    params = tmp_path / 'map.yaml'
    params.write_text('/**:\n  ros__parameters:\n    landmarks_file: '
                      f"{tmp_path / 'before' / 'landmarks_seen.yaml'}\n")
    after = _run(bag, tmp_path / 'after', '--params-file', str(params))
    assert after['map_poles_elsewhere'] == []
    assert not (tmp_path / 'after' / 'landmarks_seen.yaml').exists()
    assert after['association']['share_associated'] > before['association']['share_associated']
    assert after['association']['share_associated'] >= 0.99
    truth = after['ground_truth']
    assert truth['position_rmse_m'] <= 0.02 and truth['nees_share_in_band'] >= 0.9


def test_a_landmarks_file_that_cannot_be_read_is_one_line(tmp_path, capsys):
    trip = simulate_trip(SimulationConfig(duration_s=10.0), seed=2)
    bag = write_trip_bag(trip, tmp_path / 'bag')
    params = tmp_path / 'map.yaml'
    params.write_text(f"/**:\n  ros__parameters:\n    landmarks_file: {tmp_path / 'no.yaml'}\n")
    assert main(['-q', 'run', str(bag), '-o', str(tmp_path / 'out'), '--no-plots',
                 '--params-file', str(params)]) == 1
    error = capsys.readouterr().err.strip()
    assert error.count('\n') == 0 and 'no.yaml' in error
    assert not (tmp_path / 'out').exists()
    params.write_text('/**:\n  ros__parameters:\n    landmarks_file: 3\n')
    assert main(['-q', 'run', str(bag), '-o', str(tmp_path / 'out'), '--no-plots',
                 '--params-file', str(params)]) == 1
    error = capsys.readouterr().err.strip()
    assert "parameter 'landmarks_file' must be a file name" in error
