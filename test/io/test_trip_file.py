"""Simulator trips as self-describing .npz files, and `convert` accepting them."""

from __future__ import annotations

import numpy as np
import pytest
from synthetic_logs import make_trip
from test_bag_roundtrip import assert_same_trip

from gyro_ekf.cli.main import main
from gyro_ekf.io.bag_reader import read_trip_bag
from gyro_ekf.io.errors import LogFormatError
from gyro_ekf.io.sources import load_log
from gyro_ekf.io.trip_file import is_trip_file, load_trip, save_trip


def test_save_load_round_trip(tmp_path, synthetic_trip):
    path = save_trip(synthetic_trip, tmp_path / 'trip.npz')
    assert is_trip_file(path)
    back = load_trip(path)
    assert_same_trip(back, synthetic_trip, stamp_atol=0.0)
    np.testing.assert_array_equal(back.scans[1].angles_rad, synthetic_trip.scans[1].angles_rad)
    assert back.walls is None
    with np.load(path) as data:
        assert str(data['format']) == 'gyro_ekf.trip' and int(data['format_version']) == 1


def test_a_trip_file_without_a_map_figure_still_loads(tmp_path, synthetic_trip, caplog):
    # Files written before the map figure existed hold four noise figures.
    path = save_trip(synthetic_trip, tmp_path / 'trip.npz')
    with np.load(path) as data:
        arrays = {key: data[key] for key in data.files}
    assert arrays['noise'].shape == (5,)
    arrays['noise'] = arrays['noise'][:4]
    np.savez(tmp_path / 'old.npz', **arrays)
    back = load_trip(tmp_path / 'old.npz')
    assert 'old.npz: written by an older gyro_ekf' in caplog.text
    assert back.noise.landmark_m is None
    assert back.noise.gyro_rad_s == synthetic_trip.noise.gyro_rad_s
    arrays['noise'] = arrays['noise'][:3]
    np.savez(tmp_path / 'bad.npz', **arrays)
    with pytest.raises(LogFormatError, match="bad.npz: key 'noise'"):
        load_trip(tmp_path / 'bad.npz')


def test_existing_trip_file_needs_force(tmp_path, synthetic_trip):
    path = save_trip(synthetic_trip, tmp_path / 'trip.npz')
    with pytest.raises(LogFormatError, match='exists already'):
        save_trip(make_trip(seed=9), path)
    save_trip(make_trip(seed=9), path, force=True)
    assert load_trip(path).name == 'synthetic9'
    assert sorted(p.name for p in tmp_path.iterdir()) == ['trip.npz']


def test_bad_trip_files(tmp_path):
    garbage = tmp_path / 'garbage.npz'
    garbage.write_bytes(b'PK\x03\x04 not really a zip')
    with pytest.raises(LogFormatError, match='garbage.npz: not a readable .npz trip file'):
        load_trip(garbage)
    other = tmp_path / 'other.npz'
    np.savez(other, x=np.arange(3))
    assert not is_trip_file(other)
    with pytest.raises(LogFormatError, match="other.npz: key 'format' is missing"):
        load_trip(other)
    newer = tmp_path / 'newer.npz'
    np.savez(newer, format=np.array('gyro_ekf.trip'), format_version=np.array(2))
    with pytest.raises(LogFormatError, match="newer.npz: key 'format_version' is 2"):
        load_trip(newer)


def test_truncated_arrays_are_named(tmp_path, synthetic_trip):
    path = save_trip(synthetic_trip, tmp_path / 'trip.npz')
    with np.load(path) as data:
        arrays = {key: data[key] for key in data.files}
    arrays['speed.speed_m_s'] = arrays['speed.speed_m_s'][:-3]
    np.savez(tmp_path / 'short.npz', **arrays)
    with pytest.raises(LogFormatError, match=r"short.npz: key 'speed.speed_m_s' has \d+ rows "
                                             r"but 'speed.stamp_s' has \d+"):
        load_trip(tmp_path / 'short.npz')


def test_convert_accepts_a_trip_file(tmp_path, synthetic_trip):
    path = save_trip(synthetic_trip, tmp_path / 'in' / 'trip.npz')
    assert main(['convert', str(path), '-o', str(tmp_path / 'bag')]) == 0
    assert_same_trip(read_trip_bag(tmp_path / 'bag'), synthetic_trip)
    assert load_log([tmp_path / 'in']).name == synthetic_trip.name  # folder of one trip
    with pytest.raises(LogFormatError, match='give it alone'):
        load_log([path], map_path=tmp_path / 'map.mat')
