"""`gyro-ekf demo` end to end, as `make demo` runs it: the README's first command.

Until this test, nothing ran the demo whole: a change to the recorder's idle rule once made
`make demo` end with "ekf_node published no bias ... no pose" while every test passed (only
the README check found it). Here the demo runs in its own process on the bundled bag, in a
domain claimed for this test (loopback discovery), and its own verdict, exit code and
products are checked. The demo's checks are of accuracy and completeness, none of speed:
a slow machine makes it take longer, not fail.
"""

from __future__ import annotations

import json
from pathlib import Path
import subprocess
import sys

import pytest

pytest.importorskip('rclpy')

from gyro_ekf.cli.demo import BIAS_LIMIT_DEG_S, POSITION_LIMIT_M  # noqa: E402
from gyro_ekf.io.bag_reader import iter_bag_messages  # noqa: E402

pytestmark = pytest.mark.ros

REPO = Path(__file__).resolve().parents[2]
DEMO_BAG = REPO / 'bags' / 'sim_static_start'
"""The Makefile's DEMO_BAG."""

# Far beyond what the demo takes on a loaded 2-core machine: a bound on a hang, not a pace.
TIMEOUT_S = 1200.0


def _demo(output: Path, env: dict[str, str], *extra: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, '-m', 'gyro_ekf.cli.main', 'demo', str(DEMO_BAG), '-o', str(output),
         '--timeout-s', str(TIMEOUT_S), *extra],
        env=env, capture_output=True, text=True, timeout=TIMEOUT_S + 120.0, check=False)


def test_the_demo_on_the_bundled_bag_says_ok_and_writes_its_products(tmp_path, ros_env):
    output = tmp_path / 'demo'
    done = _demo(output, ros_env)
    detail = f'exit {done.returncode}\nstdout:\n{done.stdout}\nstderr:\n{done.stderr}'
    assert done.returncode == 0, detail
    assert done.stdout.strip().splitlines()[-1].startswith('verdict: OK'), detail
    assert 'Traceback' not in done.stderr, detail

    summary = json.loads((output / 'summary.json').read_text())
    assert summary['verdict'] == {'ok': True, 'problems': [],
                                  'bias_limit_deg_s': BIAS_LIMIT_DEG_S,
                                  'position_limit_m': POSITION_LIMIT_M}
    # Every figure the verdict judges is there (a missing one is a problem of its own, but
    # say which) and the node's health verdict is its own, not a default.
    for key in ('offline_bias_deg_s', 'calibration_node_bias_deg_s', 'online_bias_deg_s',
                'true_bias_deg_s', 'final_position_error_m'):
        assert summary.get(key) is not None, key
    assert summary['ekf_resets'] == 0
    assert summary['ekf_verdict'] == 'ok', summary.get('ekf_verdict_reasons')
    # The calibration node and the offline calibration are one core function on one static
    # window: the same bias, to the printed digit and far below.
    assert summary['calibration_node_bias_deg_s'] == pytest.approx(
        summary['offline_bias_deg_s'], abs=1e-6)
    assert 'all acknowledged: True' in summary['replay']

    # The recorded bag reads back and holds the node outputs the summary was made from.
    topics = {}
    for message in iter_bag_messages(output / 'bag'):
        topics[message.topic] = topics.get(message.topic, 0) + 1
    assert {'/gyro_bias', '/ekf/pose', '/ekf/bias', '/diagnostics'} <= set(topics), topics
    assert (output / 'trajectory.png').stat().st_size > 0

    # A second demo into the same folder replaces the first one's products (make demo runs
    # with --force); without --force the folder is refused, the products left as they are.
    before = (output / 'summary.json').read_bytes()
    refused = _demo(output, ros_env)
    assert refused.returncode == 1, refused.stderr
    assert refused.stderr.strip().splitlines()[-1].startswith('gyro-ekf demo: error: ')
    assert 'Traceback' not in refused.stderr
    assert (output / 'summary.json').read_bytes() == before
    # One that fails (its replay given a second) leaves no summary: not the first one's OK.
    failed = _demo(output, ros_env, '--force', '--timeout-s', '1')
    assert failed.returncode == 1, failed.stderr
    assert 'did not finish within 1' in failed.stderr, failed.stderr
    assert not (output / 'summary.json').exists()
    assert not (output / 'trajectory.png').exists()
