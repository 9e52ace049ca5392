"""Style checks in the ament spirit: flake8 (99 columns) and pep257 docstrings."""

import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
SOURCES = [str(REPO / 'gyro_ekf'), str(REPO / 'benchmarks'), str(REPO / 'test'),
           str(REPO / 'setup.py')]
# ament_pep257's default ignores: presence of docstrings is not enforced, their form is.
PEP257_IGNORE = 'D100,D101,D102,D103,D104,D105,D106,D107,D203,D212,D404'


@pytest.mark.linter
def test_flake8():
    result = subprocess.run([sys.executable, '-m', 'flake8', '--max-line-length=99',
                             *SOURCES], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stdout + result.stderr


@pytest.mark.linter
def test_pep257():
    result = subprocess.run([sys.executable, '-m', 'pydocstyle', '--convention=pep257',
                             f'--add-ignore={PEP257_IGNORE}',
                             str(REPO / 'gyro_ekf')], capture_output=True, text=True,
                            timeout=120)
    assert result.returncode == 0, result.stdout + result.stderr
