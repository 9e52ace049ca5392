"""Every documented error of `convert`: it is raised, names file and field, leaves nothing."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from synthetic_logs import leftovers, make_trip, write_2016, write_2021, write_2022, write_2023

from gyro_ekf.cli.main import main
from gyro_ekf.io.bag_writer import write_trip_bag
from gyro_ekf.io.errors import BagError, LogFormatError
from gyro_ekf.io.matlab import load_course_log
from gyro_ekf.io.sidecar import sidecar_path


def _convert_fails(capsys, sources: list[Path], out_dir: Path, match: str,
                   *options: str) -> str:
    """Run `gyro-ekf convert`, expect exit 1 with `match` on stderr and no output at all."""
    out_dir.mkdir(exist_ok=True)
    before = leftovers(out_dir)
    code = main(['convert', *map(str, sources), '-o', str(out_dir / 'bag'), *options])
    err = capsys.readouterr().err
    assert code == 1, err
    assert match in err
    assert len(err.strip().splitlines()) == 1
    assert leftovers(out_dir) == before
    return err


def _set(path: str, value):
    """Return a `change` callback that replaces variables[path] ('a.b.c')."""
    def change(variables):
        parts = path.split('.')
        target = variables
        for part in parts[:-1]:
            target = target[part]
        target[parts[-1]] = value
    return change


def test_corrupt_mat(tmp_path, capsys):
    bad = tmp_path / 'log' / 'data019b.mat'
    bad.parent.mkdir()
    bad.write_bytes(b'MATLAB 5.0 MAT-file' + bytes(range(256)) * 4)
    with pytest.raises(LogFormatError, match='data019b.mat: not a readable MATLAB v5 file'):
        load_course_log([bad])
    _convert_fails(capsys, [bad], tmp_path / 'out', 'data019b.mat')


def test_truncated_mat(tmp_path, capsys):
    good = write_2022(tmp_path / 'full' / 'data019b.mat')
    cut = tmp_path / 'log' / 'data019b.mat'
    cut.parent.mkdir()
    cut.write_bytes(good.read_bytes()[: good.stat().st_size // 2])
    with pytest.raises(LogFormatError,
                       match=r'data019b.mat: not a readable MATLAB v5 file \(corrupt or '):
        load_course_log([cut])
    _convert_fails(capsys, [cut], tmp_path / 'out', 'data019b.mat')


def test_inconsistent_lengths_2016(tmp_path, capsys):
    write_2016(tmp_path / 'log', n=50,
               change=_set('Vel.speeds', np.zeros(49, dtype=np.float32)))
    err = _convert_fails(capsys, [tmp_path / 'log'], tmp_path / 'out',
                         "Speed_dataC.mat: field 'Vel.speeds' has 49 samples but 'Vel.times' "
                         'has 50')
    assert 'error' in err


def test_wrong_shape_names_file_and_field(tmp_path, capsys):
    path = write_2022(tmp_path / 'data019b.mat',
                      change=_set('vw', np.zeros((3, 100), dtype=np.float32)))
    with pytest.raises(LogFormatError) as raised:
        load_course_log([path])
    assert str(raised.value) == ("data019b.mat: field 'data.vw' has shape (3, 100), "
                                 'expected (2, n)')
    _convert_fails(capsys, [path], tmp_path / 'out', "field 'data.vw' has shape (3, 100)")


def test_scan_array_of_other_length_than_truth(tmp_path):
    path = write_2023(tmp_path / 'DataUsr_006k.mat',
                      change=_set('scans2', np.zeros((301, 7), dtype=np.uint16)))
    with pytest.raises(LogFormatError, match=r"field 'data.scans2' has shape \(301, 7\)"):
        load_course_log([path])


def test_index_out_of_range(tmp_path):
    def change(variables):
        variables['A']['Z'][2, 5] = 99
    path = write_2021(tmp_path / 'log', change=change)
    with pytest.raises(LogFormatError,
                       match=r"Measurements_AAS01.mat: field 'A.Z\(3,:\)' holds index 99"):
        load_course_log([path])


def test_map_missing_where_needed(tmp_path, capsys):
    path = write_2021(tmp_path / 'log', with_map=False)
    with pytest.raises(LogFormatError, match='Measurements_AAS01.mat: the 2021 format needs '
                                             'its map'):
        load_course_log([path])
    _convert_fails(capsys, [path], tmp_path / 'out', 'needs its map')


def test_stamps_out_of_order(tmp_path, capsys):
    def change(variables):
        variables['data']['table'][0, 20] = 5  # far behind its neighbours
    path = write_2022(tmp_path / 'data019b.mat',
                      change=lambda data: change({'data': data}))
    with pytest.raises(LogFormatError, match=r"data019b.mat: field 'data.table\(1,:\)' goes "
                                             r'back in time at index 20'):
        load_course_log([path])
    _convert_fails(capsys, [path], tmp_path / 'out', 'goes back in time')


def test_laser_stamps_out_of_order_2016(tmp_path):
    def change(variables):
        times = variables['dataL']['times']
        times[3], times[4] = times[4], times[3]
    write_2016(tmp_path / 'log', change=change)
    with pytest.raises(LogFormatError, match=r"Laser__2C.mat: field 'dataL.times' goes back"):
        load_course_log([tmp_path / 'log'])


def test_unknown_format_says_what_was_expected(tmp_path, capsys):
    import scipy.io
    other = tmp_path / 'other.mat'
    scipy.io.savemat(other, {'something': np.arange(3)})
    with pytest.raises(LogFormatError, match=r"other.mat: variables \['something'\] match no "
                                             'course log; expected the 2016 Project-1 trio'):
        load_course_log([other])
    _convert_fails(capsys, [other], tmp_path / 'out', 'expected the 2016 Project-1 trio')


def test_incomplete_trio_and_mixed_formats(tmp_path):
    paths = write_2016(tmp_path / 'log')
    with pytest.raises(LogFormatError, match=r"missing \['dataL'\]"):
        load_course_log(paths[:2])
    sim = write_2022(tmp_path / 'sim' / 'data019b.mat')
    with pytest.raises(LogFormatError, match='mix logs of different formats'):
        load_course_log([*paths, sim])
    with pytest.raises(LogFormatError, match='no such file or directory'):
        load_course_log([tmp_path / 'nope.mat'])


def test_unknown_sim_event_type(tmp_path):
    def change(data):
        data['table'][2, 4] = 7
    path = write_2022(tmp_path / 'data019b.mat', change=change)
    with pytest.raises(LogFormatError, match=r"'data.table\(3,:\)' has sensor type 7"):
        load_course_log([path])


def test_existing_output_refused_unless_force(tmp_path, capsys):
    source = write_2022(tmp_path / 'data019b.mat')
    out = tmp_path / 'out' / 'bag'
    assert main(['convert', str(source), '-o', str(out)]) == 0
    stamp = (out / 'metadata.yaml').stat().st_mtime_ns
    capsys.readouterr()
    assert main(['convert', str(source), '-o', str(out)]) == 1
    assert 'exists already; use --force' in capsys.readouterr().err
    assert (out / 'metadata.yaml').stat().st_mtime_ns == stamp
    assert main(['convert', str(source), '-o', str(out), '--force',
                 '--start-time', '1800000000']) == 0
    assert leftovers(out.parent) == ['bag', 'bag.params.yaml']


def test_failed_write_leaves_nothing_and_keeps_old_output(tmp_path):
    trip = make_trip()
    out = tmp_path / 'bag'

    def explode(done, total):
        raise RuntimeError('interrupted')
    with pytest.raises(RuntimeError):
        write_trip_bag(trip, out, progress=explode)
    assert leftovers(tmp_path) == []
    write_trip_bag(trip, out)
    before = sorted(p.name for p in out.iterdir())
    yaml_text = sidecar_path(out).read_text()
    with pytest.raises(RuntimeError):
        write_trip_bag(make_trip(seed=5), out, force=True, progress=explode)
    assert leftovers(tmp_path) == ['bag', 'bag.params.yaml']
    assert sorted(p.name for p in out.iterdir()) == before
    assert sidecar_path(out).read_text() == yaml_text


def test_trip_stamps_out_of_order_refused_by_writer(tmp_path, synthetic_trip):
    stamps = synthetic_trip.scans[0].stamp_s
    stamps[7] = stamps[3]  # arrays are shared, not copied: this edits the trip
    with pytest.raises(BagError, match=r"topic 'scan': stamp went back .* at message 7"):
        write_trip_bag(synthetic_trip, tmp_path / 'bag')
    assert leftovers(tmp_path) == []


def test_start_time_zero_or_garbage_refused(tmp_path, capsys):
    source = write_2022(tmp_path / 'data019b.mat')
    for bad in ('0', '-5', 'yesterday'):
        _convert_fails(capsys, [source], tmp_path / 'out', f'--start-time {bad!r}',
                       f'--start-time={bad}')
    with pytest.raises(BagError, match='after the epoch'):
        write_trip_bag(make_trip(), tmp_path / 'bag', start_time_ns=0)
    assert not (tmp_path / 'bag').exists()
