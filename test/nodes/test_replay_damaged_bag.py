"""`gyro-ekf replay` of a damaged bag: one line naming the file, never a traceback.

A copy of the bundled bag gets one flipped bit in a chunk halfway through. The replay checks
the bag's bytes as `info` and `run` do before it publishes anything (it used to publish the
chunks before the damage, then end in rosbags' "Chunk checksum mismatch" traceback). A bag
damaged after that check is still read through rosbags: what it raises then is one line
naming the bag and how far the replay got; so it is with `--no-verify`, which skips the
check (the messages before the damage are then published, and acknowledged by every reader
before the replay ends).
"""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip('rclpy')

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / 'io'))
from mcap_layout import chunks, flip, mcap_of  # noqa: E402

from gyro_ekf.cli.main import main  # noqa: E402
from gyro_ekf.cli.replay import BagSource  # noqa: E402
from gyro_ekf.errors import GyroEkfError  # noqa: E402

REPO = Path(__file__).resolve().parents[2]
BAG = REPO / 'bags' / 'sim_static_start'


def copy_of_bag(tmp_path: Path) -> Path:
    bag = tmp_path / BAG.name
    shutil.copytree(BAG, bag)
    return bag


def damage_middle_chunk(bag: Path, index: int | None = None) -> int:
    """Flip a bit inside the chunk halfway through the bag's .mcap (or chunk `index`).

    Returns:
        The damaged chunk's offset.
    """
    mcap = mcap_of(bag)
    spans = chunks(mcap.read_bytes())
    assert len(spans) >= 3  # chunks before the damaged one: an unchecked replay sends them
    chunk = spans[len(spans) // 2 if index is None else index]
    flip(mcap, chunk.offset + chunk.length // 2, bit=3)
    return chunk.offset


def replayer(ros_processes, tmp_path: Path, namespace: str):
    """Return the IMU messages a probe receives, and replay(bag, name, *options).

    replay runs `gyro-ekf replay` of imu into the namespace as fast as it can, spinning the
    probe meanwhile, and returns its exit code and output.
    """
    from gyro_ekf.nodes import qos
    from sensor_msgs.msg import Imu

    processes, probe = ros_processes
    # Keep-all, so that the probe loses nothing a replay publishes, however late it spins.
    received = probe.subscribe(Imu, f'{namespace}/imu', qos.LOSSLESS)

    def replay(bag: Path, name: str, *options: str) -> tuple[int, str]:
        log = tmp_path / f'{name}.log'
        # --wait-for: a replay that publishes at all does so to the probe, matched first.
        process = subprocess.Popen(
            [sys.executable, '-m', 'gyro_ekf.cli.main', 'replay', str(bag), '--rate', '0',
             '--topics', 'imu', '--wait-for', 'imu:1', '--wait-timeout-s', '60', *options,
             '--ros-args', '-r', f'__ns:={namespace}'],
            env=processes.env, cwd=REPO, stdout=log.open('w'), stderr=subprocess.STDOUT)
        try:
            probe.spin_until(lambda: process.poll() is not None, 120, f'{name} to end')
        finally:
            if process.poll() is None:
                process.kill()
                process.wait()
        return process.returncode, log.read_text()

    return received, replay


def test_a_damaged_bag_is_refused_in_one_line_before_anything_is_published(
        ros_processes, tmp_path, capsys):
    _, probe = ros_processes
    received, replay = replayer(ros_processes, tmp_path, '/replay_damaged')
    bag = copy_of_bag(tmp_path)
    offset = damage_middle_chunk(bag)
    code, output = replay(bag, 'replay_damaged')
    assert code == 1, output
    assert 'Traceback' not in output
    lines = output.strip().splitlines()
    assert len(lines) == 1, output
    assert lines[0].startswith(
        f'gyro-ekf replay: error: {mcap_of(bag)}: chunk at offset {offset}: CRC mismatch'), lines
    # The same words as info's (and run's) refusal of the bag.
    assert main(['info', str(bag)]) == 1
    refused = capsys.readouterr().err.strip()
    assert refused.removeprefix('gyro-ekf info: ') == lines[0].removeprefix('gyro-ekf replay: ')

    # The probe takes what a replay publishes: the intact bag's first messages, and nothing
    # more, so the damaged bag's replay published none.
    code, output = replay(BAG, 'replay_intact', '--duration-s', '0.2')
    assert code == 0, output
    published = int(re.search(r'replayed (\d+) messages', output).group(1))
    assert published > 0, output
    probe.spin_until(lambda: len(received) >= published, 60, 'the intact replay')
    assert len(received) == published


def test_a_bag_damaged_after_the_check_ends_the_replay_in_one_line(tmp_path):
    bag = copy_of_bag(tmp_path)
    source = BagSource(bag, ['imu'], 0.0, None)  # checked: intact
    damage_middle_chunk(bag)  # say, written over while it is replayed
    sent = 0
    with pytest.raises(GyroEkfError) as raised:  # what main prints as one line
        for _ in source():
            sent += 1
    message = str(raised.value)
    assert sent > 0
    assert message.startswith(f'{bag}: cannot read the bag (ReaderError): '), message
    assert message.endswith(f'(the replay stopped after {sent} messages of this pass)'), message
    assert '\n' not in message


def test_no_verify_publishes_up_to_the_damage_then_ends_in_one_line(ros_processes, tmp_path):
    # There was no way to skip the check before publishing (a long bag known to be fine).
    _, probe = ros_processes
    received, replay = replayer(ros_processes, tmp_path, '/replay_no_verify')
    bag = copy_of_bag(tmp_path)
    damage_middle_chunk(bag, index=1)   # the first chunk's messages go out, no more
    code, output = replay(bag, 'replay_no_verify', '--no-verify')
    assert code == 1, output
    assert 'Traceback' not in output
    # Besides the error, only the --wait-for progress lines (INFO, as discovery goes).
    lines = [line for line in output.strip().splitlines()
             if not line.startswith('INFO gyro_ekf.cli.replay: --wait-for: ')]
    assert len(lines) == 1, output
    match = re.fullmatch(
        rf'gyro-ekf replay: error: {re.escape(str(bag))}: cannot read the bag '
        r'\(ReaderError\): .+ \(the replay stopped after (\d+) messages of this pass\); '
        r'every reliable reader acknowledged the (\d+) messages published before it', lines[0])
    assert match, lines[0]
    # Unchecked, the chunk before the damage went out, every message of it: the replay
    # waits for the readers' acknowledgements before it ends on the error (it used to end at
    # once, and a reader could miss the last few in flight).
    sent = int(match.group(1))
    assert sent > 0
    assert int(match.group(2)) == sent
    probe.spin_until(lambda: len(received) >= sent, 60, 'the unchecked replay')
    assert len(received) == sent


def test_a_bag_not_verified_is_opened_and_fails_where_it_is_damaged(tmp_path):
    bag = copy_of_bag(tmp_path)
    damage_middle_chunk(bag)
    with pytest.raises(GyroEkfError, match='CRC mismatch'):
        BagSource(bag, ['imu'], 0.0, None)
    source = BagSource(bag, ['imu'], 0.0, None, verify=False)
    sent = 0
    with pytest.raises(GyroEkfError) as raised:
        for _ in source():
            sent += 1
    assert sent > 0
    assert str(raised.value).endswith(f'(the replay stopped after {sent} messages of this '
                                      'pass)')
