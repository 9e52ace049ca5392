"""Shared fixtures: course logs from ../shared/data and a loopback-only ROS environment."""

from __future__ import annotations

import itertools
import os
from pathlib import Path

import pytest

REPO_ROOT = Path(__file__).resolve().parent.parent
SHARED_DATA = REPO_ROOT.parent / 'shared' / 'data' / 'mtrn4010'

# Loopback-only discovery for everything this test process starts, before any rclpy import.
os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
os.environ.setdefault('ROS_DOMAIN_ID', '42')
os.environ.setdefault('MPLBACKEND', 'Agg')

_domain_ids = itertools.count(100 + (os.getpid() % 50) * 2)


def _shared(relative: str) -> Path:
    path = SHARED_DATA / relative
    if not path.exists():
        message = f'course log {path} is missing (../shared/data must sit beside the repo)'
        if os.environ.get('CI'):
            pytest.fail(message)
        pytest.skip(message)
    return path


@pytest.fixture(scope='session')
def shared_data():
    """Return a function mapping a path under ../shared/data/mtrn4010 to an existing Path.

    Missing data fails the test when CI is set and skips it elsewhere.
    """
    return _shared


@pytest.fixture
def ros_env(tmp_path, monkeypatch):
    """Environment for a test that starts rclpy nodes: loopback, own domain, own log dir.

    Returns the environment dict to hand to subprocesses; it is also applied to this
    process (before rclpy.init) through monkeypatch.
    """
    domain_id = str(next(_domain_ids) % 200)
    log_dir = tmp_path / 'ros_log'
    log_dir.mkdir()
    values = {
        'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST',
        'ROS_DOMAIN_ID': domain_id,
        'ROS_LOG_DIR': str(log_dir),
        'PYTHONUNBUFFERED': '1',
    }
    for key, value in values.items():
        monkeypatch.setenv(key, value)
    return dict(os.environ)
