"""ekf_node says when its own gate starved it, in /diagnostics, as `gyro-ekf run` does.

The bag is a simulated 30-s trip (the stress suite's base config, seed 370004) whose gyro
bias steps by -0.48 deg/s at 8.6 s, as the platform sets off: most detections soon lie
beside their poles, outside the gate, and the filter is re-associated by map distance
(core/gate_starved.py). The node counts it as the offline run does and gives the same
verdict.

In its own module, so its processes run in their own ROS domain next to nobody else's.
"""

from __future__ import annotations

import dataclasses
import math

import pytest

from ekf_harness import run_and_replay

pytestmark = pytest.mark.ros


@pytest.fixture(scope='module')
def step_run(ros_processes, tmp_path_factory):
    """The bag through the detector and EKF nodes, and through `gyro-ekf run`."""
    from gyro_ekf.analysis.stress import base_config
    from gyro_ekf.core.simulator import simulate_trip

    config = dataclasses.replace(base_config(30.0), gyro_bias_step_rad_s=math.radians(-0.48),
                                 gyro_bias_step_at_s=8.6)
    return run_and_replay(ros_processes, simulate_trip(config, 370004),
                          tmp_path_factory.mktemp('gate_starved'))


def test_node_says_its_gate_starved_it_as_the_offline_run_does(step_run):
    offline, (_, _, values), replay = step_run
    assert 'all acknowledged: True' in replay
    association = offline['association']
    assert association['gate_starved'] >= 1
    assert association['recoveries'] >= association['gate_starved']
    said = [r for r in offline['health']['reasons'] if 'ran off its covariance' in r]
    assert len(said) == 1, offline['health']['reasons']
    assert values['gate_starved'] == str(association['gate_starved'])
    assert values['verdict'] == 'degraded'
    assert values['verdict_reasons'].split(' | ') == offline['health']['reasons']
