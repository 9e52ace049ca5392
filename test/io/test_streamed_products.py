"""Products written while the run goes (io.streamed_products): the same bytes, errors said."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from gyro_ekf.analysis.offline import run_trip
from gyro_ekf.core.simulator import SimulationConfig, simulate_trip
from gyro_ekf.errors import GyroEkfError
from gyro_ekf.io import results, streamed_products
from gyro_ekf.io.errors import OutputError
from gyro_ekf.io.streamed_products import StreamedProducts

START_NS = 1_700_000_000_000_000_000
FILES = ('estimates.csv', 'estimates/estimates.mcap', 'estimates/metadata.yaml')

pytestmark = pytest.mark.skipif(not hasattr(os, 'fork'), reason='no fork on this platform')


@pytest.fixture(scope='module')
def trip_and_run():
    """A 30 s trip with two LiDARs and ground truth, and its plain run."""
    trip = simulate_trip(SimulationConfig(duration_s=30.0, second_lidar=True), seed=5)
    return trip, run_trip(trip)


def _batch(folder: Path, trip, run, path_length=None) -> Path:
    folder.mkdir()
    est = run.result.estimates
    results.write_estimates_csv(folder / 'estimates.csv', est.stamp_s, est.state,
                                est.covariance)
    results.write_estimates_bag(folder / 'estimates', START_NS, est.stamp_s, est.state,
                                est.covariance, run.speed_m_s, run.yaw_rate_rad_s, trip=trip,
                                updates=run.result.updates, path_length=path_length)
    return folder


def _streamed(folder: Path, trip, **kwargs) -> Path:
    folder.mkdir()
    with StreamedProducts(folder / 'estimates.csv', folder / 'estimates', START_NS, trip,
                          **kwargs) as products:
        run_trip(trip, on_rows=products, into=products.estimates)
        products.finish()
    return folder


@pytest.mark.parametrize('spare_core', [True, False])
@pytest.mark.parametrize('path_length', [None, 7])
def test_written_as_the_rows_come_are_the_bytes_written_at_the_end(
        tmp_path, trip_and_run, monkeypatch, spare_core, path_length):
    # In a child (a core to spare) or block by block here: what the batch writers write.
    trip, run = trip_and_run
    whole = _batch(tmp_path / 'whole', trip, run, path_length)
    writers = tmp_path / 'writers'
    real = streamed_products._Writer.add

    def add(self, *args):
        with open(writers, 'a', encoding='ascii') as file:
            file.write(f'{os.getpid()}\n')
        return real(self, *args)
    monkeypatch.setattr(streamed_products._Writer, 'add', add)
    monkeypatch.setattr(streamed_products, 'spare_core', lambda: spare_core)
    streamed = _streamed(tmp_path / 'streamed', trip, path_length=path_length)
    for name in FILES:
        assert (streamed / name).read_bytes() == (whole / name).read_bytes(), name
    pids = {int(line) for line in writers.read_text().split()}
    assert len(writers.read_text().split()) > 2  # several blocks
    assert (pids != {os.getpid()}) == spare_core and len(pids) == 1
    assert sorted(p.name for p in streamed.iterdir()) == ['estimates', 'estimates.csv']


def test_no_bag_writes_the_csv_alone(tmp_path, trip_and_run):
    trip, run = trip_and_run
    folder = tmp_path / 'out'
    folder.mkdir()
    with StreamedProducts(folder / 'estimates.csv', None, START_NS, trip) as products:
        run_trip(trip, on_rows=products, into=products.estimates)
        products.finish()
    assert [p.name for p in folder.iterdir()] == ['estimates.csv']
    assert (folder / 'estimates.csv').read_bytes() == (
        _batch(tmp_path / 'whole', trip, run) / 'estimates.csv').read_bytes()


@pytest.mark.parametrize('spare_core', [True, False])
def test_a_write_that_fails_midway_is_raised_and_leaves_nothing(tmp_path, trip_and_run,
                                                                monkeypatch, spare_core):
    # Disk full at the bag's third block: the OutputError naming the bag comes back (from
    # the child as it was raised there), and no product nor staged file is left.
    trip, _ = trip_and_run
    monkeypatch.setattr(streamed_products, 'spare_core', lambda: spare_core)
    real = results.EstimatesBag._write_block
    calls = []

    def full(self, stop):
        calls.append(stop)
        if len(calls) == 3:
            raise OSError(28, 'No space left on device')
        return real(self, stop)
    monkeypatch.setattr(results.EstimatesBag, '_write_block', full)
    folder = tmp_path / 'out'
    with pytest.raises(OutputError, match=r'out/estimates: cannot write the estimates bag: '
                                          r'no space left on device'):
        _streamed(folder, trip)
    assert list(folder.iterdir()) == []


def test_a_folder_that_cannot_be_written_is_named(tmp_path, trip_and_run):
    trip, _ = trip_and_run
    with pytest.raises(OutputError, match='gone/estimates.csv: cannot write'):
        with StreamedProducts(tmp_path / 'gone' / 'estimates.csv', None, START_NS,
                              trip) as products:
            run_trip(trip, on_rows=products, into=products.estimates)
            products.finish()


class _Stopped(GyroEkfError):
    pass


@pytest.mark.parametrize('spare_core', [True, False])
def test_a_run_that_fails_leaves_nothing_and_no_child(tmp_path, trip_and_run, monkeypatch,
                                                      spare_core):
    trip, _ = trip_and_run
    monkeypatch.setattr(streamed_products, 'spare_core', lambda: spare_core)
    folder = tmp_path / 'out'
    folder.mkdir()
    blocks = []

    def stop_at_the_fifth_block(*args):
        blocks.append(args[0])
        if len(blocks) == 5:
            raise _Stopped('the run failed')
        products(*args)
    with pytest.raises(_Stopped):
        with StreamedProducts(folder / 'estimates.csv', folder / 'estimates', START_NS,
                              trip) as products:
            run_trip(trip, on_rows=stop_at_the_fifth_block, into=products.estimates)
    assert list(folder.iterdir()) == []
    with pytest.raises(ChildProcessError):
        os.waitpid(-1, os.WNOHANG)  # every child reaped


def test_rows_out_of_step_with_the_trip_or_not_in_its_arrays_are_refused(tmp_path,
                                                                         trip_and_run):
    trip, run = trip_and_run
    est = run.result.estimates
    from gyro_ekf.core.trip_run import Estimates, UpdateLog
    no_updates = UpdateLog(np.zeros(0), np.zeros(0, dtype=np.int64), np.zeros((0, 2)),
                           np.zeros(0))
    with pytest.raises(OutputError, match='rows 1-3 out of step'):
        with StreamedProducts(tmp_path / 'estimates.csv', None, START_NS,
                              trip) as products:
            mine = products.estimates
            for name in ('stamp_s', 'state', 'covariance', 'wander_rad_s'):
                getattr(mine, name)[:3] = getattr(est, name)[:3]
            products(1, Estimates(mine.stamp_s[1:3], mine.state[1:3], mine.covariance[1:3],
                                  mine.wander_rad_s[1:3]), no_updates)
            products.finish()
    with pytest.raises(OutputError, match='not in its arrays'):
        with StreamedProducts(tmp_path / 'estimates.csv', None, START_NS,
                              trip) as products:
            products(0, Estimates(est.stamp_s[:3], est.state[:3], est.covariance[:3],
                                  est.wander_rad_s[:3]), no_updates)
    assert list(tmp_path.iterdir()) == []
