"""Writes that lose nothing: --force replaces only gyro-ekf's own products, and a read-only
or full file system gives one error line and leaves any previous output as it was.

The file-system cases run the command in a private mount namespace (`unshare -rm`) on a
real read-only bind mount or a small tmpfs, and list what is left before the namespace
goes away; where unshare is not allowed they are skipped, and the same failures are
raised at the Python boundary (OSError with EROFS/ENOSPC) by the monkeypatched tests.
"""

from __future__ import annotations

import errno
import os
from pathlib import Path
import shlex
import shutil
import subprocess
import sys

import pytest

from gyro_ekf.cli.main import main

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture(scope='module')
def short_bag(tmp_path_factory) -> Path:
    """A 20 s simulated trip (with its sidecar)."""
    bag = tmp_path_factory.mktemp('writes') / 'short'
    assert main(['-q', 'simulate', '-o', str(bag), '--duration-s', '20', '--static-s', '5',
                 '--seed', '4']) == 0
    return bag


@pytest.fixture(scope='module')
def short_npz(tmp_path_factory) -> Path:
    trip = tmp_path_factory.mktemp('writes') / 'short.npz'
    assert main(['-q', 'simulate', '-o', str(trip), '--duration-s', '10', '--static-s', '2',
                 '--seed', '5']) == 0
    return trip


def _user_folder(path: Path) -> None:
    path.mkdir()
    (path / 'notes.txt').write_text('my notes')
    (path / 'sub').mkdir()
    (path / 'sub' / 'data.csv').write_text('1,2')


def _user_files_intact(path: Path) -> bool:
    return ((path / 'notes.txt').read_text() == 'my notes'
            and (path / 'sub' / 'data.csv').read_text() == '1,2')


def test_convert_force_refuses_a_folder_holding_user_files(short_npz, tmp_path, capsys):
    out = tmp_path / 'mine'
    _user_folder(out)
    assert main(['convert', str(short_npz), '-o', str(out), '--force']) == 1
    err = capsys.readouterr().err.strip()
    assert err.count('\n') == 0, err
    assert f'{out / "notes.txt"}: is not part of a bag' in err
    assert _user_files_intact(out)
    assert not (tmp_path / 'mine.params.yaml').exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ['mine']


def test_convert_force_replaces_its_own_bag(short_npz, tmp_path):
    out = tmp_path / 'bag'
    assert main(['-q', 'convert', str(short_npz), '-o', str(out)]) == 0
    first = (out / 'bag.mcap').read_bytes()
    (out / 'metadata.yaml').write_text('stale')
    assert main(['-q', 'convert', str(short_npz), '-o', str(out), '--force']) == 0
    assert (out / 'bag.mcap').read_bytes() == first
    assert (out / 'metadata.yaml').read_text() != 'stale'
    assert sorted(p.name for p in tmp_path.iterdir()) == ['bag', 'bag.params.yaml']


def test_simulate_force_refuses_a_file_where_the_bag_goes(tmp_path, capsys):
    out = tmp_path / 'notes.txt'
    out.write_text('my notes')
    assert main(['simulate', '-o', str(out), '--duration-s', '5', '--force']) == 1
    assert 'exists and is not a bag folder' in capsys.readouterr().err
    assert out.read_text() == 'my notes'


def test_simulate_force_refuses_a_folder_where_the_trip_file_goes(tmp_path, capsys):
    out = tmp_path / 'trip.npz'
    _user_folder(out)
    assert main(['simulate', '-o', str(out), '--duration-s', '5', '--force']) == 1
    assert 'exists and is not a trip file' in capsys.readouterr().err
    assert _user_files_intact(out)


def test_make_bags_force_refuses_a_bag_folder_with_a_user_file(tmp_path, capsys):
    bag = tmp_path / 'sim_static_start'
    bag.mkdir()
    (bag / 'metadata.yaml').write_text('old')
    (bag / 'README.txt').write_text('mine')
    assert main(['make-bags', str(tmp_path), '--force']) == 1
    assert f'{bag / "README.txt"}: is not part of a bag' in capsys.readouterr().err
    assert (bag / 'README.txt').read_text() == 'mine'
    assert (bag / 'metadata.yaml').read_text() == 'old'


def test_run_into_the_current_folder(short_bag, tmp_path, monkeypatch):
    work = tmp_path / 'work'
    work.mkdir()
    monkeypatch.chdir(work)
    assert main(['-q', 'run', str(short_bag), '-o', '.', '--no-plots', '--no-progress']) == 0
    names = sorted(p.name for p in work.iterdir())
    assert names == ['estimates', 'estimates.csv', 'summary.json']
    assert sorted(p.name for p in tmp_path.iterdir()) == ['work']


def test_run_force_refuses_a_folder_holding_user_files(short_bag, tmp_path, capsys):
    out = tmp_path / 'out'
    assert main(['-q', 'run', str(short_bag), '-o', str(out), '--no-plots',
                 '--no-progress']) == 0
    (out / 'notes.txt').write_text('my notes')
    before = (out / 'summary.json').read_text()
    assert main(['run', str(short_bag), '-o', str(out), '--force', '--no-progress']) == 1
    err = capsys.readouterr().err
    assert f'{out / "notes.txt"}: is not a product of gyro-ekf run' in err
    assert (out / 'summary.json').read_text() == before
    assert (out / 'notes.txt').read_text() == 'my notes'


def test_run_force_replaces_its_own_products(short_bag, tmp_path):
    out = tmp_path / 'out'
    assert main(['-q', 'run', str(short_bag), '-o', str(out), '--no-progress']) == 0
    assert (out / 'trajectory.png').exists()
    folder = out.stat().st_ino
    assert main(['-q', 'run', str(short_bag), '-o', str(out), '--force', '--no-plots',
                 '--no-progress']) == 0
    assert out.stat().st_ino == folder   # the folder stays, its products are replaced
    # The new output replaces the old as a whole: no stale figure of the earlier run.
    names = sorted(p.name for p in out.iterdir())
    assert names == ['estimates', 'estimates.csv', 'summary.json']
    assert sorted(p.name for p in tmp_path.iterdir()) == ['out']


@pytest.mark.parametrize('code,words', [(errno.ENOSPC, 'no space left on device'),
                                        (errno.EROFS, 'read-only file system')])
def test_run_turns_a_failed_write_into_one_line_and_keeps_the_old_output(
        short_bag, tmp_path, capsys, monkeypatch, code, words):
    from gyro_ekf.io import results

    out = tmp_path / 'out'
    out.mkdir()
    (out / 'summary.json').write_text('{"earlier": true}')
    real = results.EstimatesCsv.add

    def fail(self, *args):
        # (In the child that writes the CSV as the rows come, where a core is free: its
        # OSError comes back as it was raised.)
        real(self, *args)
        raise OSError(code, os.strerror(code), str(self.path))
    monkeypatch.setattr(results.EstimatesCsv, 'add', fail)
    assert main(['run', str(short_bag), '-o', str(out), '--force', '--no-progress']) == 1
    err = capsys.readouterr().err.strip()
    assert err == f'gyro-ekf run: error: {out}: cannot write the outputs: {words}'
    assert sorted(p.name for p in tmp_path.iterdir()) == ['out']
    assert [p.name for p in out.iterdir()] == ['summary.json']
    assert (out / 'summary.json').read_text() == '{"earlier": true}'


@pytest.mark.parametrize('code,words', [(errno.ENOSPC, 'no space left on device'),
                                        (errno.EROFS, 'read-only file system')])
def test_convert_turns_a_failed_write_into_one_line(short_npz, tmp_path, capsys, monkeypatch,
                                                    code, words):
    from gyro_ekf.io import bag_writer

    def fail(*args, **kwargs):
        raise OSError(code, os.strerror(code))
    monkeypatch.setattr(bag_writer, '_write', fail)
    out = tmp_path / 'bag'
    assert main(['convert', str(short_npz), '-o', str(out)]) == 1
    assert capsys.readouterr().err.strip() == (
        f'gyro-ekf convert: error: {out}: cannot write the bag: {words}')
    assert list(tmp_path.iterdir()) == []


def _unshare_works() -> bool:
    if shutil.which('unshare') is None:
        return False
    probe = subprocess.run(['unshare', '-rm', 'sh', '-c', 'mount -t tmpfs tmpfs /mnt'],
                           capture_output=True)
    return probe.returncode == 0


needs_unshare = pytest.mark.skipif(not _unshare_works(),
                                   reason='unshare -rm with mounts is not allowed here')


def _in_namespace(setup: str, command: list[str], after: str, work: Path
                  ) -> subprocess.CompletedProcess:
    """Run setup, the gyro-ekf command and after in a private mount namespace.

    The command's stderr goes to a file in `work` (the test's own folder, outside what the
    setup mounts): in a shared folder a second copy of the suite would write the same file.
    """
    gyro = ' '.join(shlex.quote(a) for a in [sys.executable, '-m', 'gyro_ekf.cli.main', '-q',
                                             *command])
    err = shlex.quote(str(work / 'err.txt'))
    script = f'set -e; {setup}; {gyro} 2>{err} && echo EXIT=0 || echo EXIT=$?; ' \
             f'echo STDERR; cat {err}; echo AFTER; {after}'
    env = dict(os.environ, PYTHONPATH=str(REPO), MPLBACKEND='Agg')
    return subprocess.run(['unshare', '-rm', 'sh', '-c', script], capture_output=True,
                          text=True, env=env, timeout=300, cwd=work)


@needs_unshare
def test_run_on_a_full_disk_gives_one_line_and_keeps_the_old_output(short_bag, tmp_path):
    disk = tmp_path / 'disk'
    disk.mkdir()
    setup = (f'mount -t tmpfs -o size=192k tmpfs {disk}; mkdir {disk}/out; '
             f"echo '{{\"earlier\": true}}' > {disk}/out/summary.json")
    result = _in_namespace(setup, ['run', str(short_bag), '-o', f'{disk}/out', '--force',
                                   '--no-progress'],
                           f'ls -A {disk}; ls -A {disk}/out; cat {disk}/out/summary.json',
                           tmp_path)
    stdout = result.stdout
    assert 'EXIT=1' in stdout, stdout + result.stderr
    error = stdout.split('STDERR\n')[1].split('AFTER\n')[0].strip()
    # One line naming the output (the file that did not fit in it) and the reason.
    assert error.count('\n') == 0, error
    assert error.startswith(f'gyro-ekf run: error: {disk}/out'), error
    assert error.endswith('no space left on device'), error
    assert stdout.split('AFTER\n')[1].split() == ['out', 'summary.json', '{"earlier":',
                                                  'true}']


@needs_unshare
def test_convert_and_run_on_a_read_only_file_system_give_one_line(short_bag, short_npz,
                                                                  tmp_path):
    disk = tmp_path / 'ro'
    disk.mkdir()
    (disk / 'out').mkdir()
    (disk / 'out' / 'summary.json').write_text('{}')
    setup = f'mount --bind {disk} {disk}; mount -o remount,ro,bind {disk}'
    run = _in_namespace(setup, ['run', str(short_bag), '-o', f'{disk}/out', '--force',
                                '--no-progress'], f'ls -A {disk} {disk}/out', tmp_path)
    assert 'EXIT=1' in run.stdout, run.stdout + run.stderr
    error = run.stdout.split('STDERR\n')[1].split('AFTER\n')[0].strip()
    assert error == f'gyro-ekf run: error: {disk}/out: cannot write the outputs: ' \
                    'read-only file system'
    convert = _in_namespace(setup, ['convert', str(short_npz), '-o', f'{disk}/bag'], 'true',
                            tmp_path)
    assert 'EXIT=1' in convert.stdout, convert.stdout + convert.stderr
    error = convert.stdout.split('STDERR\n')[1].split('AFTER\n')[0].strip()
    assert error == f'gyro-ekf convert: error: {disk}/bag: cannot write the bag: ' \
                    'read-only file system'
    assert sorted(p.name for p in disk.iterdir()) == ['out']
    assert [p.name for p in (disk / 'out').iterdir()] == ['summary.json']
