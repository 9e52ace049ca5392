"""`gyro-ekf convert` and `gyro-ekf info` as a user runs them."""

from __future__ import annotations

import io
import re
import sys

import pytest
from synthetic_logs import write_2023

from gyro_ekf.cli.convert import _progress_bar, parse_start_time
from gyro_ekf.cli.main import main
from gyro_ekf.io.bag_reader import read_bag


def test_start_time_forms():
    assert parse_start_time('1700000000') == 1_700_000_000 * 10**9
    assert parse_start_time('1700000000.000000001') == 1_700_000_000 * 10**9 + 1
    assert parse_start_time('2023-11-14T22:13:20Z') == 1_700_000_000 * 10**9
    assert parse_start_time('2023-11-14T23:13:20.5+01:00') == 1_700_000_000_500_000_000


def test_convert_then_info(tmp_path, capsys):
    source = write_2023(tmp_path / 'log' / 'DataUsr_006k.mat')
    out = tmp_path / 'bag'
    assert main(['convert', str(source.parent), '-o', str(out), '--storage', 'sqlite3',
                 '--start-time', '2024-01-02T03:04:05Z']) == 0
    assert capsys.readouterr().out == ''  # convert's product is the bag, not stdout
    back = read_bag(out)
    assert back.start_time_ns == parse_start_time('2024-01-02T03:04:05Z')
    assert main(['info', str(out)]) == 0
    text = capsys.readouterr().out
    assert 'storage:   sqlite3 (rosbag2 metadata version 9)' in text
    assert 'start:     2024-01-02T03:04:05.000000000Z' in text
    duration = back.trip.end_s - back.trip.start_s
    assert f'duration:  {duration:.4f} s' in text
    rows = dict(re.findall(r'^\s+(/\S+)\s+\S+\s+(\d+)\s', text, re.M))
    assert rows == {'/landmark_map': '1', '/initialpose': '1', '/imu': '100', '/odom': '100',
                    '/scan': '8', '/scan2': '8', '/ground_truth': '8'}
    assert re.search(r'/landmark_map\s+geometry_msgs/msg/PoseArray\s+1\s+transient_local',
                     text)
    assert 'bag.params.yaml' in text
    assert 'bag.db3: not checked (sqlite3 storage carries no CRCs)' in text


def test_info_on_missing_bag(tmp_path, capsys):
    assert main(['info', str(tmp_path / 'nothing')]) == 1
    assert 'no such bag' in capsys.readouterr().err


class _FakeTerminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_progress_bar_only_on_a_terminal(monkeypatch):
    monkeypatch.setattr(sys, 'stderr', io.StringIO())
    assert _progress_bar() == (None, None)
    pytest.importorskip('tqdm')
    terminal = _FakeTerminal()
    monkeypatch.setattr(sys, 'stderr', terminal)
    update, bar = _progress_bar()
    update(5, 10)
    bar.close()
    assert '50%' in terminal.getvalue()
