"""The package builds and tests itself as an ament_python package with colcon."""

from __future__ import annotations

import configparser
from importlib import metadata
import re
import shutil
import subprocess
import sys
from pathlib import Path

from packaging.requirements import Requirement
import pytest

REPO = Path(__file__).resolve().parent.parent
NODES = ('calibration_node', 'landmark_detector_node', 'ekf_node')
SKIP_DIRS = {'.venv', '.git', 'build', 'install', 'log', 'results', '.ros', '__pycache__',
             '.pytest_cache'}


def _colcon() -> str:
    colcon = Path(sys.executable).with_name('colcon')
    if not colcon.exists():
        found = shutil.which('colcon')
        assert found, 'colcon is not installed (pip install .[test] brings it)'
        return found
    return str(colcon)


@pytest.fixture(scope='module')
def workspace(tmp_path_factory):
    """A colcon workspace with a copy of this package, built once."""
    root = tmp_path_factory.mktemp('ws')
    shutil.copytree(REPO, root / 'src' / 'gyro_ekf',
                    ignore=lambda _dir, names: [n for n in names if n in SKIP_DIRS])
    result = subprocess.run([_colcon(), 'build', '--event-handlers', 'console_direct-'],
                            cwd=root, capture_output=True, text=True, timeout=900)
    assert result.returncode == 0, result.stdout + result.stderr
    return root


def test_colcon_build_installs_the_ros_layout(workspace):
    prefix = workspace / 'install' / 'gyro_ekf'
    for executable in NODES + ('gyro-ekf',):
        path = prefix / 'lib' / 'gyro_ekf' / executable
        assert path.is_file(), f'{path} missing: `ros2 run gyro_ekf {executable}` would fail'
        assert path.stat().st_mode & 0o111
    share = prefix / 'share'
    assert (share / 'ament_index' / 'resource_index' / 'packages' / 'gyro_ekf').is_file()
    assert (share / 'gyro_ekf' / 'package.xml').is_file()
    assert list((share / 'gyro_ekf' / 'config').glob('*.yaml')), 'config/*.yaml not installed'
    # The nodes' Fast DDS writer profile (nodes/runtime.py) is package data.
    assert list(prefix.glob('lib/python*/site-packages/gyro_ekf/nodes/fastdds_writer.xml')), \
        'gyro_ekf/nodes/fastdds_writer.xml not installed'


def test_colcon_test_runs_the_package_tests(workspace):
    result = subprocess.run(
        [_colcon(), 'test', '--event-handlers', 'console_direct-', '--pytest-args',
         '-q', 'test/core/test_models.py'],
        cwd=workspace, capture_output=True, text=True, timeout=900)
    assert result.returncode == 0, result.stdout + result.stderr
    summary = subprocess.run([_colcon(), 'test-result', '--all'], cwd=workspace,
                             capture_output=True, text=True, timeout=60)
    match = re.search(r'Summary: (\d+) tests, (\d+) errors, (\d+) failures', summary.stdout)
    assert match, summary.stdout + summary.stderr
    tests, errors, failures = map(int, match.groups())
    assert tests > 10 and errors == 0 and failures == 0, summary.stdout


def test_the_built_package_states_its_extras(workspace):
    # The metadata colcon installed, as pip and importlib read it.
    found = list((workspace / 'install' / 'gyro_ekf' / 'lib').glob(
        'python*/site-packages/gyro_ekf*.*-info'))
    assert len(found) == 1, found
    built = metadata.Distribution.at(found[0])
    assert set(built.metadata.get_all('Provides-Extra')) >= {'ros', 'test', 'bench'}
    requires = [Requirement(text) for text in built.requires]
    extra_of = {r.name: str(r.marker) if r.marker else '' for r in requires}
    assert extra_of['pytest'] == 'extra == "test"'
    assert extra_of['ros-jazzy-rclpy'] == 'extra == "ros"'
    assert extra_of['numpy'] == ''


def test_setup_cfg_puts_scripts_where_ros2_run_looks():
    # `colcon build` installs through [install], `--symlink-install` develops through
    # [develop]; the first is exercised by test_colcon_build_installs_the_ros_layout.
    config = configparser.ConfigParser(interpolation=None)
    config.read(REPO / 'setup.cfg')
    assert config['install']['install_scripts'] == '$base/lib/gyro_ekf'
    assert config['develop']['script_dir'] == '$base/lib/gyro_ekf'


def test_core_imports_no_ros_and_no_file_io_libraries():
    code = ('import sys, gyro_ekf.core.events, gyro_ekf.core.calibration, '
            'gyro_ekf.core.trip_run, gyro_ekf.core.stream_order, gyro_ekf.core.stamps, '
            'gyro_ekf.core.simulator; '
            "bad = [m for m in ('rclpy', 'rosbags', 'scipy', 'matplotlib') if m in sys.modules]; "
            'print(bad); sys.exit(1 if bad else 0)')
    result = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                            timeout=60)
    assert result.returncode == 0, result.stdout + result.stderr
