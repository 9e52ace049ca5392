"""`gyro-ekf calibrate` on the real logs: the course value, and refusal on moving starts.

Every refusal is one line naming the input: the bag (and its topic) or the log's file.
"""

import dataclasses
import json
import math
from pathlib import Path
import shutil
import sys

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / 'io'))
from synthetic_logs import write_2016, write_2021  # noqa: E402

from gyro_ekf.cli.main import main  # noqa: E402
from gyro_ekf.core.simulator import SimulationConfig, simulate_trip  # noqa: E402
from gyro_ekf.io.bag_writer import write_trip_bag  # noqa: E402
from gyro_ekf.io.sidecar import sidecar_path  # noqa: E402
from gyro_ekf.io.trip_file import save_trip  # noqa: E402


def test_calibrate_2016_log_prints_the_course_bias(shared_data, capsys):
    assert main(['calibrate', str(shared_data('2016_project1')), '--json']) == 0
    report = json.loads(capsys.readouterr().out)
    print('2016 bias deg/s:', report['bias_deg_s'], 'sigma deg/s:', report['sigma_deg_s'])
    assert report['bias_deg_s'][2] == pytest.approx(-0.9748, abs=0.001)
    assert report['n_samples'] == 1001
    assert all(report['axes_known'])


PER_AXIS = ('bias_rad_s', 'sigma_rad_s', 'bias_deg_s', 'sigma_deg_s', 'standard_error_deg_s')


def test_calibrate_2021_log_yaw_only(shared_data, capsys):
    assert main(['calibrate', str(shared_data('2021_aas01')), '--json']) == 0
    report = json.loads(capsys.readouterr().out)
    assert report['axes_known'] == [False, False, True]
    # The 2021 log stores the same trip's yaw rate in 0.01 deg/s.
    assert report['bias_deg_s'][2] == pytest.approx(-0.9748, abs=0.01)
    # x and y are not measured: null, not a bias and a noise of exactly 0 (as before).
    for key in PER_AXIS:
        assert report[key][:2] == [None, None], key
        assert report[key][2] > 0 if 'sigma' in key or 'error' in key else report[key][2] < 0


def test_calibrate_a_bag_says_null_for_the_axes_it_does_not_measure(tmp_path, capsys):
    # The same simulated trip written as a bag twice, its gyro once with x and y marked
    # not measured (as convert writes a yaw-rate-only log): only those two become null.
    from gyro_ekf.io.bag_writer import write_trip_bag
    from gyro_ekf.io.trip_file import load_trip

    assert main(['-q', 'simulate', '-o', str(tmp_path / 'trip.npz'), '--duration-s', '20',
                 '--static-s', '8', '--seed', '4']) == 0
    trip = load_trip(tmp_path / 'trip.npz')
    z_only = dataclasses.replace(trip.imu, axes_known=(False, False, True))
    reports = []
    for name, written in (('xyz', trip), ('z', dataclasses.replace(trip, imu=z_only))):
        bag = write_trip_bag(written, tmp_path / name)
        assert main(['-q', 'calibrate', str(bag), '--json']) == 0
        reports.append(json.loads(capsys.readouterr().out))
    every, z = reports
    assert every['axes_known'] == [True, True, True] and z['axes_known'] == [False, False, True]
    for key in PER_AXIS:
        assert None not in every[key], key
        assert z[key] == [None, None, every[key][2]], key


@pytest.mark.parametrize('log', ['2022_sim/data019b.mat', '2023_sim/DataUsr_006k.mat'])
def test_calibrate_refuses_logs_that_move_from_the_start(shared_data, capsys, log):
    assert main(['calibrate', str(shared_data(log))]) == 1
    assert 'platform moved' in capsys.readouterr().err


def _refused(capsys, *argv: str) -> str:
    """Run calibrate, expect exit 1 and one line of error without a traceback; return it."""
    code = main(['-q', 'calibrate', *argv])
    err = capsys.readouterr().err
    assert code == 1, err
    assert 'Traceback' not in err and len(err.strip().splitlines()) == 1, err
    return err.strip().removeprefix('gyro-ekf calibrate: error: ')


@pytest.fixture(scope='module')
def bags(tmp_path_factory) -> dict[str, Path]:
    """Simulated trips as the project's writer writes them: one starting static, one not."""
    folder = tmp_path_factory.mktemp('bags')
    return {name: write_trip_bag(simulate_trip(SimulationConfig(duration_s=20.0,
                                                                static_s=static_s), seed=4),
                                 folder / name)
            for name, static_s in (('static', 8.0), ('moving', 0.0))}


def test_a_refused_window_names_the_bag_and_its_topic(bags, capsys):
    # The core's reason alone ("platform moved: ...") said nothing of which input.
    moving, static = bags['moving'], bags['static']
    assert _refused(capsys, str(moving)).startswith(
        f"{moving}: topic '/odom': platform moved: speed ")
    assert _refused(capsys, str(moving), '--ignore-speed').startswith(
        f"{moving}: topic '/imu': platform not static: gyro z spread ")
    assert _refused(capsys, str(static), '--window-length-s', '100') == (
        f"{static}: topic '/imu': the static window 0.00-100.00 s needs data until 100.00 s, "
        'but the gyro stream ends at 20.00 s')


def test_a_platform_turning_in_place_is_refused_by_its_scans(bags, tmp_path, capsys):
    # The odometry reads no speed and the gyro a steady rate: the window's mean took a
    # 0.2 deg/s turn for bias, and calibrate printed it with exit 0.
    turning = write_trip_bag(simulate_trip(SimulationConfig(
        duration_s=20.0, static_s=8.0, static_turn_rad_s=math.radians(0.2)), seed=4),
        tmp_path / 'turning')
    error = _refused(capsys, str(turning))
    assert error.startswith(f"{turning}: topic '/scan': platform not static: its LiDAR 'scan' "
                            'saw it turn +0.19'), error
    # --ignore-scans: the gyro's word alone, as before (the bias then holds the turn).
    assert main(['-q', 'calibrate', str(turning), '--ignore-scans', '--json']) == 0
    report = json.loads(capsys.readouterr().out)
    assert report['bias_deg_s'][2] == pytest.approx(-0.9 + 0.2, abs=0.02)
    assert report['scan_turns'] == []
    # A still one: what the LiDAR saw is printed with the bias.
    assert main(['-q', 'calibrate', str(bags['static'])]) == 0
    out = capsys.readouterr().out
    assert "LiDAR 'scan': turned " in out and 'poles through 51 scans): no turn in place ' \
        'beyond 0.0' in out, out
    assert main(['-q', 'calibrate', str(bags['static']), '--json']) == 0
    (turn,) = json.loads(capsys.readouterr().out)['scan_turns']
    assert turn['topic'] == 'scan' and turn['scans'] == 51 and abs(turn['rate_deg_s']) < 0.002


def test_a_refused_window_names_the_file_of_the_log_or_trip_file(tmp_path, capsys):
    # The 2016 log spreads over three files: the one holding the refused stream is named.
    log = tmp_path / 'log'
    write_2016(log)   # 0.6 s long, moving from its second sample on
    assert _refused(capsys, str(log)).startswith(
        'IMU_dataC.mat: the static window 0.00-5.00 s needs data until 5.00 s')
    assert _refused(capsys, str(log), '--window-length-s', '0.4').startswith(
        'Speed_dataC.mat: platform moved: speed ')
    trip = save_trip(simulate_trip(SimulationConfig(duration_s=20.0, static_s=0.0), seed=4),
                     tmp_path / 'moving.npz')
    assert _refused(capsys, str(trip)).startswith('moving.npz: platform moved: ')


def test_a_file_of_a_bag_or_a_bag_without_metadata_gets_the_bag_readers_advice(
        bags, tmp_path, capsys):
    # These went to the course-log reader: "good.mcap: not a readable MATLAB v5 file".
    bag = bags['static']
    (mcap,) = bag.glob('*.mcap')
    for given in (mcap, bag / 'metadata.yaml'):
        assert _refused(capsys, str(given)) == (
            f'{given}: is a file; give the bag folder that holds it, {bag}')
    params = sidecar_path(bag)
    assert _refused(capsys, str(params)) == (
        f'{params}: is a file; give the bag folder (the one holding metadata.yaml)')
    torn = tmp_path / 'torn'
    torn.mkdir()
    shutil.copy(mcap, torn / mcap.name)
    assert _refused(capsys, str(torn)) == (
        f'{torn}: no metadata.yaml (was its recorder killed?); run `gyro-ekf reindex {torn}`')


def test_unreadable_yaml_of_a_bag_is_one_line_naming_the_file(bags, tmp_path, capsys):
    # YAML errors came with their multi-line pointer to the spot.
    for name, damaged in (('meta', 'metadata.yaml'), ('side', None)):
        bag = tmp_path / name
        shutil.copytree(bags['static'], bag)
        shutil.copy(sidecar_path(bags['static']), sidecar_path(bag))
        target = bag / damaged if damaged else sidecar_path(bag)
        target.write_text(target.read_text() + 'x: [\n')
        error = _refused(capsys, str(bag))
        assert (f'{target}: while parsing a flow node' in error if damaged
                else error.startswith(f'{target.name}: not valid YAML: ')), error


def test_a_trip_file_that_is_no_zip_archive_is_refused_without_numpys_pickle_advice(
        tmp_path, capsys):
    # numpy took the text for a pickle and said "you can load it unsafely".
    path = tmp_path / 'trip.npz'
    path.write_text('not a trip\n')
    assert _refused(capsys, str(path)) == (
        'trip.npz: not a readable .npz trip file: no zip archive (truncated, or not a .npz '
        'file at all?)')


@pytest.mark.shared_data
def test_calibrate_says_nothing_of_a_map_it_never_uses(shared_data, tmp_path, capsys, caplog):
    # The 2016 log has no map beside it: calibrate warned "converting without landmarks".
    assert main(['calibrate', str(shared_data('2016_project1')), '--json']) == 0
    assert json.loads(capsys.readouterr().out)['bias_deg_s'][2] == pytest.approx(
        -0.9748, abs=0.001)
    assert [r.getMessage() for r in caplog.records if r.levelname == 'WARNING'] == []
    # convert, whose bag feeds the EKF, still says so (a small 2016 trio: same reader).
    log = tmp_path / 'log'
    write_2016(log)
    caplog.clear()
    assert main(['-q', 'convert', str(log), '-o', str(tmp_path / 'bag')]) == 0
    assert 'converting without landmarks' in caplog.text


@pytest.mark.shared_data
def test_calibrate_reads_the_2021_log_without_its_map(shared_data, tmp_path, capsys):
    # It refused: "the 2021 format needs its map ...; none was given (--map)", an option
    # calibrate does not have, for a map it never uses.
    alone = tmp_path / 'alone'
    alone.mkdir()
    shutil.copy(shared_data('2021_aas01/Measurements_AAS01.mat'), alone)
    assert main(['-q', 'calibrate', str(alone / 'Measurements_AAS01.mat'), '--json']) == 0
    report = json.loads(capsys.readouterr().out)
    assert report['bias_deg_s'][2] == pytest.approx(-0.9748, abs=0.01)
    # convert still needs the map.
    assert main(['-q', 'convert', str(alone), '-o', str(tmp_path / 'bag')]) == 1
    assert 'the 2021 format needs its map' in capsys.readouterr().err
    # A refusal of the window still names the file of the log alone.
    assert _refused(capsys, str(write_2021(tmp_path / 'small', with_map=False))).startswith(
        'Measurements_AAS01.mat: the static window ')
