"""`gyro-ekf stress` end to end on one short trip per class (no figures asserted)."""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
import shlex
import shutil
import subprocess
import sys

import numpy as np
import pytest

from gyro_ekf.analysis.stress import BOUNDS, CLASSES, best_bias_error, trip_jobs
from gyro_ekf.cli.main import main

REPO = Path(__file__).resolve().parents[2]


def test_stress_runs_one_trip_per_class_and_writes_json(tmp_path, capsys):
    output = tmp_path / 'out' / 'stress.json'
    code = main(['-q', 'stress', '--trips-per-class', '1', '--workers', '2', '--duration-s',
                 '30', '--seed', '3', '-o', str(output)])
    assert code == 0
    printed = capsys.readouterr().out
    results = json.loads(output.read_text())
    names = [c.name for c in CLASSES]
    assert list(results['classes']) == names
    assert results['suite']['trips'] == len(names) == len(results['trips'])
    assert results['bounds'] == BOUNDS
    for name in names:
        assert name in printed
        assert results['classes'][name]['trips'] == 1
    assert [r['class'] for r in results['trips']] == names
    for record in results['trips']:
        assert 'error' not in record, record
        assert record['seed'] == 30_000
        assert record['verdict'] in ('ok', 'degraded', 'failed')
        # The classification follows the figures and the verdict.
        expected = [name for name, bound in BOUNDS.items()
                    if record[name] is None
                    or (abs(record[name]) > bound if name != 'nees_share_in_band'
                        else record[name] < bound)]
        assert record['missed'] == expected
        assert record['passed'] == (not expected)
        assert record['silent'] == (bool(expected) and record['verdict'] == 'ok')
        # Only a wander has a best estimate's error of its own to report.
        best = record['best_bias_error_deg_s']
        assert (best is None) == (record['class'] != 'coloured_gyro')
        assert record['beyond_reach'] == (best is not None
                                          and abs(best) > BOUNDS['bias_error_final_deg_s'])
        summary = results['classes'][record['class']]
        assert summary['passed'] == int(record['passed'])
        assert summary['silent_failures'] == int(record['silent'])
        below, above = record['nees_share_below_band'], record['nees_share_above_band']
        assert below + above + record['nees_share_in_band'] == pytest.approx(1.0)
        assert summary['silent_nees_below_band'] == int(
            record['silent'] and record['missed'] == ['nees_share_in_band'] and below > above)
    assert results['totals']['silent_nees_below_band'] == sum(
        c['silent_nees_below_band'] for c in results['classes'].values())
    changes = {r['class']: r['changes'] for r in results['trips']}
    assert changes['clean'] == {}
    yaw = [v for k, v in changes['mount_yaw'].items() if k.endswith('yaw_error_rad')]
    assert len(yaw) == 1 and 0.0 < abs(yaw[0]) <= math.radians(10.0)
    assert 1 <= changes['extra_reflectors']['extra_reflectors'] <= 4
    assert 2.0 <= changes['lidar_dropout']['lidar_dropout_s'] <= 10.0


def test_jobs_are_seeded():
    first, again, other = (trip_jobs(3, seed) for seed in (1, 1, 2))
    assert first == again
    assert len(first) == 3 * len(CLASSES)
    assert [j.changes for j in first] != [j.changes for j in other]
    # Every class drives the same scenes: trip k has seed 10_000 * seed + k in each.
    assert {j.seed for j in first} == {10_000, 10_001, 10_002}


@pytest.mark.parametrize('argument', [['--trips-per-class', '0'], ['--workers', 'x'],
                                      ['--duration-s', '5']])
def test_bad_arguments_are_usage_errors(argument, tmp_path):
    with pytest.raises(SystemExit) as exit_info:
        main(['stress', '-o', str(tmp_path / 'x.json'), *argument])
    assert exit_info.value.code == 2
    assert not (tmp_path / 'x.json').exists()


def test_static_start_is_the_suites_choice():
    from gyro_ekf.analysis.stress import base_config, run_job
    from gyro_ekf.core.simulator import simulate_trip
    assert base_config(120.0).static_s == 8.0
    assert base_config(20.0).static_s == 5.0
    jobs = trip_jobs(1, 0, 40.0, static_s=14.0)
    assert {job.static_s for job in jobs} == {14.0}
    # A bias step still falls while driving.
    step = next(job for job in jobs if job.stress_class == 'bias_step')
    assert 14.0 <= step.changes['gyro_bias_step_at_s'] <= 30.0
    trip = simulate_trip(base_config(40.0, 14.0), jobs[0].seed)
    assert trip.static_duration_s == pytest.approx(14.0, abs=0.02)
    record = run_job(jobs[0])
    assert 'error' not in record and record['verdict'] in ('ok', 'degraded', 'failed')
    for static_s in (-1.0, 20.5):
        with pytest.raises(ValueError, match='static start'):
            base_config(40.0, static_s)


def test_static_start_beyond_half_the_trip_is_refused(tmp_path, capsys):
    output = tmp_path / 'x.json'
    assert main(['stress', '-o', str(output), '--duration-s', '60', '--static-s', '31']) == 1
    assert '--static-s 31: at most 0.5 of --duration-s 60' in capsys.readouterr().err
    assert not output.exists()
    with pytest.raises(SystemExit) as exit_info:
        main(['stress', '-o', str(output), '--static-s', '-2'])
    assert exit_info.value.code == 2


def _no_trip(*args, **kwargs):
    raise AssertionError('a trip ran before the output was checked')


@pytest.mark.parametrize('case', ['existing file', 'folder', 'fifo', 'parent is a file'])
def test_an_output_it_may_not_or_cannot_write_is_refused_before_any_trip(
        tmp_path, capsys, monkeypatch, case):
    # stress used to overwrite any file, and to fail on a folder or an unwritable one only
    # after every trip had run (about 2 CPU-minutes at the default size).
    from gyro_ekf.analysis import stress

    monkeypatch.setattr(stress, 'run_suite', _no_trip)
    mine = tmp_path / 'mine.json'
    mine.write_text('{"mine": true}')
    output, said = {
        'existing file': (mine, f'{mine}: exists; --force replaces a file'),
        'folder': (tmp_path, f'{tmp_path}: is a folder; give a JSON file name'),
        'fifo': (tmp_path / 'pipe', f"{tmp_path / 'pipe'}: is not a file; give a JSON file "
                 'name'),
        'parent is a file': (mine / 'stress.json',
                             f"{mine / 'stress.json'}: cannot write: {mine} is not a folder"),
    }[case]
    if case == 'fifo':
        os.mkfifo(output)
    before = sorted(p.name for p in tmp_path.iterdir())
    assert main(['stress', '-o', str(output), '--trips-per-class', '1', '--duration-s', '20',
                 '--workers', '1']) == 1
    assert capsys.readouterr().err == f'gyro-ekf stress: error: {said}\n'
    assert sorted(p.name for p in tmp_path.iterdir()) == before
    assert mine.read_text() == '{"mine": true}'


def test_force_replaces_an_existing_output_whole(tmp_path, capsys):
    output = tmp_path / 'stress.json'
    output.write_text('{"earlier": true}')
    assert main(['-q', 'stress', '-o', str(output), '--force', '--trips-per-class', '1',
                 '--duration-s', '20', '--workers', '1']) == 0
    results = json.loads(output.read_text())
    assert results['suite']['trips'] == len(CLASSES) == len(results['trips'])
    assert [p.name for p in tmp_path.iterdir()] == ['stress.json']   # no staged file left


@pytest.mark.skipif(shutil.which('unshare') is None or subprocess.run(
    ['unshare', '-rm', 'sh', '-c', 'mount -t tmpfs tmpfs /mnt'], capture_output=True
).returncode != 0, reason='unshare -rm with mounts is not allowed here')
def test_a_read_only_folder_is_refused_before_any_trip(tmp_path):
    # A real read-only bind mount in a private mount namespace (as test/cli/test_writes.py).
    folder = tmp_path / 'ro'
    folder.mkdir()
    script = ('import sys; from gyro_ekf.analysis import stress; from gyro_ekf.cli.main '
              'import main; stress.run_suite = None; '   # a trip would be a TypeError
              f"sys.exit(main(['stress', '-o', {str(folder / 'stress.json')!r}]))")
    command = ' '.join(shlex.quote(a) for a in [sys.executable, '-c', script])
    result = subprocess.run(
        ['unshare', '-rm', 'sh', '-c', f'mount --bind {folder} {folder}; '
         f'mount -o remount,ro,bind {folder} {folder}; {command}'],
        capture_output=True, text=True, timeout=300, env=dict(os.environ, PYTHONPATH=str(REPO)))
    assert result.returncode == 1, result.stderr
    assert result.stderr == (f"gyro-ekf stress: error: {folder / 'stress.json'}: cannot "
                             'write: read-only file system\n')
    assert list(folder.iterdir()) == []


def test_best_bias_error_is_the_generalised_least_squares_mean_of_the_wander():
    rng = np.random.default_rng(5)
    period, tau, n = 0.5, 1.7, 80
    phi = math.exp(-period / tau)
    wander = np.empty(n)
    wander[0] = rng.standard_normal()
    for k in range(1, n):
        wander[k] = phi * wander[k - 1] + math.sqrt(1.0 - phi * phi) * rng.standard_normal()
    # The readable definition: b's GLS estimate from b + c, c's covariance phi^|i-j| (b = 0).
    covariance = phi ** np.abs(np.subtract.outer(np.arange(n), np.arange(n)))
    weights = np.linalg.solve(covariance, np.ones(n))
    expected = weights @ wander / weights.sum()
    assert best_bias_error(wander, period, tau) == pytest.approx(expected, rel=1e-12)
    # Not the plain mean (the ends weigh more), but it tends to it as tau shrinks.
    assert best_bias_error(wander, period, tau) != pytest.approx(wander.mean(), rel=1e-3)
    assert best_bias_error(wander, period, 1e-6) == pytest.approx(wander.mean(), rel=1e-12)
    assert best_bias_error(wander[:2], period, tau) == pytest.approx(wander[:2].mean())


def test_a_coloured_trip_reports_its_wanders_best_estimate_error():
    from gyro_ekf.analysis.stress import run_job
    coloured = tuple(c for c in CLASSES if c.name == 'coloured_gyro')
    job = trip_jobs(1, 4, 30.0, classes=coloured)[0]
    wander = job.config.gyro_colored_noise_rad_s
    assert wander > 0.0
    record = run_job(job)
    trip = job.simulate()
    # The simulator's own wander on that trip, as the trip carries it.
    clean = trip_jobs(1, 4, 30.0, classes=CLASSES[:1])[0].simulate()
    added = trip.imu.angular_velocity_rad_s[:, 2] - clean.imu.angular_velocity_rad_s[:, 2]
    expected = best_bias_error(added, 1.0 / job.config.imu_rate_hz,
                               job.config.gyro_colored_noise_tau_s)
    assert record['best_bias_error_deg_s'] == pytest.approx(math.degrees(expected), abs=1e-12)
    assert record['beyond_reach'] == (abs(math.degrees(expected))
                                      > BOUNDS['bias_error_final_deg_s'])


def test_silent_misses_below_the_band_are_counted_apart():
    from gyro_ekf.analysis.stress import _class_summary, table

    def record(missed, verdict, below, above):
        return {'passed': not missed, 'silent': bool(missed) and verdict == 'ok',
                'verdict': verdict, 'missed': missed, 'nees_share_in_band': 1 - below - above,
                'nees_share_below_band': below, 'nees_share_above_band': above}
    records = [record(['nees_share_in_band'], 'ok', 0.15, 0.0),        # conservative
               record(['nees_share_in_band'], 'ok', 0.0, 0.15),        # overconfident
               record(['nees_share_in_band', 'position_rmse_m'], 'ok', 0.15, 0.0),
               record(['nees_share_in_band'], 'degraded', 0.15, 0.0),  # loud
               record([], 'ok', 0.02, 0.02)]
    summary = _class_summary(CLASSES[0], records)
    assert summary['silent_failures'] == 3
    assert summary['silent_nees_below_band'] == 1
    results = {'classes': {'clean': summary},
               'suite': {'trips': 5, 'duration_s': 120.0, 'static_s': 8.0, 'seed': 0,
                         'elapsed_s': 1.0, 'workers': 1},
               'totals': {'pass_rate': 0.2, 'silent_failures': 3, 'errors': 0,
                          'silent_nees_below_band': 1}}
    assert '3 silent failure(s) (1 of them the NEES share alone missed below' in table(results)


def test_share_intervals_are_wilson_scores():
    from gyro_ekf.analysis.stress import _Z95, wilson_interval
    assert _Z95 == pytest.approx(1.96, abs=1e-3)
    z2 = _Z95 * _Z95
    # At the ends the Wilson interval has closed forms: 0 of n up to z^2 / (n + z^2),
    # n of n down from n / (n + z^2) (25 trips: 13.3 % and 86.7 %).
    assert wilson_interval(0, 25) == pytest.approx([0.0, z2 / (25 + z2)], abs=1e-12)
    assert wilson_interval(25, 25) == pytest.approx([25 / (25 + z2), 1.0], abs=1e-12)
    # Symmetric about a half; k and n - k mirror each other.
    low, high = wilson_interval(10, 20)
    assert low + high == pytest.approx(1.0, abs=1e-12)
    low, high = wilson_interval(19, 25)
    assert wilson_interval(6, 25) == pytest.approx([1.0 - high, 1.0 - low], abs=1e-12)
    # The share inside, the interval narrower with more trips.
    assert low < 19 / 25 < high
    low4, high4 = wilson_interval(76, 100)
    assert low < low4 < 0.76 < high4 < high
    assert wilson_interval(0, 0) is None


def test_the_table_prints_each_share_with_its_interval():
    from gyro_ekf.analysis.stress import _class_summary, table
    records = [{'passed': k < 24, 'silent': False, 'verdict': 'ok' if k < 24 else 'degraded',
                'missed': [] if k < 24 else ['nees_share_in_band']} for k in range(25)]
    summary = _class_summary(CLASSES[0], records)
    assert summary['pass_rate_ci95'] == pytest.approx([0.8046, 0.9929], abs=1e-4)
    assert summary['silent_rate_ci95'][0] == 0.0
    results = {'classes': {'clean': summary},
               'suite': {'trips': 25, 'duration_s': 120.0, 'static_s': 8.0, 'seed': 0,
                         'elapsed_s': 1.0, 'workers': 1},
               'totals': {'pass_rate': 0.96, 'pass_rate_ci95': summary['pass_rate_ci95'],
                          'silent_failures': 0, 'silent_rate_ci95': [0.0, 0.1332],
                          'errors': 0}}
    text = table(results)
    assert "a miss there is the data's" not in text
    assert '96 % (80-99)' in text
    assert '0 % (0-13)' in text
    assert 'seed 0: 96 % (80-99) within the bounds' in text
    assert '0 silent failure(s) (share 0.0-13.3 %, 95 % CI)' in text


def test_the_table_says_how_many_trips_the_data_put_beyond_reach():
    from gyro_ekf.analysis.stress import _class_summary, table
    records = [{'passed': k != 3, 'silent': False, 'verdict': 'degraded',
                'missed': [] if k != 3 else ['bias_error_final_deg_s'],
                'best_bias_error_deg_s': 0.025 if k == 3 else 0.001, 'beyond_reach': k == 3}
               for k in range(25)]
    coloured = next(c for c in CLASSES if c.name == 'coloured_gyro')
    summary = _class_summary(coloured, records)
    assert summary['beyond_reach'] == 1
    results = {'classes': {'coloured_gyro': summary},
               'suite': {'trips': 25, 'duration_s': 120.0, 'static_s': 8.0, 'seed': 0,
                         'elapsed_s': 1.0, 'workers': 1},
               'totals': {'pass_rate': 0.96, 'silent_failures': 0, 'errors': 0}}
    assert ('coloured_gyro: 1 of 25 trip(s) end on a wander that leaves even the best '
            'estimate of a constant bias beyond 0.02 deg/s (best_bias_error_deg_s in the '
            "JSON): a miss there is the data's, not the filter's") in table(results)
