"""A plain `pip install .` (no extras) in a fresh venv runs `gyro-ekf run` on a bundled bag.

This catches an import that only a development install satisfies (an extra's package, or a
module reached through another dependency). The wheels come from a cache beside the test
environment, filled once with `pip download` (pip's own configuration and cache apply) and
used with --no-index after that, so repeated runs need no network. Where the cache cannot be
filled the test is skipped, except under CI, where it fails.
"""

from __future__ import annotations

import fcntl
import json
import os
from pathlib import Path
import subprocess
import sys
import venv

import numpy as np
import pytest

from test_dependencies import setup_keywords

REPO = Path(__file__).resolve().parent.parent
BAG = REPO / 'bags' / 'sim_static_start'
# Generous: a loaded 2-core machine unpacks numpy, scipy and matplotlib slowly.
PIP_TIMEOUT_S = 900

pytestmark = pytest.mark.clean_install


def _wheel_cache(tmp_path_factory) -> Path:
    """Beside the venv running the tests (it goes when the venv goes); tmp elsewhere."""
    if sys.prefix != sys.base_prefix and os.access(sys.prefix, os.W_OK):
        cache = Path(sys.prefix) / 'gyro_ekf-clean-install-wheels'
        cache.mkdir(exist_ok=True)
        return cache
    return tmp_path_factory.mktemp('wheels')


def _pip(python: Path, *args: str, env: dict[str, str]) -> subprocess.CompletedProcess:
    return subprocess.run([str(python), '-m', 'pip', *args], capture_output=True, text=True,
                          timeout=PIP_TIMEOUT_S, env=env)


def _clean_env(**extra: str) -> dict[str, str]:
    """This environment without anything that would let the test venv's packages in."""
    env = {k: v for k, v in os.environ.items()
           if k not in ('PYTHONPATH', 'PYTHONHOME', 'VIRTUAL_ENV', 'PIP_REQUIRE_VIRTUALENV')}
    env.update(extra)
    return env


@pytest.fixture(scope='module')
def clean_venv(tmp_path_factory) -> Path:
    """A venv with `pip install .` and no extras; returns its bin directory."""
    cache = _wheel_cache(tmp_path_factory)
    root = tmp_path_factory.mktemp('clean')
    venv.create(root / 'venv', with_pip=True, symlinks=True)
    python = root / 'venv' / 'bin' / 'python'
    env = _clean_env(PIP_DISABLE_PIP_VERSION_CHECK='1')
    requirements = root / 'requirements.txt'
    # What `pip install .` needs: the runtime requirements and the build backend.
    requirements.write_text('\n'.join([*setup_keywords()['install_requires'],
                                       'setuptools', 'wheel']) + '\n')
    offline = ('--no-index', '--find-links', str(cache))
    # One filler at a time: concurrent suites share the cache.
    with open(cache / '.lock', 'w') as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        ready = _pip(python, 'download', '-q', *offline, '-d', str(cache), '-r',
                     str(requirements), env=env)
        if ready.returncode != 0:
            filled = _pip(python, 'download', '-q', '-d', str(cache), '-r', str(requirements),
                          env=env)
            if filled.returncode != 0:
                message = f'cannot fill the wheel cache {cache}:\n{filled.stderr[-2000:]}'
                if os.environ.get('CI'):
                    pytest.fail(message)
                pytest.skip(message)
    installed = _pip(python, 'install', '-q', *offline, str(REPO), env=env)
    assert installed.returncode == 0, installed.stdout + installed.stderr
    return root / 'venv' / 'bin'


def test_the_clean_install_has_no_extras(clean_venv):
    code = ('import importlib.util as u; '
            'print([m for m in ("rclpy", "mcap", "filterpy", "pytest") if u.find_spec(m)])')
    result = subprocess.run([str(clean_venv / 'python'), '-c', code], capture_output=True,
                            text=True, timeout=120, env=_clean_env(), cwd=clean_venv)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == '[]'


def test_gyro_ekf_run_works_from_a_plain_pip_install(clean_venv, tmp_path):
    out = tmp_path / 'out'
    # cwd outside the checkout, so the installed copy is what runs.
    result = subprocess.run([str(clean_venv / 'gyro-ekf'), 'run', str(BAG), '-o', str(out),
                             '--no-plots'], capture_output=True, text=True,
                            timeout=PIP_TIMEOUT_S, env=_clean_env(MPLBACKEND='Agg'),
                            cwd=tmp_path)
    output = result.stdout + result.stderr
    assert result.returncode == 0, output
    summary = json.loads((out / 'summary.json').read_text())
    assert abs(summary['ground_truth']['bias_error_final_deg_s']) <= 0.02
    # The same estimates as the development install gives.
    dev = tmp_path / 'dev'
    reference = subprocess.run([sys.executable, '-m', 'gyro_ekf.cli.main', 'run', str(BAG),
                                '-o', str(dev), '--no-plots'], capture_output=True, text=True,
                               timeout=PIP_TIMEOUT_S, cwd=REPO)
    assert reference.returncode == 0, reference.stdout + reference.stderr
    ours, theirs = (np.loadtxt(d / 'estimates.csv', delimiter=',', skiprows=1)
                    for d in (out, dev))
    assert ours.shape == theirs.shape
    assert np.abs(ours - theirs).max() < 1e-9
