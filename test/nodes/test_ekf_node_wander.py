"""ekf_node says a gyro wander it found in /diagnostics, as `gyro-ekf run` does in summary.json.

The bag is `make stress` seed 7, coloured_gyro trip 8: a Gauss-Markov wander of 0.036 deg/s
over 3.3 s on the yaw rate. Its bias watch sees no drift and its noise stays as stated, so
the wander found is the one thing that says the gyro is not as configured (before it was
a reason the trip ended 0.023 deg/s off with verdict ok: a silent failure).

In its own module, so its processes run in their own ROS domain next to nobody else's.
"""

from __future__ import annotations

import re

import pytest

from ekf_harness import run_and_replay

pytestmark = pytest.mark.ros

WANDERS = 'the gyro wanders: a yaw-rate error that reverts over about 2 s, sigma '


@pytest.fixture(scope='module')
def coloured_run(ros_processes, tmp_path_factory):
    """The bag through the detector and EKF nodes, and through `gyro-ekf run`."""
    from gyro_ekf.analysis.stress import stress_trip

    return run_and_replay(ros_processes, stress_trip('coloured_gyro', 7, 8),
                          tmp_path_factory.mktemp('wander'))


def test_node_says_the_wander_it_found_as_the_offline_run_does(coloured_run):
    from diagnostic_msgs.msg import DiagnosticStatus

    offline, (level, message, values), replay = coloured_run
    assert 'all acknowledged: True' in replay
    found = offline['online_bias']['gyro_wander_deg_s']
    assert found > 0.0
    assert offline['health']['verdict'] == 'degraded'
    assert any(r.startswith(WANDERS) for r in offline['health']['reasons'])
    # The node found it too, in the same data, and says so.
    node_found = float(values['gyro_wander_deg_s'])
    print(f'wander found: node {node_found:.4f}, offline {found:.4f} deg/s; node reasons: '
          f'{values["verdict_reasons"]}')
    assert node_found > 0.0
    # Re-openings where the modelled wander held one sign, as the offline run counts them.
    assert values['bias_reopened_wander_held'] == str(
        offline['online_bias']['reopened_wander_held'])
    # A wander a still stop showed (core/stop_wander.py), as the offline run has it.
    online = offline['online_bias']
    assert values['gyro_wander_stop_deg_s'] == f"{online['gyro_wander_stop_deg_s']:.4f}"
    assert values['gyro_wander_stop_ruled_out'] == str(
        online['gyro_wander_stop_ruled_out_s'] is not None).lower()
    assert values['verdict'] == 'degraded'
    assert level == DiagnosticStatus.WARN
    reasons = values['verdict_reasons'].split(' | ')
    # The reason's sigma (3 decimals) is the one in /diagnostics' figure (4 decimals): both
    # round the same value, so they agree to the coarser rounding.
    said = [float(m.group(1)) for m in (
        re.match(re.escape(WANDERS) + r'(\d+\.\d+) deg/s, none configured, found at ', r)
        for r in reasons) if m]
    assert len(said) == 1 and abs(said[0] - node_found) <= 0.00051, reasons
    assert message.startswith('degraded: ')
