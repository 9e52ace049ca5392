"""A bag's params file records the bag it was written with; one of another trip is refused.

The sidecar carries a trip's initial pose, LiDAR mounts, noise figures, time zero and true
gyro bias; copied beside another trip's bag it used to be taken without a word, and every
run and truth comparison on that bag was silently wrong. Its `trip.bag` fingerprint
(message count, first and last log time) is checked by every reader; a sidecar written
before it existed is still taken, and `info` says it was not checked.
"""

from __future__ import annotations

import dataclasses
import functools
import shutil
from pathlib import Path

from mcap_layout import chunks, mcap_of
import pytest
from rosbags.rosbag2 import Reader
import yaml

from gyro_ekf.cli.main import main
from gyro_ekf.core.simulator import SimulationConfig, simulate_trip
from gyro_ekf.io.bag_open import metadata
from gyro_ekf.io.bag_reader import read_bag
from gyro_ekf.io.bag_writer import write_trip_bag
from gyro_ekf.io.errors import BagError
from gyro_ekf.io.sidecar import (BagFingerprint, fingerprint_of, parse_yaml, read_sidecar,
                                 sidecar_path, to_yaml)

BAGS = Path(__file__).resolve().parents[2] / 'bags'


@functools.lru_cache(maxsize=None)
def trip(duration_s: float, seed: int):
    """A short simulated trip (static start, so calibration works as on the bundled bag)."""
    return simulate_trip(dataclasses.replace(SimulationConfig(), duration_s=duration_s,
                                             static_s=6.0), seed=seed)


@pytest.fixture(scope='module')
def bags(tmp_path_factory) -> tuple[Path, Path]:
    """Two bags of two simulated trips, each with its own sidecar (never modified)."""
    folder = tmp_path_factory.mktemp('trips')
    return (write_trip_bag(trip(12.0, 3), folder / 'trip_a'),
            write_trip_bag(trip(15.0, 4), folder / 'trip_b'))


def copy_of(bag: Path, folder: Path, sidecar_of: Path | None = None) -> Path:
    """Copy a bag folder and a sidecar (its own, or `sidecar_of`'s) into folder."""
    copy = folder / bag.name
    shutil.copytree(bag, copy)
    shutil.copy(sidecar_path(sidecar_of or bag), sidecar_path(copy))
    return copy


def held(bag: Path) -> BagFingerprint:
    """The bag's fingerprint as rosbags reads its messages: count, first and last log time."""
    with Reader(bag) as reader:
        times = [t for _, t, _ in reader.messages()]
    return BagFingerprint(len(times), min(times), max(times))


def _run(bag: Path, out: Path) -> int:
    return main(['-q', 'run', str(bag), '-o', str(out), '--no-progress'])


@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
def test_the_writer_records_the_bag_it_wrote_and_the_record_round_trips(tmp_path, storage):
    bag = write_trip_bag(trip(12.0, 3), tmp_path / 'trip', storage=storage)
    params = read_sidecar(bag)
    assert params is not None and params.bag is not None
    # What the data holds, and what metadata.yaml states (what info prints).
    assert params.bag == held(bag) == fingerprint_of(metadata(bag), bag)
    assert params.bag.message_count > 1000
    tree = yaml.safe_load(sidecar_path(bag).read_text())['/**']['ros__parameters']
    assert tree['trip']['bag'] == {'message_count': params.bag.message_count,
                                   'first_stamp_ns': params.bag.first_stamp_ns,
                                   'last_stamp_ns': params.bag.last_stamp_ns}
    # ROS parameter types only: whole numbers (int64 holds a stamp in ns until 2262).
    assert all(isinstance(v, int) and v < 2**63 for v in tree['trip']['bag'].values())
    again = parse_yaml(to_yaml(params), sidecar_path(bag))
    assert again.bag == params.bag


@pytest.mark.parametrize('name', ['sim_static_start', 'sim_moving_start'])
def test_the_bundled_bags_carry_their_own_fingerprint(name):
    bag = BAGS / name
    assert read_sidecar(bag).bag == held(bag)


def _one_error_line(err: str, command: str) -> str:
    lines = [line for line in err.strip().splitlines() if line]
    assert len(lines) == 1 and 'Traceback' not in err, err
    assert lines[0].startswith(f'gyro-ekf {command}: error: '), lines[0]
    return lines[0]


def test_a_sidecar_of_another_simulated_trip_is_refused_naming_both(bags, tmp_path, capsys):
    trip_a, trip_b = bags
    bag = copy_of(trip_b, tmp_path, sidecar_of=trip_a)   # trip_a's params beside trip_b
    want = held(trip_a).describe()
    have = held(trip_b).describe()
    assert want != have

    out = tmp_path / 'out'
    assert _run(bag, out) == 1
    line = _one_error_line(capsys.readouterr().err, 'run')
    assert (f'{sidecar_path(bag)}: belongs to a bag of {want}; bag {bag} has {have} '
            '(as its messages hold)') in line, line
    assert not out.exists()

    code = main(['info', str(bag)])
    captured = capsys.readouterr()
    assert code == 1 and captured.out == ''
    line = _one_error_line(captured.err, 'info')
    assert (f'{sidecar_path(bag)}: belongs to a bag of {want}; bag {bag} has {have} '
            '(as its metadata.yaml states)') in line, line
    assert main(['info', '--no-verify', str(bag)]) == 1

    # Every other reader of the pair: calibrate-mounts and demo read the bag as run does,
    # demo and a script read the sidecar alone.
    with pytest.raises(BagError, match='belongs to a bag of'):
        read_bag(bag)
    with pytest.raises(BagError, match='belongs to a bag of'):
        read_sidecar(bag)
    # The bag with its own params file is fine, and the same file beside its own bag too.
    assert _run(trip_b, tmp_path / 'own') == 0
    assert read_sidecar(trip_a).bag == held(trip_a)


def test_replay_refuses_a_sidecar_of_another_trip_before_it_publishes(bags, tmp_path):
    pytest.importorskip('rclpy')
    from gyro_ekf.cli.replay import BagSource

    trip_a, trip_b = bags
    BagSource(trip_b, None, 0.0, None)
    bag = copy_of(trip_b, tmp_path, sidecar_of=trip_a)
    with pytest.raises(BagError, match=f'{sidecar_path(bag)}: belongs to a bag of'):
        BagSource(bag, None, 0.0, None)


def without_fingerprint(bag: Path) -> None:
    """Make the bag's sidecar one an older gyro_ekf wrote: no trip.bag."""
    path = sidecar_path(bag)
    document = yaml.safe_load(path.read_text())
    del document['/**']['ros__parameters']['trip']['bag']
    path.write_text(yaml.safe_dump(document, sort_keys=False))


def test_a_sidecar_without_a_fingerprint_is_taken_and_info_says_it_was_not_checked(
        bags, tmp_path, capsys):
    trip_a, _ = bags
    assert main(['info', str(trip_a)]) == 0
    assert '(fingerprint matches this bag)' in capsys.readouterr().out
    bag = copy_of(trip_a, tmp_path)
    without_fingerprint(bag)
    params = read_sidecar(bag)
    assert params is not None and params.bag is None
    assert params.initial_pose.tolist() == read_sidecar(trip_a).initial_pose.tolist()
    assert main(['info', str(bag)]) == 0
    out = capsys.readouterr().out
    assert f'params:    {sidecar_path(bag)} (sidecar: not fingerprinted' in out, out
    assert _run(bag, tmp_path / 'out') == 0
    # Even beside another trip's bag: there is nothing to compare (as before).
    other = copy_of(bags[1], tmp_path / 'other', sidecar_of=bag)
    assert read_sidecar(other).bag is None


@pytest.mark.parametrize('entry, value', [('message_count', None), ('first_stamp_ns', -1),
                                          ('last_stamp_ns', 'late'), ('last_stamp_ns', 1.5)])
def test_a_damaged_fingerprint_is_refused_naming_the_parameter(bags, tmp_path, entry, value):
    # A fingerprint in part would check nothing and pass for one.
    bag = copy_of(bags[0], tmp_path)
    path = sidecar_path(bag)
    document = yaml.safe_load(path.read_text())
    record = document['/**']['ros__parameters']['trip']['bag']
    if value is None:
        del record[entry]
    else:
        record[entry] = value
    path.write_text(yaml.safe_dump(document, sort_keys=False))
    with pytest.raises(BagError, match=rf"{path.name}: parameter 'trip\.bag"):
        read_bag(bag)


@pytest.mark.parametrize('damage', ['no metadata.yaml', 'summary cut'])
def test_reindex_keeps_the_fingerprint_valid(bags, tmp_path, capsys, damage):
    # A bag whose recorder or copy was cut short after its last chunk: reindex rebuilds the
    # summary and metadata.yaml from the same messages, so the params file still fits.
    trip_a, _ = bags
    bag = copy_of(trip_a, tmp_path)
    mcap = mcap_of(bag)
    if damage == 'summary cut':
        data = mcap.read_bytes()
        mcap.write_bytes(data[:chunks(data)[-1].end + 20])
    (bag / 'metadata.yaml').unlink()
    assert main(['reindex', str(bag)]) == 0
    captured = capsys.readouterr()
    assert 'wrote' in captured.out and 'belongs to a bag' not in captured.err
    if damage == 'summary cut':
        assert 'a new .mcap' in captured.out
        assert mcap.read_bytes() != mcap_of(trip_a).read_bytes()
    assert read_sidecar(bag).bag == held(bag) == held(trip_a)
    assert main(['info', str(bag)]) == 0
    assert '(fingerprint matches this bag)' in capsys.readouterr().out
    assert _run(bag, tmp_path / 'out') == 0


def test_a_tail_reindex_leaves_out_makes_another_bag_and_reindex_says_so(
        bags, tmp_path, capsys, caplog):
    trip_a, _ = bags
    bag = copy_of(trip_a, tmp_path)
    mcap = mcap_of(bag)
    data = mcap.read_bytes()
    spans = chunks(data)
    assert len(spans) >= 2
    mcap.write_bytes(data[:spans[-1].offset + 10])       # the last chunk cut in the middle
    assert main(['reindex', str(bag)]) == 0
    now = held(bag)
    assert now.message_count < held(trip_a).message_count
    assert (f'{sidecar_path(bag)}: written with a bag of {held(trip_a).describe()}; {bag} now '
            f'has {now.describe()}: run, info and replay refuse the pair') in caplog.text
    assert 'delete its trip.bag entries' in caplog.text
    capsys.readouterr()
    assert _run(bag, tmp_path / 'out') == 1
    assert 'belongs to a bag of' in capsys.readouterr().err
