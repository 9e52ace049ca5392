"""Bad input offline: `convert`, `run` and `calibrate` refuse it in one line or, with
--skip-bad, drop and count it; nothing non-finite reaches the filter or the output.

Damaged logs are built in tmp_path: small synthetic ones (test/io/synthetic_logs.py) and
copies of the real course logs (shared data) with a few values changed.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
import shutil
import sys

import numpy as np
import pytest
import scipy.io

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / 'io'))
from synthetic_logs import leftovers, write_2016, write_2022  # noqa: E402

from gyro_ekf.cli.main import main  # noqa: E402
from gyro_ekf.core.simulator import SimulationConfig, simulate_trip  # noqa: E402
from gyro_ekf.io.bag_writer import write_trip_bag  # noqa: E402
from gyro_ekf.io.sidecar import sidecar_path  # noqa: E402


def _fails(capsys, argv: list[str], *matches: str) -> str:
    """Run the CLI, expect exit 1 and a one-line error holding every match."""
    code = main(['-q', *argv])
    err = capsys.readouterr().err
    assert code == 1, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and 'Traceback' not in err, err
    for match in matches:
        assert match in lines[0], lines[0]
    return lines[0]


def _strict_json(text: str):
    def refuse(constant):
        raise AssertionError(f'non-standard JSON constant {constant}')
    return json.loads(text, parse_constant=refuse)


def _damaged_2016(shared_data, folder: Path, change) -> Path:
    """Copy the real 2016 trio (and the map) into folder, with `change(imu_vars)` applied."""
    folder.mkdir()
    source = shared_data('2016_project1')
    for name in ('Speed_dataC.mat', 'Laser__2C.mat'):
        shutil.copy(source / name, folder / name)
    shutil.copy(shared_data('2021_aas01/MapMTRN4010.mat'), folder / 'MapMTRN4010.mat')
    imu = scipy.io.loadmat(source / 'IMU_dataC.mat', simplify_cells=True)['IMU']
    change(imu)
    scipy.io.savemat(folder / 'IMU_dataC.mat', {'IMU': imu})
    return folder


def _nan_gyro(first: int, count: int):
    def change(imu):
        imu['DATAf'][5, first:first + count] = np.nan   # row 6: the yaw rate
    return change


@pytest.mark.shared_data
def test_real_2016_log_with_ten_nan_gyro_samples(shared_data, tmp_path, capsys, caplog):
    log = _damaged_2016(shared_data, tmp_path / 'log', _nan_gyro(20_000, 10))
    bag = tmp_path / 'bag'
    _fails(capsys, ['convert', str(log), '-o', str(bag)],
           'error: IMU_dataC.mat: imu.angular_velocity.z[20000]: nan is not finite')
    assert leftovers(tmp_path) == ['log']

    assert main(['convert', str(log), '-o', str(bag), '--skip-bad']) == 0
    assert '--skip-bad dropped 10 samples: 10 imu.angular_velocity.z (not finite)' in caplog.text
    out = tmp_path / 'run'
    assert main(['-q', 'run', str(bag), '-o', str(out), '--no-plots', '--no-bag',
                 '--no-progress']) == 0
    rows = np.loadtxt(out / 'estimates.csv', delimiter=',', skiprows=1)
    assert rows.shape[0] == 44_578 - 10
    assert np.isfinite(rows).all()
    summary = _strict_json((out / 'summary.json').read_text())
    assert summary['association']['share_associated'] > 0.98
    assert summary['input']['samples_dropped_total'] == 0   # the bag itself is clean


@pytest.mark.shared_data
def test_calibrate_with_nan_never_prints_a_nan_bias(shared_data, tmp_path, capsys):
    log = _damaged_2016(shared_data, tmp_path / 'log', _nan_gyro(100, 3))  # in the window
    _fails(capsys, ['calibrate', str(log), '--json'], 'imu.angular_velocity.z[100]')
    assert main(['-q', 'calibrate', str(log), '--json', '--skip-bad']) == 0
    report = _strict_json(capsys.readouterr().out)
    assert report['n_samples'] == 1001 - 3
    assert report['bias_deg_s'][2] == pytest.approx(-0.9748, abs=0.001)


def test_2016_log_one_inf_gyro_and_one_nan_speed(tmp_path, capsys, caplog):
    def inf_gyro(variables):
        variables['IMU']['DATAf'][5, 40] = np.inf
    write_2016(tmp_path / 'a', change=inf_gyro)
    _fails(capsys, ['convert', str(tmp_path / 'a'), '-o', str(tmp_path / 'bag_a')],
           'error: IMU_dataC.mat: imu.angular_velocity.z[40]: inf is not finite')

    def nan_speed(variables):
        variables['Vel']['speeds'][7] = np.nan
    write_2016(tmp_path / 'b', change=nan_speed)
    _fails(capsys, ['convert', str(tmp_path / 'b'), '-o', str(tmp_path / 'bag_b')],
           'error: Speed_dataC.mat: speed.speed_m_s[7]: nan is not finite')
    assert main(['convert', str(tmp_path / 'b'), '-o', str(tmp_path / 'bag_b'),
                 '--skip-bad']) == 0
    assert '1 speed.speed_m_s (not finite)' in caplog.text
    assert not list(tmp_path.glob('bag_a*'))


@pytest.mark.parametrize('row, value, field', [
    (1, np.nan, 'imu.angular_velocity.z[12]: nan is not finite'),
    (1, np.inf, 'imu.angular_velocity.z[12]: inf is not finite'),
    (0, np.nan, 'speed.speed_m_s[12]: nan is not finite')])
def test_2022_log_with_nan_or_inf(tmp_path, capsys, row, value, field):
    def change(data):
        data['vw'][row, 12] = value
    path = write_2022(tmp_path / 'data019b.mat', change=change)
    _fails(capsys, ['convert', str(path), '-o', str(tmp_path / 'bag')], 'data019b.mat: ' + field)
    assert leftovers(tmp_path) == ['data019b.mat']
    assert main(['-q', 'convert', str(path), '-o', str(tmp_path / 'bag'), '--skip-bad']) == 0


@pytest.mark.parametrize('key, value, match', [
    ('pose0', np.array([np.nan, 3.0, 0.1], dtype=np.float32), 'initial_pose: nan is not finite'),
    ('Landmarks', np.array([[5.0, np.nan], [7.0, 8.0]], dtype=np.float32),  # rows x, y
     'landmarks.xy_m[1]: nan is not finite')])
def test_2022_log_with_nan_pose_or_landmark_is_refused_even_with_skip_bad(
        tmp_path, capsys, key, value, match):
    path = write_2022(tmp_path / 'data019b.mat', change=lambda data: data.__setitem__(key, value))
    _fails(capsys, ['convert', str(path), '-o', str(tmp_path / 'bag'), '--skip-bad'],
           'data019b.mat: ' + match)
    assert leftovers(tmp_path) == ['data019b.mat']


def test_log_whose_time_goes_back_10_s(tmp_path, capsys, caplog):
    def change(data):
        table = data['table'].astype(np.int64)
        table[0] += 200_000
        table[0, 60:] -= 100_000            # 10 s back (counts of 0.1 ms)
        data['table'] = table.astype(np.uint32)
    path = write_2022(tmp_path / 'data019b.mat', change=change)
    _fails(capsys, ['convert', str(path), '-o', str(tmp_path / 'bag')],
           "data019b.mat: field 'data.table(1,:)' goes back in time at index 60")
    bag = tmp_path / 'bag'
    assert main(['convert', str(path), '-o', str(bag), '--skip-bad']) == 0
    assert 'imu.stamp_s (time went back)' in caplog.text
    assert 'speed.stamp_s (time went back)' in caplog.text


def test_stamp_jump_of_300000_s(tmp_path, capsys, caplog):
    def change(variables):
        variables['IMU']['times'][50] += np.uint32(3_000_000_000)   # +300 000 s
    write_2016(tmp_path / 'log', change=change)
    _fails(capsys, ['convert', str(tmp_path / 'log'), '-o', str(tmp_path / 'bag')],
           "IMU_dataC.mat: field 'IMU.times' jumps ahead at index 50",
           '+300000.0050 s) and back after it')
    assert main(['convert', str(tmp_path / 'log'), '-o', str(tmp_path / 'bag'),
                 '--skip-bad']) == 0
    assert '1 imu.stamp_s (stamp jumped ahead)' in caplog.text
    out = tmp_path / 'run'
    # The bag holds the clean trip: the run ends (it would predict 300 000 s in 0.1 s steps).
    assert main(['-q', 'run', str(tmp_path / 'bag'), '-o', str(out), '--no-plots',
                 '--no-bag', '--no-progress']) == 0
    assert _strict_json((out / 'summary.json').read_text())['trip']['duration_s'] < 1.0


@pytest.fixture(scope='module')
def sim_trip():
    return simulate_trip(SimulationConfig(duration_s=20.0, static_s=0.0), seed=4)


def _bag_of(trip, folder: Path) -> Path:
    return write_trip_bag(trip, folder / 'bag')


def test_run_checks_the_bag_against_the_limits_of_its_params_file(tmp_path, capsys, sim_trip):
    # limits.* reached the nodes but `run` skipped them.
    bag = _bag_of(sim_trip, tmp_path)
    params = tmp_path / 'slow.yaml'
    params.write_text('/**:\n  ros__parameters:\n    limits.max_speed_m_s: 0.1\n')
    _fails(capsys, ['run', str(bag), '-o', str(tmp_path / 'out'), '--params-file', str(params)],
           'speed.speed_m_s[', 'exceeds the limit 0.1 m/s')
    assert not (tmp_path / 'out').exists()


def test_run_on_a_bag_with_two_nan_imu_messages(tmp_path, capsys, sim_trip):
    rates = sim_trip.imu.angular_velocity_rad_s.copy()
    rates[[300, 301], 2] = np.nan
    bag = _bag_of(dataclasses.replace(sim_trip, imu=dataclasses.replace(
        sim_trip.imu, angular_velocity_rad_s=rates)), tmp_path)
    out = tmp_path / 'out'
    _fails(capsys, ['run', str(bag), '-o', str(out)], 'bag: imu.angular_velocity.z[300]')
    assert not out.exists()      # validated before the output folder is made

    assert main(['-q', 'run', str(bag), '-o', str(out), '--skip-bad', '--no-plots',
                 '--no-progress']) == 0
    summary = _strict_json((out / 'summary.json').read_text())
    assert summary['input']['skip_bad'] is True
    assert summary['input']['samples_dropped'] == {'imu': 2}
    assert summary['input']['dropped'] == [{'field': 'imu.angular_velocity.z',
                                            'reason': 'not finite', 'count': 2,
                                            'first_index': 300}]
    assert summary['ground_truth']['position_rmse_m'] < 0.05
    rows = np.loadtxt(out / 'estimates.csv', delimiter=',', skiprows=1)
    assert rows.shape[0] == len(sim_trip.imu.stamp_s) - 2 and np.isfinite(rows).all()


def test_run_refuses_a_yaw_rate_of_1e300(tmp_path, capsys, sim_trip):
    rates = sim_trip.imu.angular_velocity_rad_s.copy()
    rates[1000, 2] = 1e300
    bag = _bag_of(dataclasses.replace(sim_trip, imu=dataclasses.replace(
        sim_trip.imu, angular_velocity_rad_s=rates)), tmp_path)
    _fails(capsys, ['run', str(bag), '-o', str(tmp_path / 'out')],
           'imu.angular_velocity.z[1000]: |1e+300| rad/s exceeds the limit 35 rad/s')
    assert not (tmp_path / 'out').exists()


def _set_in_sidecar(bag: Path, section: str, key: str, value: str) -> None:
    """Replace the first `key:` value after `section:` in the bag's params sidecar."""
    sidecar = sidecar_path(bag)
    text = sidecar.read_text()
    start = text.index(key + ':', text.index(section + ':'))
    end = text.index('\n', start)
    sidecar.write_text(f'{text[:start]}{key}: {value}{text[end:]}')


@pytest.mark.parametrize('key, value, match', [
    ('x_m', '.nan', "parameter 'lidar.scan': mount is not finite"),
    ('yaw_rad', '.inf', "parameter 'lidar.scan': mount is not finite"),
    ('y_m', '1.0e+6', "parameter 'lidar.scan': mount offset 1e+06 m exceeds the limit 10 m"),
])
def test_run_refuses_a_bad_lidar_mount_in_the_sidecar(tmp_path, capsys, sim_trip, key, value,
                                                      match):
    bag = _bag_of(sim_trip, tmp_path)
    _set_in_sidecar(bag, 'lidar', key, value)
    _fails(capsys, ['run', str(bag), '-o', str(tmp_path / 'out')], 'bag.params.yaml', match)
    assert not (tmp_path / 'out').exists()


def test_run_refuses_a_nan_initial_pose_in_the_sidecar(tmp_path, capsys, sim_trip):
    bag = _bag_of(sim_trip, tmp_path)
    _set_in_sidecar(bag, 'initial_pose', 'x_m', '.nan')
    _fails(capsys, ['run', str(bag), '-o', str(tmp_path / 'out')],
           "bag.params.yaml: parameter 'initial_pose': nan is not finite")


@pytest.mark.parametrize('section, key, value, match', [
    ('initial_pose', 'yaw_rad', '1.0e+308',
     "parameter 'initial_pose': yaw |1e+308| rad exceeds the limit 1000 rad"),
    ('lidar', 'yaw_rad', '1.0e+30', "parameter 'lidar.scan': |1e+30| rad exceeds the limit"),
    ('trip', 'static_duration_s', '1.0e+308',
     "parameter 'trip.static_duration_s': 1e+308 s exceeds the limit 1e+06 s"),
])
def test_run_refuses_a_finite_but_implausible_angle_or_duration_in_the_sidecar(
        tmp_path, capsys, sim_trip, section, key, value, match):
    # Found by `make fuzz`: finite, so they passed, and run exited 0 with them.
    bag = _bag_of(sim_trip, tmp_path)
    _set_in_sidecar(bag, section, key, value)
    _fails(capsys, ['run', str(bag), '-o', str(tmp_path / 'out')], 'bag.params.yaml', match)
    assert not (tmp_path / 'out').exists()


def test_run_refuses_a_nan_in_the_params_file(tmp_path, capsys, sim_trip):
    bag = _bag_of(sim_trip, tmp_path)
    params = tmp_path / 'filter.yaml'
    params.write_text('/**:\n  ros__parameters:\n    gyro_noise_rad_s: .nan\n')
    _fails(capsys, ['run', str(bag), '-o', str(tmp_path / 'out'), '--params-file', str(params)],
           'filter.yaml', "'gyro_noise_rad_s' = nan is not finite")
    assert not (tmp_path / 'out').exists()


def test_trip_file_whose_time_goes_back_10_s(tmp_path, capsys, caplog, sim_trip):
    from gyro_ekf.io.trip_file import save_trip
    stamps = sim_trip.speed.stamp_s.copy()
    stamps[1000:] -= 10.0
    path = save_trip(dataclasses.replace(sim_trip, speed=dataclasses.replace(
        sim_trip.speed, stamp_s=stamps)), tmp_path / 'trip.npz')
    _fails(capsys, ['convert', str(path), '-o', str(tmp_path / 'bag')],
           'trip.npz: speed.stamp_s[1000]: time went back')
    assert leftovers(tmp_path) == ['trip.npz']
    assert main(['-q', 'convert', str(path), '-o', str(tmp_path / 'bag'), '--skip-bad']) == 0
    assert 'speed.stamp_s (time went back)' in caplog.text


def test_trip_file_with_two_speeds_at_one_stamp_or_a_sample_recorded_twice(
        tmp_path, capsys, caplog, sim_trip):
    # Two odometry samples at one stamp with other speeds were converted without a word
    # (a bag with two such messages is refused); a sample recorded twice was written twice.
    import yaml

    from gyro_ekf.io.bag_reader import read_bag
    from gyro_ekf.io.trip_file import save_trip
    stamps = sim_trip.speed.stamp_s.copy()
    speeds = sim_trip.speed.speed_m_s.copy()
    stamps[1001] = stamps[1000]
    speeds[1001] = speeds[1000] + 0.1
    path = save_trip(dataclasses.replace(sim_trip, speed=dataclasses.replace(
        sim_trip.speed, stamp_s=stamps, speed_m_s=speeds)), tmp_path / 'trip.npz')
    bag = tmp_path / 'bag'
    _fails(capsys, ['convert', str(path), '-o', str(bag)],
           f'error: trip.npz: speed.stamp_s[1001]: stamp {stamps[1000]:.6f} s is that of '
           'sample 1000, but speed.speed_m_s differs: two values for one instant')
    assert leftovers(tmp_path) == ['trip.npz']
    assert main(['-q', 'convert', str(path), '-o', str(bag), '--skip-bad']) == 0
    assert ('--skip-bad dropped 1 samples: 1 speed.stamp_s (same stamp as the previous '
            'sample, other values)') in caplog.text
    speed = read_bag(bag).trip.speed
    assert len(speed.stamp_s) == len(stamps) - 1 and np.all(np.diff(speed.stamp_s) > 0)
    assert speed.speed_m_s[1000] == speeds[1000]        # the first value is the one kept

    # The same sample twice: dropped and counted with or without --skip-bad.
    imu = sim_trip.imu
    twice = {name: np.insert(values, 501, values[500], axis=0) for name, values in (
        ('stamp_s', imu.stamp_s), ('angular_velocity_rad_s', imu.angular_velocity_rad_s),
        ('linear_acceleration_m_s2', imu.linear_acceleration_m_s2)) if values is not None}
    path = save_trip(dataclasses.replace(sim_trip, imu=dataclasses.replace(imu, **twice)),
                     tmp_path / 'twice.npz')
    caplog.clear()
    assert main(['-q', 'convert', str(path), '-o', str(tmp_path / 'bag2')]) == 0
    assert ('twice.npz: dropped 1 exact repeat(s) of the sample before (same stamp and '
            'values, kept once): 1 imu (first at index 501)') in caplog.text
    topics = yaml.safe_load((tmp_path / 'bag2' / 'metadata.yaml').read_text())[
        'rosbag2_bagfile_information']['topics_with_message_count']
    assert {t['topic_metadata']['name']: t['message_count'] for t in topics}['/imu'] \
        == len(imu.stamp_s)


def test_run_on_a_bag_whose_last_imu_stamp_jumped_300000_s_ends(tmp_path, capsys, sim_trip):
    stamps = sim_trip.imu.stamp_s.copy()
    stamps[-1] += 300_000.0     # nothing after it comes back: only the jump limit catches it
    bag = _bag_of(dataclasses.replace(sim_trip, imu=dataclasses.replace(
        sim_trip.imu, stamp_s=stamps)), tmp_path)
    out = tmp_path / 'out'
    _fails(capsys, ['run', str(bag), '-o', str(out)],
           f'bag: imu.stamp_s[{len(stamps) - 1}]: stamp jumped ahead 300000 s')
    assert not out.exists()
    assert main(['-q', 'run', str(bag), '-o', str(out), '--skip-bad', '--no-plots', '--no-bag',
                 '--no-progress']) == 0
    summary = _strict_json((out / 'summary.json').read_text())
    assert summary['input']['dropped'][0]['reason'] == 'stamp jumped ahead'
    assert summary['trip']['duration_s'] < 21.0


def test_2016_log_with_a_nan_landmark_in_its_map_names_the_map(tmp_path, capsys):
    write_2016(tmp_path / 'log')
    scipy.io.savemat(tmp_path / 'log' / 'MapMTRN4010.mat', {'Map': {
        'x': np.array([1.0, np.nan, 3.0], dtype=np.float32),
        'y': np.array([4.0, 5.0, 6.5], dtype=np.float32), 'n': 3}})
    _fails(capsys, ['convert', str(tmp_path / 'log'), '-o', str(tmp_path / 'bag'), '--skip-bad'],
           'error: MapMTRN4010.mat: landmarks.xy_m[1]: nan is not finite')
    assert not (tmp_path / 'bag').exists()


def test_a_map_option_naming_a_file_that_is_no_map_is_refused(tmp_path, capsys):
    # It used to join the log's files: the log converted without landmarks, with a warning
    # that no map was given.
    write_2016(tmp_path / 'log')
    _fails(capsys, ['convert', str(tmp_path / 'log'), '-o', str(tmp_path / 'bag'), '--map',
                    str(tmp_path / 'log' / 'IMU_dataC.mat')],
           "error: IMU_dataC.mat: not a landmark map: no variable 'Map' (it has ['IMU'])")
    assert not (tmp_path / 'bag').exists()


def test_run_ignores_and_counts_bad_message_covariances(tmp_path, capsys, caplog, sim_trip):
    rate_vars = np.full(len(sim_trip.imu.stamp_s), sim_trip.noise.gyro_rad_s ** 2)
    rate_vars[[100, 200]] = [np.inf, -5.0]  # (a NaN the writer takes as "not given")
    speed_vars = np.zeros(len(sim_trip.speed.stamp_s))
    speed_vars[50] = 1e9  # a sigma of 31 km/s: beyond any speed
    bag = _bag_of(dataclasses.replace(
        sim_trip, imu=dataclasses.replace(sim_trip.imu, yaw_rate_variance=rate_vars),
        speed=dataclasses.replace(sim_trip.speed, speed_variance=speed_vars)), tmp_path)
    out = tmp_path / 'out'
    assert main(['run', str(bag), '-o', str(out), '--no-plots', '--no-progress']) == 0
    summary = _strict_json((out / 'summary.json').read_text())
    assert summary['input']['covariances_ignored'] == {
        'imu.angular_velocity_covariance[8]': 2, 'speed.twist.covariance[0]': 1}
    assert summary['input']['covariances_used'] == {
        'imu.angular_velocity_covariance[8]': len(rate_vars) - 2}
    assert 'ignored bad message covariances' in caplog.text
    assert summary['ground_truth']['position_rmse_m'] < 0.05


def test_message_covariances_replace_the_noise_unless_ignored(tmp_path, sim_trip):
    # Messages that say the gyro is 5 times noisier than the log states.
    rate_vars = np.full(len(sim_trip.imu.stamp_s), (5.0 * sim_trip.noise.gyro_rad_s) ** 2)
    bag = _bag_of(dataclasses.replace(sim_trip, imu=dataclasses.replace(
        sim_trip.imu, yaw_rate_variance=rate_vars)), tmp_path)
    yaw_variance = {}
    for flags in ([], ['--ignore-message-covariance']):
        out = tmp_path / ('ignored' if flags else 'used')
        assert main(['-q', 'run', str(bag), '-o', str(out), '--no-plots', '--no-progress',
                     '--no-bag', *flags]) == 0
        rows = np.loadtxt(out / 'estimates.csv', delimiter=',', skiprows=1, max_rows=400)
        header = (out / 'estimates.csv').read_text().splitlines()[0].split(',')
        yaw_variance[bool(flags)] = rows[-1, header.index('var_yaw')]
    # The noisier gyro leaves more doubt about the heading.
    assert yaw_variance[False] > yaw_variance[True]


def test_what_convert_skip_bad_dropped_counts_in_every_command_on_the_bag(
        tmp_path, capsys, caplog):
    # The bag convert --skip-bad wrote carried no trace of the samples it dropped: run on it
    # said ok where run --skip-bad on the same samples in a bag says degraded.
    from gyro_ekf.io.trip_file import save_trip
    trip = simulate_trip(SimulationConfig(duration_s=20.0, static_s=8.0, second_lidar=True),
                         seed=4)
    rates = trip.imu.angular_velocity_rad_s.copy()
    rates[[600, 601], 2] = np.nan
    log = save_trip(dataclasses.replace(trip, imu=dataclasses.replace(
        trip.imu, angular_velocity_rad_s=rates)), tmp_path / 'trip.npz')
    bag = tmp_path / 'bag'
    assert main(['-q', 'convert', str(log), '-o', str(bag), '--skip-bad']) == 0
    capsys.readouterr()
    warning = ('bag: when trip.npz was converted, --skip-bad dropped 2 samples: '
               '2 imu.angular_velocity.z (not finite)')

    out = tmp_path / 'out'
    caplog.clear()
    assert main(['run', str(bag), '-o', str(out), '--no-plots', '--no-bag', '--no-progress',
                 '--strict']) == 3
    assert warning in caplog.text
    summary = _strict_json((out / 'summary.json').read_text())
    assert summary['input']['samples_dropped_total'] == 0       # nothing dropped now ...
    assert summary['input']['dropped_when_converted'] == {      # ... but at the conversion
        'source': 'trip.npz', 'samples_dropped_total': 2, 'samples_dropped': {'imu': 2},
        'dropped': [{'field': 'imu.angular_velocity.z', 'reason': 'not finite', 'count': 2,
                     'first_index': 600}],
        'time_breaks': {}}
    assert summary['health']['verdict'] == 'degraded'
    assert ('input dropped when the log was converted (gyro-ekf convert --skip-bad on '
            'trip.npz): 2 (imu samples 2), more than 0') in summary['health']['reasons']

    assert main(['info', str(bag)]) == 0
    assert ('dropped:   when trip.npz was converted, --skip-bad dropped 2 samples: 2 '
            'imu.angular_velocity.z (not finite, first at index 600); indexes count in the '
            'log, these samples are not in the bag') in capsys.readouterr().out.splitlines()
    for command in (['calibrate', str(bag)], ['calibrate-mounts', str(bag)]):
        caplog.clear()
        assert main(command) == 0
        assert warning in caplog.text, command
    capsys.readouterr()
