"""Shared fixtures: course logs from ../shared/data and a loopback-only ROS environment."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from gyro_ekf.ros_env import claim_domain, ros_env_values

REPO_ROOT = Path(__file__).resolve().parent.parent
SHARED_DATA = REPO_ROOT.parent / 'shared' / 'data' / 'mtrn4010'

# Loopback-only discovery in a domain of this session alone for anything this test process
# starts without a fixture, before any rclpy import (not 42: `make demo` and a concurrent
# `make test` use that). The claim lasts until this process exits.
_SESSION_DOMAIN = claim_domain()
os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
os.environ['ROS_DOMAIN_ID'] = str(_SESSION_DOMAIN.domain_id)
os.environ.setdefault('MPLBACKEND', 'Agg')


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

    The domain is claimed for this test alone (gyro_ekf.ros_env: no other test or run on
    this machine uses it meanwhile). Returns the environment dict to hand to subprocesses;
    it is also applied to this process (before rclpy.init) through monkeypatch.
    """
    log_dir = tmp_path / 'ros_log'
    log_dir.mkdir()
    with claim_domain() as lease:
        for key, value in ros_env_values(lease.domain_id, log_dir).items():
            monkeypatch.setenv(key, value)
        yield dict(os.environ)
