"""DDS domains for tests and benchmarks: never shared by two runs on one machine at a time."""

from __future__ import annotations

import os
from pathlib import Path
import signal
import socket
import subprocess
import sys
import time

import pytest

import gyro_ekf.ros_env as domains

HOLDER = ('import sys; from gyro_ekf.ros_env import claim_domain; '
          'lease = claim_domain(); print(lease.domain_id, flush=True); sys.stdin.read()')


@pytest.fixture
def holder():
    """Another process (another test run) holding a domain until it is killed."""
    process = subprocess.Popen([sys.executable, '-c', HOLDER], stdin=subprocess.PIPE,
                               stdout=subprocess.PIPE, text=True)
    try:
        line = process.stdout.readline()
        assert line.strip().isdigit(), f'the holder printed {line!r}'
        yield process, int(line)
    finally:
        if process.poll() is None:
            process.kill()
        process.wait()


def test_a_domain_held_by_another_process_is_not_handed_out(holder, monkeypatch):
    process, domain = holder
    assert domains.try_claim(domain) is None
    # Even when it is the only candidate left.
    monkeypatch.setattr(domains, 'DOMAIN_IDS', (domain,))
    with pytest.raises(domains.DomainUnavailableError, match='no free ROS domain'):
        domains.claim_domain()
    # A killed holder leaves no stale claim behind: the kernel drops its lock.
    process.send_signal(signal.SIGKILL)
    process.wait()
    with domains.claim_domain() as lease:
        assert lease.domain_id == domain


def test_claims_of_one_process_differ_and_are_given_back():
    with domains.claim_domain() as first, domains.claim_domain() as second:
        assert first.domain_id != second.domain_id
        for lease in (first, second):
            assert lease.domain_id in domains.DOMAIN_IDS
            assert lease.domain_id not in (0, 42)
            assert domains.try_claim(lease.domain_id) is None
        domain = first.domain_id
    again = domains.try_claim(domain)
    assert again is not None  # given back on leaving the with block
    again.release()


def test_a_domain_with_dds_ports_bound_is_passed_over(monkeypatch):
    with domains.claim_domain() as lease:
        domain = lease.domain_id
        # A participant started without a lock (by hand, or by an older checkout) binds
        # ports in its domain's block of 250: here its first unicast discovery port. (Not
        # the block's end: the block of domain 232, the last, ends past port 65535, and a
        # second suite running beside this one can leave this test that domain.)
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as bound:
            bound.bind(('127.0.0.1', 7400 + 250 * domain + 10))
            assert domains.domain_ports_in_use(domain)
            lease.release()
            monkeypatch.setattr(domains, 'DOMAIN_IDS', (domain,))
            with pytest.raises(domains.DomainUnavailableError):
                domains.claim_domain()


def test_the_environment_keeps_discovery_on_this_machine(tmp_path):
    values = domains.ros_env_values(17, tmp_path / 'log')
    assert values['ROS_AUTOMATIC_DISCOVERY_RANGE'] == 'LOCALHOST'
    assert values['ROS_DOMAIN_ID'] == '17'
    assert values['ROS_LOG_DIR'] == str(tmp_path / 'log')


def test_fixtures_run_in_a_claimed_domain(ros_env):
    # The fixture's claim is held for the test: nobody else can take the domain meanwhile.
    assert ros_env['ROS_AUTOMATIC_DISCOVERY_RANGE'] == 'LOCALHOST'
    assert domains.try_claim(int(ros_env['ROS_DOMAIN_ID'])) is None


def test_a_child_env_is_private_and_runs_this_package(tmp_path):
    env = domains.child_env(17, tmp_path / 'log', base={'PYTHONPATH': '/elsewhere',
                                                        'ROS_DOMAIN_ID': '0'})
    assert env['ROS_AUTOMATIC_DISCOVERY_RANGE'] == 'LOCALHOST'
    assert env['ROS_DOMAIN_ID'] == '17'
    package_root = Path(domains.__file__).resolve().parents[1]
    assert env['PYTHONPATH'].split(os.pathsep) == [str(package_root), '/elsewhere']


CHILD = '''import signal, sys, time
if sys.argv[1:] == ['stubborn']:
    signal.signal(signal.SIGINT, signal.SIG_IGN)
print('ready', flush=True)
try:
    while True:
        time.sleep(0.05)
except KeyboardInterrupt:
    print('stopped on SIGINT', flush=True)
'''


def _wait_for_line(processes, name, line, timeout_s=30.0):
    deadline = time.monotonic() + timeout_s
    while line not in processes.log(name):
        assert time.monotonic() < deadline, f'{name} never printed {line!r}'
        time.sleep(0.01)


def test_children_stop_on_sigint_and_the_stubborn_one_is_killed(tmp_path):
    (tmp_path / 'child_module.py').write_text(CHILD)
    processes = domains.ChildProcesses(domains.child_env(17, tmp_path / 'log'), tmp_path,
                                       cwd=tmp_path)
    polite = processes.start('polite', 'child_module')
    stubborn = processes.start('stubborn', 'child_module', 'stubborn')
    for name in ('polite', 'stubborn'):
        _wait_for_line(processes, name, 'ready')
    killed = []
    processes.stop_all(timeout_s=1.0, on_kill=killed.append)
    assert polite.returncode == 0
    assert 'stopped on SIGINT' in processes.log('polite')
    assert killed == ['stubborn'] and stubborn.returncode == -signal.SIGKILL
