"""Bad command-line arguments: one line naming the option (or file), never a traceback.

Each case runs the real CLI through its main(argv) entry and checks the exit code, that
stderr is a single line holding the option and the value, and that nothing was written.
"""

from __future__ import annotations

from pathlib import Path
import subprocess
import sys

import pytest

from gyro_ekf.cli.main import main

REPO = Path(__file__).resolve().parents[2]
STATIC_BAG = REPO / 'bags' / 'sim_static_start'
MOVING_BAG = REPO / 'bags' / 'sim_moving_start'


def _fails(capsys, argv: list[str], *matches: str, code: int = 1) -> str:
    """Run the CLI, expect `code` and a one-line error holding every match."""
    result = main(['-q', *argv])
    err = capsys.readouterr().err
    assert result == code, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and 'Traceback' not in err, err
    for match in matches:
        assert match in lines[0], lines[0]
    return lines[0]


@pytest.fixture
def no_processes(monkeypatch):
    """Keep any ROS process a command would start local, and fail the test if one starts."""
    from gyro_ekf import ros_env

    import rclpy

    monkeypatch.setenv('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    monkeypatch.setenv('ROS_DOMAIN_ID', '64')

    def refuse(self, name, *args):
        raise AssertionError(f'{name} was started before the arguments were checked')

    def refuse_init(*args, **kwargs):
        raise AssertionError('rclpy was started before the arguments were checked')
    monkeypatch.setattr(ros_env.ChildProcesses, 'start', refuse)
    monkeypatch.setattr(rclpy, 'init', refuse_init)


# 1. Tracebacks -----------------------------------------------------------------------------

@pytest.mark.parametrize('value', ['nan', 'inf'])
def test_simulate_refuses_a_duration_that_is_not_finite(tmp_path, capsys, value):
    _fails(capsys, ['simulate', '-o', str(tmp_path / 's'), '--duration-s', value],
           f'gyro-ekf simulate: error: --duration-s: {value} is not a finite number')
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize('value,words', [
    ('nan', "--start-time 'nan': not a finite number"),
    ('inf', "--start-time 'inf': not a finite number"),
    ('1e30', "--start-time '1e30': not before 2038-01-19T03:14:08Z"),
    ('2262-04-12T00:00:00Z', "--start-time '2262-04-12T00:00:00Z': not before 2038"),
])
def test_convert_refuses_a_start_time_that_is_not_finite_or_too_late(
        tmp_path, capsys, value, words):
    trip = tmp_path / 'trip.npz'
    assert main(['-q', 'simulate', '-o', str(trip), '--duration-s', '5', '--static-s', '2']) == 0
    _fails(capsys, ['convert', str(trip), '-o', str(tmp_path / 'bag'), '--start-time', value],
           'gyro-ekf convert: error: ' + words)
    assert sorted(p.name for p in tmp_path.iterdir()) == ['trip.npz']


def test_convert_refuses_a_start_time_whose_log_ends_after_2038(tmp_path, capsys):
    trip = tmp_path / 'trip.npz'
    assert main(['-q', 'simulate', '-o', str(trip), '--duration-s', '5', '--static-s', '2']) == 0
    _fails(capsys, ['convert', str(trip), '-o', str(tmp_path / 'bag'), '--start-time',
                    '2147483645'],
           "--start-time '2147483645': the 5 s log would end after 2038-01-19T03:14:08Z")
    assert sorted(p.name for p in tmp_path.iterdir()) == ['trip.npz']


@pytest.mark.parametrize('command', ['convert', 'calibrate'])
def test_an_empty_trip_file_is_refused_naming_it(tmp_path, capsys, command):
    empty = tmp_path / 'e.npz'
    empty.write_bytes(b'')
    argv = [command, str(empty)] + (['-o', str(tmp_path / 'bag')] if command == 'convert'
                                    else [])
    _fails(capsys, argv, f'gyro-ekf {command}: error: {empty}: not a readable .npz trip '
           'file: the file is empty')
    assert [p.name for p in tmp_path.iterdir()] == ['e.npz']


def test_demo_refuses_a_file_as_output_folder(tmp_path, capsys, no_processes):
    target = tmp_path / 'notes.txt'
    target.write_text('mine')
    _fails(capsys, ['demo', str(STATIC_BAG), '-o', str(target)],
           f'gyro-ekf demo: error: {target}: exists and is not a folder')
    assert target.read_text() == 'mine'


def test_demo_turns_an_output_folder_it_cannot_create_into_one_line(tmp_path, capsys,
                                                                    no_processes):
    target = tmp_path / 'notes.txt'
    target.write_text('mine')
    _fails(capsys, ['demo', str(STATIC_BAG), '-o', str(target / 'out')],
           f'gyro-ekf demo: error: {target}/out: cannot write the outputs: not a directory')
    assert [p.name for p in tmp_path.iterdir()] == ['notes.txt']


# 2. Numbers that make no sense ---------------------------------------------------------------

@pytest.mark.parametrize('argv,words', [
    (['--duration-s', '10', '--static-s', '20'],
     '--static-s: 20 s is longer than the trip (--duration-s 10 s)'),
    (['--lidar-yaw-error-deg', 'nan'], '--lidar-yaw-error-deg: nan is not a finite number'),
    (['--lidar-offset-m', 'nan', '0'], '--lidar-offset-m (X): nan is not a finite number'),
    (['--lidar-offset-m', '0', 'inf'], '--lidar-offset-m (Y): inf is not a finite number'),
    (['--second-lidar', '--lidar2-yaw-error-deg', 'nan'],
     '--lidar2-yaw-error-deg: nan is not a finite number'),
])
def test_simulate_refuses_numbers_that_make_no_sense(tmp_path, capsys, argv, words):
    _fails(capsys, ['simulate', '-o', str(tmp_path / 's'), *argv],
           'gyro-ekf simulate: error: ' + words)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize('argv,words', [
    (['--duration-s', '-1'], '--duration-s: must be > 0 s, got -1'),
    (['--flush-s', '0'], '--flush-s: must be > 0 s, got 0'),
    (['--flush-s', 'nan'], '--flush-s: nan is not a finite number'),
    (['--idle-exit-s', '-2'], '--idle-exit-s: must be > 0 s, got -2'),
])
def test_record_refuses_durations_that_are_not_positive(
        tmp_path, capsys, no_processes, argv, words):
    _fails(capsys, ['record', '/gyro_bias', '-o', str(tmp_path / 'r'), *argv],
           'gyro-ekf record: error: ' + words)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize('argv,words', [
    (['--start-s', '1000'],
     f'--start-s: 1000 s is beyond the end of {STATIC_BAG} (the bag lasts 90.000 s)'),
    (['--start-s', '-5'], '--start-s: must be >= 0 s, got -5'),
    (['--start-s', 'nan'], '--start-s: nan is not a finite number'),
    (['--duration-s', '-1'], '--duration-s: must be > 0 s, got -1'),
    (['--clock', '--clock-hz', '0'], '--clock-hz: must be > 0 Hz, got 0'),
])
def test_replay_refuses_a_window_outside_the_bag(capsys, no_processes, argv, words):
    _fails(capsys, ['replay', str(STATIC_BAG), *argv], 'gyro-ekf replay: error: ' + words)


@pytest.mark.parametrize('argv,words', [
    (['--rate', '-1'], '--rate: must be >= 0, got -1'),
    (['--rate', 'nan'], '--rate: nan is not a finite number'),
    (['--publish-every-n', '0'], '--publish-every-n: must be >= 1, got 0'),
    (['--timeout-s', '0'], '--timeout-s: must be > 0 s, got 0'),
])
def test_demo_checks_its_numbers_before_starting_anything(tmp_path, capsys, no_processes,
                                                          argv, words):
    _fails(capsys, ['demo', str(STATIC_BAG), '-o', str(tmp_path / 'd'), *argv],
           'gyro-ekf demo: error: ' + words)
    assert list(tmp_path.iterdir()) == []


# 4. Messages that name the option --------------------------------------------------------

@pytest.mark.parametrize('argv,words', [
    (['--window-length-s', '-1'], '--window-length-s: must be within [0.1, 10000] s, got -1'),
    (['--window-length-s', 'nan'], '--window-length-s: nan is not a finite number'),
    (['--window-start-s', '-5'], '--window-start-s: must be within [0, 1e+06] s, got -5'),
])
def test_calibrate_names_a_bad_window_option(capsys, argv, words):
    _fails(capsys, ['calibrate', str(STATIC_BAG), *argv], 'gyro-ekf calibrate: error: ' + words)


def test_calibrate_says_it_takes_one_bag_at_a_time(capsys):
    _fails(capsys, ['calibrate', str(STATIC_BAG), str(MOVING_BAG)],
           f'gyro-ekf calibrate: error: {STATIC_BAG}: calibrate takes one bag at a time '
           '(got 2 sources)')


@pytest.mark.parametrize('argv,words', [
    (['--lidar-yaw-error-deg', '400'],
     '--lidar-yaw-error-deg: must be within [-180, 180] deg, got 400'),
    (['--second-lidar', '--lidar2-yaw-error-deg', '-200'],
     '--lidar2-yaw-error-deg: must be within [-180, 180] deg, got -200'),
    (['--static-s', 'nan'], '--static-s: nan is not a finite number'),
    (['--static-s', '-1'], '--static-s: must be within [0, 100000] s, got -1'),
    (['--static-turn-deg-s', '40'],
     '--static-turn-deg-s: must be within [-28.6479, 28.6479] deg/s, got 40'),
    # A turn through no static window was no turn at all, with exit 0.
    (['--static-s', '0', '--static-turn-deg-s', '1'],
     '--static-turn-deg-s: the turn is made through the static window, and --static-s is 0'),
])
def test_simulate_names_the_option_in_its_own_unit(tmp_path, capsys, argv, words):
    _fails(capsys, ['simulate', '-o', str(tmp_path / 's'), *argv],
           'gyro-ekf simulate: error: ' + words)
    assert list(tmp_path.iterdir()) == []


# 3. Silent topics and empty bags ---------------------------------------------------------

@pytest.fixture(scope='module')
def silent_recording(tmp_path_factory):
    """`record` of two topics nobody publishes, for 1 s (a real process, domain 64)."""
    import subprocess
    import sys

    from gyro_ekf.ros_env import child_env

    folder = tmp_path_factory.mktemp('silent')
    bag = folder / 'bag'
    result = subprocess.run(
        [sys.executable, '-m', 'gyro_ekf.cli.main', '-q', 'record', '/never_published',
         '/also_never:std_msgs/msg/String', '-o', str(bag), '--duration-s', '1'],
        env=child_env(64, folder / 'ros_log'), cwd=REPO, capture_output=True, text=True,
        timeout=120)
    return bag, result


@pytest.mark.ros
def test_record_warns_naming_the_topics_that_got_no_message(silent_recording):
    bag, result = silent_recording
    assert result.returncode == 0, result.stderr
    assert 'Traceback' not in result.stderr
    warnings = [line for line in result.stderr.splitlines() if line.startswith('WARNING')]
    assert len(warnings) == 1, result.stderr
    assert f'{bag}: no message on /never_published, /also_never' in warnings[0], warnings


@pytest.mark.ros
def test_info_on_a_bag_without_messages_says_so(silent_recording, capsys):
    bag, _ = silent_recording
    assert main(['info', str(bag)]) == 0
    out = capsys.readouterr().out
    assert 'start:     - (the bag has no messages)' in out, out
    assert '2262' not in out, out
    assert 'messages:  0' in out, out


# 5. demo into a folder that holds files --------------------------------------------------

def _earlier_demo(folder: Path) -> None:
    """Lay out what a demo leaves in its output folder."""
    (folder / 'bag').mkdir(parents=True)
    (folder / 'bag' / 'metadata.yaml').write_text('old')
    (folder / 'bag' / 'bag.mcap').write_text('old')
    (folder / 'ros_log').mkdir()
    (folder / 'ros_log' / 'python3_123_1700000000000.log').write_text('old')
    for name in ('ekf_node.log', 'replay.log', 'summary.json', 'trajectory.png'):
        (folder / name).write_text('old')


def test_demo_refuses_a_non_empty_folder_without_force(tmp_path, capsys, no_processes):
    out = tmp_path / 'out'
    _earlier_demo(out)
    _fails(capsys, ['demo', str(STATIC_BAG), '-o', str(out)],
           f'gyro-ekf demo: error: {out}: folder is not empty; use --force')
    assert (out / 'summary.json').read_text() == 'old'


def test_demo_force_refuses_a_folder_holding_user_files(tmp_path, capsys, no_processes):
    out = tmp_path / 'out'
    _earlier_demo(out)
    (out / 'notes.txt').write_text('mine')
    _fails(capsys, ['demo', str(STATIC_BAG), '-o', str(out), '--force'],
           f'gyro-ekf demo: error: {out}/notes.txt: is not a product of gyro-ekf demo')
    assert (out / 'notes.txt').read_text() == 'mine'


def test_demo_force_goes_ahead_on_an_earlier_demo_folder(tmp_path, capsys, no_processes):
    out = tmp_path / 'out'
    _earlier_demo(out)
    # The first process it starts is where the (refused) nodes would begin.
    with pytest.raises(AssertionError, match='calibration_node was started'):
        main(['-q', 'demo', str(STATIC_BAG), '-o', str(out), '--force'])


def test_simulate_without_static_s_keeps_a_short_trip_static_throughout(tmp_path):
    from gyro_ekf.io.trip_file import load_trip

    trip = tmp_path / 'short.npz'
    assert main(['-q', 'simulate', '-o', str(trip), '--duration-s', '5']) == 0
    assert load_trip(trip).static_duration_s == 5.0


def test_a_reader_that_goes_away_ends_the_command_without_a_traceback():
    # `gyro-ekf calibrate BAG --json | head -c 10` ended in a BrokenPipeError traceback.
    process = subprocess.Popen(
        [sys.executable, '-m', 'gyro_ekf.cli.main', 'calibrate', str(STATIC_BAG),
         '--json'], stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    process.stdout.close()  # before the command writes: its first write finds no reader
    stderr = process.stderr.read().decode()
    assert process.wait() == 141, stderr
    assert 'Traceback' not in stderr and 'Broken pipe' not in stderr, stderr


@pytest.mark.parametrize('command', ['simulate', 'record', 'stress', 'run', 'convert'])
def test_help_shows_no_none_default(command, capsys):
    # `--path-length ... default 600 ... (default: None)`: two defaults, one of them wrong.
    with pytest.raises(SystemExit):
        main([command, '--help'])
    assert '(default: None)' not in capsys.readouterr().out
