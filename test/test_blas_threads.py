"""The CLI and the node executables run numpy on one BLAS thread unless told otherwise."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

NAMES = ('OMP_NUM_THREADS', 'OPENBLAS_NUM_THREADS', 'MKL_NUM_THREADS')


def _threads_after_import(module, **env):
    clean = {k: v for k, v in os.environ.items() if k not in NAMES}
    code = (f'import {module}, os, numpy; '
            f'print(" ".join(os.environ[n] for n in {NAMES!r}))')
    out = subprocess.run([sys.executable, '-c', code], env={**clean, **env},
                         capture_output=True, text=True, check=True)
    return out.stdout.split()


@pytest.mark.parametrize('module', ['gyro_ekf.cli.main', 'gyro_ekf.nodes'])
def test_one_blas_thread_by_default_and_the_callers_setting_wins(module):
    assert _threads_after_import(module) == ['1', '1', '1']
    assert _threads_after_import(module, OPENBLAS_NUM_THREADS='2') == ['1', '2', '1']


def test_the_core_leaves_a_users_threading_alone():
    clean = {k: v for k, v in os.environ.items() if k not in NAMES}
    code = 'import gyro_ekf.core.events, os; print(os.environ.get("OPENBLAS_NUM_THREADS"))'
    out = subprocess.run([sys.executable, '-c', code], env=clean, capture_output=True,
                         text=True, check=True)
    assert out.stdout.strip() == 'None'
